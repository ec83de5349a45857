//! # osap-module
//!
//! The logic of osap-rs module firmware, shared by every board and by the
//! simulator: a stepper axis that follows MAXL control points in
//! synchronized time and makes step/direction ticks at 100 kHz, and an I/O
//! set (digital pins, PWM, analog inputs, timed pulses, and level and
//! event tracks that change outputs at stamped times, [`levels`]) and up to two
//! heaters with their own runaway protection ([`heater`]), all exposed as
//! PIPES functions that a network scan finds ([`functions`]). A firmware
//! crate supplies only board glue: links, the step generator's peripheral,
//! and a [`board::Board`].
//!
//! A module is a value, [`Module`], that holds its logic state and its
//! board; a process may hold any number of them (the simulator runs one per
//! simulated module). The module's PIPES functions reach it through a
//! [`ModuleHandle`], so each function port is bound to one module.
//!
//! ## How a firmware uses it
//! 1. Keep one [`ModuleCell`] in a `static` (the runtime task and the step
//!    interrupt both use the module, so it lives behind a critical
//!    section); at boot, [`ModuleCell::install`] the board.
//! 2. Build the ports with [`ModulePorts::new`]`(&CELL)` and pass
//!    [`ModulePorts::ports`] to `Runtime::poll`; after every poll,
//!    [`ModuleHandle::publish_time`] the runtime's `time_map()`.
//! 3. From the step interrupt, call [`ModuleCell::fill_step_word`] for each
//!    word the step generator needs; from the limit switch's edge
//!    interrupt, call [`ModuleCell::limit_changed`].
//!
//! Each call holds the lock only for its own short work. `no_std`, no
//! allocation.
//!
//! ## Safe by itself
//! Every output has a safe value (`set_safe_pwm`, `set_safe_digital`; see
//! [`io`]), and the module applies them by itself:
//! - on `halt` (every stop a host makes sends it), with the axis halted;
//! - when its stream runs dry mid-motion and its backstop brakes the axis
//!   (a carriage that stopped must not leave a laser burning in one place);
//! - when its output watchdog fires: nothing reached it from upstream for
//!   `set_output_watchdog`'s timeout ([`watchdog`]).
//!
//! Each of these also ends a torque request ([`torque`]; the motor then
//! holds where it stands) and turns every heater off (target 0), and a heater cuts
//! itself off when its temperature runs away or its sensor fails
//! ([`heater`]), recording a fault.
//!
//! A limit switch press does not: the module does not stop on it by itself
//! (homing presses its switch on purpose), and the host's stop that follows
//! a press outside homing is a `halt`, which does.
#![no_std]
#![deny(missing_docs)]
// Lints as policy: every public type can be printed, and `pub` means
// reachable from outside the crate.
#![warn(missing_debug_implementations, unreachable_pub)]
#![forbid(unsafe_code)]

#[cfg(test)]
extern crate std;

pub mod blocks;
pub mod board;
pub mod boot;
pub mod failure;
pub mod fault;
pub mod functions;
pub mod heater;
pub mod hot_start;
pub mod io;
pub mod levels;
pub mod loadcell;
pub mod ports;
pub mod rate_store;
pub mod sampler;
pub mod sizes;
pub mod stepper;
pub mod tach;
pub mod torque;
pub mod watchdog;

pub use functions::FUNCTION_SET_ID;
pub use ports::{ModulePort, ModulePorts, PORT_COUNT, PORT_INDICES};
pub use stepper::{STEP_TICK_US, TICKS_PER_WORD};

use board::Board;
use boot::BootRequest;
use core::cell::RefCell;
use critical_section::Mutex;
use fault::{Fault, FaultKind};
use heater::Heaters;
use io::Io;
use loadcell::LoadCell;
use osap_core::clock::TimeMap;
use osap_core::{Duration, Instant, SystemInstant};
use stepper::Stepper;
use tach::Tach;
use watchdog::Watchdog;

/// The limit switch's latest edge.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Limit {
    /// The level after the edge.
    pub level: bool,
    /// When the edge happened ([`SystemInstant::ZERO`]: no edge yet).
    pub time: SystemInstant,
    /// Edges since boot.
    pub edges: u32,
}

