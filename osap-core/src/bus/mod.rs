//! Bus links: one link index serving many drops on a shared half-duplex
//! medium (RS-485).
//!
//! A bus has one **head** (drop 0) and up to 254 **drops** (1..=254). Every
//! frame reaches every station; the [bus frame header](header) names who it
//! is for and who sent it, so a station takes frames for itself and for
//! [`BROADCAST`] and ignores (and counts) the rest.
//!
//! **Arbitration** is by polling, so two stations never talk at once: the
//! head owns the medium and lends it out one turn at a time.
//!
//! - Every frame the head addresses to one drop carries `GRANT`: the
//!   addressed drop answers in the same turn (a request's reply leaves at
//!   once, not a polling cycle later). Broadcast frames grant nothing.
//! - When the head has nothing to send, or has sent
//!   [`BusConfig::head_burst`] frames since its last poll, it polls the next
//!   drop in address order with a bare `GRANT` frame, so every drop gets a
//!   turn for what it sends unasked (time requests, streams).
//! - A granted drop sends up to [`BusConfig::burst`] frames (to any drop)
//!   and hands the medium back with `END`, on its last frame or on a bare
//!   frame. In a turn from a bare poll, a frame carrying a time stamp
//!   request of the drop's own ends the turn (`END`), whatever burst is
//!   left: the head answers it in the pass that reads it, so the request's
//!   round trip is wire time and the head's serve pass, not also the
//!   drop's next runtime pass (whose varying length the clock's round-trip
//!   filter would reject). Whatever else the drop had queued waits for its
//!   next turn. A turn that came with data for the drop is not ended by a
//!   time request: the answer the head waits for must not be put off by
//!   the clock, which asks again and again while it settles. A turn that came with data for the drop lasts
//!   [`BusConfig::answer_passes`] more runtime passes, so a port that
//!   answers on its next pass still answers in this turn.
//! - A drop that does not answer within [`BusConfig::reply_timeout`]
//!   beyond the wire time of what the head queued and of one full frame
//!   loses its turn and counts as absent; absent drops are polled only
//!   every [`BusConfig::absent_every`] cycles, so empty addresses cost
//!   little. The head still lists a drop it ever heard as known
//!   ([`BusInfo::known`]): a drop that missed a turn (busy, hung, or
//!   starved of CPU in a simulation) is asked by a scan and found, or
//!   reported missing, never silently left out. Only an `END` carrying the current turn number
//!   ([`TURN_MASK`]) ends a turn, never a late one from an earlier turn.
//! - Flow control: the head lends the medium only while its runtime has
//!   room for a drop's whole turn ([`BusCore::set_rx_room`]), so what a
//!   drop sends is read, its `END` included.
//!
//! Packets wait for the medium in the runtime's packet stack, not here: a
//! bus link is clear to send only in its own turn, so whatever leaves is
//! the earliest deadline, and time-stamp messages are stamped as they
//! actually start onto the wire.
//!
//! [`BusCore`] is the sans-IO state machine over any packet-level lower
//! link (which frames bytes on a UART, or models a medium in simulation);
//! [`BusLink`] joins the two into a [`LinkGateway`].

pub mod header;
pub mod role;

pub use header::{
    turn_flags, BusFrameError, BusHeader, BROADCAST, END, GRANT, HEAD, HEADER_LEN, TURN_MASK,
};
pub use role::{BadRole, BusRole, Switchable};

use crate::link::{BusInfo, GatewayCounters, LinkGateway, LinkInfo, LinkSendError, Received};
use crate::time::{Duration, Instant};

