//! The send handle the runtime lends its ports.

use super::*;

/// The runtime's implementation of a port's send handle.
pub(super) struct Sender<
    'r,
    const SLOTS: usize,
    const MTU: usize,
    const PORTS: usize,
    const LINKS: usize,
> {
    pub(super) stack: &'r mut PacketStack<SLOTS, MTU, PORTS, LINKS>,
    pub(super) counters: &'r mut Counters,
    pub(super) now: Instant,
}

impl<const SLOTS: usize, const MTU: usize, const PORTS: usize, const LINKS: usize> PacketSink
    for Sender<'_, SLOTS, MTU, PORTS, LINKS>
{
    fn clear_to_send(&self, from: u16) -> Result<(), ClaimError> {
        self.stack.check_claim(Owner::Port(from))
    }

    fn send(
        &mut self,
        from: u16,
        route: &Route,
        terminal: Instruction,
        ttl: u16,
        write: &mut dyn FnMut(&mut [u8]) -> Option<usize>,
    ) -> Result<(), SendError> {
        queue_packet(
            self.stack,
            self.counters,
            Owner::Port(from),
            self.now,
            route,
            terminal,
            ttl,
            write,
        )
    }
}

/// Writes a fresh packet into a slot charged to `owner` and queues it: the
/// header for `route` and `terminal`, then whatever payload `write` puts in
/// the room left under the route MTU (it returns the payload length, or
/// `None` if the payload does not fit).
#[allow(clippy::too_many_arguments)]
pub(super) fn queue_packet<
    const SLOTS: usize,
    const MTU: usize,
    const PORTS: usize,
    const LINKS: usize,
>(
    stack: &mut PacketStack<SLOTS, MTU, PORTS, LINKS>,
    counters: &mut Counters,
    owner: Owner,
    now: Instant,
    route: &Route,
    terminal: Instruction,
    ttl: u16,
    write: &mut dyn FnMut(&mut [u8]) -> Option<usize>,
) -> Result<(), SendError> {
    let mtu = route.mtu().min(MTU as u16);
    let pushed = stack.push_with(owner, now, |buf| {
        let start = route
            .write_header(buf, terminal, ttl, mtu)
            .map_err(|e| match e {
                PacketError::TooLong => SendError::TooLong,
                e => SendError::BadAddress(e),
            })?;
        let room = buf
            .get_mut(start..usize::from(mtu))
            .ok_or(SendError::TooLong)?;
        let room_len = room.len();
        let n = write(room)
            .filter(|&n| n <= room_len)
            .ok_or(SendError::TooLong)?;
        Ok((start + n, now + Duration::from_micros(ttl.into())))
    });
    match pushed {
        Ok(_) => Ok(()),
        Err(PushError::Claim(c)) => {
            match c {
                ClaimError::QuotaExceeded => bump(&mut counters.quota_refused),
                ClaimError::StackFull => bump(&mut counters.stack_full),
                ClaimError::UnknownOwner => {}
            }
            Err(SendError::NotClear(c))
        }
        Err(PushError::Write(e)) => Err(e),
        Err(PushError::Length) => Err(SendError::TooLong),
    }
}
