//! Ports: the runtime's interfaces up into software.
//!
//! A port object receives packets addressed to it through
//! [`Port::on_packet`] and sends through the [`PortTx`] it is handed there and
//! in [`Port::poll`]. One object may serve several consecutive port indices
//! ([`Port::port_count`]), which lets a component that owns a group of ports
//! (a function with its pipes, say) answer on one and send from another.
//!
//! Port 0 of every runtime is the netresponder and is built in; the ports a
//! caller attaches are numbered from 1, in slice order.

use crate::packet::{Instruction, PacketError};
use crate::route::Route;
use crate::stack::ClaimError;
use crate::time::{Instant, SystemInstant};
use core::fmt;

/// The names a port reports to a network scan.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PortInfo<'a> {
    /// What kind of port this is (for example `pipes_function`).
    pub type_name: &'a str,
    /// An instance name, often empty.
    pub name: &'a str,
}

/// A packet handed to a port.
#[derive(Debug, Clone, Copy)]
pub struct Delivery<'a> {
    /// Which of the object's ports it arrived at (0 for single ports).
    pub offset: u16,
    /// The payload, starting with its transport key.
    pub payload: &'a [u8],
    /// The way back to the sender, with the route MTU it was sent with.
    pub reply_route: Route,
    /// The port it was sent from, in the sender's runtime.
    pub source_port: u16,
    /// When it arrived in this runtime.
    pub arrival: Instant,
    /// When it would have expired.
    pub deadline: Instant,
}

impl Delivery<'_> {
    /// Whether it came from a port in this same runtime.
    pub fn is_local(&self) -> bool {
        self.reply_route.is_empty()
    }
}

/// Why a port could not send.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum SendError {
    /// The port is at its quota or the stack is full: not clear to send.
    NotClear(ClaimError),
    /// The packet does not fit the route MTU or the runtime's packet size.
    TooLong,
    /// The route or destination port cannot be encoded.
    BadAddress(PacketError),
    /// The sending port index does not belong to the caller.
    NoSuchPort,
}

impl fmt::Display for SendError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SendError::NotClear(e) => write!(f, "not clear to send: {e}"),
            SendError::TooLong => f.write_str("packet is longer than the route allows"),
            SendError::BadAddress(e) => write!(f, "bad address: {e}"),
            SendError::NoSuchPort => f.write_str("no such sending port"),
        }
    }
}

impl core::error::Error for SendError {}

/// What a [`PortTx`] writes through; implemented by the runtime.
pub(crate) trait PacketSink {
    fn clear_to_send(&self, from: u16) -> Result<(), ClaimError>;
    fn send(
        &mut self,
        from: u16,
        route: &Route,
        terminal: Instruction,
        ttl: u16,
        write: &mut dyn FnMut(&mut [u8]) -> Option<usize>,
    ) -> Result<(), SendError>;
}

/// A port's handle for sending, valid for one callback.
pub struct PortTx<'a> {
    pub(crate) sink: &'a mut dyn PacketSink,
    pub(crate) base: u16,
    pub(crate) count: u16,
    pub(crate) now: Instant,
    pub(crate) system: SystemInstant,
}

impl core::fmt::Debug for PortTx<'_> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("PortTx")
            .field("base", &self.base)
            .field("count", &self.count)
            .field("now", &self.now)
            .field("system", &self.system)
            .finish_non_exhaustive()
    }
}