/// How a station behaves on its bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BusConfig {
    /// This station's drop address: [`HEAD`] (0) for the head, 1..=254 for
    /// a drop.
    pub drop: u8,
    /// Head only: the highest drop address it polls (1..=254).
    pub max_drop: u8,
    /// Frames a drop may send per turn.
    pub burst: u8,
    /// Frames the head may send between two polls of drops in address
    /// order.
    pub head_burst: u8,
    /// Drop only: runtime passes a drop keeps a turn that came with data
    /// for it before it ends the turn with a bare `END`.
    pub answer_passes: u8,
    /// Head only: how long a granted drop has to start answering, beyond
    /// the wire time of the grant and of one full frame, µs.
    pub reply_timeout: Duration,
    /// Head only: a drop that missed its last turn is polled once every
    /// this many cycles (1 polls every drop every cycle).
    pub absent_every: u8,
}

impl BusConfig {
    /// The head of a bus polling drops `1..=max_drop`.
    pub const fn head(max_drop: u8) -> Self {
        BusConfig {
            drop: HEAD,
            max_drop,
            burst: 2,
            head_burst: 4,
            answer_passes: 1,
            reply_timeout: Duration::from_micros(500),
            absent_every: 16,
        }
    }

    /// A drop at address `drop`.
    pub const fn drop(drop: u8) -> Self {
        BusConfig {
            drop,
            ..BusConfig::head(0)
        }
    }

    /// Whether this is the head's configuration.
    pub const fn is_head(&self) -> bool {
        self.drop == HEAD
    }
}

/// What a bus station counts, beyond its lower link's counts.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BusCounters {
    /// Frames whose bus header was malformed (dropped).
    pub malformed: u32,
    /// Frames for other drops (ignored).
    pub other_drop: u32,
    /// Frames carrying our own address as source (an echo or a duplicate
    /// address on the bus; dropped).
    pub echo: u32,
    /// Grants sent (head) or received (drop).
    pub grants: u32,
    /// Head: turns a drop let time out.
    pub timeouts: u32,
    /// Frames a drop sent out of turn (head: heard from a drop it had not
    /// granted).
    pub out_of_turn: u32,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Turn {
    /// The head owns the medium (head), or the drop is silent (drop).
    Idle,
    /// Head: the medium is granted to `drop` until `until`; `poll` if by a
    /// bare grant in address order (rather than with data). Drop: we hold
    /// it.
    Granted {
        drop: u8,
        until: Instant,
        poll: bool,
    },
}

/// The bus state machine of one station, sans-IO: frames go out and come
/// in through a lower packet link passed to each call. `N` is the largest
/// bus frame (header + packet) it builds; a packet longer than
/// `N - HEADER_LEN` is refused.
#[derive(Debug, Clone)]
pub struct BusCore<const N: usize> {
    config: BusConfig,
    turn: Turn,
    /// Frames sent in the current turn (head: since its last poll of a
    /// drop in address order).
    sent: u8,
    /// Drop: runtime passes left in a turn before it is ended.
    hold: u8,
    /// Head: packets the runtime could take from the bus now.
    room: u8,
    /// The current turn's number (head: of its last grant; drop: of the
    /// grant it holds), carried in [`TURN_MASK`].
    turn_no: u8,
    /// Head: local time by which what it has queued on the lower link is
    /// on the wire (its own estimate, from the frames' lengths).
    tx_free: Instant,
    /// Head: the last drop granted (the next grant goes to one after it).
    cursor: u8,
    /// Head: full polling cycles completed.
    cycle: u32,
    /// Drops heard on their last turn (head), or the head heard (drop:
    /// bit 0).
    present: [u32; 8],
    /// Stations heard at least once: a missed turn clears `present`, never
    /// this, so a drop that went quiet is still reported (as silent).
    known: [u32; 8],
    /// The source of the packet last returned by `receive`.
    last_from: Option<u8>,
    now: Instant,
    /// Head: wire time of one full frame on the lower link, µs.
    frame: Duration,
    /// The lower link was not clear at the last poll: wait for it to wake
    /// the runtime rather than asking to be polled at once.
    blocked: bool,
    counters: BusCounters,
    scratch: [u8; N],
}

