//! The packet stack: fixed slots served earliest deadline first, in order
//! per owner.
//!
//! Every packet a runtime holds lives in one of `N` slots of `MTU` bytes.
//! Each slot is charged to its *owner*: the port that wrote it, the link it
//! arrived on, or the runtime itself. Owners have hold quotas (by default 2
//! slots per port and 4 per link), so one busy producer cannot fill the stack
//! and starve the rest; a producer over quota is simply not clear to send,
//! which pushes back on it.
//!
//! # Serving order
//!
//! Occupied slots are threaded on a doubly linked list in serving order, so
//! the runtime loop walks it front to back without ever re-sorting. The
//! order is earliest deadline first, with one rule on top: **a packet never
//! overtakes a queued packet of its own owner.** Each slot has a *serving
//! key*: its deadline, or the key of its owner's newest queued packet if
//! that is later. The list is sorted by key, first come, first served among
//! equal keys. So packets of different owners go earliest deadline first,
//! and the packets of one owner (one link, one port) leave in the order they
//! came, whatever their deadlines.
//!
//! The rule matters because a deadline is rebuilt at every hop from the
//! packet's own arrival (`arrival + ttl`, docs/protocol.md §1): two packets
//! that a sender sent in order, the second after a scheduling delay, reach
//! the next hop in one read with the second one's deadline earlier. Served
//! by deadline alone, the second would overtake the first, and a stream of
//! motion points would reach its module out of order.
//!
//! The key only places a slot in the list. The slot keeps its own deadline:
//! it expires by it, and the TTL written when it is sent on counts from it.
//! Since keys may be later than deadlines, the list's head is not always
//! the earliest deadline: [`PacketStack::earliest_deadline`] looks at every
//! slot.
//!
//! A new packet is placed by walking back from the tail, which is one step
//! in the common case (equal TTLs, arriving in order); taking a packet out is
//! constant time and moves no memory.

use crate::time::Instant;
use core::fmt;
use heapless::Vec;

/// End of the list.
const NIL: u16 = u16::MAX;

/// Default number of slots a port may hold at once.
pub const DEFAULT_PORT_QUOTA: u8 = 2;
/// Default number of slots a link gateway may hold at once.
pub const DEFAULT_LINK_QUOTA: u8 = 4;
/// Default number of slots the runtime may hold for its own system messages.
pub const DEFAULT_SYSTEM_QUOTA: u8 = 4;

/// Who a slot is charged to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Owner {
    /// A port, by index.
    Port(u16),
    /// A link gateway, by index.
    Link(u8),
    /// The runtime itself (system messages such as time stamps).
    System,
}

/// Why a slot could not be claimed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum ClaimError {
    /// Every slot is in use.
    StackFull,
    /// The owner already holds as many slots as its quota allows.
    QuotaExceeded,
    /// The owner's index is beyond what this stack tracks.
    UnknownOwner,
}

impl fmt::Display for ClaimError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            ClaimError::StackFull => "packet stack is full",
            ClaimError::QuotaExceeded => "owner is at its packet quota",
            ClaimError::UnknownOwner => "owner index is out of range",
        })
    }
}

impl core::error::Error for ClaimError {}

/// Why [`PacketStack::push_with`] did not store a packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum PushError<E> {
    /// No slot could be claimed.
    Claim(ClaimError),
    /// The writer closure failed; the slot was returned.
    Write(E),
    /// The writer reported a length longer than the slot; the slot was
    /// returned.
    Length,
}

impl<E: fmt::Display> fmt::Display for PushError<E> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PushError::Claim(e) => write!(f, "no slot: {e}"),
            PushError::Write(e) => write!(f, "the packet could not be written: {e}"),
            PushError::Length => f.write_str("the written length is longer than the slot"),
        }
    }
}

impl<E: fmt::Debug + fmt::Display> core::error::Error for PushError<E> {}

/// Identifies an occupied slot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct SlotId(u16);

impl SlotId {
    /// The slot's index in the stack.
    pub const fn index(self) -> usize {
        self.0 as usize
    }
}

/// What the stack knows about one occupied slot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SlotMeta {
    /// Length of the packet in the slot.
    pub len: u16,
    /// When the packet entered this runtime.
    pub arrival: Instant,
    /// When the packet expires; it is dropped once `now > deadline`.
    pub deadline: Instant,
    /// Who the slot is charged to.
    pub owner: Owner,
}

impl SlotMeta {
    const EMPTY: SlotMeta = SlotMeta {
        len: 0,
        arrival: Instant::ZERO,
        deadline: Instant::ZERO,
        owner: Owner::System,
    };
}

