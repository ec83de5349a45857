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
//! serving order (earliest deadline first, never ahead of a packet of the
//! same owner: see [`crate::stack`]), dropping what has expired, forwarding
//! what a clear link can take, delivering what a clear port can take, and
//! answering system messages and port 0. A packet whose link or port is busy
//! simply waits its turn; it never holds up the packets behind it that go
//! elsewhere. A link or port found busy stays busy for the rest of the walk,
//! even if it clears meanwhile (a host link's other half runs on another
//! thread): the packets behind the waiting one, bound for the same place,
//! wait too, so each link and port takes its packets in serving order.

use crate::clock::{
    own_time_message, Clock, TimeConfig, TimeReply, CODE_TIME_REPLY, CODE_TIME_REQUEST,
    TIME_REPLY_LEN, TIME_REQUEST_LEN,
};
use crate::codec::Writer;
use crate::counters::{bump, Counters, LinkCounters};
use crate::link::LinkGateway;
use crate::netresponder::{self, BuildKey, Changes, Identity, Level, NameTooLong};
use crate::packet::{Instruction, Packet, PacketError};
use crate::port::{Delivery, PacketSink, Port, PortTx, SendError};
use crate::route::Route;
use crate::stack::{ClaimError, Owner, PacketStack, PushError, SlotId, SlotMeta};
use crate::time::{Duration, Instant, SystemInstant};
use crate::transport::Transport;

mod deliver;
mod ingest;
mod sender;
mod system;

use deliver::split_delivery;
use ingest::stamp_time_message;
use sender::{queue_packet, Sender};

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

/// The links and ports one walk of the stack found busy: they stay busy
/// until the walk ends, so no packet behind a waiting one reaches the same
/// place first.
struct Busy<const PORTS: usize> {
    links: u64,
    ports: [bool; PORTS],
}

impl<const PORTS: usize> Busy<PORTS> {
    fn new() -> Self {
        Busy {
            links: 0,
            ports: [false; PORTS],
        }
    }

    /// Whether link `i` was found busy in this walk.
    fn link(&self, i: u8) -> bool {
        1u64.checked_shl(u32::from(i))
            .is_some_and(|bit| self.links & bit != 0)
    }

    /// Marks link `i` busy for the rest of the walk.
    fn set_link(&mut self, i: u8) {
        if let Some(bit) = 1u64.checked_shl(u32::from(i)) {
            self.links |= bit;
        }
    }

    /// Whether port `index` was found busy in this walk. (A port index
    /// beyond `PORTS` has no entry: it has no quota either, so it cannot
    /// have sent what comes to it.)
    fn port(&self, index: u16) -> bool {
        self.ports.get(usize::from(index)).copied().unwrap_or(false)
    }

    /// Marks port `index` busy for the rest of the walk.
    fn set_port(&mut self, index: u16) {
        if let Some(p) = self.ports.get_mut(usize::from(index)) {
            *p = true;
        }
    }
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
                function_set: 0,
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

    /// Sets the function-set id reported in runtime information (see
    /// [`Identity::function_set`]).
    pub fn with_function_set(mut self, id: u32) -> Self {
        self.identity.function_set = id;
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
        let mut busy = Busy::<PORTS>::new();
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
                    self.forward(slot, j, None, now, meta.deadline, links, &mut busy)
                }
                Ok(Instruction::BusForward { bus, drop }) => {
                    self.forward(slot, bus, Some(drop), now, meta.deadline, links, &mut busy)
                }
                Ok(Instruction::PortHandle { src, dst: 0 }) => {
                    self.answer_netresponder(slot, src, now, ports, links)
                }
                Ok(Instruction::PortHandle { src, dst }) => {
                    self.deliver(slot, src, dst, now, ports, &mut busy)
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
