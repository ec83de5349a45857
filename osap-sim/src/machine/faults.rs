//! Fault injection on a simulated machine: cut and restore a link, corrupt
//! a link's bytes at a rate, reset a module (a power cycle), freeze a
//! module's main loop.
//!
//! Faults are applied where the real ones happen. A cut link goes down at
//! both ends, as a pulled cable does. Corrupted bytes are flipped in the
//! frame the real framing code built (COBS and CRC-16, as on a UART), and
//! the receiving end decodes it with the real decoder: a frame that fails
//! is dropped and counted as a frame error on the receiving link, exactly
//! as a firmware's link would count it. A frozen module stops polling its
//! runtime (no packets in or out, nothing answered) while its step
//! generator keeps running from what is queued, as a firmware's step
//! interrupt does when its main loop hangs.
//!
//! [`Fault`] parses from a line of text (`cut hub-a`, `corrupt hub-a 1e-4`,
//! `reset a`, `freeze b`, `thaw b`, `restore hub-a`), which is what
//! `osap serve --sim --control` reads from its standard input.

use osap_core::framing::{encode_frame, max_frame_len, FrameDecoder};
use std::fmt;
use std::str::FromStr;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use crate::rng::Rng;

/// Largest packet any simulated link carries (the host's MTU).
const MAX_PACKET: usize = 2048;

/// One fault to inject, or to lift.
#[derive(Debug, Clone, PartialEq)]
pub enum Fault {
    /// Takes a link down at both ends until [`Fault::Restore`].
    Cut(String),
    /// Brings a cut link back (if both its ends are running).
    Restore(String),
    /// Flips each byte on the link (both directions) with this probability.
    /// 0 stops corrupting.
    Corrupt {
        /// The link.
        link: String,
        /// Probability that a byte has one bit flipped, `[0, 1]`.
        per_byte: f64,
    },
    /// Power-cycles a module: it stops, then boots afresh.
    Reset(String),
    /// Stops a module's main loop: its runtime is not polled (packets pile
    /// up and are dropped, nothing is answered) while its steps run on.
    Freeze(String),
    /// Lets a frozen module's loop run again.
    Thaw(String),
}

/// A line that is not a [`Fault`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FaultParseError(pub String);

impl fmt::Display for FaultParseError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}; expected one of: cut LINK, restore LINK, corrupt LINK RATE, reset MODULE, \
             freeze MODULE, thaw MODULE (LINK is its index or its ends, e.g. hub-a)",
            self.0
        )
    }
}

impl std::error::Error for FaultParseError {}

impl FromStr for Fault {
    type Err = FaultParseError;

    fn from_str(line: &str) -> Result<Fault, FaultParseError> {
        let words: Vec<&str> = line.split_whitespace().collect();
        let err = |m: &str| Err(FaultParseError(m.to_string()));
        match words.as_slice() {
            ["cut", link] => Ok(Fault::Cut(link.to_string())),
            ["restore", link] => Ok(Fault::Restore(link.to_string())),
            ["corrupt", link, rate] => match rate.parse::<f64>() {
                Ok(p) if (0.0..=1.0).contains(&p) => Ok(Fault::Corrupt {
                    link: link.to_string(),
                    per_byte: p,
                }),
                _ => err(&format!(
                    "corrupt: rate {rate:?} is not a probability in [0, 1]"
                )),
            },
            ["reset", module] => Ok(Fault::Reset(module.to_string())),
            ["freeze", module] => Ok(Fault::Freeze(module.to_string())),
            ["thaw", module] => Ok(Fault::Thaw(module.to_string())),
            [] => err("empty line"),
            [word, ..] => err(&format!(
                "unknown fault command {word:?} (or wrong arguments)"
            )),
        }
    }
}

impl fmt::Display for Fault {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Fault::Cut(l) => write!(f, "cut {l}"),
            Fault::Restore(l) => write!(f, "restore {l}"),
            Fault::Corrupt { link, per_byte } => write!(f, "corrupt {link} {per_byte}"),
            Fault::Reset(m) => write!(f, "reset {m}"),
            Fault::Freeze(m) => write!(f, "freeze {m}"),
            Fault::Thaw(m) => write!(f, "thaw {m}"),
        }
    }
}