/// One module: its logic state and its board.
pub struct Module<B> {
    /// The stepper axis.
    pub stepper: Stepper,
    /// The I/O set.
    pub io: Io,
    /// The level and event tracks on the I/O set's outputs.
    pub tracks: levels::Tracks,
    /// The heaters.
    pub heaters: Heaters,
    /// The load cell.
    pub loadcell: LoadCell,
    /// The tachometer.
    pub tach: Tach,
    /// The limit switch.
    pub limit: Limit,
    /// The runtime's latest local-to-system time map.
    pub time: TimeMap,
    /// The latest fault and the faults since boot (`get_fault`).
    pub fault: Fault,
    /// A reboot into the bootloader, armed by `enter_bootloader`.
    pub boot: BootRequest,
    /// The output watchdog, armed by `set_output_watchdog`.
    pub watchdog: Watchdog,
    /// The torque request, while the motor is a torque device
    /// ([`torque`]).
    pub torque: torque::Torque,
    /// Samples batched into blocks (`sample_block`, [`sampler`]).
    pub sampler: sampler::Sampler,
    /// When the latest control point was accepted.
    last_point_at: SystemInstant,
    /// Whether the latest control point was refused.
    refusing: bool,
    /// The late-step count the latest `StepOverrun` record carried.
    late_reported: u64,
    board: B,
    /// The step words' time anchor: a (local, system) pair read off `time`.
    step_anchor: Option<StepAnchor>,
}

/// Reading the time map takes 64-bit multiplies (library calls on a
/// Cortex-M0+), too many to do for every step word; words within
/// [`ANCHOR_SPAN`] of the last reading take its offset instead. Over
/// that span a rate error of 500 ppm (far beyond a crystal's) moves a tick
/// by 2 µs, a typical 50 ppm by 0.2 µs.
#[derive(Debug, Clone, Copy)]
struct StepAnchor {
    map: TimeMap,
    local: Instant,
    system: SystemInstant,
}

/// How long a step-word time anchor is used.
pub const ANCHOR_SPAN: Duration = Duration::from_micros(4096);

impl<B: Board> Module<B> {
    /// A fresh module on `board`: the motor disabled (the driver is told at
    /// once), no stream, no pulses, the identity time map.
    pub fn new(mut board: B) -> Self {
        board.stepper().set_enable(false);
        Module {
            stepper: Stepper::new(),
            io: Io::new(),
            tracks: levels::Tracks::new(),
            heaters: Heaters::new(),
            loadcell: LoadCell::new(),
            tach: Tach::new(),
            limit: Limit::default(),
            time: TimeMap::IDENTITY,
            fault: Fault::default(),
            boot: BootRequest::default(),
            watchdog: Watchdog::new(),
            torque: torque::Torque::default(),
            sampler: sampler::Sampler::new(),
            last_point_at: SystemInstant::ZERO,
            refusing: false,
            late_reported: 0,
            board,
            step_anchor: None,
        }
    }

    /// The board.
    pub fn board(&self) -> &B {
        &self.board
    }

    /// The board, to change what its simulated inputs read, say.
    pub fn board_mut(&mut self) -> &mut B {
        &mut self.board
    }

    /// Local time now.
    pub fn local_now(&self) -> Instant {
        self.board.now()
    }

    /// Synchronized time now.
    pub fn system_now(&self) -> SystemInstant {
        self.time.system_time(self.board.now())
    }

    /// Hands the module the runtime's latest time map (call after every
    /// poll).
    pub fn publish_time(&mut self, map: TimeMap) {
        self.time = map;
    }

    /// The next step-generator word, its first tick at local time `local` (the
    /// step generator's own running count of ticks, anchored to the local
    /// clock, so interrupt latency does not move the ticks).
    pub fn fill_step_word(&mut self, local: Instant) -> u32 {
        let t0 = match self.step_anchor {
            Some(a)
                if a.map == self.time
                    && local >= a.local
                    && local.as_micros() - a.local.as_micros() < ANCHOR_SPAN.as_micros() =>
            {
                // Plain arithmetic on the step interrupt's path (the
                // saturating operators cost a Cortex-M0+ cycles per word):
                // `local` is not before the anchor, and within its span
                // nothing can overflow.
                let since = local.as_micros() - a.local.as_micros();
                SystemInstant::from_micros(a.system.as_micros() + since)
            }
            _ => {
                let system = self.time.system_time(local);
                self.step_anchor = Some(StepAnchor {
                    map: self.time,
                    local,
                    system,
                });
                system
            }
        };
        let faults = self.stepper.counters().faults;
        let word = self.stepper.fill_word(t0);
        if self.stepper.counters().faults != faults {
            self.on_backstop(t0);
        }
        if self.stepper.late_steps() != self.late_reported {
            self.on_late_steps(t0);
        }
        word
    }