fn bit(set: &[u32; 8], d: u8) -> bool {
    set[usize::from(d / 32)] & (1 << (d % 32)) != 0
}

fn set_bit(set: &mut [u32; 8], d: u8, on: bool) {
    let w = &mut set[usize::from(d / 32)];
    if on {
        *w |= 1 << (d % 32);
    } else {
        *w &= !(1 << (d % 32));
    }
}

fn bump(c: &mut u32) {
    *c = c.wrapping_add(1);
}

impl<const N: usize> BusCore<N> {
    /// A station with the given configuration. The head starts by assuming
    /// every drop up to `max_drop` present, so the first cycle finds them.
    pub fn new(config: BusConfig) -> Self {
        let mut present = [0u32; 8];
        if config.is_head() {
            for d in 1..=config.max_drop.min(254) {
                set_bit(&mut present, d, true);
            }
        }
        BusCore {
            config,
            turn: Turn::Idle,
            sent: 0,
            hold: 0,
            room: u8::MAX,
            turn_no: 0,
            tx_free: Instant::ZERO,
            cursor: 0,
            cycle: 0,
            present,
            known: [0; 8],
            last_from: None,
            now: Instant::ZERO,
            frame: Duration::ZERO,
            blocked: false,
            counters: BusCounters::default(),
            scratch: [0; N],
        }
    }

    /// The configuration.
    pub fn config(&self) -> &BusConfig {
        &self.config
    }

    /// What the station counted.
    pub fn counters(&self) -> &BusCounters {
        &self.counters
    }

    /// Address, the stations known present (drops for the head; the
    /// head, as drop 0, for a drop) and those ever heard.
    pub fn info(&self) -> BusInfo {
        BusInfo {
            drop: self.config.drop,
            present: self.present,
            known: self.known,
        }
    }

    /// Whether drop `d` is known present.
    pub fn is_present(&self, d: u8) -> bool {
        bit(&self.present, d)
    }

    /// Tells the station how many packets its runtime could take from the
    /// bus now. The head lends the medium (a grant) only while a drop's
    /// whole turn ([`BusConfig::burst`] frames) fits, so nothing a drop
    /// sends has to be dropped and its `END` is always read.
    pub fn set_rx_room(&mut self, room: u8) {
        self.room = room;
    }

    /// Head: whether a drop's whole turn would fit in the runtime.
    fn can_lend(&self) -> bool {
        self.room >= self.config.burst.max(1)
    }

    fn owns_medium(&self) -> bool {
        match (self.config.is_head(), self.turn) {
            // Out of room to lend the medium, the head's own frames (which
            // free room) are not held back for polls that cannot happen.
            (true, Turn::Idle) => self.sent < self.config.head_burst.max(1) || !self.can_lend(),
            (false, Turn::Granted { .. }) => self.sent < self.config.burst.max(1),
            _ => false,
        }
    }

    /// Whether a packet may go out now: in our turn, with burst left, and
    /// the lower link clear.
    pub fn clear_to_send<L: LinkGateway + ?Sized>(&self, lower: &L) -> bool {
        self.owns_medium() && lower.clear_to_send()
    }

    /// Largest packet a bus frame can carry on `lower`.
    pub fn mtu<L: LinkGateway + ?Sized>(&self, lower: &L) -> u16 {
        let own = (N.saturating_sub(HEADER_LEN)).min(usize::from(u16::MAX)) as u16;
        lower.mtu().saturating_sub(HEADER_LEN as u16).min(own)
    }

    fn send_frame<L: LinkGateway + ?Sized>(
        &mut self,
        lower: &mut L,
        header: BusHeader,
        packet: &[u8],
    ) -> Result<(), LinkSendError> {
        let end = HEADER_LEN + packet.len();
        let frame = self.scratch.get_mut(..end).ok_or(LinkSendError)?;
        frame[..HEADER_LEN].copy_from_slice(&header.to_bytes());
        frame[HEADER_LEN..].copy_from_slice(packet);
        lower.send(frame)?;
        let start = self.tx_free.max(self.now + lower.queue_delay());
        self.tx_free = start + lower.transmit_time(end);
        Ok(())
    }

