//! Link gateways: the runtime's interfaces down to network links.
//!
//! A gateway moves whole packets; framing (for byte streams) happens inside
//! the gateway, below this trait. The runtime pulls received packets with
//! [`LinkGateway::receive`] only while the link has quota in the packet stack,
//! so a full runtime leaves packets in the link's own buffer and the link's
//! flow control (or the wire) pushes back on the sender.

pub mod queue;

pub use crate::counters::GatewayCounters;
use crate::time::{Duration, Instant};

/// The names a link gateway reports to a network scan.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LinkInfo<'a> {
    /// What kind of link this is (for example `uart`, `usb_cdc`, `udp`).
    pub type_name: &'a str,
    /// An instance name, often empty.
    pub name: &'a str,
}

/// What a bus link reports of itself (see [`crate::bus`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct BusInfo {
    /// This station's drop address (0 = the head).
    pub drop: u8,
    /// Drops known present, one bit per address (bit `d % 32` of word
    /// `d / 32`): the drops that answered their last turn for the head,
    /// the head (drop 0) for a drop.
    pub present: [u32; 8],
    /// Stations heard at least once since the bus started, in the same
    /// bits: a superset of `present`. A drop here but not in `present` was
    /// heard before and missed its last turn (busy, hung or unplugged):
    /// it is still there to ask, and a scan that did not ask it would lose
    /// it without a word.
    pub known: [u32; 8],
}

impl BusInfo {
    /// Whether drop `d` is known present.
    pub fn is_present(&self, d: u8) -> bool {
        self.present[usize::from(d / 32)] & (1 << (d % 32)) != 0
    }

    /// The drops known present, ascending.
    pub fn drops(&self) -> impl Iterator<Item = u8> + '_ {
        (0..=254u8).filter(|&d| self.is_present(d))
    }

    /// Whether drop `d` was heard at least once ([`known`](Self::known)).
    pub fn is_known(&self, d: u8) -> bool {
        self.known[usize::from(d / 32)] & (1 << (d % 32)) != 0
    }
}

/// A packet a link gateway has received.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Received {
    /// Length of the packet. If larger than the buffer the runtime offered,
    /// the packet was not copied and is dropped as oversize.
    pub len: usize,
    /// When its first byte arrived on the wire, on the runtime's local
    /// clock, if the link can tell (a receive interrupt, or the frame's end
    /// minus its wire time). Clock sync is only as good as this stamp; links
    /// that cannot tell leave it `None` and the runtime uses the poll time.
    pub timestamp: Option<Instant>,
}

/// A link gateway could not transmit a packet it had said it was clear for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LinkSendError;

impl core::fmt::Display for LinkSendError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("link failed to transmit")
    }
}

impl core::error::Error for LinkSendError {}

/// An interface from a runtime to one network link.
pub trait LinkGateway {
    /// The names of this link.
    fn info(&self) -> LinkInfo<'_>;

    /// Whether the link is up (connected, enumerated, has a peer).
    fn is_open(&self) -> bool;

    /// Largest packet the link carries, in bytes.
    fn mtu(&self) -> u16;

    /// Whether [`send`](Self::send) would accept a packet now.
    fn clear_to_send(&self) -> bool;

    /// Transmits one packet. Only called after `clear_to_send` returned true.
    fn send(&mut self, packet: &[u8]) -> Result<(), LinkSendError>;

    /// How long the link takes to put `len` bytes of packet on the wire, µs
    /// (for a UART: framing overhead and bits at the baud rate). The runtime
    /// takes it off the TTL it writes, so time on the wire counts against a
    /// packet's deadline; links that cannot tell return 0.
    fn transmit_time(&self, len: usize) -> Duration {
        let _ = len;
        Duration::ZERO
    }

    /// How long from now until a packet sent now would start onto the wire,
    /// µs: the time to drain what is queued ahead of it, or to reach the
    /// next bus slot (a USB device knows its frame timing from SOF). The
    /// runtime adds it to the time stamps of clock-sync messages it
    /// transmits, so they describe the moment on the wire.
    fn queue_delay(&self) -> Duration {
        Duration::ZERO
    }