    /// The backstop latched with the axis moving, in the word starting at
    /// `t0`: a fault, and the axis brakes to a stop on its own, so its
    /// tools go off. Out of line: the step interrupt's common path stays
    /// as short as it was.
    #[cold]
    #[inline(never)]
    fn on_backstop(&mut self, t0: SystemInstant) {
        let quiet = (t0 - self.last_point_at).as_micros();
        let quiet = u32::try_from(quiet).unwrap_or(u32::MAX);
        self.fault.record(t0, FaultKind::Backstop, quiet, true);
        self.apply_safe_outputs();
    }

    /// The late-step count differs from the one last recorded, in the word
    /// starting at `t0`: a `StepOverrun` record with the running count,
    /// which a host compares with its bound (see [`fault`]), at most one a
    /// word, and held back while a record of another kind is younger than
    /// [`fault::FAULT_HOLD`] (then made at the first word after it). A
    /// count that went down is a restarted step generator: nothing to
    /// report.
    #[cold]
    #[inline(never)]
    fn on_late_steps(&mut self, t0: SystemInstant) {
        let late = self.stepper.late_steps();
        if late < self.late_reported {
            self.late_reported = late;
        } else if self.fault.takes_late_steps(t0) {
            self.late_reported = late;
            let count = u32::try_from(late).unwrap_or(u32::MAX);
            let stopped = self.stepper.is_stopped();
            self.fault
                .record(t0, FaultKind::StepOverrun, count, stopped);
        }
    }

    /// Queues a control point (see [`Stepper::add_point`]), recording a
    /// refusal as a fault: [`FaultKind::OverLimit`] with the limits it went
    /// past for a point past the axis's limits, [`FaultKind::Refused`] with
    /// the refusal's code for any other.
    pub fn queue_point(
        &mut self,
        time: SystemInstant,
        position: f32,
    ) -> Result<(), stepper::StepperError> {
        let now = self.system_now();
        let result = self.stepper.add_point(time, position);
        match result {
            Ok(()) => self.last_point_at = now,
            Err(stepper::StepperError::OverLimit) => {
                let which = fault::over_limit_detail(self.stepper.over_limit());
                self.fault.record(now, FaultKind::OverLimit, which, false);
            }
            // The points missing before this one are the ones this module
            // just refused: the gap is their consequence, and the record
            // keeps their cause (a host that reads the fault a few points
            // later must still learn why the stream broke).
            Err(stepper::StepperError::Gap) if self.refusing => self.fault.count_consequence(),
            Err(e) => {
                let stopped = self.stepper.is_stopped();
                self.fault
                    .record(now, FaultKind::Refused, u32::from(e.code()), stopped);
            }
        }
        self.refusing = result.is_err();
        result
    }

    /// Halts the axis (see [`Stepper::halt`]) and puts every output in its
    /// safe state ([`apply_safe_outputs`](Self::apply_safe_outputs)),
    /// recording it as a fault.
    pub fn halt_axis(&mut self) {
        self.end_torque();
        self.stepper.halt();
        self.apply_safe_outputs();
        let now = self.system_now();
        self.fault.record(now, FaultKind::Halted, 0, true);
    }

    /// Halts the axis for the comparator block in slot `slot` (see
    /// [`crate::blocks`]): the stepper's emergency stop, recorded as a
    /// [`FaultKind::BlockHalt`] fault. Outputs and heaters are left as they
    /// are: a probe that touched the bed is no reason to cool the nozzle.
    pub fn halt_by_block(&mut self, slot: u8) {
        self.end_torque();
        self.stepper.halt();
        let now = self.system_now();
        self.fault
            .record(now, FaultKind::BlockHalt, u32::from(slot), true);
    }

