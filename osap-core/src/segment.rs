//! Segmentation: datagrams larger than one packet.
//!
//! A payload that does not fit the route's MTU travels as segments under
//! transport key 3. Each segment is `[03][id u8][index u8][count u8][len
//! u16][body]`: `id` tells one datagram from the next of the same sender,
//! `index` is the segment's place among `count`, and `len` is the length of
//! the whole datagram. Every segment but the last carries exactly `stride =
//! ceil(len / count)` bytes, so a receiver can place any segment on arrival
//! (reordering is harmless) and check each header against the others.
//!
//! The reassembled datagram is itself a payload starting with its own
//! transport key (raw, request or reply; never another segment), so the
//! sequential transport rides inside unchanged: a long reply is
//! `[02][seq][body]`, cut into segments.
//!
//! [`Reassembler`] keeps a fixed number of datagrams in flight in fixed
//! buffers. It delivers a datagram only when every segment is in; a datagram
//! still incomplete when its timeout passes is dropped whole and counted, so
//! a lost segment never yields a partial datagram. [`SegmentSender`] sends a
//! datagram as segments from a port, as many per loop as the port is clear
//! to send, reading the bytes from a [`SegmentSource`] so that the sender
//! needs no buffer for the whole datagram.
//!
//! Segmentation of large datagrams is one of the gaps the OSAP chapter of
//! *Modular Machine Control* names; this layout is the project's own.

use crate::port::{PortTx, SendError};
use crate::route::Route;
use crate::time::{Duration, Instant};
use core::fmt;

/// Transport key of a segment.
pub const KEY_SEGMENT: u8 = 3;
/// Bytes of a segment header, the transport key included.
pub const HEADER_LEN: usize = 6;
/// Default reassembly timeout: a datagram whose segments do not all arrive
/// within this time of the first one is dropped.
pub const DEFAULT_TIMEOUT: Duration = Duration::from_millis(100);
/// Datagrams a default [`Reassembler`] keeps in flight.
pub const DEFAULT_SLOTS: usize = 2;
/// Largest datagram a default [`Reassembler`] takes, bytes.
pub const DEFAULT_BYTES: usize = 512;
/// A reassembler in its default configuration (what a microcontroller
/// keeps; hosts use larger ones).
pub type DefaultReassembler = Reassembler<DEFAULT_SLOTS, DEFAULT_BYTES>;
/// How long a blocked [`SegmentSender`] waits before it tries again.
pub const RETRY: Duration = Duration::from_micros(200);

/// Why a segment was refused, or a datagram could not be segmented.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum SegmentError {
    /// The payload ends inside the segment header.
    Truncated,
    /// The transport key is not [`KEY_SEGMENT`].
    NotSegment(u8),
    /// `count` is 0 or `index` is not below it.
    BadIndex,
    /// `len` cannot be cut into `count` non-empty segments of one stride.
    BadLength,
    /// The body is not as long as the header says it must be.
    BodyLength,
    /// The header disagrees with earlier segments of the same datagram.
    Inconsistent,
    /// The reassembled datagram starts with the segment key again.
    Nested,
    /// The datagram is longer than a reassembly buffer (or than 65535 or 255
    /// segments allow, when sending).
    TooLarge,
    /// Every reassembly slot holds a datagram in progress.
    NoSlot,
    /// The packet room is too small for a header and one byte.
    NoRoom,
    /// The datagram was not all sent within its time to live.
    Expired,
}

impl fmt::Display for SegmentError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            SegmentError::Truncated => "segment header is truncated",
            SegmentError::NotSegment(_) => "not a segment",
            SegmentError::BadIndex => "segment index is not below the count",
            SegmentError::BadLength => "datagram length does not fit the segment count",
            SegmentError::BodyLength => "segment body has the wrong length",
            SegmentError::Inconsistent => "segment disagrees with its datagram",
            SegmentError::Nested => "segmented datagram holds another segment",
            SegmentError::TooLarge => "datagram is too large",
            SegmentError::NoSlot => "every reassembly slot is busy",
            SegmentError::NoRoom => "packet has no room for a segment",
            SegmentError::Expired => "datagram was not sent within its time to live",
        })
    }
}

impl core::error::Error for SegmentError {}

