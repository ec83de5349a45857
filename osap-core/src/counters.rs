//! What a runtime has done and dropped, counted.
//!
//! Every packet a runtime drops is counted under the reason it was dropped,
//! so a host can read these (through the netresponder) and see where traffic
//! goes missing instead of guessing.

/// Event and drop counters of one runtime. All counts wrap at `u32::MAX`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counters {
    /// Packets taken in from link gateways.
    pub received: u32,
    /// Packets sent out on link gateways.
    pub forwarded: u32,
    /// Packets handed to ports (the netresponder included).
    pub delivered: u32,
    /// System messages handled.
    pub system: u32,
    /// Packets dropped because their deadline passed.
    pub expired: u32,
    /// Dropped: the route named a link or bus this runtime does not have.
    pub no_route: u32,
    /// Dropped: the route named a link that is closed.
    pub link_closed: u32,
    /// Dropped: no port with the destination index.
    pub no_port: u32,
    /// Dropped: malformed header or instruction.
    pub malformed: u32,
    /// Dropped: longer than a buffer, a link MTU or the header's `mtu`.
    pub oversize: u32,
    /// Sends refused because the sender (a port, or the runtime for its own
    /// replies) was at its quota.
    pub quota_refused: u32,
    /// Sends refused because every slot was in use.
    pub stack_full: u32,
    /// Sends a link gateway failed after saying it was clear.
    pub link_errors: u32,
    /// Netresponder requests that were malformed or unanswerable.
    pub netresponder_errors: u32,
    /// Dropped: unknown system message code or malformed body.
    pub unknown_system: u32,
}

impl Counters {
    /// Total packets dropped for any reason.
    pub fn dropped(&self) -> u32 {
        [
            self.expired,
            self.no_route,
            self.link_closed,
            self.no_port,
            self.malformed,
            self.oversize,
            self.unknown_system,
        ]
        .iter()
        .fold(0u32, |a, b| a.wrapping_add(*b))
    }
}

/// Adds one to a counter, wrapping.
#[inline]
pub(crate) fn bump(counter: &mut u32) {
    *counter = counter.wrapping_add(1);
}
