//! Transports on top of port-to-port packets.
//!
//! The first payload byte of every port-to-port packet is a transport key.
//! Key 0 is a raw datagram. Keys 1 and 2 form the sequential transport: a
//! request carries a `u16` sequence number and its reply echoes it, so a
//! caller with several calls in flight knows which one each reply answers.
//! [`Requester`] keeps that bookkeeping for the caller.
//!
//! Key 3 ([`KEY_SEGMENT`]) carries one segment of a payload too large for
//! one packet; the reassembled payload starts with its own key again (see
//! [`crate::segment`]). [`Transport::decode`] does not unwrap segments: a
//! receiver reassembles first and decodes the whole payload.

use crate::time::Instant;
use core::fmt;

/// Transport key of a raw datagram.
pub const KEY_RAW: u8 = 0;
/// Transport key of a sequential request.
pub const KEY_REQUEST: u8 = 1;
/// Transport key of a sequential reply.
pub const KEY_REPLY: u8 = 2;
/// Transport key of a segment of a larger payload ([`crate::segment`]).
pub const KEY_SEGMENT: u8 = crate::segment::KEY_SEGMENT;
/// Highest key reserved for the project's own transports.
pub const KEY_RESERVED_MAX: u8 = 15;

/// The transport header at the front of a port-to-port payload.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Transport {
    /// No transport state.
    Raw,
    /// A request with its sequence number.
    Request(u16),
    /// A reply to the request with this sequence number.
    Reply(u16),
}

/// A payload whose transport header could not be read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum TransportError {
    /// The payload is empty or ends inside the header.
    Truncated,
    /// The key is a segment (3, reassemble first with [`crate::segment`]),
    /// reserved (4..=15) or unknown (above 15).
    UnknownKey(u8),
}

impl fmt::Display for TransportError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            TransportError::Truncated => f.write_str("transport header is truncated"),
            TransportError::UnknownKey(k) => write!(f, "unknown transport key {k}"),
        }
    }
}

impl core::error::Error for TransportError {}

impl Transport {
    /// Splits a payload into its transport header and body.
    pub fn decode(payload: &[u8]) -> Result<(Transport, &[u8]), TransportError> {
        match payload {
            [] => Err(TransportError::Truncated),
            [KEY_RAW, rest @ ..] => Ok((Transport::Raw, rest)),
            [KEY_REQUEST | KEY_REPLY, a, b, rest @ ..] => {
                let seq = u16::from_le_bytes([*a, *b]);
                let t = if payload[0] == KEY_REQUEST {
                    Transport::Request(seq)
                } else {
                    Transport::Reply(seq)
                };
                Ok((t, rest))
            }
            [KEY_REQUEST | KEY_REPLY, ..] => Err(TransportError::Truncated),
            [k, ..] => Err(TransportError::UnknownKey(*k)),
        }
    }

    /// Header length in bytes.
    pub const fn encoded_len(&self) -> usize {
        match self {
            Transport::Raw => 1,
            Transport::Request(_) | Transport::Reply(_) => 3,
        }
    }

    /// Writes the header at the start of `out`, returning its length, or
    /// `None` if `out` is too short.
    pub fn encode(&self, out: &mut [u8]) -> Option<usize> {
        let (key, seq) = match *self {
            Transport::Raw => (KEY_RAW, None),
            Transport::Request(s) => (KEY_REQUEST, Some(s)),
            Transport::Reply(s) => (KEY_REPLY, Some(s)),
        };
        let dst = out.get_mut(..self.encoded_len())?;
        dst[0] = key;
        if let Some(s) = seq {
            dst[1..3].copy_from_slice(&s.to_le_bytes());
        }
        Some(self.encoded_len())
    }

    /// The header of the reply to this request.
    pub const fn reply(&self) -> Option<Transport> {
        match *self {
            Transport::Request(s) => Some(Transport::Reply(s)),
            _ => None,
        }
    }
}

/// A request that has been sent and awaits its reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Pending<T> {
    /// Sequence number the request was sent with.
    pub seq: u16,
    /// When it was sent.
    pub sent: Instant,
    /// When to give up on it.
    pub deadline: Instant,
    /// Caller data carried with the request (e.g. which query it was).
    pub tag: T,
}

/// What became of a reply handed to [`Requester::on_reply`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReplyMatch<T> {
    /// It answers this outstanding request, which is now closed.
    Matched(Pending<T>),
    /// No outstanding request has this sequence number (late, duplicate or
    /// stray); it should be counted and dropped.
    Unknown,
}

/// The requesting side of the sequential transport: hands out sequence
/// numbers, remembers up to `N` outstanding requests, matches replies to them
/// and times them out.
///
/// With `N = 1` it is stop-and-wait, which also guarantees that requests are
/// handled in the order they were issued.
#[derive(Debug)]
pub struct Requester<T, const N: usize> {
    next_seq: u16,
    pending: heapless::Vec<Pending<T>, N>,
    timeouts: u32,
    stray_replies: u32,
}

