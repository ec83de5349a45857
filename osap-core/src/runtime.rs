//! The runtime: one node of an OSAP network.
//!
//! A [`Runtime`] owns the packet stack and the runtime's identity; the ports
//! and link gateways stay with the caller and are lent to
//! [`Runtime::poll`] on every call, so the caller can reach its own port
//! objects between polls. Port 0 (the netresponder) is built in; the caller's
//! ports are numbered from 1 in slice order, links from 0.
//!
//! `poll(now)` is the whole loop, sans-IO: it lets links and ports run, pulls
//! received packets in while links have quota, then walks the stack in
//! deadline order, dropping what has expired, forwarding what a clear link can
//! take, delivering what a clear port can take, and answering system messages
//! and port 0. A packet whose link or port is busy simply waits its turn;
//! it never holds up the packets behind it.

use crate::clock::{
    Clock, TimeConfig, TimeReply, CODE_TIME_REPLY, CODE_TIME_REQUEST, TIME_REPLY_LEN,
    TIME_REQUEST_LEN,
};
use crate::codec::Writer;
use crate::counters::{bump, Counters, LinkCounters};
use crate::link::LinkGateway;
use crate::netresponder::{self, BuildKey, Changes, Identity, Level, NameTooLong};
use crate::packet::{Instruction, Packet, PacketError, HEADER_LEN};
use crate::port::{Delivery, PacketSink, Port, PortTx, SendError};
use crate::route::Route;
use crate::stack::{ClaimError, Owner, PacketStack, PushError, SlotId, SlotMeta};
use crate::time::{Duration, Instant, SystemInstant};
use crate::transport::Transport;

/// Tunables of a runtime; the defaults suit a microcontroller.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RuntimeConfig {
    /// Slots each port may hold in the stack at once.
    pub port_quota: u8,
    /// Slots each link gateway may hold in the stack at once.
    pub link_quota: u8,
    /// Slots the runtime may hold for its own system messages.
    pub system_quota: u8,
    /// Time-to-live of replies the runtime writes itself (netresponder,
    /// time stamps), µs.
    pub reply_ttl_us: u16,
    /// Most packets served in one poll; bounds the time one poll takes even
    /// if ports keep answering each other locally.
    pub max_packets_per_poll: u16,
}

impl Default for RuntimeConfig {
    fn default() -> Self {
        RuntimeConfig {
            port_quota: crate::stack::DEFAULT_PORT_QUOTA,
            link_quota: crate::stack::DEFAULT_LINK_QUOTA,
            system_quota: crate::stack::DEFAULT_SYSTEM_QUOTA,
            reply_ttl_us: 20_000,
            max_packets_per_poll: 64,
        }
    }
}

/// What one [`Runtime::poll`] did, and when the next one is due.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct PollResult {
    /// Packets forwarded, delivered or answered.
    pub handled: usize,
    /// Packets dropped (expired, unroutable, malformed).
    pub dropped: usize,
    /// Packets left waiting for a busy link or port.
    pub waiting: usize,
    /// The local time by which `poll` must run again: the earliest deadline
    /// of a waiting packet, the next clock-sync request, or a port's own
    /// [`wake_at`](crate::port::Port::wake_at). Poll sooner when a link or
    /// port has news.
    pub wake_at: Option<Instant>,
    /// The per-poll budget ran out with work left: poll again at once.
    pub more: bool,
}

enum Served {
    Done,
    Dropped,
    Wait,
}

/// A runtime with `SLOTS` packet slots of `MTU` bytes, quota entries for
/// `PORTS` port indices (port 0 included) and up to `LINKS` link gateways.
pub struct Runtime<
    const SLOTS: usize = 16,
    const MTU: usize = 256,
    const PORTS: usize = 32,
    const LINKS: usize = 8,