/// How a datagram of `len` bytes is cut: `count` segments, each but the
/// last `stride` bytes long.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Plan {
    /// Datagram length.
    pub len: u16,
    /// Number of segments (1..=255).
    pub count: u8,
    /// Bytes in every segment but the last.
    pub stride: u16,
}

impl Plan {
    /// The plan for a datagram of `len` bytes sent in packets whose payload
    /// may take `room` bytes (segment header included). Segments come out as
    /// even as possible, never longer than the room.
    pub fn new(len: usize, room: usize) -> Result<Plan, SegmentError> {
        let body = room.checked_sub(HEADER_LEN).filter(|&b| b > 0);
        let body = body.ok_or(SegmentError::NoRoom)?;
        let len16 = u16::try_from(len).map_err(|_| SegmentError::TooLarge)?;
        if len == 0 {
            return Err(SegmentError::BadLength);
        }
        let count = u8::try_from(len.div_ceil(body)).map_err(|_| SegmentError::TooLarge)?;
        Plan::from_header(len16, count)
    }

    /// The plan a header's `len` and `count` imply, if they are consistent:
    /// `count` segments of `ceil(len / count)` bytes, the last one non-empty.
    pub fn from_header(len: u16, count: u8) -> Result<Plan, SegmentError> {
        if count == 0 {
            return Err(SegmentError::BadIndex);
        }
        let (l, c) = (usize::from(len), usize::from(count));
        if l < c {
            return Err(SegmentError::BadLength);
        }
        let stride = l.div_ceil(c);
        if (c - 1) * stride >= l {
            return Err(SegmentError::BadLength);
        }
        Ok(Plan {
            len,
            count,
            // stride <= len, which fits u16.
            stride: stride as u16,
        })
    }

    /// Where segment `index` starts in the datagram.
    pub fn offset(&self, index: u8) -> usize {
        usize::from(index) * usize::from(self.stride)
    }

    /// How many bytes segment `index` carries (0 past the last).
    pub fn body_len(&self, index: u8) -> usize {
        let end = (self.offset(index) + usize::from(self.stride)).min(usize::from(self.len));
        end.saturating_sub(self.offset(index))
    }
}

/// A segment's header.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SegmentHeader {
    /// Which datagram of its sender it belongs to.
    pub id: u8,
    /// Its place among the datagram's segments.
    pub index: u8,
    /// The datagram's segments in all.
    pub count: u8,
    /// The datagram's length, bytes.
    pub len: u16,
}

impl SegmentHeader {
    /// Reads and checks a segment (a payload starting with [`KEY_SEGMENT`]):
    /// its header, and that its body is exactly as long as the header
    /// implies. Returns the header, its plan and the body.
    pub fn decode(payload: &[u8]) -> Result<(SegmentHeader, Plan, &[u8]), SegmentError> {
        let (head, body) = match payload {
            [] => return Err(SegmentError::Truncated),
            [k, ..] if *k != KEY_SEGMENT => return Err(SegmentError::NotSegment(*k)),
            _ => payload
                .split_first_chunk::<HEADER_LEN>()
                .ok_or(SegmentError::Truncated)?,
        };
        let h = SegmentHeader {
            id: head[1],
            index: head[2],
            count: head[3],
            len: u16::from_le_bytes([head[4], head[5]]),
        };
        let plan = Plan::from_header(h.len, h.count)?;
        if h.index >= h.count {
            return Err(SegmentError::BadIndex);
        }
        if body.len() != plan.body_len(h.index) {
            return Err(SegmentError::BodyLength);
        }
        Ok((h, plan, body))
    }

    /// Writes the header (key included) at the start of `out`; `None` if
    /// `out` is shorter than [`HEADER_LEN`].
    pub fn encode(&self, out: &mut [u8]) -> Option<usize> {
        let l = self.len.to_le_bytes();
        out.get_mut(..HEADER_LEN)?.copy_from_slice(&[
            KEY_SEGMENT,
            self.id,
            self.index,
            self.count,
            l[0],
            l[1],
        ]);
        Some(HEADER_LEN)
    }
}

/// Whether a payload is a segment (starts with [`KEY_SEGMENT`]).
pub fn is_segment(payload: &[u8]) -> bool {
    payload.first() == Some(&KEY_SEGMENT)
}