    /// Copies the next received packet into `buf`, if there is one.
    fn receive(&mut self, buf: &mut [u8]) -> Option<Received>;

    /// Called once per runtime loop before packets are exchanged.
    fn poll(&mut self, now: Instant) {
        let _ = now;
    }

    /// What the gateway counts of its own traffic (frames, frame errors,
    /// its own drops, disconnects), for the netresponder's link-counters
    /// request; `None` if it keeps no counters.
    fn counters(&self) -> Option<GatewayCounters> {
        None
    }

    /// For a bus link (one link index serving many drops, addressed with
    /// `bus_forward`): its address and the drops it knows. `None` for a
    /// point-to-point link.
    fn bus(&self) -> Option<BusInfo> {
        None
    }

    /// Transmits one packet to drop `drop` of a bus link (255 = every
    /// drop). Only called after `clear_to_send` returned true; a
    /// point-to-point link ignores the address.
    fn send_to(&mut self, drop: u8, packet: &[u8]) -> Result<(), LinkSendError> {
        let _ = drop;
        self.send(packet)
    }

    /// For a bus link: the drop that sent the packet most recently returned
    /// by [`receive`](Self::receive).
    fn received_from(&self) -> Option<u8> {
        None
    }

    /// When the link needs [`poll`](Self::poll) again by itself (a bus
    /// turn to hand on or time out), on the runtime's local clock.
    fn wake_at(&self) -> Option<Instant> {
        None
    }

    /// Told by the runtime before each [`poll`](Self::poll): how many
    /// packets it could take from this link now. A bus head lends the
    /// medium only while a drop's whole turn would fit, so what a drop
    /// sends is never left unread (its turn's `END` behind it).
    fn set_rx_room(&mut self, room: u8) {
        let _ = room;
    }

    /// Whether the network may set this link's bus role (netresponder key
    /// `SET_BUS`): true for a link that can switch between point to point
    /// and a bus station ([`crate::bus::Switchable`]).
    fn bus_configurable(&self) -> bool {
        false
    }
}

macro_rules! forward_link_gateway {
    () => {
        fn info(&self) -> LinkInfo<'_> {
            (**self).info()
        }
        fn is_open(&self) -> bool {
            (**self).is_open()
        }
        fn mtu(&self) -> u16 {
            (**self).mtu()
        }
        fn clear_to_send(&self) -> bool {
            (**self).clear_to_send()
        }
        fn send(&mut self, packet: &[u8]) -> Result<(), LinkSendError> {
            (**self).send(packet)
        }
        fn transmit_time(&self, len: usize) -> Duration {
            (**self).transmit_time(len)
        }
        fn queue_delay(&self) -> Duration {
            (**self).queue_delay()
        }
        fn receive(&mut self, buf: &mut [u8]) -> Option<Received> {
            (**self).receive(buf)
        }
        fn poll(&mut self, now: Instant) {
            (**self).poll(now)
        }
        fn counters(&self) -> Option<GatewayCounters> {
            (**self).counters()
        }
        fn bus(&self) -> Option<BusInfo> {
            (**self).bus()
        }
        fn send_to(&mut self, drop: u8, packet: &[u8]) -> Result<(), LinkSendError> {
            (**self).send_to(drop, packet)
        }
        fn received_from(&self) -> Option<u8> {
            (**self).received_from()
        }
        fn wake_at(&self) -> Option<Instant> {
            (**self).wake_at()
        }
        fn set_rx_room(&mut self, room: u8) {
            (**self).set_rx_room(room)
        }
        fn bus_configurable(&self) -> bool {
            (**self).bus_configurable()
        }
    };
}

impl<T: LinkGateway + ?Sized> LinkGateway for &mut T {
    forward_link_gateway!();
}

#[cfg(feature = "std")]
impl<T: LinkGateway + ?Sized> LinkGateway for std::boxed::Box<T> {
    forward_link_gateway!();
}