    /// Drives every output to its safe value (see [`io`]), turns every
    /// heater off (see [`heater`]; nothing on a board without I/O), and
    /// ends a torque request: the motor holds where it stands ([`torque`]).
    pub fn apply_safe_outputs(&mut self) {
        // Before the safe values: nothing queued may switch a tool back on.
        self.tracks.clear();
        self.end_torque();
        if let Some(hw) = self.board.io() {
            self.io.apply_safe(hw);
            // After the safe values: a heater's output ends at 0 whatever
            // was written to it before.
            self.heaters.off_all(hw);
        }
    }

    /// Upstream reached one of the module's functions (a call or a pipe
    /// datagram) at local time `now`: the output watchdog starts again.
    /// The module's function ports call it ([`ModulePort`]).
    pub fn feed_watchdog(&mut self, now: Instant) {
        self.watchdog.feed(now);
    }

    /// Fires the output watchdog if upstream has been quiet past its
    /// timeout at local time `now`: every output goes to its safe value,
    /// and a [`FaultKind::OutputWatchdog`] fault is recorded (once, until
    /// the next feed). The runtime's loop calls it through the pulse timer
    /// port, at [`watchdog::Watchdog::deadline`].
    pub fn poll_watchdog(&mut self, now: Instant) {
        if let Some(quiet) = self.watchdog.poll(now) {
            self.apply_safe_outputs();
            let quiet = u32::try_from(quiet.as_micros()).unwrap_or(u32::MAX);
            let stopped = self.stepper.is_stopped();
            let at = self.time.system_time(now);
            self.fault
                .record(at, FaultKind::OutputWatchdog, quiet, stopped);
        }
    }

    /// The limit switch's level as read at boot, before any edge: sets the
    /// level `read_limit` reports without counting an edge or stamping a
    /// time.
    pub fn limit_initial(&mut self, level: bool) {
        self.limit.level = level;
    }

    /// The limit switch's level changed to `level` at local time `local`
    /// (the edge interrupt's time stamp).
    /// A press (the input reads low) is recorded as a fault.
    pub fn limit_changed(&mut self, local: Instant, level: bool) {
        self.limit = Limit {
            level,
            time: self.time.system_time(local),
            edges: self.limit.edges.wrapping_add(1),
        };
        if !level {
            let stopped = self.stepper.is_stopped();
            self.fault.record(
                self.limit.time,
                FaultKind::LimitHit,
                self.limit.edges,
                stopped,
            );
        }
    }

    /// Starts and ends timed pulses and applies the level and event
    /// tracks' points due at local time `now` (synchronized `system`): the
    /// runtime's loop calls it through the pulse timer port.
    pub fn poll_io(&mut self, now: Instant, system: SystemInstant) {
        if let Some(hw) = self.board.io() {
            self.io.poll(hw, now, system);
            self.tracks.poll(hw, now, system);
        }
    }

    /// Runs the heaters' control period if one is due at local time `now`
    /// (see [`heater`]), recording each runaway it finds as a
    /// [`FaultKind::HeaterRunaway`] fault. The runtime's loop calls it
    /// through the pulse timer port, at
    /// [`Heaters::wake_at`](heater::Heaters::wake_at).
    pub fn poll_heaters(&mut self, now: Instant) {
        for index in 0..heater::HEATERS as u8 {
            self.poll_heater(now, index);
        }
    }

    /// [`poll_heaters`](Self::poll_heaters) for heater `index` alone: the
    /// pulse timer port runs each heater in a critical section of its own.
    pub fn poll_heater(&mut self, now: Instant, index: u8) {
        let Some(hw) = self.board.io() else {
            return;
        };
        if let Some(reason) = self.heaters.poll_heater(hw, now, index) {
            let at = self.time.system_time(now);
            let detail = heater::runaway_detail(index, reason);
            let stopped = self.stepper.is_stopped();
            self.fault
                .record(at, FaultKind::HeaterRunaway, detail, stopped);
        }
    }

    /// Reads the load cell's sample if its converter has one (see
    /// [`loadcell`]), at local time `now`. The runtime's loop calls it
    /// through the pulse timer port, at
    /// [`LoadCell::wake_at`](loadcell::LoadCell::wake_at).
    pub fn poll_loadcell(&mut self, now: Instant) {
        if let Some(hw) = self.board.io() {
            self.loadcell.poll(hw, now);
        }
    }