/// What a reassembler counted. All counts wrap.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ReassemblyStats {
    /// Segments taken into a datagram.
    pub segments: u32,
    /// Datagrams delivered whole.
    pub delivered: u32,
    /// Segments already held (or of a datagram already delivered), ignored.
    pub duplicates: u32,
    /// Datagrams dropped incomplete when their timeout passed: a segment
    /// was lost.
    pub lost: u32,
    /// Segments refused for a malformed or inconsistent header, and
    /// completed datagrams refused because they hold another segment.
    pub malformed: u32,
    /// Segments refused because their datagram is longer than a buffer.
    pub too_large: u32,
    /// Segments refused because every slot held a datagram in progress.
    pub no_slot: u32,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum SlotState {
    Free,
    /// Collecting segments.
    Open,
    /// Delivered; kept until its deadline only to recognise duplicates, and
    /// reused before then if a new datagram needs the room.
    Done,
}

/// Received-segment bits for up to 255 segments.
type Seen = [u32; 8];

fn seen_bit(seen: &Seen, i: u8) -> bool {
    seen[usize::from(i / 32)] & (1 << (i % 32)) != 0
}

#[derive(Debug, Clone)]
struct Slot<const B: usize> {
    state: SlotState,
    route: Route,
    port: u16,
    id: u8,
    plan: Plan,
    got: u8,
    seen: Seen,
    deadline: Instant,
    buf: [u8; B],
}

impl<const B: usize> Slot<B> {
    const EMPTY: Self = Slot {
        state: SlotState::Free,
        route: Route::local(),
        port: 0,
        id: 0,
        plan: Plan {
            len: 0,
            count: 0,
            stride: 0,
        },
        got: 0,
        seen: [0; 8],
        deadline: Instant::ZERO,
        buf: [0; B],
    };

    fn is(&self, route: &Route, port: u16, id: u8) -> bool {
        self.state != SlotState::Free
            && self.port == port
            && self.id == id
            && self.route.as_bytes() == route.as_bytes()
    }
}

/// Reassembles segmented datagrams: `SLOTS` datagrams in flight at once,
/// each of at most `BYTES` bytes, with no allocation.
///
/// Datagrams are told apart by the sender's reply route, its port and the
/// segment `id`. A datagram is delivered only whole; one still incomplete
/// [`timeout`](Self::with_timeout) after its first segment is dropped and
/// counted as lost.
#[derive(Debug, Clone)]
pub struct Reassembler<const SLOTS: usize, const BYTES: usize> {
    slots: [Slot<BYTES>; SLOTS],
    timeout: Duration,
    stats: ReassemblyStats,
}

impl<const SLOTS: usize, const BYTES: usize> Default for Reassembler<SLOTS, BYTES> {
    fn default() -> Self {
        Self::new()
    }
}

fn bump(c: &mut u32) {
    *c = c.wrapping_add(1);
}

impl<const SLOTS: usize, const BYTES: usize> Reassembler<SLOTS, BYTES> {
    /// An empty reassembler with the default timeout.
    pub const fn new() -> Self {
        Reassembler {
            slots: [Slot::EMPTY; SLOTS],
            timeout: DEFAULT_TIMEOUT,
            stats: ReassemblyStats {
                segments: 0,
                delivered: 0,
                duplicates: 0,
                lost: 0,
                malformed: 0,
                too_large: 0,
                no_slot: 0,
            },
        }
    }

    /// The same reassembler with datagrams timing out `timeout` after
    /// their first segment.
    pub const fn with_timeout(mut self, timeout: Duration) -> Self {
        self.timeout = timeout;
        self
    }

    /// What it has counted.
    pub fn stats(&self) -> &ReassemblyStats {
        &self.stats
    }

    /// Datagrams being collected now.
    pub fn in_progress(&self) -> usize {
        self.slots
            .iter()
            .filter(|s| s.state == SlotState::Open)
            .count()
    }

    /// The earliest time a datagram in progress times out.
    pub fn next_deadline(&self) -> Option<Instant> {
        self.slots
            .iter()
            .filter(|s| s.state == SlotState::Open)
            .map(|s| s.deadline)
            .min()
    }

    /// Drops every datagram whose timeout has passed at `now`, counting the
    /// incomplete ones as lost.
    pub fn expire(&mut self, now: Instant) {
        for s in self.slots.iter_mut() {
            if s.state != SlotState::Free && now >= s.deadline {
                if s.state == SlotState::Open {
                    bump(&mut self.stats.lost);
                }
                s.state = SlotState::Free;
            }
        }
    }

