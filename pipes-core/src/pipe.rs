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
//!
//! A pipe keeps a small queue of datagrams waiting for its port to be clear
//! to send ([`PipeState`]); when the queue is full the **oldest** waiting
//! datagram is dropped and counted, never silently.
//!
//! A **best-effort** pipe sends each datagram raw and forgets it. An
//! **acknowledged** pipe sends each datagram as a sequential request and
//! keeps it at the front of its queue until the destination replies (ok, or
//! an error, which is counted as a remote error): one datagram in flight at
//! a time, so the queue's order is kept. With no reply within the pipe's
//! [`ack_timeout`](PipeState::ack_timeout) it sends the same request again
//! (same sequence number), up to [`max_retries`](PipeState::max_retries)
//! times, then counts a failure and drops it. Delivery is **at least once**:
//! when an acknowledgement is lost the destination receives the datagram
//! again. A datagram dropped by a full queue while in flight is dropped like
//! any other (counted in `overflows`); a late reply to it is ignored.
use osap_core::codec::{Reader, Writer};
use osap_core::route::Route;

use crate::control::{ControlError, DecodeError};

/// The most output → input pairs in one pipe's argmap.
pub const MAX_ARGMAP: usize = 8;

/// The flag bit that asks for acknowledged delivery.
pub const FLAG_ACKED: u8 = 0x01;

/// How long an acknowledged pipe waits for a reply before it sends a
/// datagram again, unless set otherwise ([`PipeState::ack_timeout`]).
pub const DEFAULT_ACK_TIMEOUT: osap_core::Duration = osap_core::Duration::from_millis(20);

/// How many times an acknowledged pipe sends a datagram again before it
/// counts a failure, unless set otherwise ([`PipeState::max_retries`]).
pub const DEFAULT_ACK_RETRIES: u8 = 3;

/// How a pipe delivers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PipeDelivery {
    /// Send and forget; losses are the network's counters' business.
    #[default]
    BestEffort,
    /// Acknowledged delivery: each datagram is a request, retransmitted
    /// until the destination replies or the retries run out (at least once;
    /// see the module docs).
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
#[non_exhaustive]
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

impl core::error::Error for PipeError {}

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

/// A pipe's counters, as the "get pipe stats" reply carries them.
///
/// Wire form (`docs/pipes.md` §5): `[sent: u32][overflows: u32]
/// [send_errors: u32][remote_errors: u32][acked: u32][retries: u32]
/// [failures: u32]` then the last remote error as `[status][body]` (status
/// 0, no body: none). Counters wrap.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct PipeStats {
    /// Datagrams sent.
    pub sent: u32,
    /// Datagrams dropped because the queue was full.
    pub overflows: u32,
    /// Datagrams that could not be built or sent.
    pub send_errors: u32,
    /// Error reports the destination sent back.
    pub remote_errors: u32,
    /// Datagrams the destination acknowledged (acknowledged pipes).
    pub acked: u32,
    /// Datagrams sent again for want of an acknowledgement.
    pub retries: u32,
    /// Datagrams dropped unacknowledged after the last retry.
    pub failures: u32,
    /// The last error report the destination sent back.
    pub last_remote_error: Option<ControlError>,
}

impl PipeStats {
    /// Writes the counters. On error nothing is written.
    pub fn encode(&self, w: &mut Writer<'_>) -> Result<(), DecodeError> {
        let start = w.len();
        let r = (|| -> Result<(), DecodeError> {
            for c in [
                self.sent,
                self.overflows,
                self.send_errors,
                self.remote_errors,
                self.acked,
                self.retries,
                self.failures,
            ] {
                w.u32(c)?;
            }
            match &self.last_remote_error {
                None => w.u8(0)?,
                Some(e) => e.encode(w)?,
            }
            Ok(())
        })();
        if r.is_err() {
            w.truncate(start);
        }
        r
    }

    /// Reads the counters from `r`.
    pub fn decode(r: &mut Reader<'_>) -> Result<PipeStats, DecodeError> {
        let sent = r.u32()?;
        let overflows = r.u32()?;
        let send_errors = r.u32()?;
        let remote_errors = r.u32()?;
        let acked = r.u32()?;
        let retries = r.u32()?;
        let failures = r.u32()?;
        let last_remote_error = match r.u8()? {
            0 => None,
            status => Some(ControlError::decode_body(status, r)?),
        };
        Ok(PipeStats {
            sent,
            overflows,
            send_errors,
            remote_errors,
            acked,
            retries,
            failures,
            last_remote_error,
        })
    }
}