    /// Head: the deadline of a grant whose frame was just queued: its wire
    /// time and that of what was queued before it, one full frame of
    /// answer, and the reply timeout.
    fn grant_deadline(&self) -> Instant {
        self.tx_free + self.frame + self.config.reply_timeout
    }

    /// Sends `packet` to drop `to` (or [`BROADCAST`]) in our turn. A drop's
    /// last frame of its burst carries `END`; a head's frame to one drop
    /// carries `GRANT`, lending that drop the medium.
    pub fn send_to<L: LinkGateway + ?Sized>(
        &mut self,
        lower: &mut L,
        to: u8,
        packet: &[u8],
    ) -> Result<(), LinkSendError> {
        if !self.owns_medium() || to == self.config.drop {
            return Err(LinkSendError);
        }
        let head = self.config.is_head();
        // Without room for the answer, the frame goes without a grant and
        // the drop answers in its next poll.
        let grant = head && to != BROADCAST && to != HEAD && self.can_lend();
        // A drop's time request ends a bare-poll turn: the head answers it
        // at once, so the requester's round trip is the wire's and the
        // head's serve pass, not also the drop's own next pass (which
        // varies). A turn with data for us is kept for its answer.
        let poll_turn = matches!(self.turn, Turn::Granted { poll: true, .. });
        let last = !head
            && (self.sent.saturating_add(1) >= self.config.burst.max(1)
                || (poll_turn && crate::clock::wire::is_own_time_request(packet)));
        if grant {
            self.turn_no = self.turn_no.wrapping_add(1);
        }
        let turn = if grant || !head {
            turn_flags(self.turn_no)
        } else {
            0
        };
        let header = BusHeader {
            dst: to,
            src: self.config.drop,
            flags: turn
                | if last {
                    END
                } else if grant {
                    GRANT
                } else {
                    0
                },
        };
        if head {
            self.frame = lower.transmit_time(usize::from(lower.mtu()));
        }
        self.send_frame(lower, header, packet)?;
        self.sent = self.sent.saturating_add(1);
        if last {
            self.turn = Turn::Idle;
        } else if grant {
            bump(&mut self.counters.grants);
            self.turn = Turn::Granted {
                drop: to,
                until: self.grant_deadline(),
                poll: false,
            };
        }
        Ok(())
    }

    /// Takes the next frame for this station off `lower`, handling grants
    /// and ends, and returns its packet (moved to the start of `buf`).
    /// Frames for others, malformed headers and echoes are counted and
    /// skipped.
    pub fn receive<L: LinkGateway + ?Sized>(
        &mut self,
        lower: &mut L,
        buf: &mut [u8],
    ) -> Option<Received> {
        loop {
            let rx = lower.receive(buf)?;
            let Some(frame) = buf.get(..rx.len) else {
                // Too long for the runtime's buffer: it drops it as oversize.
                return Some(rx);
            };
            let header = match BusHeader::parse(frame) {
                Ok((h, _)) => h,
                Err(_) => {
                    bump(&mut self.counters.malformed);
                    continue;
                }
            };
            if header.src == self.config.drop {
                bump(&mut self.counters.echo);
                continue;
            }
            let len = rx.len - HEADER_LEN;
            self.heard(header, len > 0);
            if header.dst != self.config.drop && header.dst != BROADCAST {
                bump(&mut self.counters.other_drop);
                continue;
            }
            if len == 0 {
                continue; // a bare grant or end
            }
            buf.copy_within(HEADER_LEN..rx.len, 0);
            self.last_from = Some(header.src);
            // The runtime takes it: one place less for a turn to fill.
            self.room = self.room.saturating_sub(1);
            return Some(Received {
                len,
                timestamp: rx.timestamp,
            });
        }
    }