    /// Takes one segment (`payload`, starting with [`KEY_SEGMENT`]) sent from
    /// port `port` whose way back is `route`, at local time `now`.
    ///
    /// Returns the whole datagram when this segment completes it, `None`
    /// while it is incomplete or when the segment is a duplicate, and an
    /// error (also counted) when the segment is refused.
    pub fn on_segment<'s>(
        &'s mut self,
        now: Instant,
        route: &Route,
        port: u16,
        payload: &'s [u8],
    ) -> Result<Option<&'s [u8]>, SegmentError> {
        self.expire(now);
        let (h, plan, body) = match SegmentHeader::decode(payload) {
            Ok(x) => x,
            Err(e) => {
                bump(&mut self.stats.malformed);
                return Err(e);
            }
        };
        if usize::from(h.len) > BYTES {
            bump(&mut self.stats.too_large);
            return Err(SegmentError::TooLarge);
        }
        let i = match self.slots.iter().position(|s| s.is(route, port, h.id)) {
            Some(i) => i,
            None => self.open(now, route, port, h.id, plan)?,
        };
        let stats = &mut self.stats;
        let slot = &mut self.slots[i];
        if slot.plan != plan {
            bump(&mut stats.malformed);
            return Err(SegmentError::Inconsistent);
        }
        if slot.state == SlotState::Done || seen_bit(&slot.seen, h.index) {
            bump(&mut stats.duplicates);
            return Ok(None);
        }
        let at = plan.offset(h.index);
        // decode() checked the body length against the plan, and the plan
        // against BYTES above, so this range is inside the buffer.
        let Some(dst) = slot.buf.get_mut(at..at + body.len()) else {
            bump(&mut stats.malformed);
            return Err(SegmentError::BodyLength);
        };
        dst.copy_from_slice(body);
        slot.seen[usize::from(h.index / 32)] |= 1 << (h.index % 32);
        slot.got += 1;
        bump(&mut stats.segments);
        if slot.got < plan.count {
            return Ok(None);
        }
        slot.state = SlotState::Done;
        let data = &slot.buf[..usize::from(plan.len)];
        if is_segment(data) {
            bump(&mut stats.malformed);
            return Err(SegmentError::Nested);
        }
        bump(&mut stats.delivered);
        Ok(Some(data))
    }

    /// Finds a slot for a new datagram: a free one, else the delivered one
    /// kept longest for duplicates.
    fn open(
        &mut self,
        now: Instant,
        route: &Route,
        port: u16,
        id: u8,
        plan: Plan,
    ) -> Result<usize, SegmentError> {
        let free = self.slots.iter().position(|s| s.state == SlotState::Free);
        let done = || {
            self.slots
                .iter()
                .enumerate()
                .filter(|(_, s)| s.state == SlotState::Done)
                .min_by_key(|(_, s)| s.deadline)
                .map(|(i, _)| i)
        };
        let Some(i) = free.or_else(done) else {
            bump(&mut self.stats.no_slot);
            return Err(SegmentError::NoSlot);
        };
        let s = &mut self.slots[i];
        s.state = SlotState::Open;
        s.route = *route;
        s.port = port;
        s.id = id;
        s.plan = plan;
        s.got = 0;
        s.seen = [0; 8];
        s.deadline = now.saturating_add(self.timeout);
        Ok(i)
    }
}

/// The bytes of a datagram to send in segments, read a window at a time.
pub trait SegmentSource {
    /// The datagram's length, bytes.
    fn len(&self) -> usize;

    /// Whether the datagram is empty.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Copies the datagram's bytes from `offset` into `out`, as many as fit
    /// or remain; returns how many.
    fn read_at(&self, offset: usize, out: &mut [u8]) -> usize;
}

impl SegmentSource for [u8] {
    fn len(&self) -> usize {
        <[u8]>::len(self)
    }

    fn read_at(&self, offset: usize, out: &mut [u8]) -> usize {
        let src = self.get(offset..).unwrap_or(&[]);
        let n = src.len().min(out.len());
        out[..n].copy_from_slice(&src[..n]);
        n
    }
}

/// Collects the part of a datagram written piece by piece that falls in a
/// window: a [`SegmentSource`] whose datagram is made of fields (a
/// signature, say) writes all of them through [`put`](Self::put) and only
/// the bytes from `start` on that fit `out` are kept.
#[derive(Debug)]
pub struct Window<'a> {
    pos: usize,
    start: usize,
    out: &'a mut [u8],
    written: usize,
}