/// A pipe in a function's table: its configuration, its queue of `Q`
/// datagrams of up to `B` bytes each (transport header included) waiting for
/// its port (or, on an acknowledged pipe, the front one for its reply), and
/// its counters.
#[derive(Debug, Clone)]
pub struct PipeState<const Q: usize, const B: usize> {
    /// The configuration.
    pub config: PipeConfig,
    queue: [([u8; B], usize); Q],
    head: usize,
    queued: usize,
    /// Its counters.
    pub stats: PipeStats,
    /// Acknowledged pipes: how long to wait for a reply before sending
    /// again.
    pub ack_timeout: osap_core::Duration,
    /// Acknowledged pipes: how many times to send a datagram again before
    /// dropping it as a failure.
    pub max_retries: u8,
    next_seq: u16,
    in_flight: Option<InFlight>,
}

/// The front datagram of an acknowledged pipe, sent and waiting for its reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct InFlight {
    seq: u16,
    sent_at: osap_core::Instant,
    sends: u8,
}

/// What an acknowledged pipe should do with its front datagram now.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AckStep {
    /// Nothing is in flight: send the front datagram, if any, as new.
    SendNew,
    /// The front datagram waits for its reply.
    Wait,
    /// No reply in time: send the front datagram again.
    Resend,
    /// No reply after the last retry: drop it (counted as a failure).
    GiveUp,
}

impl<const Q: usize, const B: usize> PipeState<Q, B> {
    /// A pipe with an empty queue and zeroed counters.
    pub const fn new(config: PipeConfig) -> Self {
        PipeState {
            config,
            queue: [([0; B], 0); Q],
            head: 0,
            queued: 0,
            stats: PipeStats {
                sent: 0,
                overflows: 0,
                send_errors: 0,
                remote_errors: 0,
                acked: 0,
                retries: 0,
                failures: 0,
                last_remote_error: None,
            },
            ack_timeout: DEFAULT_ACK_TIMEOUT,
            max_retries: DEFAULT_ACK_RETRIES,
            next_seq: 0,
            in_flight: None,
        }
    }

    /// The counters.
    pub fn stats(&self) -> PipeStats {
        self.stats
    }

    /// Whether the front datagram has been sent and waits for its reply
    /// (acknowledged pipes).
    pub fn awaiting_ack(&self) -> bool {
        self.in_flight.is_some()
    }

    /// What to do with the front datagram at time `now` (acknowledged pipes).
    pub fn ack_step(&self, now: osap_core::Instant) -> AckStep {
        match self.in_flight {
            None => AckStep::SendNew,
            Some(f) if now - f.sent_at < self.ack_timeout => AckStep::Wait,
            Some(f) if f.sends > self.max_retries => AckStep::GiveUp,
            Some(_) => AckStep::Resend,
        }
    }

    /// The front datagram as a request with a new sequence number (written
    /// into its header), for its first send. `None` if the queue is empty
    /// or the datagram has no request header.
    pub fn front_as_new_request(&mut self) -> Option<(u16, &[u8])> {
        if self.queued == 0 {
            return None;
        }
        let seq = self.next_seq;
        let (buf, n) = self.queue.get_mut(self.head)?;
        let d = buf.get_mut(..*n)?;
        let hdr = osap_core::transport::Transport::Request(seq);
        if d.first() != Some(&osap_core::transport::KEY_REQUEST) {
            return None;
        }
        hdr.encode(d)?;
        self.next_seq = seq.wrapping_add(1);
        Some((seq, d))
    }

    /// Records that the front datagram, request `seq`, was sent at `now`
    /// (first send or retry).
    pub fn mark_sent(&mut self, seq: u16, now: osap_core::Instant) {
        match &mut self.in_flight {
            Some(f) if f.seq == seq => {
                f.sends = f.sends.saturating_add(1);
                f.sent_at = now;
                self.stats.retries = self.stats.retries.wrapping_add(1);
            }
            _ => {
                self.in_flight = Some(InFlight {
                    seq,
                    sent_at: now,
                    sends: 1,
                });
                self.stats.sent = self.stats.sent.wrapping_add(1);
            }
        }
    }

    /// When the datagram in flight should be sent again if no ack comes.
    pub fn ack_deadline(&self) -> Option<osap_core::Instant> {
        self.in_flight.map(|f| f.sent_at + self.ack_timeout)
    }

    /// The sequence number of the datagram in flight, if any.
    pub fn in_flight_seq(&self) -> Option<u16> {
        self.in_flight.map(|f| f.seq)
    }

    /// Drops the front datagram after its last retry went unanswered.
    pub fn give_up(&mut self) {
        self.stats.failures = self.stats.failures.wrapping_add(1);
        self.pop();
    }