    /// Reads the tachometer's pulse count (see [`tach`]), at local time
    /// `now`. The runtime's loop calls it through the pulse timer port, at
    /// [`Tach::wake_at`](tach::Tach::wake_at).
    pub fn poll_tach(&mut self, now: Instant) {
        if let Some(hw) = self.board.io() {
            self.tach.poll(hw, now);
        }
    }

    /// When [`poll_io`](Self::poll_io) next has work, local time.
    pub fn io_wake_at(&self, now: Instant, system: SystemInstant) -> Option<Instant> {
        let tracks = self.tracks.wake_at(now, system);
        self.io.wake_at(now, system).into_iter().chain(tracks).min()
    }

    /// Reboots into the bootloader if `enter_bootloader` armed it and it is
    /// due at local time `now` (see [`boot`]): disables the driver, then
    /// hands over to the board, which on hardware does not return. The
    /// runtime's loop calls it through the pulse timer port.
    pub fn poll_boot(&mut self, now: Instant) {
        if self.boot.take_due(now) {
            self.stepper.set_enable(false);
            self.board.stepper().set_enable(false);
            self.board.reboot_to_bootloader();
        }
    }
}

impl<B> core::fmt::Debug for Module<B> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Module")
            .field("stepper", &self.stepper)
            .field("limit", &self.limit)
            .field("time", &self.time)
            .finish_non_exhaustive()
    }
}

/// How a module's function ports reach their module: a firmware's
/// `&'static` [`ModuleCell`], or a host's shared handle (the simulator's).
/// Each port holds a clone.
pub trait ModuleHandle: Clone {
    /// The module's board.
    type Board: Board;

    /// Runs `f` on the module; `None` if there is none (a firmware that
    /// never installed its board).
    fn with<R>(&self, f: impl FnOnce(&mut Module<Self::Board>) -> R) -> Option<R>;

    /// Hands the module the runtime's latest time map (call after every
    /// poll).
    fn publish_time(&self, map: TimeMap) {
        self.with(|m| m.publish_time(map));
    }
}

/// A firmware's one module, in a `static` behind a critical section: the
/// runtime task and the step interrupt both use it.
pub struct ModuleCell<B> {
    module: Mutex<RefCell<Option<Module<B>>>>,
}

impl<B> core::fmt::Debug for ModuleCell<B> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("ModuleCell").finish_non_exhaustive()
    }
}

impl<B> ModuleCell<B> {
    /// An empty cell: every function fails with
    /// [`functions::NOT_INSTALLED`] and step words make no steps until
    /// [`install`](Self::install).
    pub const fn new() -> Self {
        ModuleCell {
            module: Mutex::new(RefCell::new(None)),
        }
    }
}

impl<B> Default for ModuleCell<B> {
    fn default() -> Self {
        Self::new()
    }
}

impl<B: Board> ModuleCell<B> {
    /// Installs the board: a fresh, disabled module. Installing again
    /// replaces everything.
    pub fn install(&self, board: B) {
        let module = Module::new(board);
        critical_section::with(|cs| *self.module.borrow_ref_mut(cs) = Some(module));
    }

    /// Runs `f` on the installed module inside a critical section; `None`
    /// before [`install`](Self::install).
    pub fn with<R>(&self, f: impl FnOnce(&mut Module<B>) -> R) -> Option<R> {
        critical_section::with(|cs| self.module.borrow_ref_mut(cs).as_mut().map(f))
    }

    /// [`Module::fill_step_word`]; before [`install`](Self::install) the
    /// word makes no steps.
    pub fn fill_step_word(&self, local: Instant) -> u32 {
        self.with(|m| m.fill_step_word(local)).unwrap_or(0)
    }

    /// [`Module::limit_initial`].
    pub fn limit_initial(&self, level: bool) {
        self.with(|m| m.limit_initial(level));
    }

    /// [`Module::limit_changed`].
    pub fn limit_changed(&self, local: Instant, level: bool) {
        self.with(|m| m.limit_changed(local, level));
    }
}

impl<B: Board> ModuleHandle for &ModuleCell<B> {
    type Board = B;

    fn with<R>(&self, f: impl FnOnce(&mut Module<B>) -> R) -> Option<R> {
        ModuleCell::with(self, f)
    }
}