impl<'a> Window<'a> {
    /// A window over the datagram's bytes from `start`, into `out`.
    pub fn new(start: usize, out: &'a mut [u8]) -> Self {
        Window {
            pos: 0,
            start,
            out,
            written: 0,
        }
    }

    /// Appends the next piece of the datagram.
    pub fn put(&mut self, bytes: &[u8]) {
        let end = self.pos + bytes.len();
        if end > self.start && self.written < self.out.len() {
            let skip = self.start.saturating_sub(self.pos);
            let src = &bytes[skip..];
            let n = src.len().min(self.out.len() - self.written);
            self.out[self.written..self.written + n].copy_from_slice(&src[..n]);
            self.written += n;
        }
        self.pos = end;
    }

    /// Whether the window is full (the caller may stop writing).
    pub fn is_full(&self) -> bool {
        self.written == self.out.len()
    }

    /// Bytes kept so far.
    pub fn written(&self) -> usize {
        self.written
    }
}

/// What a [`SegmentSender`] counted. All counts wrap.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SenderStats {
    /// Datagrams started.
    pub datagrams: u32,
    /// Segments sent.
    pub segments: u32,
    /// Datagrams given up unfinished: past their deadline, replaced by a
    /// newer one, or refused by the runtime.
    pub abandoned: u32,
}

/// What [`SegmentSender::pump`] left.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pump {
    /// Nothing (more) to send.
    Idle,
    /// Segments remain; the port was not clear to send.
    Blocked,
    /// The datagram was given up (see [`SenderStats::abandoned`]).
    Abandoned(SegmentError),
}

#[derive(Debug, Clone, Copy)]
struct Outgoing {
    route: Route,
    dst: u16,
    ttl: u16,
    id: u8,
    len: usize,
    /// Set by the first segment sent, from the room it found.
    plan: Option<Plan>,
    next: u8,
    deadline: Instant,
}

/// Sends one datagram at a time as segments from a port, resuming each loop
/// where the port's quota stopped it.
#[derive(Debug, Clone, Default)]
pub struct SegmentSender {
    next_id: u8,
    active: Option<Outgoing>,
    wake: Instant,
    stats: SenderStats,
}

impl SegmentSender {
    /// A sender with nothing to send.
    pub const fn new() -> Self {
        SegmentSender {
            next_id: 0,
            active: None,
            wake: Instant::ZERO,
            stats: SenderStats {
                datagrams: 0,
                segments: 0,
                abandoned: 0,
            },
        }
    }

    /// What it has counted.
    pub fn stats(&self) -> &SenderStats {
        &self.stats
    }

    /// Whether a datagram is being sent.
    pub fn is_busy(&self) -> bool {
        self.active.is_some()
    }

    /// When the port should be polled again to go on sending.
    pub fn wake_at(&self) -> Option<Instant> {
        self.active.map(|_| self.wake)
    }

    /// Starts sending a datagram of `len` bytes to port `dst` at the end of
    /// `route`, each segment living `ttl` µs; the whole datagram is given
    /// up if unfinished `ttl` µs from `now`. A datagram still being sent is
    /// abandoned. The bytes are read from the source handed to
    /// [`pump`](Self::pump), which must describe this same datagram.
    pub fn start(&mut self, now: Instant, route: &Route, dst: u16, ttl: u16, len: usize) {
        if self.active.is_some() {
            bump(&mut self.stats.abandoned);
        }
        let id = self.next_id;
        self.next_id = id.wrapping_add(1);
        bump(&mut self.stats.datagrams);
        self.wake = now;
        self.active = Some(Outgoing {
            route: *route,
            dst,
            ttl,
            id,
            len,
            plan: None,
            next: 0,
            deadline: now + Duration::from_micros(ttl.into()),
        });
    }

    /// Gives up the datagram being sent, if any, without counting it.
    pub fn cancel(&mut self) {
        self.active = None;
    }