impl<T: Copy, const N: usize> Default for Requester<T, N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<T: Copy, const N: usize> Requester<T, N> {
    /// A requester with nothing outstanding.
    pub const fn new() -> Self {
        Requester {
            next_seq: 0,
            pending: heapless::Vec::new(),
            timeouts: 0,
            stray_replies: 0,
        }
    }

    /// Whether another request may be issued now.
    pub fn can_issue(&self) -> bool {
        !self.pending.is_full()
    }

    /// Number of outstanding requests.
    pub fn outstanding(&self) -> usize {
        self.pending.len()
    }

    /// Reserves a sequence number for a request sent at `now` that expires at
    /// `deadline`. Returns `None` when `N` requests are already outstanding.
    pub fn issue(&mut self, now: Instant, deadline: Instant, tag: T) -> Option<u16> {
        // Skip numbers still in flight so a wrapped counter never aliases.
        let mut seq = self.next_seq;
        while self.pending.iter().any(|p| p.seq == seq) {
            seq = seq.wrapping_add(1);
        }
        self.pending
            .push(Pending {
                seq,
                sent: now,
                deadline,
                tag,
            })
            .ok()?;
        self.next_seq = seq.wrapping_add(1);
        Some(seq)
    }

    /// Withdraws a request that could not be sent after all.
    pub fn cancel(&mut self, seq: u16) -> Option<Pending<T>> {
        let i = self.pending.iter().position(|p| p.seq == seq)?;
        Some(self.pending.swap_remove(i))
    }

    /// Matches a reply's sequence number against the outstanding requests.
    pub fn on_reply(&mut self, seq: u16) -> ReplyMatch<T> {
        match self.cancel(seq) {
            Some(p) => ReplyMatch::Matched(p),
            None => {
                self.stray_replies = self.stray_replies.wrapping_add(1);
                ReplyMatch::Unknown
            }
        }
    }

    /// Removes and returns one request whose deadline has passed.
    pub fn take_expired(&mut self, now: Instant) -> Option<Pending<T>> {
        let i = self.pending.iter().position(|p| now > p.deadline)?;
        self.timeouts = self.timeouts.wrapping_add(1);
        Some(self.pending.swap_remove(i))
    }

    /// The earliest deadline among outstanding requests.
    pub fn next_deadline(&self) -> Option<Instant> {
        self.pending.iter().map(|p| p.deadline).min()
    }

    /// Requests that timed out so far.
    pub fn timeouts(&self) -> u32 {
        self.timeouts
    }

    /// Replies that matched nothing so far.
    pub fn stray_replies(&self) -> u32 {
        self.stray_replies
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_round_trip() {
        let mut b = [0u8; 3];
        for t in [
            Transport::Raw,
            Transport::Request(0x1234),
            Transport::Reply(7),
        ] {
            let n = t.encode(&mut b).unwrap();
            let mut with_body = [0u8; 4];
            with_body[..n].copy_from_slice(&b[..n]);
            with_body[n] = 0xEE;
            assert_eq!(Transport::decode(&with_body[..n + 1]), Ok((t, &[0xEE][..])));
        }
        assert_eq!(Transport::decode(&[1, 0]), Err(TransportError::Truncated));
        assert_eq!(Transport::decode(&[3]), Err(TransportError::UnknownKey(3)));
        assert_eq!(Transport::decode(&[]), Err(TransportError::Truncated));
    }

    #[test]
    fn requester_matches_and_times_out() {
        let mut r: Requester<u8, 2> = Requester::new();
        let a = r
            .issue(Instant::ZERO, Instant::from_micros(100), 1)
            .unwrap();
        let b = r.issue(Instant::ZERO, Instant::from_micros(50), 2).unwrap();
        assert_ne!(a, b);
        assert!(r
            .issue(Instant::ZERO, Instant::from_micros(10), 3)
            .is_none());
        assert_eq!(r.next_deadline(), Some(Instant::from_micros(50)));
        assert!(matches!(r.on_reply(a), ReplyMatch::Matched(p) if p.tag == 1));
        assert_eq!(r.on_reply(a), ReplyMatch::Unknown);
        assert_eq!(r.take_expired(Instant::from_micros(50)), None);
        assert_eq!(
            r.take_expired(Instant::from_micros(51)).map(|p| p.tag),
            Some(2)
        );
        assert_eq!(r.timeouts(), 1);
        assert_eq!(r.stray_replies(), 1);
    }

    #[test]
    fn wrapped_sequence_numbers_skip_outstanding_ones() {
        let mut r: Requester<(), 2> = Requester::new();
        r.next_seq = u16::MAX;
        let a = r.issue(Instant::ZERO, Instant::from_micros(1), ()).unwrap();
        assert_eq!(a, u16::MAX);
        r.next_seq = u16::MAX; // force a collision
        let b = r.issue(Instant::ZERO, Instant::from_micros(1), ()).unwrap();
        assert_eq!(b, 0);
    }
}