> {
    identity: Identity,
    config: RuntimeConfig,
    stack: PacketStack<SLOTS, MTU, PORTS, LINKS>,
    netresponder: netresponder::State,
    clock: Clock<LINKS>,
    counters: Counters,
    link_counters: [LinkCounters; LINKS],
    /// Per link: the local time a packet last came in on it, whether the
    /// runtime took it or dropped it as malformed or oversize (anything
    /// there is a neighbour); cleared while the link is closed.
    link_heard: [Option<Instant>; LINKS],
    /// Bus links (as a drop) with a time request of ours waiting for the
    /// medium, one bit per link: a drop asks again only once it has left.
    bus_time_waiting: u64,
    /// When each bus link (as a drop) last asked the head for time.
    #[cfg_attr(not(feature = "sync"), allow(dead_code))]
    bus_time_asked: [Option<Instant>; LINKS],
    changes: Changes,
    scratch: [u8; MTU],
}

impl<const SLOTS: usize, const MTU: usize, const PORTS: usize, const LINKS: usize> core::fmt::Debug
    for Runtime<SLOTS, MTU, PORTS, LINKS>
{
    /// A summary: the stack's buffers and per-link tables are not printed.
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Runtime")
            .field("config", &self.config)
            .field("stack", &self.stack)
            .field("clock", &self.clock.status())
            .field("counters", &self.counters)
            .finish_non_exhaustive()
    }
}

