//! Receiving: clock stamp requests out, packets in from the links.

use super::*;

impl<const SLOTS: usize, const MTU: usize, const PORTS: usize, const LINKS: usize>
    Runtime<SLOTS, MTU, PORTS, LINKS>
{
    /// Sends the clock's time stamp requests when they are due, and forgets
    /// neighbours whose links have closed.
    #[cfg(feature = "sync")]
    pub(super) fn sync_clock<L: LinkGateway>(&mut self, now: Instant, links: &[L]) {
        let mut open = 0u64;
        for (i, link) in links.iter().enumerate().take(LINKS) {
            // Time flows down a bus from its head: a drop's neighbour on it
            // is the head alone, and the head asks none of its drops.
            let head = link.bus().is_some_and(|b| b.drop == crate::bus::HEAD);
            if link.is_open() && !head {
                open |= 1 << i;
            } else {
                self.clock.forget(i);
                self.bus_time_waiting &= !(1 << i);
            }
        }
        let due = self.clock.due_requests(now, open);
        let interval = Duration::from_micros(self.clock.config().interval_us.into());
        for (i, link) in links.iter().enumerate().take(LINKS) {
            // A full stack skips this request rather than stalling: the next
            // interval tries again.
            if due & (1 << i) != 0 {
                let hop = match link.bus() {
                    // A shared medium carries one request per drop at a
                    // time, at the plain rate: a point-to-point link's
                    // discovery burst, or the bursts that hunt for a phase
                    // against USB frames, would take the bus from every
                    // other drop.
                    Some(_)
                        if self.bus_time_waiting & (1 << i) != 0
                            || self.bus_time_asked[i].is_some_and(|t| now < t + interval) =>
                    {
                        continue
                    }
                    Some(_) => Instruction::BusForward {
                        bus: i as u8,
                        drop: crate::bus::HEAD,
                    },
                    None => Instruction::LinkForward(i as u8),
                };
                if self.request_time_via(now, hop).is_ok() && link.bus().is_some() {
                    self.bus_time_waiting |= 1 << i;
                    self.bus_time_asked[i] = Some(now);
                }
            }
        }
    }

    pub(super) fn ingest<L: LinkGateway>(&mut self, now: Instant, links: &mut [L]) {
        enum Rx {
            Empty,
            Oversize,
            Malformed,
        }
        for (i, link) in links.iter_mut().enumerate().take(LINKS) {
            if !link.is_open() {
                // Whoever is there after it reopens must be heard anew.
                self.link_heard[i] = None;
                continue;
            }
            let index = i as u8;
            let owner = Owner::Link(index);
            let bus = link.bus().is_some();
            // Take packets only while the link has quota: otherwise they stay
            // in the link's own buffer, which pushes back on the sender.
            let mut refused = None;
            while self.stack.check_claim(owner).is_ok() {
                let mut stamp = None;
                let pushed = self.stack.push_with(owner, now, |buf| {
                    let rx = link.receive(buf).ok_or(Rx::Empty)?;
                    stamp = rx.timestamp;
                    let packet = buf.get_mut(..rx.len).ok_or(Rx::Oversize)?;
                    // Off a bus, the hop back names the sender's drop.
                    let back = match (bus, link.received_from()) {
                        (false, _) => Instruction::LinkForward(index),
                        (true, Some(drop)) => Instruction::BusForward { bus: index, drop },
                        (true, None) => return Err(Rx::Malformed),
                    };
                    let mut view = Packet::new_checked(packet).map_err(|_| Rx::Malformed)?;
                    view.ingest(back).map_err(|_| Rx::Malformed)?;
                    if rx.len > usize::from(view.mtu()) {
                        return Err(Rx::Oversize);
                    }
                    let arrival = rx.timestamp.unwrap_or(now);
                    Ok((rx.len, arrival + Duration::from_micros(view.ttl().into())))
                });
                if !matches!(
                    pushed,
                    Err(PushError::Write(Rx::Empty)) | Err(PushError::Claim(_))
                ) {
                    // Even a packet dropped below came from a neighbour.
                    self.link_heard[i] = Some(now);
                }
                match pushed {
                    Ok(slot) => {
                        bump(&mut self.counters.received);
                        self.count_link(i, |t| &mut t.received);
                        let len = self.stack.packet(slot).len();
                        self.count_link_bytes(i, len, |t| &mut t.rx_bytes);
                        if let Some(ts) = stamp.take() {
                            self.stack.set_arrival(slot, ts);
                        }
                    }
                    Err(PushError::Write(Rx::Empty)) => break,
                    Err(PushError::Claim(e)) => {
                        refused = Some(e);
                        break;
                    }
                    Err(PushError::Write(Rx::Oversize)) | Err(PushError::Length) => {
                        bump(&mut self.counters.received);
                        bump(&mut self.counters.oversize);
                        self.count_link(i, |t| &mut t.received);
                        self.count_link(i, |t| &mut t.rx_dropped);
                    }
                    Err(PushError::Write(Rx::Malformed)) => {
                        bump(&mut self.counters.received);
                        bump(&mut self.counters.malformed);
                        self.count_link(i, |t| &mut t.received);
                        self.count_link(i, |t| &mut t.rx_dropped);
                    }
                }
            }
            if let Err(e) = self.stack.check_claim(owner) {
                refused = refused.or(Some(e));
            }
            // A bus cannot push back on one sender, and its turns are
            // handed on in its frames: keep reading it so a turn's END is
            // seen, dropping (and counting) packets there is no room for.
            // The head's flow control (`set_rx_room`) keeps this rare.
            if let (true, Some(e)) = (bus, refused) {
                while link.receive(&mut self.scratch).is_some() {
                    self.link_heard[i] = Some(now);
                    bump(&mut self.counters.received);
                    bump(match e {
                        ClaimError::StackFull => &mut self.counters.stack_full,
                        _ => &mut self.counters.quota_refused,
                    });
                    self.count_link(i, |t| &mut t.received);
                    self.count_link(i, |t| &mut t.rx_dropped);
                }
            }
        }
    }
}

/// Rewrites the stamp of a time message this runtime originated as it starts
/// onto the wire at local time `on_wire`: a request gets our local counter;
/// a reply's responder time (our local counter when the request arrived,
/// written when the reply was made) becomes our system time at the midpoint
/// of that and now, rounded to the nearest µs.
///
/// The midpoint is taken on the local counter and mapped once, in the time
/// map's fixed point: the mean of two system times each read in whole µs
/// (and halved in whole µs) lost up to a µs a hop, always the same way,
/// which the requester cannot tell from the link's delay.
pub(super) fn stamp_time_message<const LINKS: usize>(
    packet: &mut [u8],
    on_wire: Instant,
    clock: &Clock<LINKS>,
) {
    let Some((code, at)) = own_time_message(packet) else {
        return; // forwarded for someone else, or not a time message
    };
    let body = &mut packet[at..];
    match (code, body.len()) {
        (CODE_TIME_REQUEST, TIME_REQUEST_LEN) => {
            body.copy_from_slice(&on_wire.as_micros().to_le_bytes())
        }
        (CODE_TIME_REPLY, TIME_REPLY_LEN) => {
            let mut arrived = [0u8; 8];
            arrived.copy_from_slice(&body[8..16]);
            let arrived = Instant::from_micros(u64::from_le_bytes(arrived));
            // Both ends through today's map: a hard jump between the two
            // cannot put the midpoint outside them.
            let mid = clock.time_map().midpoint_rounded(arrived, on_wire);
            body[8..16].copy_from_slice(&mid.as_micros().to_le_bytes());
        }
        _ => {}
    }
}
