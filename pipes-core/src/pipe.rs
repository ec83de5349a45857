//! Pipes: where a function sends its outputs.
//!
//! A pipe names a destination (a [`Route`] with its MTU, a port at the end
//! of it, a time-to-live) and an **argmap**: which of the source function's
//! outputs go to which of the destination function's inputs. Each pipe sends
//! from its own port, so replies and error reports for it come back to it.
//!
//! Wire form of a pipe (the body of "set pipe" and of the "get pipe" reply):
//!
//! ```text
//! [route length: u8][route instructions][route MTU: u16][destination port: u16]
//! [ttl µs: u16][flags: u8][n: u8] n × ([output index: u8][input index: u8])
//! ```
//!
//! Flags: bit 0 asks for acknowledged delivery, every other bit must be 0.
//! This implementation sends best-effort only and refuses pipes that ask for
//! acknowledgements ([`ControlError::Unsupported`](crate::control::ControlError::Unsupported)).
//!
//! A pipe keeps a small queue of datagrams waiting for its port to be clear
//! to send ([`PipeState`]); when the queue is full the **oldest** waiting
//! datagram is dropped and counted, never silently.

use osap_core::codec::{Reader, Writer};
use osap_core::route::Route;

use crate::control::DecodeError;

/// The most output → input pairs in one pipe's argmap.
pub const MAX_ARGMAP: usize = 8;

/// The flag bit that asks for acknowledged delivery.
pub const FLAG_ACKED: u8 = 0x01;

/// How a pipe delivers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PipeDelivery {
    /// Send and forget; losses are the network's counters' business.
    #[default]
    BestEffort,
    /// Acknowledged delivery (declared on the wire; refused by this
    /// implementation, which does not do acknowledgements yet).
    Acked,
}

/// One argmap entry: the source's output `output` goes to the destination's
/// input `input`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ArgPair {
    /// The source function's output index.
    pub output: u8,
    /// The destination function's input index.
    pub input: u8,
}

/// Why a pipe could not be built.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PipeError {
    /// The argmap already holds [`MAX_ARGMAP`] pairs.
    ArgmapFull,
    /// Two pairs name the same destination input.
    DuplicateInput(u8),
}

impl core::fmt::Display for PipeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            PipeError::ArgmapFull => write!(f, "argmap holds at most {MAX_ARGMAP} pairs"),
            PipeError::DuplicateInput(i) => write!(f, "destination input {i} mapped twice"),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for PipeError {}

/// A pipe's configuration.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PipeConfig {
    /// The route to the destination runtime, with its MTU.
    pub route: Route,
    /// The destination function's control port in that runtime.
    pub port: u16,
    /// Time-to-live of each datagram, µs.
    pub ttl: u16,
    /// How it delivers.
    pub delivery: PipeDelivery,
    argmap: [ArgPair; MAX_ARGMAP],
    len: u8,
}

impl PipeConfig {
    /// A best-effort pipe to `port` at the end of `route`, with an empty argmap.
    pub const fn new(route: Route, port: u16, ttl: u16) -> PipeConfig {
        PipeConfig {
            route,
            port,
            ttl,
            delivery: PipeDelivery::BestEffort,
            argmap: [ArgPair {
                output: 0,
                input: 0,
            }; MAX_ARGMAP],
            len: 0,
        }
    }

    /// Adds an argmap pair.
    pub fn map(&mut self, output: u8, input: u8) -> Result<(), PipeError> {
        if self.argmap().iter().any(|p| p.input == input) {
            return Err(PipeError::DuplicateInput(input));
        }
        let slot = self
            .argmap
            .get_mut(usize::from(self.len))
            .ok_or(PipeError::ArgmapFull)?;
        *slot = ArgPair { output, input };
        self.len += 1;
        Ok(())
    }

    /// This pipe with one more argmap pair.
    pub fn with(mut self, output: u8, input: u8) -> Result<PipeConfig, PipeError> {
        self.map(output, input)?;
        Ok(self)
    }

