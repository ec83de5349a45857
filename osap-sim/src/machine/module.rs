//! One simulated module: an osap-core runtime sized like firmware, in its
//! own tokio task, on a drifting clock; for a `stepper`, osap-module's
//! logic on a [`SimBoard`], its step words clocked out as the firmware's
//! step generator clocks them.

use super::board::SimBoard;
use super::clock::DriftClock;
use super::switch::{self, Input, Publisher};
use osap_core::clock::TimeMap;
use osap_core::link::{LinkGateway, LinkInfo, LinkSendError, Received};
use osap_core::port::Port;
use osap_core::{Duration, Instant};
use osap_host::clock::HostClock;
use osap_host::driver::{self, Driven, PollOutcome};
use osap_host::link::ChannelLink;
use osap_module::{Module, ModuleHandle, STEP_TICK_US, TICKS_PER_WORD};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use tokio::sync::{mpsc, Notify};

pub use crate::topology::{FIRMWARE_LINKS, MODULE_LINKS, MODULE_MTU, MODULE_PORTS, MODULE_SLOTS};

/// A simulated module's osap-module instance, shared by its function ports,
/// its step generator and the [`SimModule`](super::SimModule) handle.
#[derive(Clone)]
pub struct SharedModule(Arc<Mutex<Module<SimBoard>>>);

impl SharedModule {
    pub(crate) fn new(module: Module<SimBoard>) -> Self {
        SharedModule(Arc::new(Mutex::new(module)))
    }

    /// Runs `f` on the module (its logic state and its board).
    pub fn lock<R>(&self, f: impl FnOnce(&mut Module<SimBoard>) -> R) -> R {
        let mut m = self.0.lock().unwrap_or_else(|e| e.into_inner());
        f(&mut m)
    }
}

impl ModuleHandle for SharedModule {
    type Board = SimBoard;

    fn with<R>(&self, f: impl FnOnce(&mut Module<SimBoard>) -> R) -> Option<R> {
        Some(self.lock(f))
    }
}

impl std::fmt::Debug for SharedModule {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.lock(|m| m.fmt(f))
    }
}

/// Local time one step word covers.
const WORD: Duration = Duration::from_micros((STEP_TICK_US * TICKS_PER_WORD) as u64);
/// How far ahead of the local clock step words are filled: as the
/// firmware's FIFO (8 words, 1.28 ms) plus a tokio timer's 1 ms
/// granularity, so words are always ready before their ticks.
const STEP_LEAD: Duration = Duration::from_micros(8 * WORD.as_micros() + 1_000);
/// How often a moving axis's step generator is topped up, local time.
const STEP_REFILL: Duration = Duration::from_millis(1);
/// How often a torque device commutes, local time: its firmware's timer
/// (1 kHz: a tokio timer's tick, which shorter waits would round up to).
const COMMUTATE: Duration = Duration::from_millis(1);

/// The firmware's step generator, simulated: it asks the module for each
/// word of 16 ticks (the same `fill_step_word` the firmware's step
/// interrupt calls) and hands the board each step in it, and it delivers
/// the limit switch's edges to the module at their times, as the firmware's
/// edge interrupt does. With switches over several motors
/// ([`SwitchSpec`](super::SwitchSpec)) it also publishes its motor's steps
/// to the modules whose switches watch it, and merges what the motors its
/// own input watches published (see `switch.rs`).
#[derive(Clone)]
pub(crate) struct StepClock {
    module: SharedModule,
    /// Local time of the next word's first tick.
    next: Instant,
    /// Publishes this motor's steps, if a switch watches it.
    publisher: Option<Publisher>,
    /// The limit input, if switches over motors drive it (else the motor's
    /// own switch does).
    input: Option<Input>,
}

impl StepClock {
    pub(crate) fn new(
        module: SharedModule,
        boot_local: Instant,
        publisher: Option<Publisher>,
        input: Option<Input>,
    ) -> Self {
        StepClock {
            module,
            // Word-aligned to the counter, as a step generator started at boot.
            next: Instant::from_micros(
                boot_local.as_micros().div_ceil(WORD.as_micros()) * WORD.as_micros(),
            ),
            publisher,
            input,
        }
    }

    /// Clocks out every word of `m` up to local `until`, publishing the
    /// steps if a switch watches the motor.
    fn run(
        next: &mut Instant,
        publisher: &mut Option<Publisher>,
        m: &mut Module<SimBoard>,
        until: Instant,
    ) {
        while *next <= until {
            let word = m.fill_step_word(*next);
            let mut start = None;
            for k in 0..TICKS_PER_WORD {
                let bits = (word >> (2 * k)) & 3;
                if bits & 1 != 0 {
                    let t = *next + Duration::from_micros(u64::from(k * STEP_TICK_US));
                    m.board_mut().step(t, bits & 2 != 0);
                    if let Some(p) = publisher {
                        let word_at = *start.get_or_insert_with(|| p.instant_at(*next));
                        let at = switch::tick_instant(word_at, k, STEP_TICK_US);
                        p.step(at, m.board().motor().position());
                    }
                }
            }
            *next += WORD;
        }
    }

