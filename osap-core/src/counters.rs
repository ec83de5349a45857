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

/// What a link gateway counts of its own traffic, below the runtime (see
/// [`crate::link::LinkGateway::counters`]). All counts wrap at `u32::MAX`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct GatewayCounters {
    /// Frames (packets) received off the wire.
    pub frames: u32,
    /// Frames dropped as damaged: bad CRC or COBS, too short, too long.
    pub frame_errors: u32,
    /// Received packets the gateway dropped because its queue to the
    /// runtime was full.
    pub rx_dropped: u32,
    /// Packets to send the gateway dropped because its send queue was full
    /// (a peer that stopped reading).
    pub tx_dropped: u32,
    /// Times the link went down.
    pub disconnects: u32,
}

/// One link's counters: what the runtime counted of the packets it took
/// from and sent on the link, and what the link's gateway counts itself
/// (`None` when it keeps no counters). The runtime's counts wrap at
/// `u32::MAX`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LinkCounters {
    /// Packets taken in from the link.
    pub received: u32,
    /// Packets sent on the link.
    pub sent: u32,
    /// Packets in from the link dropped at once: malformed, or longer than
    /// a slot or their header's `mtu`.
    pub rx_dropped: u32,
    /// Packets bound out on the link dropped because their deadline passed
    /// (waiting for it, or before they could land).
    pub expired: u32,
    /// Packets bound out on the link dropped because it was closed.
    pub closed: u32,
    /// Sends the gateway failed after saying it was clear.
    pub send_errors: u32,
    /// The gateway's own counts.
    pub gateway: Option<GatewayCounters>,
    /// Bytes of the packets taken in from the link (those counted in
    /// `received`).
    pub rx_bytes: u32,
    /// Bytes of the packets sent on the link (those counted in `sent`).
    pub tx_bytes: u32,
    /// What the link carries, packet bytes per second, from its
    /// [`transmit_time`](crate::link::LinkGateway::transmit_time); 0 when
    /// it cannot tell (a socket). Filled in by the netresponder.
    pub capacity_bytes_per_s: u32,
    /// Packet slots of the runtime's stack held now by packets that
    /// arrived on this link, and by the netresponder's replies to them.
    /// Filled in by the netresponder.
    pub held: u16,
    /// The runtime's packet slots in all. Filled in by the netresponder;
    /// 0 from a runtime of the first layout (without the load fields).
    pub slots: u16,
}

impl LinkCounters {
    /// Bytes of [`encode`](Self::encode)'s output: the first layout (45
    /// bytes) and the load fields (16).
    pub const ENCODED_LEN: usize = 6 * 4 + 1 + 5 * 4 + 3 * 4 + 2 * 2;

    /// Writes the netresponder's link-counters fields (after the link
    /// index): six `u32` runtime counts, a `u8` saying whether gateway
    /// counts follow (1) or not (0), and five `u32` gateway counts (zero
    /// when there are none). `docs/protocol.md` lays them out.
    pub fn encode(&self, w: &mut crate::codec::Writer<'_>) -> Result<(), crate::codec::CodecError> {
        for v in [
            self.received,
            self.sent,
            self.rx_dropped,
            self.expired,
            self.closed,
            self.send_errors,
        ] {
            w.u32(v)?;
        }
        w.u8(u8::from(self.gateway.is_some()))?;
        let g = self.gateway.unwrap_or_default();
        for v in [
            g.frames,
            g.frame_errors,
            g.rx_dropped,
            g.tx_dropped,
            g.disconnects,
        ] {
            w.u32(v)?;
        }
        w.u32(self.rx_bytes)?;
        w.u32(self.tx_bytes)?;
        w.u32(self.capacity_bytes_per_s)?;
        w.u16(self.held)?;
        w.u16(self.slots)?;
        Ok(())
    }

    /// Reads what [`encode`](Self::encode) wrote. Extra bytes after it are
    /// left for later versions of the layout.
    pub fn decode(r: &mut crate::codec::Reader<'_>) -> Result<Self, crate::codec::CodecError> {
        let mut c = LinkCounters {
            received: r.u32()?,
            sent: r.u32()?,
            rx_dropped: r.u32()?,
            expired: r.u32()?,
            closed: r.u32()?,
            send_errors: r.u32()?,
            ..LinkCounters::default()
        };
        let kept = r.u8()? != 0;
        let g = GatewayCounters {
            frames: r.u32()?,
            frame_errors: r.u32()?,
            rx_dropped: r.u32()?,
            tx_dropped: r.u32()?,
            disconnects: r.u32()?,
        };
        c.gateway = kept.then_some(g);
        // The load fields came later: a runtime of the first layout ends
        // here, and they read as 0. A part of them is a truncated reply.
        if !r.rest().is_empty() {
            c.rx_bytes = r.u32()?;
            c.tx_bytes = r.u32()?;
            c.capacity_bytes_per_s = r.u32()?;
            c.held = r.u16()?;
            c.slots = r.u16()?;
        }
        Ok(c)
    }
}
