//! The module's PIPES functions: what a network scan finds on every
//! osap-rs module firmware, whatever the board.
//!
//! Each is a plain function wrapped by `#[pipes_core::function]`, working
//! on the installed module (see [`crate::install`]); [`ModuleFn`] gathers
//! them so a runtime can hold them in one array. Failure codes are
//! [`StepperError`] and [`IoError`] codes, plus [`NOT_INSTALLED`].
//!
//! | function | inputs | outputs |
//! |---|---|---|
//! | `add_point` | `time: u64`, `position: f32` | — |
//! | `set_interval` | `interval_us: u32` | — |
//! | `get_position` | — | `time: u64`, `position: f32` |
//! | `get_status` | — | `mode: u8`, `queued: u16`, `enabled: bool`, `faults: u32` |
//! | `get_counters` | — | `points: u32`, `refused: u32`, `last_refused: u8`, `filled: u32` |
//! | `get_steps` | — | `steps: i64`, `up: u64`, `down: u64`, `overruns: u64` |
//! | `set_enable` | `on: bool` | — |
//! | `set_scale` | `full_steps_per_unit: f32` | — |
//! | `set_microsteps` | `microsteps: u16` | — |
//! | `read_limit` | — | `time: u64`, `level: bool`, `edges: u32` |
//! | `halt` | — | — |
//! | `digital_write` | `pin: u8`, `level: bool` | — |
//! | `digital_read` | `pin: u8` | `time: u64`, `level: bool` |
//! | `pwm_write` | `channel: u8`, `duty: f32` | — |
//! | `pulse` | `pin: u8`, `duration_us: u32` | — |
//! | `pulse_at` | `time: u64`, `pin: u8`, `duration_us: u32` | — |
//! | `analog_read` | `channel: u8` | `time: u64`, `value: f32` |
//!
//! Times are synchronized system µs. `read_limit` is meant as a pipe source
//! with its output mode set to "on change": it then sends each switch edge
//! with the edge's own time stamp, taken in the pin interrupt.

use crate::io::IoError;
use crate::stepper::StepperError;
use crate::{with, Module};
use pipes_core::function::{CallError, Implementation, Outputs};
use pipes_core::signature::Signature;
use pipes_core::Value;

/// Failure code of every function on a firmware that never called
/// [`crate::install`].
pub const NOT_INSTALLED: u8 = 100;

fn on_module<R>(f: impl FnOnce(&mut Module) -> R) -> Result<R, CallError> {
    with(f).ok_or(CallError::Failed(NOT_INSTALLED))
}

/// [`on_module`] for work that can be refused with its own failure code.
fn fallible<R, E: Into<CallError>>(
    f: impl FnOnce(&mut Module) -> Result<R, E>,
) -> Result<R, CallError> {
    on_module(f)?.map_err(Into::into)
}

/// Queues a control point: the axis is at `position` (user units) at
/// synchronized `time` (a multiple of the interval).
#[pipes_core::function]
pub fn add_point(time: u64, position: f32) -> Result<(), CallError> {
    fallible(|m| m.stepper.add_point(time, position))
}

/// Sets the control-point interval, µs (a power of two, 256 to 16 384),
/// while no stream is queued.
#[pipes_core::function]
pub fn set_interval(interval_us: u32) -> Result<(), CallError> {
    fallible(|m| m.stepper.set_interval(interval_us))
}

/// Where the steps sent so far put the motor (user units), and the
/// synchronized time of the latest step tick they include.
#[pipes_core::function(outputs = "time, position")]
pub fn get_position() -> Result<(u64, f32), CallError> {
    on_module(|m| m.stepper.position())
}

/// The axis mode (0 disabled, 1 idle, 2 tracking, 3 backstop, 4 halted),
/// points queued, whether the motor is powered, and faults since boot.
#[pipes_core::function(outputs = "mode, queued, enabled, faults")]
pub fn get_status() -> Result<(u8, u16, bool, u32), CallError> {
    on_module(|m| {
        let s = &m.stepper;
        (s.mode() as u8, s.queued(), s.enabled(), s.counters().faults)
    })
}