    /// Delivers the limit edges due by local `now`: the motor's own
    /// switch's, or the input's after merging what its motors published.
    fn deliver(input: &mut Option<Input>, m: &mut Module<SimBoard>, now: Instant) {
        match input {
            Some(input) => {
                input.merge(now);
                for (t, level) in input.take_edges(now) {
                    m.limit_changed(t, level);
                }
            }
            None => {
                for (t, level) in m.board_mut().motor_mut().take_limit_edges(now) {
                    m.limit_changed(t, level);
                }
            }
        }
    }

    /// The limit input's level at boot.
    pub(crate) fn initial_level(&self) -> bool {
        match &self.input {
            Some(input) => input.level(),
            None => self.module.lock(|m| m.board().motor().limit_level()),
        }
    }

    /// Before the module reads its clock for a poll.
    pub(crate) fn begin_poll(&self) {
        if let Some(p) = &self.publisher {
            p.begin_poll();
        }
    }

    /// Before a poll at local `now`: the words and limit edges up to now.
    /// Returns whether the axis has motion queued or running (its clock
    /// must not step then).
    pub(crate) fn catch_up(&mut self, now: Instant) -> bool {
        let StepClock {
            module,
            next,
            publisher,
            input,
        } = self;
        module.lock(|m| {
            Self::run(next, publisher, m, now);
            if let Some(p) = publisher {
                p.publish(*next, None);
            }
            Self::deliver(input, m, now);
            // A torque device's commutation timer (see osap_module::torque).
            m.commutate(now);
            !m.stepper.is_standing()
        })
    }

    /// After a poll at local `now`, which left the runtime's time map `map`:
    /// hands the module the map, then fills words a lead ahead if the axis
    /// may move; returns when it next needs a turn (local µs). One lock for
    /// all of it: this runs after every poll.
    pub(crate) fn fill_ahead(&mut self, now: Instant, map: TimeMap) -> Option<Instant> {
        let StepClock {
            module,
            next,
            publisher,
            input,
        } = self;
        module.lock(|m| {
            m.publish_time(map);
            let standing = m.stepper.is_standing();
            if !standing {
                Self::run(next, publisher, m, now + STEP_LEAD);
            }
            if let Some(p) = publisher {
                p.publish(*next, Some(standing));
            }
            Self::deliver(input, m, now);
            let limit = match input {
                Some(input) => input.next_turn(now, STEP_REFILL),
                None => m.board().motor().next_limit_edge(),
            };
            let refill = (!standing).then_some(now + STEP_REFILL);
            let commutate = m.stepper.is_torque().then_some(now + COMMUTATE);
            [limit, refill, commutate].into_iter().flatten().min()
        })
    }
}

/// The runtime a simulated module runs: sized like firmware.
pub type ModuleRuntime = osap_core::Runtime<MODULE_SLOTS, MODULE_MTU, MODULE_PORTS, MODULE_LINKS>;

/// A module's side of a link: a [`ChannelLink`] (whose receive stamps are on
/// the host's clock) whose stamps are turned into the module's local time.
pub(crate) struct ModuleLink {
    pub(crate) inner: ChannelLink,
    clock: DriftClock,
    host_clock: HostClock,
    /// On a bus: the station's bus state over `inner`.
    bus: Option<osap_core::bus::BusCore<{ MODULE_MTU + osap_core::bus::HEADER_LEN }>>,
}

impl ModuleLink {
    pub(crate) fn new(inner: ChannelLink, clock: DriftClock, host_clock: HostClock) -> Self {
        ModuleLink {
            inner,
            clock,
            host_clock,
            bus: None,
        }
    }

    /// The same link as a station of a bus.
    pub(crate) fn on_bus(mut self, config: Option<osap_core::bus::BusConfig>) -> Self {
        self.bus = config.map(osap_core::bus::BusCore::new);
        self
    }
}

