//! An in-memory link gateway: two bounded packet queues.
//!
//! A [`QueueLink`] has an outbox the runtime sends into and an inbox it
//! receives from. Whatever drives the runtimes (a test, a simulator, a host
//! process joining runtimes in one address space) moves packets between the
//! outbox of one link and the inbox of its peer with [`transfer`], which is
//! also where such a driver can model wire delay, loss or a stalled peer.
//! Nothing is shared, so no locking and no allocation are needed.

use super::{LinkGateway, LinkInfo, LinkSendError, Received};
use heapless::{Deque, Vec};

/// Type name reported for in-memory links.
pub const TYPE_NAME: &str = "queue";

/// An in-memory link with `DEPTH` packets of up to `MTU` bytes each way.
#[derive(Debug, Clone)]
pub struct QueueLink<const DEPTH: usize, const MTU: usize> {
    outbox: Deque<Vec<u8, MTU>, DEPTH>,
    inbox: Deque<Vec<u8, MTU>, DEPTH>,
    open: bool,
    name: &'static str,
    sent: u32,
    received: u32,
    disconnects: u32,
    wire_time: (u32, u32),
}

impl<const DEPTH: usize, const MTU: usize> Default for QueueLink<DEPTH, MTU> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const DEPTH: usize, const MTU: usize> QueueLink<DEPTH, MTU> {
    /// An open link with empty queues.
    pub const fn new() -> Self {
        QueueLink {
            outbox: Deque::new(),
            inbox: Deque::new(),
            open: true,
            name: "",
            sent: 0,
            received: 0,
            disconnects: 0,
            wire_time: (0, 0),
        }
    }

    /// The same link reporting a transmit time of `per_packet_us` plus
    /// `per_byte_ns` for each byte, as a serial line would.
    pub const fn with_wire_time(mut self, per_packet_us: u32, per_byte_ns: u32) -> Self {
        self.wire_time = (per_packet_us, per_byte_ns);
        self
    }

    /// The same link with an instance name.
    pub const fn named(mut self, name: &'static str) -> Self {
        self.name = name;
        self
    }

    /// Opens or closes the link (a closed link neither sends nor receives).
    /// Closing an open link counts a disconnect.
    pub fn set_open(&mut self, open: bool) {
        if self.open && !open {
            self.disconnects = self.disconnects.wrapping_add(1);
        }
        self.open = open;
    }

    /// Puts a packet in the inbox as if it came off the wire. Returns false
    /// if the inbox is full or the packet is longer than `MTU`.
    pub fn inject(&mut self, packet: &[u8]) -> bool {
        let Ok(p) = Vec::from_slice(packet) else {
            return false;
        };
        self.inbox.push_back(p).is_ok()
    }

    /// Takes the oldest packet the runtime has sent.
    pub fn take_sent(&mut self) -> Option<Vec<u8, MTU>> {
        self.outbox.pop_front()
    }

    /// Number of packets waiting in the outbox.
    pub fn outbox_len(&self) -> usize {
        self.outbox.len()
    }

    /// Number of packets waiting in the inbox.
    pub fn inbox_len(&self) -> usize {
        self.inbox.len()
    }

    /// Packets sent and received over the life of the link.
    pub fn totals(&self) -> (u32, u32) {
        (self.sent, self.received)
    }
}

/// Moves up to `max` packets from `from`'s outbox to `to`'s inbox, stopping
/// early when the inbox is full (the packets stay queued: back-pressure, not
/// loss). Returns how many moved.
pub fn transfer<const D1: usize, const D2: usize, const M1: usize, const M2: usize>(
    from: &mut QueueLink<D1, M1>,
    to: &mut QueueLink<D2, M2>,
    max: usize,
) -> usize {
    let mut moved = 0;
    while moved < max && !to.inbox.is_full() {
        let Some(p) = from.outbox.pop_front() else {
            break;
        };
        // A packet too long for the far side's MTU is lost, as on a wire.
        if let Ok(p) = Vec::from_slice(&p) {
            let _ = to.inbox.push_back(p);
        }
        moved += 1;
    }
    moved
}

impl<const DEPTH: usize, const MTU: usize> LinkGateway for QueueLink<DEPTH, MTU> {
    fn info(&self) -> LinkInfo<'_> {
        LinkInfo {
            type_name: TYPE_NAME,
            name: self.name,
        }
    }

    fn is_open(&self) -> bool {
        self.open
    }

    fn mtu(&self) -> u16 {
        MTU.min(u16::MAX as usize) as u16
    }

    fn clear_to_send(&self) -> bool {
        self.open && !self.outbox.is_full()
    }

    fn send(&mut self, packet: &[u8]) -> Result<(), LinkSendError> {
        let p = Vec::from_slice(packet).map_err(|_| LinkSendError)?;
        self.outbox.push_back(p).map_err(|_| LinkSendError)?;
        self.sent = self.sent.wrapping_add(1);
        Ok(())
    }

    fn transmit_time(&self, len: usize) -> crate::time::Duration {
        let (per_packet, per_byte_ns) = self.wire_time;
        crate::time::Duration::from_micros(
            u64::from(per_packet) + (len as u64 * u64::from(per_byte_ns)).div_ceil(1000),
        )
    }

    fn counters(&self) -> Option<super::GatewayCounters> {
        Some(super::GatewayCounters {
            frames: self.received,
            disconnects: self.disconnects,
            ..Default::default()
        })
    }

    fn receive(&mut self, buf: &mut [u8]) -> Option<Received> {
        if !self.open {
            return None;
        }
        let p = self.inbox.pop_front()?;
        self.received = self.received.wrapping_add(1);
        if let Some(dst) = buf.get_mut(..p.len()) {
            dst.copy_from_slice(&p);
        }
        Some(Received {
            len: p.len(),
            timestamp: None,
        })
    }
}
