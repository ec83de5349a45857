//! Moving a packet on: forwarding it over a link or delivering it to a port.

use super::*;

impl<const SLOTS: usize, const MTU: usize, const PORTS: usize, const LINKS: usize>
    Runtime<SLOTS, MTU, PORTS, LINKS>
{
    /// Sends the packet in `slot` on link `index`: to drop `drop` if the
    /// hop was a `bus_forward` (which needs a bus link), point to point if
    /// it was a `link_forward` (which needs a point-to-point link). A link
    /// found busy in this walk (`busy`) is not asked again.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn forward<L: LinkGateway>(
        &mut self,
        slot: SlotId,
        index: u8,
        drop: Option<u8>,
        now: Instant,
        deadline: Instant,
        links: &mut [L],
        busy: &mut Busy<PORTS>,
    ) -> Served {
        let Some(link) = links
            .get_mut(usize::from(index))
            .filter(|_| usize::from(index) < LINKS)
        else {
            return self.drop_slot(slot, Drop::NoRoute);
        };
        let i = usize::from(index);
        if link.bus().is_some() != drop.is_some() {
            return self.drop_slot(slot, Drop::NoRoute);
        }
        if !link.is_open() {
            self.count_link(i, |t| &mut t.closed);
            return self.drop_slot(slot, Drop::LinkClosed);
        }
        if busy.link(index) || !link.clear_to_send() {
            busy.set_link(index);
            return Served::Wait;
        }
        if self.stack.packet(slot).len() > usize::from(link.mtu()) {
            return self.drop_slot(slot, Drop::Oversize);
        }
        // Wire time counts against the deadline: a packet that would land
        // after it is dropped here rather than spending the link on it.
        let landing = now.saturating_add(link.transmit_time(self.stack.packet(slot).len()));
        // Whatever leaves for (or expires on) a bus ends the wait of our
        // time request there (it goes first, by its deadline, or is gone).
        if let Some(bit) = 1u64.checked_shl(u32::from(index)) {
            self.bus_time_waiting &= !bit;
        }
        if landing > deadline {
            self.stack.release(slot);
            bump(&mut self.counters.expired);
            self.count_link(i, |t| &mut t.expired);
            return Served::Dropped;
        }
        let on_wire = now.saturating_add(link.queue_delay());
        let packet = self.stack.packet_mut(slot);
        stamp_time_message(packet, on_wire, &self.clock);
        let ttl = (deadline - landing).as_micros().min(u64::from(u16::MAX)) as u16;
        // The header was checked when the slot's instruction was read, so
        // this check passes and the TTL field exists.
        if let Ok(mut view) = Packet::new_checked(&mut *packet) {
            view.set_ttl(ttl);
        }
        let len = packet.len();
        let sent = match drop {
            Some(d) => link.send_to(d, packet),
            None => link.send(packet),
        };
        match sent {
            Ok(()) => {
                bump(&mut self.counters.forwarded);
                self.count_link(i, |t| &mut t.sent);
                self.count_link_bytes(i, len, |t| &mut t.tx_bytes);
            }
            Err(_) => {
                bump(&mut self.counters.link_errors);
                self.count_link(i, |t| &mut t.send_errors);
            }
        }
        self.stack.release(slot);
        Served::Done
    }

    /// Copies the packet in `slot` into scratch and frees the slot,
    /// returning its length and metadata; the slot is then free for a reply.
    pub(super) fn take_to_scratch(&mut self, slot: SlotId) -> (usize, SlotMeta) {
        let packet = self.stack.packet(slot);
        let len = packet.len();
        self.scratch[..len].copy_from_slice(packet);
        let meta = *self.stack.meta(slot);
        self.stack.release(slot);
        (len, meta)
    }

    pub(super) fn deliver<P: Port>(
        &mut self,
        slot: SlotId,
        src: u16,
        dst: u16,
        now: Instant,
        ports: &mut [P],
        busy: &mut Busy<PORTS>,
    ) -> Served {
        let Some((object, offset, base)) = find_port(ports, dst) else {
            return self.drop_slot(slot, Drop::NoPort);
        };
        let port = &mut ports[object];
        if busy.port(dst) || !port.clear_to_receive(offset) {
            busy.set_port(dst);
            return Served::Wait;
        }
        let (len, meta) = self.take_to_scratch(slot);
        let Some((reply_route, payload)) = split_delivery(&self.scratch[..len]) else {
            bump(&mut self.counters.malformed);
            return Served::Dropped;
        };
        let count = port.port_count();
        let system = self.clock.system_time(now);
        let mut sender = Sender {
            stack: &mut self.stack,
            counters: &mut self.counters,
            now,
        };
        let mut tx = PortTx {
            sink: &mut sender,
            base,
            count,
            now,
            system,
        };
        port.on_packet(
            Delivery {
                offset,
                payload,
                reply_route,
                source_port: src,
                arrival: meta.arrival,
                deadline: meta.deadline,
            },
            &mut tx,
        );
        bump(&mut self.counters.delivered);
        Served::Done
    }
}

/// Finds the port object serving runtime port index `index` (≥ 1): returns
/// the object's slice position, the offset within it and its base index.
pub(super) fn find_port<P: Port>(ports: &[P], index: u16) -> Option<(usize, u16, u16)> {
    let mut base = 1u16;
    for (i, p) in ports.iter().enumerate() {
        let count = p.port_count();
        if index >= base && index - base < count {
            return Some((i, index - base, base));
        }
        base = base.checked_add(count)?;
    }
    None
}

/// Splits a packet whose `ptr` is at a terminal instruction into the route
/// back to its sender and the bytes after that instruction. `None` if what
/// was walked is not a valid route (a sender can put anything before `ptr`).
pub(super) fn split_delivery(packet: &[u8]) -> Option<(Route, &[u8])> {
    let view = Packet::new_checked(packet).ok()?;
    let route = Route::from_bytes(view.walked()).ok()?;
    let payload = view.after_instruction().ok()?;
    Some((route.reversed().with_mtu(view.mtu()), payload))
}