    /// Turn bookkeeping for a frame heard from `header.src` (`data`: it
    /// carried a packet).
    fn heard(&mut self, header: BusHeader, data: bool) {
        if self.config.is_head() {
            // Any frame of a drop's, in its turn or late, shows it is there.
            set_bit(&mut self.known, header.src, true);
            match self.turn {
                Turn::Granted { drop, poll, .. }
                    if drop == header.src && header.turn() == self.turn_no & 3 =>
                {
                    set_bit(&mut self.present, drop, true);
                    if header.flags & END != 0 {
                        self.end_grant(poll);
                    } else {
                        // More is coming: allow one more frame's wire time.
                        self.turn = Turn::Granted {
                            drop,
                            until: self.now + self.frame + self.config.reply_timeout,
                            poll,
                        };
                    }
                }
                _ => bump(&mut self.counters.out_of_turn),
            }
        } else if header.src == HEAD {
            set_bit(&mut self.present, HEAD, true);
            set_bit(&mut self.known, HEAD, true);
            if header.flags & GRANT != 0 && header.dst == self.config.drop {
                bump(&mut self.counters.grants);
                self.turn = Turn::Granted {
                    drop: self.config.drop,
                    until: self.now,
                    poll: !data,
                };
                self.sent = 0;
                self.turn_no = header.turn();
                self.hold = if data { self.config.answer_passes } else { 0 };
            }
        }
    }

    /// Head: the medium is back. After a poll in address order the head's
    /// burst starts afresh.
    fn end_grant(&mut self, poll: bool) {
        self.turn = Turn::Idle;
        if poll {
            self.sent = 0;
        }
    }

    /// The sender's drop of the packet last returned by
    /// [`receive`](Self::receive).
    pub fn received_from(&self) -> Option<u8> {
        self.last_from
    }

    /// Runs the turn at local time `now`; called once per runtime loop
    /// before packets are exchanged, so a turn that began while packets
    /// came in has had one serve pass of the runtime when it is ended here.
    pub fn poll<L: LinkGateway + ?Sized>(&mut self, lower: &mut L, now: Instant) {
        self.now = now;
        if !lower.is_open() {
            return;
        }
        self.blocked = !lower.clear_to_send();
        if self.config.is_head() {
            self.poll_head(lower, now);
        } else if let Turn::Granted { .. } = self.turn {
            if self.hold > 0 {
                // A port may answer what came with the grant on this pass.
                self.hold -= 1;
                return;
            }
            // Our serve pass is done: hand the medium back.
            if !self.blocked {
                let end = BusHeader {
                    dst: HEAD,
                    src: self.config.drop,
                    flags: END | turn_flags(self.turn_no),
                };
                self.turn = Turn::Idle;
                let _ = self.send_frame(lower, end, &[]);
            }
        }
    }

    fn poll_head<L: LinkGateway + ?Sized>(&mut self, lower: &mut L, now: Instant) {
        if let Turn::Granted { drop, until, poll } = self.turn {
            if now < until {
                return;
            }
            bump(&mut self.counters.timeouts);
            set_bit(&mut self.present, drop, false);
            self.end_grant(poll);
            // The head's own turn starts with a serve pass.
            return;
        }
        if !lower.clear_to_send() {
            return;
        }
        if !self.can_lend() {
            // Our own frames still go out (they free room); a poll waits.
            return;
        }
        let Some(next) = self.next_drop() else {
            self.sent = 0;
            return;
        };
        self.turn_no = self.turn_no.wrapping_add(1);
        let grant = BusHeader {
            dst: next,
            src: HEAD,
            flags: GRANT | turn_flags(self.turn_no),
        };
        self.frame = lower.transmit_time(usize::from(lower.mtu()));
        if self.send_frame(lower, grant, &[]).is_ok() {
            bump(&mut self.counters.grants);
            self.turn = Turn::Granted {
                drop: next,
                until: self.grant_deadline(),
                poll: true,
            };
        }
    }