#[derive(Debug, Clone, Copy)]
struct Hold {
    held: u8,
    max: u8,
}

/// Fixed-size packet storage in serving order (earliest deadline first,
/// never ahead of the same owner's queued packets; see the [module
/// docs](self)), with per-owner quotas.
///
/// `N` slots of `MTU` bytes; `P` ports and `L` links have quota entries.
pub struct PacketStack<const N: usize, const MTU: usize, const P: usize, const L: usize> {
    bufs: [[u8; MTU]; N],
    meta: [SlotMeta; N],
    // Serving keys: a slot's deadline, or its owner's previous queued
    // packet's key if later. The list below is sorted by them.
    key: [Instant; N],
    // Serving order: `next`/`prev` link occupied slots, head is served first.
    next: [u16; N],
    prev: [u16; N],
    queued: [bool; N],
    head: u16,
    tail: u16,
    len: u16,
    pushes: u32,
    free: Vec<u16, N>,
    ports: [Hold; P],
    links: [Hold; L],
    system: Hold,
}

impl<const N: usize, const MTU: usize, const P: usize, const L: usize> core::fmt::Debug
    for PacketStack<N, MTU, P, L>
{
    /// A summary: the slot buffers are not printed.
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("PacketStack")
            .field("slots", &N)
            .field("mtu", &MTU)
            .field("held", &self.len())
            .finish_non_exhaustive()
    }
}

