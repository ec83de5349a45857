//! # osap-module
//!
//! The logic of osap-rs module firmware, shared by every board: a stepper
//! axis that follows MAXL control points in synchronized time and makes
//! step/direction ticks at 100 kHz, and an I/O set (digital pins, PWM,
//! analog inputs, timed pulses), all exposed as PIPES functions that a
//! network scan finds ([`functions`]). A firmware crate supplies only board
//! glue: links, the step generator's peripheral, and the [`board`] traits.
//!
//! ## How a firmware uses it
//! 1. At boot, [`install`] the board's hardware and local clock.
//! 2. Build the ports with [`ModulePorts::new`] and pass
//!    [`ModulePorts::ports`] to `Runtime::poll`; after every poll,
//!    [`publish_time`] the runtime's `time_map()`.
//! 3. From the step interrupt, call [`fill_step_word`] for each word the
//!    step generator needs; from the limit switch's edge interrupt, call
//!    [`limit_changed`].
//!
//! The module's state is one global behind a critical section, because the
//! runtime task and the step interrupt both use it; each call holds the
//! lock only for its own short work. `no_std`, no allocation.
#![no_std]
#![deny(missing_docs)]
#![forbid(unsafe_code)]

#[cfg(test)]
extern crate std;

pub mod board;
pub mod functions;
pub mod io;
pub mod ports;
pub mod stepper;

pub use functions::FUNCTION_SET_ID;
pub use ports::{ModulePort, ModulePorts, PORT_COUNT, PORT_INDICES};
pub use stepper::{STEP_TICK_US, TICKS_PER_WORD};

use board::{IoHw, StepperHw};
use core::cell::RefCell;
use critical_section::Mutex;
use io::Io;
use osap_core::clock::TimeMap;
use osap_core::Micros;
use stepper::Stepper;

/// The limit switch's latest edge.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Limit {
    /// The level after the edge.
    pub level: bool,
    /// When the edge happened, synchronized µs (0: no edge yet).
    pub time: u64,
    /// Edges since boot.
    pub edges: u32,
}

/// The installed module: logic state, hardware and clock.
pub struct Module {
    /// The stepper axis.
    pub stepper: Stepper,
    /// The I/O set.
    pub io: Io,
    /// The limit switch.
    pub limit: Limit,
    /// The runtime's latest local-to-system time map.
    pub time: TimeMap,
    stepper_hw: &'static mut (dyn StepperHw + Send),
    io_hw: Option<&'static mut (dyn IoHw + Send)>,
    clock: fn() -> Micros,
    /// The step words' time anchor: a (local, system) pair read off `time`.
    step_anchor: Option<StepAnchor>,
}

/// Reading the time map takes 64-bit multiplies (library calls on a
/// Cortex-M0+), too many to do for every step word; words within
/// [`ANCHOR_SPAN_US`] of the last reading take its offset instead. Over
/// that span a rate error of 500 ppm (far beyond a crystal's) moves a tick
/// by 2 µs, a typical 50 ppm by 0.2 µs.
#[derive(Debug, Clone, Copy)]
struct StepAnchor {
    map: TimeMap,
    local: Micros,
    system: u64,
}

/// How long a step-word time anchor is used, µs.
pub const ANCHOR_SPAN_US: u64 = 4096;

impl Module {
    /// Synchronized time now.
    pub fn system_now(&self) -> u64 {
        self.time.system_time((self.clock)())
    }
}

static MODULE: Mutex<RefCell<Option<Module>>> = Mutex::new(RefCell::new(None));

/// Installs the board: its stepper driver pins, its I/O hardware (`None`
/// on a board without it: the I/O functions then fail with
/// [`io::IoError::NoHardware`]) and its local microsecond clock (the same
/// one the runtime is polled with). Installing again replaces everything
/// with a fresh, disabled module.
pub fn install(
    stepper_hw: &'static mut (dyn StepperHw + Send),
    io_hw: Option<&'static mut (dyn IoHw + Send)>,
    clock: fn() -> Micros,
) {
    stepper_hw.set_enable(false);
    let module = Module {
        stepper: Stepper::new(),
        io: Io::new(),
        limit: Limit::default(),
        time: TimeMap::IDENTITY,
        stepper_hw,
        io_hw,
        clock,
        step_anchor: None,
    };
    critical_section::with(|cs| *MODULE.borrow_ref_mut(cs) = Some(module));
}

/// Runs `f` on the installed module inside a critical section; `None`
/// before [`install`].
pub fn with<R>(f: impl FnOnce(&mut Module) -> R) -> Option<R> {
    critical_section::with(|cs| MODULE.borrow_ref_mut(cs).as_mut().map(f))
}

/// Hands the module the runtime's latest time map (call after every poll).
pub fn publish_time(map: TimeMap) {
    with(|m| m.time = map);
}

/// The next step-generator word, its first tick at local time `local` (the
/// step generator's own running count of ticks, anchored to the local
/// clock, so interrupt latency does not move the ticks). Before
/// [`install`] the word makes no steps.
pub fn fill_step_word(local: Micros) -> u32 {
    with(|m| {
        let t0 = match m.step_anchor {
            Some(a) if a.map == m.time && local >= a.local && local - a.local < ANCHOR_SPAN_US => {
                a.system + (local - a.local)
            }
            _ => {
                let system = m.time.system_time(local);
                m.step_anchor = Some(StepAnchor {
                    map: m.time,
                    local,
                    system,
                });
                system
            }
        };
        m.stepper.fill_word(t0)
    })
    .unwrap_or(0)
}

/// The limit switch's level as read at boot, before any edge: sets the
/// level `read_limit` reports without counting an edge or stamping a time.
pub fn limit_initial(level: bool) {
    with(|m| m.limit.level = level);
}

/// The limit switch's level changed to `level` at local time `local` (the
/// edge interrupt's time stamp).
pub fn limit_changed(local: Micros, level: bool) {
    with(|m| {
        m.limit = Limit {
            level,
            time: m.time.system_time(local),
            edges: m.limit.edges.wrapping_add(1),
        }
    });
}