/// What injected corruption did on one link, both directions together.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CorruptionStats {
    /// Frames that had at least one byte flipped.
    pub corrupted: u64,
    /// Of those, frames the receiver's framing rejected (each counted there
    /// as a frame error; a flipped byte that forms a delimiter can make one
    /// frame two errors).
    pub rejected: u64,
    /// Frame errors the receivers counted for them, once they arrived (a
    /// frame still on the wire is not counted yet).
    pub frame_errors: u64,
    /// Corrupted frames lost with their link: it went down while they were
    /// on the wire, so no receiver saw them.
    pub lost_with_link: u64,
    /// Corrupted frames that passed the CRC and were delivered altered
    /// (expected about once in 65 536 corrupted frames).
    pub undetected: u64,
}

/// The faults a link carries on top of its model, shared with its carriers.
#[derive(Debug, Default)]
pub(crate) struct LinkFaults {
    pub(crate) cut: AtomicBool,
    /// f64 bits: the probability per byte.
    corrupt: AtomicU64,
    corrupted: AtomicU64,
    rejected: AtomicU64,
    frame_errors: AtomicU64,
    lost_with_link: AtomicU64,
    undetected: AtomicU64,
}

impl LinkFaults {
    pub(crate) fn set_corruption(&self, per_byte: f64) {
        self.corrupt.store(per_byte.to_bits(), Ordering::Relaxed);
    }

    pub(crate) fn corruption(&self) -> f64 {
        f64::from_bits(self.corrupt.load(Ordering::Relaxed))
    }

    pub(crate) fn stats(&self) -> CorruptionStats {
        CorruptionStats {
            corrupted: self.corrupted.load(Ordering::Relaxed),
            rejected: self.rejected.load(Ordering::Relaxed),
            frame_errors: self.frame_errors.load(Ordering::Relaxed),
            lost_with_link: self.lost_with_link.load(Ordering::Relaxed),
            undetected: self.undetected.load(Ordering::Relaxed),
        }
    }