    /// The same pipe asking for `delivery`.
    pub const fn with_delivery(mut self, delivery: PipeDelivery) -> PipeConfig {
        self.delivery = delivery;
        self
    }

    /// The argmap pairs, in order.
    pub fn argmap(&self) -> &[ArgPair] {
        self.argmap.get(..usize::from(self.len)).unwrap_or(&[])
    }

    /// How many bytes [`encode`](PipeConfig::encode) writes.
    pub fn encoded_len(&self) -> usize {
        1 + self.route.len() + 2 + 2 + 2 + 1 + 1 + 2 * usize::from(self.len)
    }

    /// Writes the pipe. On error nothing is written.
    pub fn encode(&self, w: &mut Writer<'_>) -> Result<(), DecodeError> {
        if self.encoded_len() > w.remaining() {
            return Err(DecodeError::NoSpace);
        }
        let r = self.route.as_bytes();
        let put = |w: &mut Writer<'_>| -> Result<(), osap_core::codec::CodecError> {
            // A route is at most MAX_ROUTE_LEN (32) bytes.
            w.u8(r.len() as u8)?;
            w.bytes(r)?;
            w.u16(self.route.mtu())?;
            w.u16(self.port)?;
            w.u16(self.ttl)?;
            w.u8(match self.delivery {
                PipeDelivery::BestEffort => 0,
                PipeDelivery::Acked => FLAG_ACKED,
            })?;
            w.u8(self.len)?;
            for p in self.argmap() {
                w.u8(p.output)?;
                w.u8(p.input)?;
            }
            Ok(())
        };
        put(w).map_err(|_| DecodeError::NoSpace)
    }

    /// Reads a pipe from `r`.
    pub fn decode(r: &mut Reader<'_>) -> Result<PipeConfig, DecodeError> {
        let n = usize::from(r.u8()?);
        let route = Route::from_bytes(r.bytes(n)?).map_err(|_| DecodeError::BadRoute)?;
        let mtu = r.u16()?;
        let port = r.u16()?;
        let ttl = r.u16()?;
        let delivery = match r.u8()? {
            0 => PipeDelivery::BestEffort,
            FLAG_ACKED => PipeDelivery::Acked,
            f => return Err(DecodeError::BadFlags(f)),
        };
        let mut p = PipeConfig::new(route.with_mtu(mtu), port, ttl).with_delivery(delivery);
        let count = r.u8()?;
        if usize::from(count) > MAX_ARGMAP {
            return Err(DecodeError::ArgmapTooLong(count));
        }
        for _ in 0..count {
            let output = r.u8()?;
            let input = r.u8()?;
            p.map(output, input).map_err(|e| match e {
                PipeError::DuplicateInput(i) => DecodeError::DuplicateInput(i),
                PipeError::ArgmapFull => DecodeError::ArgmapTooLong(count),
            })?;
        }
        Ok(p)
    }
}

/// A pipe in a function's table: its configuration, its queue of `Q`
/// datagrams of up to `B` bytes each (transport key included) waiting for
/// its port, and its counters.
#[derive(Debug, Clone)]
pub struct PipeState<const Q: usize, const B: usize> {
    /// The configuration.
    pub config: PipeConfig,
    queue: [([u8; B], usize); Q],
    head: usize,
    queued: usize,
    /// Datagrams sent.
    pub sent: u32,
    /// Datagrams dropped because the queue was full (the oldest goes).
    pub overflows: u32,
    /// Datagrams that could not be built or sent (too long for the route or
    /// the buffer, bad address): dropped and counted.
    pub send_errors: u32,
    /// Error reports the destination sent back.
    pub remote_errors: u32,
    /// The last error report the destination sent back.
    pub last_remote_error: Option<crate::control::ControlError>,
}

impl<const Q: usize, const B: usize> PipeState<Q, B> {
    /// A pipe with an empty queue and zeroed counters.
    pub const fn new(config: PipeConfig) -> Self {
        PipeState {
            config,
            queue: [([0; B], 0); Q],
            head: 0,
            queued: 0,
            sent: 0,
            overflows: 0,
            send_errors: 0,
            remote_errors: 0,
            last_remote_error: None,
        }
    }