/// Points accepted, refused, the latest refusal's code, and single gaps
/// filled.
#[pipes_core::function(outputs = "points, refused, last_refused, filled")]
pub fn get_counters() -> Result<(u32, u32, u8, u32), CallError> {
    on_module(|m| {
        let c = m.stepper.counters();
        (c.points, c.refused, c.last_refused, c.filled)
    })
}

/// Net microsteps sent since boot, steps up, steps down, and ticks that
/// owed more than one step (their steps went out on later ticks).
#[pipes_core::function(outputs = "steps, up, down, overruns")]
pub fn get_steps() -> Result<(i64, u64, u64, u64), CallError> {
    on_module(|m| m.stepper.step_counts())
}

/// Powers the motor or lets it go limp; powering down stops the axis where
/// it stands and drops its stream, powering up clears a fault or a halt.
#[pipes_core::function]
pub fn set_enable(on: bool) -> Result<(), CallError> {
    on_module(|m| {
        m.stepper.set_enable(on);
        m.stepper_hw.set_enable(on);
    })
}

/// Sets the motor's full steps per user unit (the microstep mode
/// multiplies it), while no stream is queued.
#[pipes_core::function]
pub fn set_scale(full_steps_per_unit: f32) -> Result<(), CallError> {
    fallible(|m| m.stepper.set_scale(full_steps_per_unit))
}

/// Sets the driver's microstep mode (1, 2, 4, .. 256, as the board's driver
/// offers), while no stream is queued.
#[pipes_core::function]
pub fn set_microsteps(microsteps: u16) -> Result<(), CallError> {
    fallible(|m| {
        m.stepper.check_idle()?;
        if !m.stepper_hw.set_microsteps(microsteps) {
            return Err(StepperError::BadValue);
        }
        m.stepper.set_microsteps(microsteps)
    })
}

/// The limit switch: when its level last changed (synchronized µs, 0:
/// never), its level, and the edges seen since boot.
#[pipes_core::function(outputs = "time, level, edges")]
pub fn read_limit() -> Result<(u64, bool, u32), CallError> {
    on_module(|m| (m.limit.time, m.limit.level, m.limit.edges))
}

/// Stops stepping at once and drops the stream (an emergency stop); the
/// axis refuses points until the motor is disabled and enabled again.
#[pipes_core::function]
pub fn halt() -> Result<(), CallError> {
    on_module(|m| m.stepper.halt())
}

/// Drives digital pin `pin` high or low.
#[pipes_core::function]
pub fn digital_write(pin: u8, level: bool) -> Result<(), CallError> {
    fallible(|m| {
        let hw = m.io_hw.as_deref_mut().ok_or(IoError::NoHardware)?;
        m.io.digital_write(hw, pin, level)
    })
}

/// Reads digital pin `pin`: the synchronized time of the read and the level.
#[pipes_core::function(outputs = "time, level")]
pub fn digital_read(pin: u8) -> Result<(u64, bool), CallError> {
    fallible(|m| {
        let now = m.system_now();
        let hw = m.io_hw.as_deref_mut().ok_or(IoError::NoHardware)?;
        m.io.digital_read(hw, pin).map(|level| (now, level))
    })
}

/// Sets PWM output `channel`'s duty cycle, a fraction `0..=1`.
#[pipes_core::function]
pub fn pwm_write(channel: u8, duty: f32) -> Result<(), CallError> {
    fallible(|m| {
        let hw = m.io_hw.as_deref_mut().ok_or(IoError::NoHardware)?;
        m.io.pwm_write(hw, channel, duty)
    })
}

/// Drives `pin` high now and low `duration_us` later (at most 10 s).
#[pipes_core::function]
pub fn pulse(pin: u8, duration_us: u32) -> Result<(), CallError> {
    fallible(|m| {
        let now = (m.clock)();
        let hw = m.io_hw.as_deref_mut().ok_or(IoError::NoHardware)?;
        m.io.pulse(hw, now, pin, duration_us)
    })
}

/// Schedules a pulse of `duration_us` on `pin` at synchronized `time` (at
/// most 60 s ahead; 16 may wait at once).
#[pipes_core::function]
pub fn pulse_at(time: u64, pin: u8, duration_us: u32) -> Result<(), CallError> {
    fallible(|m| {
        let now = m.system_now();
        let hw = m.io_hw.as_deref_mut().ok_or(IoError::NoHardware)?;
        m.io.pulse_at(hw, now, time, pin, duration_us)
    })
}