    /// The next drop to poll after the cursor: present drops every cycle,
    /// absent ones every `absent_every` cycles.
    fn next_drop(&mut self) -> Option<u8> {
        let max = self.config.max_drop.min(254);
        for _ in 0..usize::from(max) * 2 {
            if self.cursor >= max {
                self.cursor = 0;
                self.cycle = self.cycle.wrapping_add(1);
            }
            self.cursor += 1;
            let d = self.cursor;
            let every = u32::from(self.config.absent_every.max(1));
            if bit(&self.present, d) || self.cycle.is_multiple_of(every) {
                return Some(d);
            }
        }
        None
    }

    /// When the station must be polled again: the head at once while it
    /// owns the medium (to grant), or at a grant's timeout; a granted drop
    /// at once (to hand the medium back).
    pub fn wake_at(&self) -> Option<Instant> {
        match (self.config.is_head(), self.turn) {
            (true, Turn::Idle) if self.config.max_drop > 0 && !self.blocked => Some(self.now),
            (true, Turn::Granted { until, .. }) => Some(until),
            (false, Turn::Granted { .. }) if !self.blocked => Some(self.now),
            _ => None,
        }
    }
}

/// A bus station over a lower packet link: a [`LinkGateway`] whose
/// [`bus`](LinkGateway::bus) is `Some`.
#[derive(Debug, Clone)]
pub struct BusLink<L, const N: usize = 259> {
    /// The bus state.
    pub core: BusCore<N>,
    /// The link below (framing, wire).
    pub lower: L,
}

impl<L: LinkGateway, const N: usize> BusLink<L, N> {
    /// A bus station over `lower`.
    pub fn new(lower: L, config: BusConfig) -> Self {
        BusLink {
            core: BusCore::new(config),
            lower,
        }
    }
}

impl<L: LinkGateway, const N: usize> LinkGateway for BusLink<L, N> {
    fn info(&self) -> LinkInfo<'_> {
        self.lower.info()
    }
    fn is_open(&self) -> bool {
        self.lower.is_open()
    }
    fn mtu(&self) -> u16 {
        self.core.mtu(&self.lower)
    }
    fn clear_to_send(&self) -> bool {
        self.core.clear_to_send(&self.lower)
    }
    fn send(&mut self, packet: &[u8]) -> Result<(), LinkSendError> {
        // Without an address: to the head, or from the head to all.
        let to = if self.core.config().is_head() {
            BROADCAST
        } else {
            HEAD
        };
        self.core.send_to(&mut self.lower, to, packet)
    }
    fn send_to(&mut self, drop: u8, packet: &[u8]) -> Result<(), LinkSendError> {
        self.core.send_to(&mut self.lower, drop, packet)
    }
    fn transmit_time(&self, len: usize) -> Duration {
        self.lower.transmit_time(len + HEADER_LEN)
    }
    fn queue_delay(&self) -> Duration {
        self.lower.queue_delay()
    }
    fn receive(&mut self, buf: &mut [u8]) -> Option<Received> {
        self.core.receive(&mut self.lower, buf)
    }
    fn poll(&mut self, now: Instant) {
        self.lower.poll(now);
        self.core.poll(&mut self.lower, now);
    }
    fn counters(&self) -> Option<GatewayCounters> {
        let mut c = self.lower.counters().unwrap_or_default();
        let b = self.core.counters();
        c.frame_errors = c.frame_errors.wrapping_add(b.malformed);
        Some(c)
    }
    fn bus(&self) -> Option<BusInfo> {
        Some(self.core.info())
    }
    fn received_from(&self) -> Option<u8> {
        self.core.received_from()
    }
    fn wake_at(&self) -> Option<Instant> {
        self.core.wake_at()
    }
    fn set_rx_room(&mut self, room: u8) {
        self.core.set_rx_room(room);
    }
}

#[cfg(test)]
mod tests;
