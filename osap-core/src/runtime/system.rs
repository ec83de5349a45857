//! What the runtime answers itself: the netresponder (port 0) and system
//! messages.

use super::*;

impl<const SLOTS: usize, const MTU: usize, const PORTS: usize, const LINKS: usize>
    Runtime<SLOTS, MTU, PORTS, LINKS>
{
    pub(super) fn answer_netresponder<P: Port, L: LinkGateway>(
        &mut self,
        slot: SlotId,
        src: u16,
        now: Instant,
        ports: &[P],
        links: &[L],
    ) -> Served {
        // The reply is charged to the link the request came in on (the
        // one it leaves by), as the request was: a peer that never reads
        // its replies then holds only its own link's quota, never the
        // netresponder's slots every other link's requests are answered
        // from. Its request's slot is freed first, so there is room. A
        // request from a local port is answered from the netresponder's
        // own quota, and waits like any packet for a busy port until the
        // reply can be stored.
        let owner = match self.stack.meta(slot).owner {
            link @ Owner::Link(_) => link,
            _ => Owner::Port(0),
        };
        if owner == Owner::Port(0) && self.stack.check_claim(owner).is_err() {
            return Served::Wait;
        }
        let (len, _) = self.take_to_scratch(slot);
        let Some((route, payload)) = split_delivery(&self.scratch[..len]) else {
            bump(&mut self.counters.malformed);
            return Served::Dropped;
        };
        let Ok((Transport::Request(seq), body)) = Transport::decode(payload) else {
            bump(&mut self.counters.netresponder_errors);
            return Served::Dropped;
        };
        let ttl = self.config.reply_ttl_us;
        // The counters query reports them as they were at the request.
        let counters = self.counters;
        let mut ctx = netresponder::Context {
            now,
            identity: &mut self.identity,
            state: &mut self.netresponder,
            clock: &mut self.clock,
            counters: &counters,
            link_counters: &self.link_counters,
            link_heard: &self.link_heard,
            link_held: &core::array::from_fn::<u8, LINKS, _>(|i| {
                self.stack.held(Owner::Link(i as u8)).unwrap_or(0)
            }),
            slots: SLOTS as u16,
            changes: &mut self.changes,
            ports,
            links,
            packet_size: MTU as u16,
            arrival_link: match route.hops().next() {
                Some(Instruction::LinkForward(l) | Instruction::BusForward { bus: l, .. }) => l,
                _ => netresponder::ARRIVED_LOCALLY,
            },
        };
        let answered = queue_packet(
            &mut self.stack,
            &mut self.counters,
            owner,
            now,
            &route,
            Instruction::PortHandle { src: 0, dst: src },
            ttl,
            &mut |room| {
                let n = Transport::Reply(seq).encode(room)?;
                let mut w = Writer::new(room.get_mut(n..)?);
                netresponder::respond(&mut ctx, body, &mut w).ok()?;
                Some(n + w.len())
            },
        );
        if answered.is_ok() {
            bump(&mut self.counters.delivered);
            Served::Done
        } else {
            bump(&mut self.counters.netresponder_errors);
            Served::Dropped
        }
    }

    pub(super) fn system_message(&mut self, slot: SlotId, code: u8, now: Instant) -> Served {
        match code {
            CODE_TIME_REQUEST => {
                if self.stack.check_claim(Owner::System).is_err() {
                    return Served::Wait;
                }
                let (len, meta) = self.take_to_scratch(slot);
                let Some((route, body)) = split_delivery(&self.scratch[..len]) else {
                    bump(&mut self.counters.unknown_system);
                    return Served::Dropped;
                };
                let Ok(stamp) = <[u8; TIME_REQUEST_LEN]>::try_from(body) else {
                    bump(&mut self.counters.unknown_system);
                    return Served::Dropped;
                };
                // Our *local* counter when the request arrived, for now:
                // at transmit it is replaced by our system time at the
                // midpoint of it and the reply's start onto the wire,
                // worked out below the µs (`stamp_time_message`).
                let reply = TimeReply {
                    request_time: Instant::from_micros(u64::from_le_bytes(stamp)),
                    responder_time: SystemInstant::from_micros(meta.arrival.as_micros()),
                    responder_tier: self.clock.tier(),
                };
                let ttl = self.config.reply_ttl_us;
                match self.push_system(now, &route, CODE_TIME_REPLY, ttl, |w| reply.encode(w).ok())
                {
                    Ok(()) => {
                        bump(&mut self.counters.system);
                        Served::Done
                    }
                    Err(_) => {
                        bump(&mut self.counters.unknown_system);
                        Served::Dropped
                    }
                }
            }
            CODE_TIME_REPLY => {
                let (len, meta) = self.take_to_scratch(slot);
                let reply = split_delivery(&self.scratch[..len]).and_then(|(route, body)| {
                    let mut hops = route.hops();
                    // From a point-to-point neighbour, or from our bus's head.
                    let link = match (hops.next(), hops.next()) {
                        (Some(Instruction::LinkForward(link)), None) => link,
                        (
                            Some(Instruction::BusForward {
                                bus,
                                drop: crate::bus::HEAD,
                            }),
                            None,
                        ) => bus,
                        _ => return None,
                    };
                    Some((link, TimeReply::decode(body).ok()?))
                });
                match reply.filter(|(link, _)| usize::from(*link) < LINKS) {
                    Some((link, reply)) => {
                        #[cfg(feature = "sync")]
                        self.clock.on_reply(usize::from(link), &reply, meta.arrival);
                        #[cfg(not(feature = "sync"))]
                        let _ = (link, reply, meta);
                        bump(&mut self.counters.system);
                        Served::Done
                    }
                    None => {
                        bump(&mut self.counters.unknown_system);
                        Served::Dropped
                    }
                }
            }
            _ => self.drop_slot(slot, Drop::UnknownSystem),
        }
    }

    pub(super) fn push_system(
        &mut self,
        now: Instant,
        route: &Route,
        code: u8,
        ttl: u16,
        body: impl FnOnce(&mut Writer<'_>) -> Option<()>,
    ) -> Result<(), SendError> {
        let mut body = Some(body);
        queue_packet(
            &mut self.stack,
            &mut self.counters,
            Owner::System,
            now,
            route,
            Instruction::SystemMsg(code),
            ttl,
            &mut |room| {
                let mut w = Writer::new(room);
                (body.take()?)(&mut w)?;
                Some(w.len())
            },
        )
    }
}