    /// A corrupted frame's `frame_errors` reached the receiver (which counts
    /// them itself), or, if `arrived` is false, were lost with the link.
    pub(crate) fn landed(&self, frame_errors: u64, arrived: bool) {
        if arrived {
            self.frame_errors.fetch_add(frame_errors, Ordering::Relaxed);
        } else {
            self.lost_with_link.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Sends `packet` through the real framing with bytes flipped at the
    /// configured rate. Returns the packets the receiver's decoder yields
    /// and the frame errors it will count when the frame arrives (report
    /// that with [`landed`](Self::landed)).
    pub(crate) fn pass(&self, rng: &mut Rng, packet: Vec<u8>) -> (Vec<Vec<u8>>, u64) {
        let rate = self.corruption();
        if rate <= 0.0 || packet.len() > MAX_PACKET {
            return (vec![packet], 0);
        }
        let mut frame = vec![0u8; max_frame_len(packet.len())];
        let Ok(len) = encode_frame(&packet, &mut frame) else {
            return (vec![packet], 0);
        };
        frame.truncate(len);
        let mut flipped = false;
        for b in frame.iter_mut() {
            if rng.chance(rate) {
                *b ^= 1u8 << rng.below(8);
                flipped = true;
            }
        }
        if !flipped {
            return (vec![packet], 0);
        }
        // The receiver resynchronises on the idle line between frames: a
        // frame whose delimiter was flipped is discarded there, an error.
        let mut decoder = FrameDecoder::<{ max_frame_len(MAX_PACKET) }>::new();
        let mut input: &[u8] = &frame;
        let mut out = Vec::new();
        let mut errors = 0;
        while let Some(r) = decoder.decode(&mut input) {
            match r {
                Ok(p) => out.push(p.to_vec()),
                Err(_) => errors += 1,
            }
        }
        if frame.last().is_some_and(|&b| b != 0) {
            errors += 1;
        }
        self.corrupted.fetch_add(1, Ordering::Relaxed);
        if !out.contains(&packet) {
            self.rejected.fetch_add(1, Ordering::Relaxed);
        }
        if out.iter().any(|p| *p != packet) {
            self.undetected.fetch_add(1, Ordering::Relaxed);
        }
        (out, errors)
    }
}

/// Why a fault could not be injected.
#[derive(Debug)]
#[non_exhaustive]
pub enum FaultError {
    /// No link has this index, name or pair of ends.
    UnknownLink {
        /// What was asked for.
        link: String,
        /// The links there are, as `index: a-b`.
        known: Vec<String>,
    },
    /// More than one link joins these two ends: name it by index.
    AmbiguousLink(String),
    /// No module has this name.
    UnknownModule {
        /// What was asked for.
        module: String,
        /// The modules there are.
        known: Vec<String>,
    },
    /// The link has no wire model (a zero-latency or memory link): its ends
    /// share queues and no bytes cross it to corrupt.
    NoWire(String),
    /// Stopping or booting the module failed.
    Module(osap_host::HostError),
    /// The module has no outputs to read (a hub, or a module that is not
    /// running).
    NoOutputs(String),
}

impl fmt::Display for FaultError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FaultError::UnknownLink { link, known } => {
                write!(f, "no link {link:?}; the links are {}", known.join(", "))
            }
            FaultError::AmbiguousLink(l) => {
                write!(f, "more than one link joins {l:?}: give the link's index")
            }
            FaultError::UnknownModule { module, known } => write!(
                f,
                "no module {module:?}; the modules are {}",
                known.join(", ")
            ),
            FaultError::NoWire(l) => write!(
                f,
                "link {l:?} has no wire model (memory or zero-latency link): no bytes to corrupt"
            ),
            FaultError::Module(e) => write!(f, "module: {e}"),
            FaultError::NoOutputs(m) => write!(
                f,
                "module {m:?} has no outputs now (a hub has none; a module that is reset or in its bootloader has none until it runs)"
            ),
        }
    }
}

impl std::error::Error for FaultError {}

impl From<osap_host::HostError> for FaultError {
    fn from(e: osap_host::HostError) -> Self {
        FaultError::Module(e)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn faults_parse_and_print() {
        for line in [
            "cut hub-a",
            "restore 2",
            "corrupt hub-b 0.001",
            "reset a",
            "freeze b",
            "thaw b",
        ] {
            let f: Fault = line.parse().unwrap();
            assert_eq!(f.to_string(), line);
        }
        for bad in ["", "cut", "corrupt hub-a 2", "corrupt hub-a x", "explode a"] {
            let e = bad.parse::<Fault>().unwrap_err();
            assert!(e.to_string().contains("expected one of"), "{e}");
        }
    }

    #[test]
    fn corruption_is_caught_by_the_real_framing_and_counted() {
        let faults = LinkFaults::default();
        faults.set_corruption(0.01);
        let mut rng = Rng::stream(7, "faults-test", 0);
        let packet: Vec<u8> = (0..120u8).collect();
        let (mut delivered, mut errors) = (0u64, 0u64);
        for _ in 0..2_000 {
            let (out, e) = faults.pass(&mut rng, packet.clone());
            delivered += out.iter().filter(|p| **p == packet).count() as u64;
            if e > 0 {
                faults.landed(e, true);
            }
            errors += e;
        }
        let s = faults.stats();
        // About 1 - 0.99^123 = 71 % of frames are hit.
        assert!(s.corrupted > 1_200 && s.corrupted < 1_600, "{s:?}");
        // A flipped frame never yields the packet intact.
        assert_eq!(s.rejected, s.corrupted, "{s:?}");
        assert_eq!(s.rejected + delivered, 2_000, "{s:?}");
        assert_eq!(s.frame_errors, errors);
        assert!(s.frame_errors >= s.rejected, "{s:?}");
        assert!(s.undetected <= 1, "{s:?}");
        faults.set_corruption(0.0);
        let (out, e) = faults.pass(&mut rng, packet.clone());
        assert_eq!((out, e), (vec![packet], 0));
    }
}