impl<const SLOTS: usize, const MTU: usize, const PORTS: usize, const LINKS: usize>
    Runtime<SLOTS, MTU, PORTS, LINKS>
{
    /// A runtime of the given type and name, with default configuration.
    pub fn new(type_name: &str, name: &str) -> Result<Self, NameTooLong> {
        const {
            assert!(
                MTU >= 16 && MTU <= 255 * 256,
                "MTU must be 16..=65280 bytes"
            );
            assert!(PORTS >= 1, "PORTS counts port 0, so it must be at least 1");
            assert!(LINKS <= 64, "link_forward addresses at most 64 links");
        };
        let mut rt = Runtime {
            identity: Identity {
                type_name: netresponder::name(type_name)?,
                name: netresponder::name(name)?,
                version: [0, 0, 0],
                build: BuildKey::Unknown,
            },
            config: RuntimeConfig::default(),
            stack: PacketStack::new(),
            netresponder: netresponder::State::default(),
            clock: Clock::new(TimeConfig::default()),
            counters: Counters::default(),
            link_counters: [LinkCounters::default(); LINKS],
            link_heard: [None; LINKS],
            bus_time_waiting: 0,
            bus_time_asked: [None; LINKS],
            changes: Changes::default(),
            scratch: [0; MTU],
        };
        rt.apply_quotas();
        // Runtimes with different names dither their time requests apart.
        let seed = name.bytes().fold(0x811c_9dc5u32, |h, b| {
            (h ^ u32::from(b)).wrapping_mul(0x0100_0193)
        });
        rt.clock.seed(seed);
        Ok(rt)
    }

    /// Sets the version and build key reported to scans.
    pub fn with_version(mut self, version: [u8; 3], build: BuildKey) -> Self {
        self.identity.version = version;
        self.identity.build = build;
        self
    }

    /// Replaces the configuration (quotas apply to every port and link).
    pub fn with_config(mut self, config: RuntimeConfig) -> Self {
        self.config = config;
        self.apply_quotas();
        self
    }

    /// Replaces the time configuration.
    pub fn with_time_config(
        mut self,
        config: TimeConfig,
    ) -> Result<Self, crate::clock::TimeConfigError> {
        self.clock.set_config(config)?;
        Ok(self)
    }

    fn apply_quotas(&mut self) {
        for p in 0..PORTS.min(u16::MAX as usize) {
            let _ = self
                .stack
                .set_quota(Owner::Port(p as u16), self.config.port_quota);
        }
        for l in 0..LINKS {
            let _ = self
                .stack
                .set_quota(Owner::Link(l as u8), self.config.link_quota);
        }
        let _ = self
            .stack
            .set_quota(Owner::System, self.config.system_quota);
    }

    /// Overrides the quota of one port or link.
    pub fn set_quota(&mut self, owner: Owner, max: u8) -> Result<(), ClaimError> {
        self.stack.set_quota(owner, max)
    }

    /// Who this runtime is.
    pub fn identity(&self) -> &Identity {
        &self.identity
    }

    /// The configuration.
    pub fn config(&self) -> &RuntimeConfig {
        &self.config
    }

    /// Renames the runtime locally (also marks the name as changed).
    pub fn set_name(&mut self, name: &str) -> Result<(), NameTooLong> {
        self.identity.name = netresponder::name(name)?;
        self.changes.name = true;
        Ok(())
    }

    /// Takes and clears what changed through the network since the last call
    /// (firmware persists a new name when `name` is set).
    pub fn take_changes(&mut self) -> Changes {
        core::mem::take(&mut self.changes)
    }

    /// Takes the latest bus role the network set (netresponder key
    /// `SET_BUS`): the link index and its role, for the owner to apply to
    /// that link (and persist). `None` if none was set since the last call.
    pub fn take_bus_request(&mut self) -> Option<(u8, crate::bus::BusRole)> {
        self.netresponder.take_bus_request()
    }

    /// The drop and event counters.
    pub fn counters(&self) -> &Counters {
        &self.counters
    }

    /// What the runtime counted of link `index`'s traffic (the gateway's
    /// own counts are not included: see [`LinkGateway::counters`]).
    pub fn link_counters(&self, index: usize) -> Option<&LinkCounters> {
        self.link_counters.get(index)
    }

    /// The local time a packet last came in on link `index` (taken, or
    /// dropped as malformed or oversize), or `None` if none has since the
    /// link last opened. A scan reads it through the netresponder's link
    /// information ([`netresponder::NEIGHBOUR_HEARD`]).
    pub fn link_heard(&self, index: usize) -> Option<Instant> {
        self.link_heard.get(index).copied().flatten()
    }

    /// The packet stack (for inspection).
    pub fn stack(&self) -> &PacketStack<SLOTS, MTU, PORTS, LINKS> {
        &self.stack
    }

    /// Synchronised system time at local time `local`.
    pub fn system_time(&self, local: Instant) -> SystemInstant {
        self.clock.system_time(local)
    }

    /// A copy of the clock's local-to-system mapping, to hand to an
    /// interrupt that stamps or schedules in system time.
    pub fn time_map(&self) -> crate::clock::TimeMap {
        self.clock.time_map()
    }

    /// The clock.
    pub fn clock(&self) -> &Clock<LINKS> {
        &self.clock
    }

    /// The clock, for configuration and hot start.
    pub fn clock_mut(&mut self) -> &mut Clock<LINKS> {
        &mut self.clock
    }

    /// The netresponder's state (scan id, debug log).
    pub fn netresponder(&self) -> &netresponder::State {
        &self.netresponder
    }

    /// Adds a line to the debug log readable over the network.
    pub fn log(&mut self, level: Level, args: core::fmt::Arguments<'_>) {
        self.netresponder.log(level, args);
    }

    /// Sends a packet from port `from` outside of a port callback (for code
    /// that drives a port object directly, as a host does).
    pub fn send(
        &mut self,
        now: Instant,
        from: u16,
        route: &Route,
        dst: u16,
        ttl: u16,
        payload: &[u8],
    ) -> Result<(), SendError> {
        let mut sender = self.sender(now);
        sender.send(
            from,
            route,
            Instruction::PortHandle { src: from, dst },
            ttl,
            &mut |buf: &mut [u8]| {
                buf.get_mut(..payload.len())?.copy_from_slice(payload);
                Some(payload.len())
            },
        )
    }

    /// Whether port `from` may send now.
    pub fn clear_to_send(&self, from: u16) -> bool {
        self.stack.check_claim(Owner::Port(from)).is_ok()
    }

    /// Sends a time stamp request to the neighbour on link `link` (the
    /// clock does this by itself every interval; this is for tests and
    /// tools). The stamp is our local counter, rewritten when the request
    /// starts onto the wire.
    pub fn request_time(&mut self, now: Instant, link: u8) -> Result<(), SendError> {
        self.request_time_via(now, Instruction::LinkForward(link))
    }

    /// Sends a time stamp request across one forwarding hop (a link, or a
    /// bus to its head).
    fn request_time_via(&mut self, now: Instant, hop: Instruction) -> Result<(), SendError> {
        let route = Route::local()
            .with_hop(hop)
            .map_err(SendError::BadAddress)?;
        let stamp = now;
        let ttl = self.config.reply_ttl_us;
        self.push_system(now, &route, CODE_TIME_REQUEST, ttl, |w| {
            w.u64(stamp.as_micros()).ok()
        })
    }

    fn sender(&mut self, now: Instant) -> Sender<'_, SLOTS, MTU, PORTS, LINKS> {
        Sender {
            stack: &mut self.stack,
            counters: &mut self.counters,
            now,
        }
    }

    /// Runs one pass of the loop at local time `now` over the caller's ports
    /// (numbered from 1) and link gateways (numbered from 0).
    pub fn poll<P: Port, L: LinkGateway>(
        &mut self,
        now: Instant,
        ports: &mut [P],
        links: &mut [L],
    ) -> PollResult {
        for (i, link) in links.iter_mut().enumerate() {
            if i < LINKS {
                link.set_rx_room(self.stack.room(Owner::Link(i as u8)));
            }
            link.poll(now);
        }
        self.ingest(now, links);
        self.poll_ports(now, ports);
        // Without the controller a runtime still answers time requests, so
        // others can synchronise through it; it just does not steer itself.
        #[cfg(feature = "sync")]
        self.sync_clock(now, links);
        let mut result = self.serve(now, ports, links);
        let ports_due = ports.iter().filter_map(|p| p.wake_at()).min();
        let links_due = links.iter().filter_map(|l| l.wake_at()).min();
        result.wake_at = [
            result.wake_at,
            self.clock.next_request(),
            ports_due,
            links_due,
        ]
        .into_iter()
        .flatten()
        .min();
        result
    }

    /// Sends the clock's time stamp requests when they are due, and forgets
    /// neighbours whose links have closed.
    #[cfg(feature = "sync")]
    fn sync_clock<L: LinkGateway>(&mut self, now: Instant, links: &[L]) {
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

    fn ingest<L: LinkGateway>(&mut self, now: Instant, links: &mut [L]) {
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

    fn poll_ports<P: Port>(&mut self, now: Instant, ports: &mut [P]) {
        let mut base = 1u16;
        let system = self.clock.system_time(now);
        for port in ports.iter_mut() {
            let count = port.port_count();
            let mut sender = self.sender(now);
            let mut tx = PortTx {
                sink: &mut sender,
                base,
                count,
                now,
                system,
            };
            port.poll(&mut tx);
            base = base.saturating_add(count);
        }
    }

    fn serve<P: Port, L: LinkGateway>(
        &mut self,
        now: Instant,
        ports: &mut [P],
        links: &mut [L],
    ) -> PollResult {
        let mut result = PollResult::default();
        let budget = usize::from(self.config.max_packets_per_poll.max(1));
        // Serving can queue new packets (replies, a port answering another
        // locally). Walk again while a pass produced some, so a reply leaves
        // in the same poll as its request; the budget bounds the passes.
        loop {
            let pushes = self.stack.pushes();
            self.serve_pass(now, budget, &mut result, ports, links);
            if result.more || self.stack.pushes() == pushes {
                break;
            }
        }
        result.waiting = self.stack.len();
        result.wake_at = self.stack.earliest_deadline();
        result
    }

    fn serve_pass<P: Port, L: LinkGateway>(
        &mut self,
        now: Instant,
        budget: usize,
        result: &mut PollResult,
        ports: &mut [P],
        links: &mut [L],
    ) {
        let mut cursor = self.stack.first();
        while let Some(slot) = cursor {
            if result.handled >= budget {
                result.more = true;
                return;
            }
            // Serving a packet only ever frees this slot and queues new
            // ones, so its successor stays valid across the call.
            cursor = self.stack.next(slot);
            let meta = *self.stack.meta(slot);
            if now > meta.deadline {
                // Counted against the link it was bound for, if any.
                if let Ok(Instruction::LinkForward(j) | Instruction::BusForward { bus: j, .. }) =
                    Packet::new_checked(self.stack.packet(slot)).and_then(|p| p.instruction())
                {
                    self.count_link(usize::from(j), |t| &mut t.expired);
                    if let Some(bit) = 1u64.checked_shl(u32::from(j)) {
                        self.bus_time_waiting &= !bit;
                    }
                }
                self.stack.release(slot);
                bump(&mut self.counters.expired);
                result.dropped += 1;
                continue;
            }
            let instruction =
                Packet::new_checked(self.stack.packet(slot)).and_then(|p| p.instruction());
            let served = match instruction {
                Err(_) => self.drop_slot(slot, Drop::Malformed),
                Ok(Instruction::LinkForward(j)) => {
                    self.forward(slot, j, None, now, meta.deadline, links)
                }
                Ok(Instruction::BusForward { bus, drop }) => {
                    self.forward(slot, bus, Some(drop), now, meta.deadline, links)
                }
                Ok(Instruction::PortHandle { src, dst: 0 }) => {
                    self.answer_netresponder(slot, src, now, ports, links)
                }
                Ok(Instruction::PortHandle { src, dst }) => {
                    self.deliver(slot, src, dst, now, ports)
                }
                Ok(Instruction::SystemMsg(code)) => self.system_message(slot, code, now),
            };
            match served {
                Served::Done => result.handled += 1,
                Served::Dropped => result.dropped += 1,
                Served::Wait => {}
            }
        }
    }

    /// Counts one on link `i`'s tally (a link index beyond `LINKS` has
    /// none).
    fn count_link(&mut self, i: usize, counter: fn(&mut LinkCounters) -> &mut u32) {
        if let Some(t) = self.link_counters.get_mut(i) {
            bump(counter(t));
        }
    }

    /// Adds `len` bytes to link `i`'s byte tally (wrapping).
    fn count_link_bytes(
        &mut self,
        i: usize,
        len: usize,
        counter: fn(&mut LinkCounters) -> &mut u32,
    ) {
        if let Some(t) = self.link_counters.get_mut(i) {
            let c = counter(t);
            *c = c.wrapping_add(len as u32);
        }
    }

    fn drop_slot(&mut self, slot: SlotId, why: Drop) -> Served {
        self.stack.release(slot);
        let c = &mut self.counters;
        bump(match why {
            Drop::Malformed => &mut c.malformed,
            Drop::NoRoute => &mut c.no_route,
            Drop::LinkClosed => &mut c.link_closed,
            Drop::NoPort => &mut c.no_port,
            Drop::Oversize => &mut c.oversize,
            Drop::UnknownSystem => &mut c.unknown_system,
        });
        Served::Dropped
    }

    /// Sends the packet in `slot` on link `index`: to drop `drop` if the
    /// hop was a `bus_forward` (which needs a bus link), point to point if
    /// it was a `link_forward` (which needs a point-to-point link).
    fn forward<L: LinkGateway>(
        &mut self,
        slot: SlotId,
        index: u8,
        drop: Option<u8>,
        now: Instant,
        deadline: Instant,
        links: &mut [L],
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
        if !link.clear_to_send() {
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
    fn take_to_scratch(&mut self, slot: SlotId) -> (usize, SlotMeta) {
        let packet = self.stack.packet(slot);
        let len = packet.len();
        self.scratch[..len].copy_from_slice(packet);
        let meta = *self.stack.meta(slot);
        self.stack.release(slot);
        (len, meta)
    }

    fn deliver<P: Port>(
        &mut self,
        slot: SlotId,
        src: u16,
        dst: u16,
        now: Instant,
        ports: &mut [P],
    ) -> Served {
        let Some((object, offset, base)) = find_port(ports, dst) else {
            return self.drop_slot(slot, Drop::NoPort);
        };
        let port = &mut ports[object];
        if !port.clear_to_receive(offset) {
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

    fn answer_netresponder<P: Port, L: LinkGateway>(
        &mut self,
        slot: SlotId,
        src: u16,
        now: Instant,
        ports: &[P],
        links: &[L],
    ) -> Served {
        // Answer only when the reply can be stored; until then the request
        // waits like any packet for a busy port.
        if self.stack.check_claim(Owner::Port(0)).is_err() {
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
            Owner::Port(0),
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

    fn system_message(&mut self, slot: SlotId, code: u8, now: Instant) -> Served {
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
                // Our time when the request arrived; averaged with our time
                // when the reply starts onto the wire at transmit.
                let reply = TimeReply {
                    request_time: Instant::from_micros(u64::from_le_bytes(stamp)),
                    responder_time: self.clock.system_time(meta.arrival),
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

    fn push_system(
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

#[derive(Clone, Copy)]
enum Drop {
    Malformed,
    NoRoute,
    LinkClosed,
    NoPort,
    Oversize,
    UnknownSystem,
}

/// Rewrites the stamp of a time message this runtime originated as it starts
/// onto the wire at local time `on_wire`: a request gets our local counter;
/// a reply's responder time becomes the mean of our system time when the
/// request arrived (written when the reply was made) and now, so it stands
/// for the midpoint of our turnaround.
fn stamp_time_message<const LINKS: usize>(
    packet: &mut [u8],
    on_wire: Instant,
    clock: &Clock<LINKS>,
) {
    const BODY: usize = HEADER_LEN + 2;
    if packet.first() != Some(&(HEADER_LEN as u8)) {
        return; // forwarded for someone else: not ours to stamp
    }
    let code = match packet
        .get(HEADER_LEN + 1)
        .map(|b| Instruction::decode(&[*b]))
    {
        Some(Ok(Instruction::SystemMsg(code))) => code,
        _ => return,
    };
    let body = &mut packet[BODY..];
    match (code, body.len()) {
        (CODE_TIME_REQUEST, TIME_REQUEST_LEN) => {
            body.copy_from_slice(&on_wire.as_micros().to_le_bytes())
        }
        (CODE_TIME_REPLY, TIME_REPLY_LEN) => {
            let mut arrived = [0u8; 8];
            arrived.copy_from_slice(&body[8..16]);
            let arrived = SystemInstant::from_micros(u64::from_le_bytes(arrived));
            let leaving = clock.system_time(on_wire);
            // Signed: a hard jump between the two may have moved time back.
            let half = leaving.signed_micros_since(arrived) / 2;
            let mid = arrived.as_micros().wrapping_add(half as u64);
            body[8..16].copy_from_slice(&mid.to_le_bytes());
        }
        _ => {}
    }
}

/// Finds the port object serving runtime port index `index` (≥ 1): returns
/// the object's slice position, the offset within it and its base index.
fn find_port<P: Port>(ports: &[P], index: u16) -> Option<(usize, u16, u16)> {
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
fn split_delivery(packet: &[u8]) -> Option<(Route, &[u8])> {
    let view = Packet::new_checked(packet).ok()?;
    let route = Route::from_bytes(view.walked()).ok()?;
    let payload = view.after_instruction().ok()?;
    Some((route.reversed().with_mtu(view.mtu()), payload))
}

/// The runtime's implementation of a port's send handle.
struct Sender<'r, const SLOTS: usize, const MTU: usize, const PORTS: usize, const LINKS: usize> {
    stack: &'r mut PacketStack<SLOTS, MTU, PORTS, LINKS>,
    counters: &'r mut Counters,
    now: Instant,
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
fn queue_packet<const SLOTS: usize, const MTU: usize, const PORTS: usize, const LINKS: usize>(
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