    /// Takes the destination's reply to request `seq`: `Ok` acknowledges
    /// the front datagram, `Err` is the destination's refusal (counted as a
    /// remote error); either way the datagram leaves the queue. Returns
    /// `false`, changing nothing, for a reply to anything but the datagram
    /// in flight (a duplicate, or a late reply to a dropped datagram).
    pub fn on_reply(&mut self, seq: u16, result: Result<(), ControlError>) -> bool {
        if self.in_flight_seq() != Some(seq) {
            return false;
        }
        match result {
            Ok(()) => self.stats.acked = self.stats.acked.wrapping_add(1),
            Err(e) => {
                self.stats.remote_errors = self.stats.remote_errors.wrapping_add(1);
                self.stats.last_remote_error = Some(e);
            }
        }
        self.pop();
        true
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
            self.stats.overflows = self.stats.overflows.wrapping_add(1);
            return;
        }
        if self.queued == Q {
            self.pop();
            self.stats.overflows = self.stats.overflows.wrapping_add(1);
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
            _ => self.stats.send_errors = self.stats.send_errors.wrapping_add(1),
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

    /// Drops the oldest waiting datagram (and forgets that it was in
    /// flight: a late reply to it is ignored).
    pub fn pop(&mut self) {
        self.in_flight = None;
        if self.queued > 0 && Q > 0 {
            self.head = (self.head + 1) % Q;
            self.queued -= 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use osap_core::time::Instant;

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
        assert_eq!(s.stats.overflows, 1);
        assert_eq!(s.queued(), 2);
        assert_eq!(s.front(), Some(&[2u8][..]));
        s.pop();
        assert_eq!(s.front(), Some(&[3u8][..]));
        s.pop();
        assert_eq!(s.front(), None);
        s.push_with(|_| None);
        assert_eq!(s.stats.send_errors, 1);
        assert_eq!(s.queued(), 0);
    }

    #[test]
    fn acked_front_waits_for_its_own_reply() {
        let mut s: PipeState<2, 8> = PipeState::new(
            PipeConfig::new(Route::local(), 1, 1).with_delivery(PipeDelivery::Acked),
        );
        s.ack_timeout = osap_core::Duration::from_micros(10);
        s.max_retries = 1;
        for x in 1..=2u8 {
            s.push_with(|b| {
                b[..4].copy_from_slice(&[1, 0, 0, x]);
                Some(4)
            });
        }
        assert_eq!(s.ack_step(Instant::ZERO), AckStep::SendNew);
        let (seq, d) = s.front_as_new_request().unwrap();
        assert_eq!((seq, d), (0, &[1u8, 0, 0, 1][..]));
        s.mark_sent(seq, Instant::ZERO);
        assert_eq!(s.ack_step(Instant::from_micros(9)), AckStep::Wait);
        assert_eq!(s.ack_step(Instant::from_micros(10)), AckStep::Resend);
        s.mark_sent(seq, Instant::from_micros(10));
        assert_eq!((s.stats.sent, s.stats.retries), (1, 1));
        assert_eq!(s.ack_step(Instant::from_micros(20)), AckStep::GiveUp);
        // A reply to another sequence number changes nothing.
        assert!(!s.on_reply(7, Ok(())));
        assert!(s.on_reply(0, Ok(())));
        assert!(!s.on_reply(0, Ok(())), "a duplicate is ignored");
        assert_eq!((s.stats.acked, s.queued()), (1, 1));
        let (seq, d) = s.front_as_new_request().unwrap();
        assert_eq!((seq, d), (1, &[1u8, 1, 0, 2][..]));
        s.mark_sent(seq, Instant::from_micros(30));
        // Overflow drops the datagram in flight; its late reply is ignored.
        for _ in 0..2 {
            s.push_with(|b| {
                b[0] = 1;
                Some(4)
            });
        }
        assert!(!s.awaiting_ack());
        assert_eq!(s.stats.overflows, 1);
        assert!(!s.on_reply(1, Err(ControlError::Malformed)));
        assert_eq!(s.stats.remote_errors, 0);
        s.mark_sent(9, Instant::from_micros(40));
        s.give_up();
        assert_eq!((s.stats.failures, s.queued()), (1, 1));
        // A best-effort datagram (raw header) is no request.
        let mut raw: PipeState<1, 4> = PipeState::new(PipeConfig::new(Route::local(), 1, 1));
        raw.push_with(|b| {
            b[0] = 0;
            Some(1)
        });
        assert!(raw.front_as_new_request().is_none());
    }
}