    /// How many datagrams wait.
    pub fn queued(&self) -> usize {
        self.queued
    }

    /// Queues a datagram built in place by `write` (which returns its
    /// length, or `None` if it does not fit). When the queue is full the
    /// oldest datagram is dropped and counted in `overflows`.
    pub fn push_with(&mut self, write: impl FnOnce(&mut [u8]) -> Option<usize>) {
        if Q == 0 {
            self.overflows = self.overflows.wrapping_add(1);
            return;
        }
        if self.queued == Q {
            self.head = (self.head + 1) % Q;
            self.queued -= 1;
            self.overflows = self.overflows.wrapping_add(1);
        }
        let at = (self.head + self.queued) % Q;
        let Some(slot) = self.queue.get_mut(at) else {
            return;
        };
        match write(&mut slot.0) {
            Some(n) if n <= B => {
                slot.1 = n;
                self.queued += 1;
            }
            _ => self.send_errors = self.send_errors.wrapping_add(1),
        }
    }

    /// The oldest waiting datagram.
    pub fn front(&self) -> Option<&[u8]> {
        if self.queued == 0 {
            return None;
        }
        let (buf, n) = self.queue.get(self.head)?;
        buf.get(..*n)
    }

    /// Drops the oldest waiting datagram.
    pub fn pop(&mut self) {
        if self.queued > 0 && Q > 0 {
            self.head = (self.head + 1) % Q;
            self.queued -= 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_round_trip() {
        let p = PipeConfig::new(Route::through_links(&[1]).unwrap().with_mtu(200), 3, 5000)
            .with(0, 1)
            .unwrap()
            .with(2, 0)
            .unwrap();
        let mut b = [0u8; 64];
        let mut w = Writer::new(&mut b);
        p.encode(&mut w).unwrap();
        let n = w.len();
        assert_eq!(n, p.encoded_len());
        let mut r = Reader::new(&b[..n]);
        assert_eq!(PipeConfig::decode(&mut r), Ok(p));
        assert!(r.is_empty());
        assert_eq!(p.with(1, 1), Err(PipeError::DuplicateInput(1)));
    }

    #[test]
    fn config_decode_errors() {
        let bad = |b: &[u8]| PipeConfig::decode(&mut Reader::new(b));
        assert_eq!(bad(&[]), Err(DecodeError::Truncated));
        assert_eq!(
            bad(&[0, 0, 1, 1, 0, 0, 0, 2]),
            Err(DecodeError::BadFlags(2))
        );
        assert_eq!(
            bad(&[0, 0, 1, 1, 0, 0, 0, 0, 9]),
            Err(DecodeError::ArgmapTooLong(9))
        );
        assert_eq!(
            bad(&[0, 0, 1, 1, 0, 0, 0, 0, 2, 0, 0, 1, 0]),
            Err(DecodeError::DuplicateInput(0))
        );
        // A route of one byte 0xff is not an instruction.
        assert_eq!(bad(&[1, 0xff]), Err(DecodeError::BadRoute));
        let mut p = PipeConfig::new(Route::local(), 1, 1);
        for i in 0..8 {
            p.map(0, i).unwrap();
        }
        assert_eq!(p.map(0, 8), Err(PipeError::ArgmapFull));
    }

    #[test]
    fn queue_drops_oldest_and_counts() {
        let mut s: PipeState<2, 4> = PipeState::new(PipeConfig::new(Route::local(), 1, 1));
        for x in 1..=3u8 {
            s.push_with(|b| {
                b[0] = x;
                Some(1)
            });
        }
        assert_eq!(s.overflows, 1);
        assert_eq!(s.queued(), 2);
        assert_eq!(s.front(), Some(&[2u8][..]));
        s.pop();
        assert_eq!(s.front(), Some(&[3u8][..]));
        s.pop();
        assert_eq!(s.front(), None);
        s.push_with(|_| None);
        assert_eq!(s.send_errors, 1);
        assert_eq!(s.queued(), 0);
    }
}