    /// Sends the next segments from the port at `offset`, while it is clear.
    pub fn pump<S: SegmentSource + ?Sized>(
        &mut self,
        tx: &mut PortTx<'_>,
        offset: u16,
        source: &S,
    ) -> Pump {
        let now = tx.now();
        loop {
            let Some(out) = self.active.as_mut() else {
                return Pump::Idle;
            };
            if now > out.deadline {
                return self.abandon(SegmentError::Expired);
            }
            if source.len() != out.len {
                return self.abandon(SegmentError::Inconsistent);
            }
            if !tx.clear_to_send_from(offset) {
                self.wake = now.saturating_add(RETRY);
                return Pump::Blocked;
            }
            let mut failed = None;
            let (route, dst, ttl) = (out.route, out.dst, out.ttl);
            let r = tx.send_with(offset, &route, dst, ttl, |buf| {
                let plan = match out.plan {
                    Some(p) => p,
                    None => match Plan::new(out.len, buf.len()) {
                        Ok(p) => p,
                        Err(e) => {
                            failed = Some(e);
                            return None;
                        }
                    },
                };
                let h = SegmentHeader {
                    id: out.id,
                    index: out.next,
                    count: plan.count,
                    len: plan.len,
                };
                let n = plan.body_len(out.next);
                let body = buf.get_mut(HEADER_LEN..HEADER_LEN + n)?;
                if source.read_at(plan.offset(out.next), body) != n {
                    failed = Some(SegmentError::Inconsistent);
                    return None;
                }
                h.encode(buf)?;
                out.plan = Some(plan);
                Some(HEADER_LEN + n)
            });
            match r {
                Ok(()) => {
                    bump(&mut self.stats.segments);
                    out.next += 1;
                    self.wake = now;
                    if out.plan.is_some_and(|p| out.next >= p.count) {
                        self.active = None;
                        return Pump::Idle;
                    }
                }
                Err(SendError::NotClear(_)) => {
                    self.wake = now.saturating_add(RETRY);
                    return Pump::Blocked;
                }
                Err(SendError::TooLong) => {
                    return self.abandon(failed.unwrap_or(SegmentError::NoRoom));
                }
                Err(_) => return self.abandon(failed.unwrap_or(SegmentError::NoRoom)),
            }
        }
    }