impl PortTx<'_> {
    /// The runtime's current local time (its free-running counter), µs.
    pub fn now(&self) -> Instant {
        self.now
    }

    /// The synchronized system time at [`now`](Self::now): what
    /// time-stamped data (motion control points, sensor readings) is keyed by.
    pub fn system_time(&self) -> SystemInstant {
        self.system
    }

    /// The runtime index of this object's first port.
    pub fn port_index(&self) -> u16 {
        self.base
    }

    /// Runs `f` with a handle for the `count` ports from `offset` on, as if
    /// they were an object of their own (offset 0 is the first of them):
    /// how an object that holds other ports (a pool of blocks, say) hands
    /// each its share. `None` if they are not all this object's.
    pub fn with_sub<R>(
        &mut self,
        offset: u16,
        count: u16,
        f: impl FnOnce(&mut PortTx<'_>) -> R,
    ) -> Option<R> {
        if offset.checked_add(count)? > self.count {
            return None;
        }
        let mut sub = PortTx {
            sink: &mut *self.sink,
            base: self.base + offset,
            count,
            now: self.now,
            system: self.system,
        };
        Some(f(&mut sub))
    }

    fn index(&self, offset: u16) -> Result<u16, SendError> {
        if offset >= self.count {
            return Err(SendError::NoSuchPort);
        }
        Ok(self.base + offset)
    }

    /// Whether the port at `offset` may send now.
    pub fn clear_to_send_from(&self, offset: u16) -> bool {
        self.index(offset)
            .is_ok_and(|i| self.sink.clear_to_send(i).is_ok())
    }

    /// Whether the (first) port may send now.
    pub fn clear_to_send(&self) -> bool {
        self.clear_to_send_from(0)
    }

    /// Sends `payload` (starting with its transport key) from the first port
    /// to port `dst` at the end of `route`, expiring after `ttl` µs.
    pub fn send(
        &mut self,
        route: &Route,
        dst: u16,
        ttl: u16,
        payload: &[u8],
    ) -> Result<(), SendError> {
        self.send_from(0, route, dst, ttl, payload)
    }

    /// [`send`](Self::send) from the port at `offset`.
    pub fn send_from(
        &mut self,
        offset: u16,
        route: &Route,
        dst: u16,
        ttl: u16,
        payload: &[u8],
    ) -> Result<(), SendError> {
        self.send_with(offset, route, dst, ttl, |buf| {
            let dst = buf.get_mut(..payload.len())?;
            dst.copy_from_slice(payload);
            Some(payload.len())
        })
    }

    /// Sends from the port at `offset`, letting `write` fill the payload in
    /// place. `write` gets the room left under the MTU and returns the
    /// payload length, or `None` if it does not fit.
    pub fn send_with(
        &mut self,
        offset: u16,
        route: &Route,
        dst: u16,
        ttl: u16,
        mut write: impl FnMut(&mut [u8]) -> Option<usize>,
    ) -> Result<(), SendError> {
        let src = self.index(offset)?;
        let terminal = Instruction::PortHandle { src, dst };
        self.sink.send(src, route, terminal, ttl, &mut write)
    }
}

/// A software interface attached to a runtime.
pub trait Port {
    /// How many consecutive port indices this object serves.
    fn port_count(&self) -> u16 {
        1
    }

    /// The names of the port at `offset`.
    fn info(&self, offset: u16) -> PortInfo<'_>;

    /// Whether the port at `offset` can take a packet now. A port that is not
    /// clear leaves its packets waiting in the stack until their deadline.
    fn clear_to_receive(&self, offset: u16) -> bool {
        let _ = offset;
        true
    }

    /// Handles a packet addressed to the port at `delivery.offset`.
    fn on_packet(&mut self, delivery: Delivery<'_>, tx: &mut PortTx<'_>);

    /// Called once per runtime loop, to do periodic work and send.
    fn poll(&mut self, tx: &mut PortTx<'_>) {
        let _ = tx;
    }

    /// The local time by which this port needs [`poll`](Self::poll) to run
    /// again (a timer, a retransmission), if any. The runtime folds it into
    /// [`PollResult::wake_at`](crate::runtime::PollResult::wake_at), so a
    /// runtime that sleeps until then never misses it. A time already past
    /// asks for a poll as soon as possible.
    fn wake_at(&self) -> Option<Instant> {
        None
    }
}

macro_rules! forward_port {
    () => {
        fn port_count(&self) -> u16 {
            (**self).port_count()
        }
        fn info(&self, offset: u16) -> PortInfo<'_> {
            (**self).info(offset)
        }
        fn clear_to_receive(&self, offset: u16) -> bool {
            (**self).clear_to_receive(offset)
        }
        fn on_packet(&mut self, delivery: Delivery<'_>, tx: &mut PortTx<'_>) {
            (**self).on_packet(delivery, tx)
        }
        fn poll(&mut self, tx: &mut PortTx<'_>) {
            (**self).poll(tx)
        }
        fn wake_at(&self) -> Option<Instant> {
            (**self).wake_at()
        }
    };
}

impl<T: Port + ?Sized> Port for &mut T {
    forward_port!();
}

#[cfg(feature = "std")]
impl<T: Port + ?Sized> Port for std::boxed::Box<T> {
    forward_port!();
}