impl LinkGateway for ModuleLink {
    fn info(&self) -> LinkInfo<'_> {
        self.inner.info()
    }
    fn is_open(&self) -> bool {
        self.inner.is_open()
    }
    fn mtu(&self) -> u16 {
        match &self.bus {
            Some(bus) => bus.mtu(&self.inner),
            None => self.inner.mtu(),
        }
    }
    fn clear_to_send(&self) -> bool {
        match &self.bus {
            Some(bus) => bus.clear_to_send(&self.inner),
            None => self.inner.clear_to_send(),
        }
    }
    fn send(&mut self, packet: &[u8]) -> Result<(), LinkSendError> {
        match &mut self.bus {
            Some(bus) => {
                let to = if bus.config().is_head() {
                    osap_core::bus::BROADCAST
                } else {
                    osap_core::bus::HEAD
                };
                bus.send_to(&mut self.inner, to, packet)
            }
            None => self.inner.send(packet),
        }
    }
    fn send_to(&mut self, drop: u8, packet: &[u8]) -> Result<(), LinkSendError> {
        match &mut self.bus {
            Some(bus) => bus.send_to(&mut self.inner, drop, packet),
            None => self.inner.send(packet),
        }
    }
    fn bus(&self) -> Option<osap_core::link::BusInfo> {
        self.bus.as_ref().map(|b| b.info())
    }
    fn received_from(&self) -> Option<u8> {
        self.bus.as_ref().and_then(|b| b.received_from())
    }
    fn wake_at(&self) -> Option<Instant> {
        self.bus.as_ref().and_then(|b| b.wake_at())
    }
    fn set_rx_room(&mut self, room: u8) {
        if let Some(bus) = &mut self.bus {
            bus.set_rx_room(room);
        }
    }
    fn poll(&mut self, now: Instant) {
        self.inner.poll(now);
        if let Some(bus) = &mut self.bus {
            bus.poll(&mut self.inner, now);
        }
    }
    fn transmit_time(&self, len: usize) -> Duration {
        let extra = if self.bus.is_some() {
            osap_core::bus::HEADER_LEN
        } else {
            0
        };
        self.inner.transmit_time(len + extra)
    }
    fn queue_delay(&self) -> Duration {
        self.inner.queue_delay()
    }
    fn counters(&self) -> Option<osap_core::counters::GatewayCounters> {
        self.inner.counters()
    }
    fn receive(&mut self, buf: &mut [u8]) -> Option<Received> {
        let mut rx = match &mut self.bus {
            Some(bus) => bus.receive(&mut self.inner, buf)?,
            None => self.inner.receive(buf)?,
        };
        rx.timestamp = rx
            .timestamp
            .map(|host| self.clock.local_at(self.host_clock.instant_at(host)));
        Some(rx)
    }
}

pub(crate) type ModuleFn = Box<dyn FnOnce(&mut ModuleRuntime, Instant) + Send>;

pub(crate) enum ModuleCommand {
    With(ModuleFn),
    Stop,
}

/// What a stopped module leaves behind for its restart: its link ends and
/// the name it had (the network may have renamed it; firmware keeps a new
/// name in flash).
pub(crate) struct Parked {
    pub(crate) links: Vec<ChannelLink>,
    pub(crate) name: String,
    /// Where a stepper's carriage stood (the motor's finest unit).
    pub(crate) carriage: i64,
}

pub(crate) struct ModuleTask {
    pub(crate) runtime: Box<ModuleRuntime>,
    pub(crate) ports: Vec<Box<dyn Port + Send>>,
    pub(crate) links: Vec<ModuleLink>,
    pub(crate) commands: mpsc::UnboundedReceiver<ModuleCommand>,
    pub(crate) wake: Arc<Notify>,
    pub(crate) clock: DriftClock,
    /// A `stepper`'s step generator (it holds the module).
    pub(crate) stepper: Option<StepClock>,
    /// Fault injection: the main loop hangs (the runtime is not polled)
    /// while the step generator runs on, as a step interrupt would.
    pub(crate) frozen: Arc<AtomicBool>,
}

impl Driven for ModuleTask {
    type Command = ModuleCommand;

    fn handle(&mut self, command: ModuleCommand) -> std::ops::ControlFlow<()> {
        match command {
            ModuleCommand::With(f) => {
                let now = self.clock.now();
                f(&mut self.runtime, now);
                std::ops::ControlFlow::Continue(())
            }
            ModuleCommand::Stop => std::ops::ControlFlow::Break(()),
        }
    }

    fn poll(&mut self) -> PollOutcome {
        if let Some(steps) = &self.stepper {
            steps.begin_poll();
        }
        let now = self.clock.now();
        if let Some(steps) = &mut self.stepper {
            let moving = steps.catch_up(now);
            self.runtime.clock_mut().set_motion_active(moving);
        }
        let result = if self.frozen.load(Ordering::Acquire) {
            osap_core::runtime::PollResult::default()
        } else {
            self.runtime.poll(now, &mut self.ports, &mut self.links)
        };
        let mut wake_at = result.wake_at;
        if let Some(steps) = &mut self.stepper {
            if let Some(t) = steps.fill_ahead(now, self.runtime.time_map()) {
                wake_at = Some(wake_at.map_or(t, |w| w.min(t)));
            }
        }
        PollOutcome {
            more: result.more,
            wake_at: wake_at.map(|t| tokio::time::Instant::from_std(self.clock.instant_at(t))),
        }
    }
}

impl ModuleTask {
    /// Polls the runtime whenever a link has news, a command comes, or the
    /// runtime's `wake_at` or the step generator's next turn comes due;
    /// stops on [`ModuleCommand::Stop`] or when every handle is gone.
    pub(crate) async fn run(mut self) -> Parked {
        let mut commands = std::mem::replace(&mut self.commands, mpsc::unbounded_channel().1);
        let wake = self.wake.clone();
        driver::drive(&mut self, &mut commands, &wake).await;
        self.park()
    }

    fn park(self) -> Parked {
        Parked {
            name: self.runtime.identity().name.to_string(),
            carriage: self
                .stepper
                .as_ref()
                .map_or(0, |s| s.module.lock(|m| m.board().motor().carriage())),
            links: self.links.into_iter().map(|l| l.inner).collect(),
        }
    }
}
