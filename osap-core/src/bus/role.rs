//! A link's bus role, chosen at run time: off (point to point), the head
//! of a bus, or one of its drops.
//!
//! A module's UART can sit on a point-to-point line or on a shared RS-485
//! pair; which one is a property of the installation, not of the firmware
//! image. So the role is a setting: the network sets it (netresponder key
//! `SET_BUS`), the firmware keeps it in flash beside the module's name, and
//! [`Switchable`] applies it to the link without a reboot.

use super::{BusConfig, BusCore, HEAD};
use crate::link::{BusInfo, GatewayCounters, LinkGateway, LinkInfo, LinkSendError, Received};
use crate::time::{Duration, Instant};

/// What a link is on its medium.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum BusRole {
    /// Point to point: no bus header, no arbitration.
    #[default]
    Off,
    /// The head of a bus, polling drops `1..=max_drop`.
    Head {
        /// The highest drop address polled (1..=254).
        max_drop: u8,
    },
    /// A drop at this address (1..=254).
    Drop(u8),
}

/// Two bytes that name no role.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BadRole;

impl core::fmt::Display for BadRole {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("not a bus role: off, head of drops 1..=254, or drop 1..=254")
    }
}

impl core::error::Error for BadRole {}

impl BusRole {
    /// The role as its two wire bytes: `[0, 0]` off, `[1, max_drop]` head,
    /// `[2, drop]` drop.
    pub fn to_bytes(self) -> [u8; 2] {
        match self {
            BusRole::Off => [0, 0],
            BusRole::Head { max_drop } => [1, max_drop],
            BusRole::Drop(d) => [2, d],
        }
    }

    /// The role two wire bytes name, refusing addresses outside 1..=254.
    pub fn from_bytes(b: [u8; 2]) -> Result<BusRole, BadRole> {
        match b {
            [0, 0] => Ok(BusRole::Off),
            [1, m @ 1..=254] => Ok(BusRole::Head { max_drop: m }),
            [2, d @ 1..=254] => Ok(BusRole::Drop(d)),
            _ => Err(BadRole),
        }
    }

    /// The bus configuration of this role, or `None` when off.
    pub fn config(self) -> Option<BusConfig> {
        match self {
            BusRole::Off => None,
            BusRole::Head { max_drop } => Some(BusConfig::head(max_drop)),
            BusRole::Drop(d) => Some(BusConfig::drop(d)),
        }
    }
}

/// A link that is point to point or a bus station, as its [`BusRole`]
/// says; the role can change while it runs. `N` is as in [`BusCore`].
#[derive(Debug)]
pub struct Switchable<L, const N: usize = 259> {
    role: BusRole,
    core: Option<BusCore<N>>,
    /// The link below (framing, wire).
    pub lower: L,
}

impl<L: LinkGateway, const N: usize> Switchable<L, N> {
    /// The link `lower` in `role`.
    pub fn new(lower: L, role: BusRole) -> Self {
        Switchable {
            role,
            core: role.config().map(BusCore::new),
            lower,
        }
    }

    /// The current role.
    pub fn role(&self) -> BusRole {
        self.role
    }

    /// Takes a new role at once; a bus station starts afresh (its turn,
    /// counters and the drops it knew are forgotten).
    pub fn set_role(&mut self, role: BusRole) {
        if role != self.role {
            self.role = role;
            self.core = role.config().map(BusCore::new);
        }
    }

    /// The bus station's state, when the link is on a bus.
    pub fn bus_core(&self) -> Option<&BusCore<N>> {
        self.core.as_ref()
    }
}