    fn abandon(&mut self, e: SegmentError) -> Pump {
        self.active = None;
        bump(&mut self.stats.abandoned);
        Pump::Abandoned(e)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn seg(id: u8, index: u8, plan: Plan, data: &[u8]) -> [u8; 64] {
        let mut b = [0u8; 64];
        SegmentHeader {
            id,
            index,
            count: plan.count,
            len: plan.len,
        }
        .encode(&mut b)
        .unwrap();
        let o = plan.offset(index);
        let n = plan.body_len(index);
        b[HEADER_LEN..HEADER_LEN + n].copy_from_slice(&data[o..o + n]);
        b
    }

    fn seg_len(plan: Plan, index: u8) -> usize {
        HEADER_LEN + plan.body_len(index)
    }

    #[test]
    fn plans_are_even_and_fit_the_room() {
        let p = Plan::new(100, 26).unwrap();
        assert_eq!((p.count, p.stride), (5, 20));
        assert_eq!(p.body_len(4), 20);
        let p = Plan::new(101, 26).unwrap();
        assert_eq!((p.count, p.stride), (6, 17));
        assert_eq!(p.body_len(5), 16);
        assert_eq!(Plan::new(10, HEADER_LEN), Err(SegmentError::NoRoom));
        assert_eq!(Plan::new(0, 64), Err(SegmentError::BadLength));
        assert_eq!(Plan::new(256 * 10, 16), Err(SegmentError::TooLarge));
        assert_eq!(Plan::from_header(9, 4), Err(SegmentError::BadLength));
        assert_eq!(Plan::from_header(3, 4), Err(SegmentError::BadLength));
        assert_eq!(Plan::from_header(3, 0), Err(SegmentError::BadIndex));
    }

    #[test]
    fn reorder_and_duplicates() {
        let data: [u8; 50] = core::array::from_fn(|i| i as u8 ^ 0x5a);
        let data = {
            let mut d = data;
            d[0] = 2; // a reply
            d
        };
        let plan = Plan::new(50, 26).unwrap();
        let route = Route::through_links(&[1]).unwrap();
        let mut r: Reassembler<2, 64> = Reassembler::new();
        let order = [2u8, 0, 0, 1];
        let mut whole = None;
        for (k, &i) in order.iter().enumerate() {
            let s = seg(7, i, plan, &data);
            let got = r
                .on_segment(Instant::from_micros(10), &route, 4, &s[..seg_len(plan, i)])
                .unwrap()
                .map(|d| d.to_vec());
            if k < order.len() - 1 {
                assert_eq!(got, None);
            }
            whole = got;
        }
        assert_eq!(whole.as_deref(), Some(&data[..]));
        // A late duplicate of a delivered datagram is only counted.
        let s = seg(7, 1, plan, &data);
        assert_eq!(
            r.on_segment(Instant::from_micros(11), &route, 4, &s[..seg_len(plan, 1)]),
            Ok(None)
        );
        assert_eq!(r.stats().duplicates, 2);
        assert_eq!(r.stats().delivered, 1);
        assert_eq!(r.stats().segments, 3);
    }

    #[test]
    fn a_lost_segment_drops_the_datagram() {
        let data = [1u8; 40];
        let plan = Plan::new(40, 26).unwrap();
        let route = Route::local();
        let mut r: Reassembler<1, 64> =
            Reassembler::new().with_timeout(Duration::from_micros(1000));
        let s = seg(1, 0, plan, &data);
        assert_eq!(
            r.on_segment(Instant::ZERO, &route, 1, &s[..seg_len(plan, 0)]),
            Ok(None)
        );
        assert_eq!(r.next_deadline(), Some(Instant::from_micros(1000)));
        // Segment 1 never comes; the last one arrives too late.
        let s = seg(1, 1, plan, &data);
        assert_eq!(
            r.on_segment(
                Instant::from_micros(1000),
                &route,
                1,
                &s[..seg_len(plan, 1)]
            ),
            Ok(None)
        );
        assert_eq!(r.stats().lost, 1);
        assert_eq!(r.in_progress(), 1, "the late segment opened a new datagram");
        r.expire(Instant::from_micros(2000));
        assert_eq!(r.stats().lost, 2);
        assert_eq!(r.stats().delivered, 0);
    }

    #[test]
    fn refusals_are_counted() {
        let route = Route::local();
        let mut r: Reassembler<1, 32> = Reassembler::new();
        let big = Plan::new(40, 26).unwrap();
        let s = seg(0, 0, big, &[0; 40]);
        assert_eq!(
            r.on_segment(Instant::ZERO, &route, 1, &s[..seg_len(big, 0)]),
            Err(SegmentError::TooLarge)
        );
        let p = Plan::new(30, 26).unwrap();
        let s = seg(0, 0, p, &[0; 30]);
        assert_eq!(
            r.on_segment(Instant::ZERO, &route, 1, &s[..seg_len(p, 0)]),
            Ok(None)
        );
        let s = seg(1, 0, p, &[0; 30]);
        assert_eq!(
            r.on_segment(Instant::ZERO, &route, 1, &s[..seg_len(p, 0)]),
            Err(SegmentError::NoSlot)
        );
        for bad in [
            &[][..],
            &[3, 0, 0][..],
            &[0, 1, 2][..],
            &[3, 0, 0, 2, 4, 0, 1][..],    // body 1 byte, stride 2
            &[3, 0, 2, 2, 4, 0, 1, 2][..], // index 2 of 2
            &[3, 0, 0, 0, 4, 0][..],       // count 0
        ] {
            assert!(
                r.on_segment(Instant::ZERO, &route, 1, bad).is_err(),
                "{bad:?}"
            );
        }
        let st = r.stats();
        assert_eq!((st.too_large, st.no_slot, st.malformed), (1, 1, 6));
    }

    #[test]
    fn nested_segments_are_refused() {
        let route = Route::local();
        let mut r: Reassembler<1, 32> = Reassembler::new();
        assert_eq!(
            r.on_segment(Instant::ZERO, &route, 1, &[3, 0, 0, 1, 1, 0, 3]),
            Err(SegmentError::Nested)
        );
        assert_eq!(r.stats().malformed, 1);
    }

    #[test]
    fn window_keeps_only_its_part() {
        let mut out = [0u8; 4];
        let mut w = Window::new(3, &mut out);
        w.put(&[0, 1]);
        w.put(&[2, 3, 4]);
        w.put(&[5, 6, 7, 8]);
        assert!(w.is_full());
        assert_eq!(w.written(), 4);
        assert_eq!(out, [3, 4, 5, 6]);
    }
}