impl<const N: usize, const MTU: usize, const P: usize, const L: usize> Default
    for PacketStack<N, MTU, P, L>
{
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize, const MTU: usize, const P: usize, const L: usize> PacketStack<N, MTU, P, L> {
    /// An empty stack with default quotas.
    pub fn new() -> Self {
        const {
            assert!(
                N > 0 && N <= u16::MAX as usize,
                "stack needs 1..=65535 slots"
            )
        };
        const { assert!(MTU <= u16::MAX as usize, "slot size must fit a u16") };
        let mut free = Vec::new();
        // Hand out low indices first: it keeps a lightly used stack's working
        // set small, which matters for cache-less microcontrollers only a
        // little, but makes debugging dumps readable.
        for i in (0..N as u16).rev() {
            let _ = free.push(i);
        }
        PacketStack {
            bufs: [[0; MTU]; N],
            meta: [SlotMeta::EMPTY; N],
            key: [Instant::ZERO; N],
            next: [NIL; N],
            prev: [NIL; N],
            queued: [false; N],
            head: NIL,
            tail: NIL,
            len: 0,
            pushes: 0,
            free,
            ports: [Hold {
                held: 0,
                max: DEFAULT_PORT_QUOTA,
            }; P],
            links: [Hold {
                held: 0,
                max: DEFAULT_LINK_QUOTA,
            }; L],
            system: Hold {
                held: 0,
                max: DEFAULT_SYSTEM_QUOTA,
            },
        }
    }

    /// Total number of slots.
    pub const fn capacity(&self) -> usize {
        N
    }

    /// Bytes per slot: the largest packet this stack can hold.
    pub const fn slot_size(&self) -> usize {
        MTU
    }

    /// Number of packets queued.
    pub fn len(&self) -> usize {
        usize::from(self.len)
    }

    /// Whether no packet is queued.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Number of free slots.
    pub fn free_slots(&self) -> usize {
        self.free.len()
    }

    fn hold(&self, owner: Owner) -> Option<&Hold> {
        match owner {
            Owner::Port(p) => self.ports.get(p as usize),
            Owner::Link(l) => self.links.get(l as usize),
            Owner::System => Some(&self.system),
        }
    }

    fn hold_mut(&mut self, owner: Owner) -> Option<&mut Hold> {
        match owner {
            Owner::Port(p) => self.ports.get_mut(p as usize),
            Owner::Link(l) => self.links.get_mut(l as usize),
            Owner::System => Some(&mut self.system),
        }
    }

    /// Sets how many slots `owner` may hold at once (0 stops it entirely).
    pub fn set_quota(&mut self, owner: Owner, max: u8) -> Result<(), ClaimError> {
        self.hold_mut(owner).ok_or(ClaimError::UnknownOwner)?.max = max;
        Ok(())
    }

    /// The quota of `owner`.
    pub fn quota(&self, owner: Owner) -> Option<u8> {
        self.hold(owner).map(|h| h.max)
    }

    /// How many more slots `owner` could claim now (its quota left, at
    /// most the free slots).
    pub fn room(&self, owner: Owner) -> u8 {
        let left = self.hold(owner).map_or(0, |h| h.max.saturating_sub(h.held));
        left.min(self.free.len().min(usize::from(u8::MAX)) as u8)
    }

    /// How many slots `owner` holds now.
    pub fn held(&self, owner: Owner) -> Option<u8> {
        self.hold(owner).map(|h| h.held)
    }

    /// Whether `owner` could claim a slot right now.
    pub fn check_claim(&self, owner: Owner) -> Result<(), ClaimError> {
        let hold = self.hold(owner).ok_or(ClaimError::UnknownOwner)?;
        if hold.held >= hold.max {
            return Err(ClaimError::QuotaExceeded);
        }
        if self.free.is_empty() {
            return Err(ClaimError::StackFull);
        }
        Ok(())
    }

    /// Claims a slot for `owner`, lets `write` fill it, and queues it by
    /// deadline, behind every packet `owner` has queued.
    ///
    /// `write` gets the whole slot buffer and returns the packet length and
    /// its deadline. If it fails, or returns a length longer than the slot,
    /// the slot goes straight back and nothing is queued.
    pub fn push_with<E>(
        &mut self,
        owner: Owner,
        arrival: Instant,
        write: impl FnOnce(&mut [u8]) -> Result<(usize, Instant), E>,
    ) -> Result<SlotId, PushError<E>> {
        self.check_claim(owner).map_err(PushError::Claim)?;
        let Some(slot) = self.free.pop() else {
            return Err(PushError::Claim(ClaimError::StackFull));
        };
        let (len, deadline) = match write(&mut self.bufs[slot as usize]) {
            Ok((len, deadline)) if len <= MTU => (len, deadline),
            Ok(_) => {
                let _ = self.free.push(slot);
                return Err(PushError::Length);
            }
            Err(e) => {
                let _ = self.free.push(slot);
                return Err(PushError::Write(e));
            }
        };
        if let Some(h) = self.hold_mut(owner) {
            h.held = h.held.saturating_add(1);
        }
        self.meta[slot as usize] = SlotMeta {
            len: len as u16,
            arrival,
            deadline,
            owner,
        };
        let key = self.serving_key(owner, deadline);
        self.key[slot as usize] = key;
        self.link_by_key(slot, key);
        Ok(SlotId(slot))
    }

    /// The serving key of a new packet of `owner` due at `deadline`: the
    /// deadline, or the key of the owner's newest queued packet if that is
    /// later. That packet is the owner's last in the list (its packets are
    /// in the order they came), so a walk back from the tail finds it, or
    /// stops at a key at or before `deadline`, before which every key is
    /// at or before `deadline` too.
    fn serving_key(&self, owner: Owner, deadline: Instant) -> Instant {
        let mut at = self.tail;
        while at != NIL {
            let i = usize::from(at);
            if self.key[i] <= deadline {
                break;
            }
            if self.meta[i].owner == owner {
                return self.key[i];
            }
            at = self.prev[i];
        }
        deadline
    }

    /// Threads `slot` into the list after every packet whose key is at or
    /// before `key`, so equal keys stay first come, first served.
    fn link_by_key(&mut self, slot: u16, key: Instant) {
        let mut after = self.tail;
        while after != NIL && self.key[usize::from(after)] > key {
            after = self.prev[usize::from(after)];
        }
        let before = if after == NIL {
            self.head
        } else {
            self.next[usize::from(after)]
        };
        self.prev[usize::from(slot)] = after;
        self.next[usize::from(slot)] = before;
        if after == NIL {
            self.head = slot;
        } else {
            self.next[usize::from(after)] = slot;
        }
        if before == NIL {
            self.tail = slot;
        } else {
            self.prev[usize::from(before)] = slot;
        }
        self.queued[usize::from(slot)] = true;
        self.len += 1;
        self.pushes = self.pushes.wrapping_add(1);
    }

    /// Packets queued over the stack's life (wrapping): a change tells the
    /// runtime that serving produced new packets.
    pub fn pushes(&self) -> u32 {
        self.pushes
    }

    fn id(&self, slot: u16) -> Option<SlotId> {
        (slot != NIL).then_some(SlotId(slot))
    }

    /// The packet served first: the earliest deadline, unless a packet of
    /// the same owner queued before it is due later (see the [module
    /// docs](self)).
    pub fn first(&self) -> Option<SlotId> {
        self.id(self.head)
    }

    /// The packet served after `slot`.
    pub fn next(&self, slot: SlotId) -> Option<SlotId> {
        if !self.is_queued(slot) {
            return None;
        }
        self.id(self.next[slot.index()])
    }

    /// Whether `slot` holds a queued packet.
    pub fn is_queued(&self, slot: SlotId) -> bool {
        self.queued.get(slot.index()).copied().unwrap_or(false)
    }

    /// The packets in serving order, first served first.
    pub fn iter(&self) -> impl Iterator<Item = SlotId> + '_ {
        core::iter::successors(self.first(), move |&s| self.next(s))
    }

    /// The slot at position `pos` in serving order (0 is served first).
    /// Walks the list: for inspection and tests, not for the hot path.
    pub fn at(&self, pos: usize) -> Option<SlotId> {
        self.iter().nth(pos)
    }

    /// The earliest deadline of any queued packet: when the first of them
    /// expires. (It need not be the first served: a packet queued behind
    /// one of its owner's may be due sooner.) Looks at every slot.
    pub fn earliest_deadline(&self) -> Option<Instant> {
        self.iter().map(|s| self.meta[s.index()].deadline).min()
    }

    /// Metadata of an occupied slot.
    pub fn meta(&self, slot: SlotId) -> &SlotMeta {
        &self.meta[slot.index()]
    }

    /// Corrects when a queued packet arrived (a link's wire time stamp).
    pub fn set_arrival(&mut self, slot: SlotId, arrival: Instant) {
        if self.is_queued(slot) {
            self.meta[slot.index()].arrival = arrival;
        }
    }

    /// The packet in a slot.
    pub fn packet(&self, slot: SlotId) -> &[u8] {
        let len = self.meta[slot.index()].len as usize;
        &self.bufs[slot.index()][..len]
    }

    /// The packet in a slot, for in-place rewrites.
    pub fn packet_mut(&mut self, slot: SlotId) -> &mut [u8] {
        let len = self.meta[slot.index()].len as usize;
        &mut self.bufs[slot.index()][..len]
    }

    /// Takes the packet in `slot` off the list and frees the slot, returning
    /// its metadata; `None` if the slot held no packet.
    pub fn release(&mut self, slot: SlotId) -> Option<SlotMeta> {
        if !self.is_queued(slot) {
            return None;
        }
        let i = slot.index();
        let (prev, next) = (self.prev[i], self.next[i]);
        if prev == NIL {
            self.head = next;
        } else {
            self.next[usize::from(prev)] = next;
        }
        if next == NIL {
            self.tail = prev;
        } else {
            self.prev[usize::from(next)] = prev;
        }
        self.queued[i] = false;
        self.len -= 1;
        let meta = self.meta[i];
        if let Some(h) = self.hold_mut(meta.owner) {
            h.held = h.held.saturating_sub(1);
        }
        let _ = self.free.push(slot.0);
        Some(meta)
    }

    /// Releases the packet at position `pos` in serving order.
    pub fn release_at(&mut self, pos: usize) -> Option<SlotMeta> {
        let slot = self.at(pos)?;
        self.release(slot)
    }

    /// Frees every slot (for a runtime reset).
    pub fn clear(&mut self) {
        while let Some(slot) = self.first() {
            self.release(slot);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    type Stack = PacketStack<4, 16, 4, 2>;

    fn push(s: &mut Stack, owner: Owner, deadline: Instant) -> Result<SlotId, ClaimError> {
        s.push_with(owner, Instant::ZERO, |buf| {
            buf[0] = deadline.as_micros() as u8;
            Ok::<_, ()>((1, deadline))
        })
        .map_err(|e| match e {
            PushError::Claim(c) => c,
            other => panic!("unexpected {other:?}"),
        })
    }

    fn order(s: &Stack) -> heapless::Vec<SlotId, 4> {
        s.iter().collect()
    }

    #[test]
    fn serves_in_deadline_order_fifo_on_ties() {
        // Four owners: earliest deadline first, first come first served
        // among equal deadlines.
        let mut s = Stack::new();
        let a = push(&mut s, Owner::Port(0), Instant::from_micros(30)).unwrap();
        let b = push(&mut s, Owner::Port(1), Instant::from_micros(10)).unwrap();
        let c = push(&mut s, Owner::Link(0), Instant::from_micros(30)).unwrap();
        let d = push(&mut s, Owner::Link(1), Instant::from_micros(20)).unwrap();
        assert_eq!(order(&s).as_slice(), &[b, d, a, c]);
        assert_eq!(s.earliest_deadline(), Some(Instant::from_micros(10)));
    }

    #[test]
    fn a_burst_from_one_link_leaves_in_arrival_order() {
        // Sent in order, the later ones after a scheduling delay, then read
        // in one go: each rebuilt deadline is earlier than the one before.
        let mut s = Stack::new();
        let link = Owner::Link(0);
        let burst: heapless::Vec<SlotId, 4> = [50, 40, 30, 20]
            .into_iter()
            .map(|d| push(&mut s, link, Instant::from_micros(d)).unwrap())
            .collect();
        assert_eq!(order(&s), burst);
        // Each keeps its own deadline, and the earliest is found though it
        // is served last.
        assert_eq!(s.meta(burst[3]).deadline, Instant::from_micros(20));
        assert_eq!(s.earliest_deadline(), Some(Instant::from_micros(20)));
        // Served one by one, the rest stay in order.
        s.release(burst[0]);
        assert_eq!(order(&s).as_slice(), &burst[1..]);
        assert_eq!(s.earliest_deadline(), Some(Instant::from_micros(20)));
        // A port's packets too.
        let mut s = Stack::new();
        let a = push(&mut s, Owner::Port(2), Instant::from_micros(9)).unwrap();
        let b = push(&mut s, Owner::Port(2), Instant::from_micros(3)).unwrap();
        assert_eq!(order(&s).as_slice(), &[a, b]);
    }

    #[test]
    fn other_owners_still_go_earliest_deadline_first() {
        let mut s = Stack::new();
        // Link 0: a, then b due sooner, held behind a (served at a's 50).
        let a = push(&mut s, Owner::Link(0), Instant::from_micros(50)).unwrap();
        let b = push(&mut s, Owner::Link(0), Instant::from_micros(20)).unwrap();
        // Due at 30, another owner's c goes before both: b's place is a's.
        let c = push(&mut s, Owner::Port(1), Instant::from_micros(30)).unwrap();
        assert_eq!(order(&s).as_slice(), &[c, a, b]);
        // Due at 50, d ties with a and b's place: after them.
        let d = push(&mut s, Owner::Link(1), Instant::from_micros(50)).unwrap();
        assert_eq!(order(&s).as_slice(), &[c, a, b, d]);
        // The earliest to expire is b, served third.
        assert_eq!(s.earliest_deadline(), Some(Instant::from_micros(20)));
        assert_eq!(s.meta(b).deadline, Instant::from_micros(20));
        // With a gone, b keeps its place (50): link 0's next packet, due
        // at 10, still goes behind it, and behind d, which came first.
        s.release(a);
        s.release(c);
        let e = push(&mut s, Owner::Link(0), Instant::from_micros(10)).unwrap();
        assert_eq!(order(&s).as_slice(), &[b, d, e]);
        s.release(b);
        s.release(d);
        s.release(e);
        // With nothing of link 0's queued, its packets go by deadline again.
        let f = push(&mut s, Owner::Link(1), Instant::from_micros(40)).unwrap();
        let g = push(&mut s, Owner::Link(0), Instant::from_micros(10)).unwrap();
        assert_eq!(order(&s).as_slice(), &[g, f]);
    }

    #[test]
    fn quotas_and_fullness() {
        let mut s = Stack::new();
        push(&mut s, Owner::Port(1), Instant::from_micros(1)).unwrap();
        push(&mut s, Owner::Port(1), Instant::from_micros(1)).unwrap();
        assert_eq!(
            push(&mut s, Owner::Port(1), Instant::from_micros(1)),
            Err(ClaimError::QuotaExceeded)
        );
        push(&mut s, Owner::Link(0), Instant::from_micros(1)).unwrap();
        push(&mut s, Owner::Link(1), Instant::from_micros(1)).unwrap();
        assert_eq!(
            push(&mut s, Owner::Link(0), Instant::from_micros(1)),
            Err(ClaimError::StackFull)
        );
        assert_eq!(
            push(&mut s, Owner::Port(9), Instant::from_micros(1)),
            Err(ClaimError::UnknownOwner)
        );
        let meta = s.release_at(0).unwrap();
        assert_eq!(meta.owner, Owner::Port(1));
        assert_eq!(s.held(Owner::Port(1)), Some(1));
        push(&mut s, Owner::Port(1), Instant::from_micros(1)).unwrap();
    }

    #[test]
    fn failed_writer_returns_the_slot() {
        let mut s = Stack::new();
        let r = s.push_with(Owner::System, Instant::ZERO, |_| {
            Err::<(usize, Instant), _>("nope")
        });
        assert_eq!(r, Err(PushError::Write("nope")));
        assert_eq!(s.free_slots(), 4);
        assert_eq!(s.held(Owner::System), Some(0));
    }
}