impl<L: LinkGateway, const N: usize> LinkGateway for Switchable<L, N> {
    fn info(&self) -> LinkInfo<'_> {
        self.lower.info()
    }
    fn is_open(&self) -> bool {
        self.lower.is_open()
    }
    fn mtu(&self) -> u16 {
        match &self.core {
            Some(c) => c.mtu(&self.lower),
            None => self.lower.mtu(),
        }
    }
    fn clear_to_send(&self) -> bool {
        match &self.core {
            Some(c) => c.clear_to_send(&self.lower),
            None => self.lower.clear_to_send(),
        }
    }
    fn send(&mut self, packet: &[u8]) -> Result<(), LinkSendError> {
        match &mut self.core {
            Some(c) => {
                let to = if c.config().is_head() {
                    super::BROADCAST
                } else {
                    HEAD
                };
                c.send_to(&mut self.lower, to, packet)
            }
            None => self.lower.send(packet),
        }
    }
    fn send_to(&mut self, drop: u8, packet: &[u8]) -> Result<(), LinkSendError> {
        match &mut self.core {
            Some(c) => c.send_to(&mut self.lower, drop, packet),
            // The runtime sends bus hops only on links that report a bus.
            None => Err(LinkSendError),
        }
    }
    fn transmit_time(&self, len: usize) -> Duration {
        let header = if self.core.is_some() {
            super::HEADER_LEN
        } else {
            0
        };
        self.lower.transmit_time(len + header)
    }
    fn queue_delay(&self) -> Duration {
        self.lower.queue_delay()
    }
    fn receive(&mut self, buf: &mut [u8]) -> Option<Received> {
        match &mut self.core {
            Some(c) => c.receive(&mut self.lower, buf),
            None => self.lower.receive(buf),
        }
    }
    fn poll(&mut self, now: Instant) {
        self.lower.poll(now);
        if let Some(c) = &mut self.core {
            c.poll(&mut self.lower, now);
        }
    }
    fn counters(&self) -> Option<GatewayCounters> {
        let Some(c) = &self.core else {
            return self.lower.counters();
        };
        let mut out = self.lower.counters().unwrap_or_default();
        out.frame_errors = out.frame_errors.wrapping_add(c.counters().malformed);
        Some(out)
    }
    fn bus(&self) -> Option<BusInfo> {
        self.core.as_ref().map(BusCore::info)
    }
    fn received_from(&self) -> Option<u8> {
        self.core.as_ref().and_then(BusCore::received_from)
    }
    fn wake_at(&self) -> Option<Instant> {
        match &self.core {
            Some(c) => c.wake_at(),
            None => self.lower.wake_at(),
        }
    }
    fn set_rx_room(&mut self, room: u8) {
        match &mut self.core {
            Some(c) => c.set_rx_room(room),
            None => self.lower.set_rx_room(room),
        }
    }
    fn bus_configurable(&self) -> bool {
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::link::queue::QueueLink;

    type Lower = QueueLink<8, 64>;

    #[test]
    fn roles_round_trip_and_bad_addresses_are_refused() {
        for role in [
            BusRole::Off,
            BusRole::Head { max_drop: 8 },
            BusRole::Drop(1),
            BusRole::Drop(254),
        ] {
            assert_eq!(BusRole::from_bytes(role.to_bytes()), Ok(role));
        }
        for bad in [
            [0, 1],
            [1, 0],
            [1, 255],
            [2, 0],
            [2, 255],
            [3, 1],
            [255, 255],
        ] {
            assert_eq!(BusRole::from_bytes(bad), Err(BadRole), "{bad:?}");
        }
    }

    #[test]
    fn off_passes_packets_through_and_a_role_adds_the_bus_header() {
        let mut link: Switchable<Lower, 64> = Switchable::new(Lower::new(), BusRole::Off);
        assert!(link.bus().is_none());
        assert!(link.bus_configurable());
        link.send(&[1, 2, 3]).unwrap();
        assert_eq!(&link.lower.take_sent().unwrap()[..], &[1, 2, 3]);
        assert!(link.send_to(3, &[1]).is_err());

        // A drop sends nothing until the head grants it a turn; granted,
        // its frame carries the header to the head.
        link.set_role(BusRole::Drop(3));
        assert_eq!(link.bus().unwrap().drop, 3);
        assert!(!link.clear_to_send());
        let grant = [3, HEAD, super::super::GRANT];
        assert!(link.lower.inject(&grant));
        let mut buf = [0u8; 64];
        assert!(link.receive(&mut buf).is_none());
        assert!(link.clear_to_send());
        link.send(&[9, 9]).unwrap();
        let frame = link.lower.take_sent().unwrap();
        assert_eq!(&frame[..2], &[HEAD, 3]);
        assert_eq!(&frame[super::super::HEADER_LEN..], &[9, 9]);

        // Back off: point to point again, no header.
        link.set_role(BusRole::Off);
        assert!(link.bus().is_none());
        link.send(&[7]).unwrap();
        assert_eq!(&link.lower.take_sent().unwrap()[..], &[7]);
    }
}