/// Samples analog input `channel`: the synchronized time of the sample and
/// the reading as a fraction of full scale.
#[pipes_core::function(outputs = "time, value")]
pub fn analog_read(channel: u8) -> Result<(u64, f32), CallError> {
    fallible(|m| {
        let now = m.system_now();
        let hw = m.io_hw.as_deref_mut().ok_or(IoError::NoHardware)?;
        m.io.analog_read(hw, channel).map(|value| (now, value))
    })
}

macro_rules! module_functions {
    ($($f:ident),* $(,)?) => {
        /// One of the module's functions, so a runtime can hold them all in
        /// one array of [`pipes_core::function::PipesFunction`]s.
        #[allow(non_camel_case_types)]
        #[derive(Debug, Clone, Copy, PartialEq, Eq)]
        pub enum ModuleFn {
            $(
                #[doc = concat!("`", stringify!($f), "`")]
                $f($f),
            )*
        }

        /// Every function, in the order a scan lists them.
        pub const ALL: [ModuleFn; [$(stringify!($f)),*].len()] = [$(ModuleFn::$f($f::pipes())),*];

        /// Every function's signature, in the order of [`ALL`]: the
        /// interface every osap-rs module firmware presents.
        pub const SIGNATURES: [&Signature; ALL.len()] = [$($f::SIGNATURE),*];

        impl Implementation for ModuleFn {
            fn signature(&self) -> &'static Signature {
                match self {
                    $(ModuleFn::$f(f) => f.signature(),)*
                }
            }

            fn call(
                &mut self,
                inputs: &[Value<'_>],
                outputs: &mut Outputs<'_>,
            ) -> Result<(), CallError> {
                match self {
                    $(ModuleFn::$f(f) => f.call(inputs, outputs),)*
                }
            }
        }
    };
}

module_functions!(
    add_point,
    set_interval,
    get_position,
    get_status,
    get_counters,
    get_steps,
    set_enable,
    set_scale,
    set_microsteps,
    read_limit,
    halt,
    digital_write,
    digital_read,
    pwm_write,
    pulse,
    pulse_at,
    analog_read,
);

/// FNV-1a, 32 bits: one step.
const fn fnv1a(mut hash: u32, bytes: &[u8]) -> u32 {
    let mut i = 0;
    while i < bytes.len() {
        hash ^= bytes[i] as u32;
        hash = hash.wrapping_mul(0x0100_0193);
        i += 1;
    }
    hash
}

/// FNV-1a's starting value.
const FNV_OFFSET: u32 = 0x811C_9DC5;

/// A `str8` as a scan reads it: a length byte, then the bytes.
const fn hash_str8(hash: u32, s: &str) -> u32 {
    fnv1a(fnv1a(hash, &[s.len() as u8]), s.as_bytes())
}

/// The identity of a function set: FNV-1a over what a scan reads of each
/// signature, in order (the function count, then per function its name,
/// and for inputs and outputs the count and each argument's name and type
/// key, as `docs/pipes.md` §5 lays them out). Two sets with the same id
/// present the same functions at the same ports.
pub const fn function_set_id(signatures: &[&Signature]) -> u32 {
    let mut hash = fnv1a(FNV_OFFSET, &[signatures.len() as u8]);
    let mut f = 0;
    while f < signatures.len() {
        let sig = signatures[f];
        hash = hash_str8(hash, sig.name);
        let lists = [sig.inputs, sig.outputs];
        let mut l = 0;
        while l < lists.len() {
            let args = lists[l];
            hash = fnv1a(hash, &[args.len() as u8]);
            let mut a = 0;
            while a < args.len() {
                hash = hash_str8(hash, args[a].name);
                hash = fnv1a(hash, &[args[a].ty.key()]);
                a += 1;
            }
            l += 1;
        }
        f += 1;
    }
    hash
}

/// The identity of [`SIGNATURES`]: every firmware embeds it, so a check of
/// the built images proves they all present the same functions (one proxy
/// serves them all).
pub const FUNCTION_SET_ID: u32 = function_set_id(&SIGNATURES);
