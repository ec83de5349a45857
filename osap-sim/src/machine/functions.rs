//! The PIPES functions of simulated modules, chosen by the module's `type`.
//!
//! Each function is a [`PipesFunction`] (control port `pipes_function`,
//! named after the function, then [`SIM_PIPES`] pipe ports `pipes_pipe`)
//! run as a port of the module's own runtime, so a scan lists it and a
//! script calls it, or pipes into it, exactly as on firmware. Times are the
//! module's local clock ([`DriftClock`]), in µs since its counter started
//! (the counter's boot value is the module's `offset_us`). The functions of
//! one module share its simulated hardware; a restart (power cut) resets it.
//!
//! # `stepper`
//!
//! | function | inputs | outputs |
//! |---|---|---|
//! | `add_control_point` | `time: u64`, `position: f32` | — |
//! | `get_position` | — | `time: u64`, `position: f32` |
//! | `set_current` | `amps: f32` | — |
//! | `get_status` | — | `points_queued: u16`, `enabled: bool` |
//!
//! The axis follows its queue of control points linearly in local time:
//! between the point it last reached (or, when a point is queued on an
//! idle axis, where it stands at that moment) and the next point it moves
//! at constant speed, reaching each point's `position` at its `time`; after
//! the last point it holds. A point whose time has already passed is
//! reached at once. The axis boots at position 0, disabled (0 A).
//! `set_current` sets the motor current; 0 A disables the axis, which stops
//! where it stands and drops its queue. Failure codes
//! ([`pipes_core::control::ControlError::CallFailed`]):
//! `add_control_point`: 1 its time is before the last queued point's,
//! 2 the queue ([`STEPPER_QUEUE`] points) is full, 3 the axis is disabled,
//! 4 the position is not finite; `set_current`: 1 not within
//! `0..=`[`STEPPER_MAX_AMPS`].
//!
//! # `io`
//!
//! | function | inputs | outputs |
//! |---|---|---|
//! | `read_pin` | `pin: u8` | `time: u64`, `level: bool` |
//! | `pulse` | `pin: u8`, `duration_us: u32` | — |
//! | `read_analog` | — | `time: u64`, `value: f32` |
//! | `comparator` | `lower: f32`, `upper: f32` | `time: u64`, `in_bounds: bool` |
//!
//! [`IO_PINS`] digital pins, all low at boot. `pulse` drives a pin high for
//! `duration_us` from now (restarting a pulse already running on it);
//! `read_pin` reads the level. The analog input is a slow sine,
//! `sin(2π·t / `[`ANALOG_PERIOD_US`]`)` with `t` the local time; `read_analog`
//! samples it and `comparator` says whether the sample lies within
//! `lower..=upper`. Failure codes: `read_pin`, `pulse`: 1 no such pin;
//! `comparator`: 1 `lower > upper` or a bound is NaN.
//!
//! # `hub`
//!
//! | function | inputs | outputs |
//! |---|---|---|
//! | `get_uptime` | — | `uptime_us: u64` |
//!
//! Local µs since the module booted.
//!
//! Any other type (e.g. `spindle`) has no functions.

use super::axis::{lock as axis_lock, AxisMotor, AxisProbe, AxisSpec, SharedAxis, SimAxis};
use super::clock::DriftClock;
use osap_core::Micros;
use pipes_core::function::{CallError, FnImpl, Outputs, PipesFunction};
use pipes_core::signature::{Arg, Signature};
use pipes_core::{ScalarType, Type, Value};
use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard};

/// Pipe slots of each simulated function.
pub const SIM_PIPES: usize = 2;
/// Datagrams each pipe of a simulated function queues.
pub const SIM_QUEUE: usize = 2;
/// Byte size of each input store and of the output buffer.
pub const SIM_STORE: usize = 64;

/// The body of a simulated function.
pub type SimBody = Box<dyn FnMut(&[Value<'_>], &mut Outputs<'_>) -> Result<(), CallError> + Send>;
/// A simulated module's function, as run in its runtime.
pub type SimFunction = PipesFunction<FnImpl<SimBody>, SIM_PIPES, SIM_QUEUE, SIM_STORE>;

const U8: Type = Type::Scalar(ScalarType::U8);
const U16: Type = Type::Scalar(ScalarType::U16);
const U32: Type = Type::Scalar(ScalarType::U32);
const U64: Type = Type::Scalar(ScalarType::U64);
const F32: Type = Type::Scalar(ScalarType::F32);
const BOOL: Type = Type::Scalar(ScalarType::Bool);

/// Stepper: `add_control_point(time: u64, position: f32)`.
pub static ADD_CONTROL_POINT: Signature = Signature {
    name: "add_control_point",
    inputs: &[Arg::new("time", U64), Arg::new("position", F32)],
    outputs: &[],
};
/// Stepper: `get_position() -> (time: u64, position: f32)`.
pub static GET_POSITION: Signature = Signature {
    name: "get_position",
    inputs: &[],
    outputs: &[Arg::new("time", U64), Arg::new("position", F32)],
};
/// Stepper: `set_current(amps: f32)`.
pub static SET_CURRENT: Signature = Signature {
    name: "set_current",
    inputs: &[Arg::new("amps", F32)],
    outputs: &[],
};
/// Stepper: `get_status() -> (points_queued: u16, enabled: bool)`.
pub static GET_STATUS: Signature = Signature {
    name: "get_status",
    inputs: &[],
    outputs: &[Arg::new("points_queued", U16), Arg::new("enabled", BOOL)],
};
/// I/O: `read_pin(pin: u8) -> (time: u64, level: bool)`.
pub static READ_PIN: Signature = Signature {
    name: "read_pin",
    inputs: &[Arg::new("pin", U8)],
    outputs: &[Arg::new("time", U64), Arg::new("level", BOOL)],
};
/// I/O: `pulse(pin: u8, duration_us: u32)`.
pub static PULSE: Signature = Signature {
    name: "pulse",
    inputs: &[Arg::new("pin", U8), Arg::new("duration_us", U32)],
    outputs: &[],
};
/// I/O: `read_analog() -> (time: u64, value: f32)`.
pub static READ_ANALOG: Signature = Signature {
    name: "read_analog",
    inputs: &[],
    outputs: &[Arg::new("time", U64), Arg::new("value", F32)],
};
/// I/O: `comparator(lower: f32, upper: f32) -> (time: u64, in_bounds: bool)`.
pub static COMPARATOR: Signature = Signature {
    name: "comparator",
    inputs: &[Arg::new("lower", F32), Arg::new("upper", F32)],
    outputs: &[Arg::new("time", U64), Arg::new("in_bounds", BOOL)],
};
/// Axis: `add_point(time: u64, position: f32)`.
pub static ADD_POINT: Signature = Signature {
    name: "add_point",
    inputs: &[Arg::new("time", U64), Arg::new("position", F32)],
    outputs: &[],
};
/// Axis: `get_state() -> (time: u64, position: f32, velocity: f32, mode: u8)`.
pub static GET_STATE: Signature = Signature {
    name: "get_state",
    inputs: &[],
    outputs: &[
        Arg::new("time", U64),
        Arg::new("position", F32),
        Arg::new("velocity", F32),
        Arg::new("mode", U8),
    ],
};
/// Axis: `endstop() -> (time: u64, count: u32)`.
pub static ENDSTOP: Signature = Signature {
    name: "endstop",
    inputs: &[],
    outputs: &[Arg::new("time", U64), Arg::new("count", U32)],
};
/// Hub: `get_uptime() -> (uptime_us: u64)`.
pub static GET_UPTIME: Signature = Signature {
    name: "get_uptime",
    inputs: &[],
    outputs: &[Arg::new("uptime_us", U64)],
};

/// The signatures of a `stepper`, in port order.
pub static STEPPER_FUNCTIONS: [&Signature; 4] =
    [&ADD_CONTROL_POINT, &GET_POSITION, &SET_CURRENT, &GET_STATUS];
/// The signatures of an `io` module, in port order.
pub static IO_FUNCTIONS: [&Signature; 4] = [&READ_PIN, &PULSE, &READ_ANALOG, &COMPARATOR];
/// The signatures of an `axis`, in port order.
pub static AXIS_FUNCTIONS: [&Signature; 5] = [
    &ADD_POINT,
    &GET_POSITION,
    &GET_STATE,
    &SET_CURRENT,
    &ENDSTOP,
];
/// The signatures of a `hub`, in port order.
pub static HUB_FUNCTIONS: [&Signature; 1] = [&GET_UPTIME];

/// Control points a stepper queues.
pub const STEPPER_QUEUE: usize = 32;
/// The highest motor current a stepper accepts, A.
pub const STEPPER_MAX_AMPS: f32 = 2.0;
/// Digital pins of an I/O module.
pub const IO_PINS: u8 = 16;
/// Period of an I/O module's simulated analog input, µs.
pub const ANALOG_PERIOD_US: u64 = 2_000_000;

/// The signatures of the functions a module of type `type_name` has, in
/// port order (empty for a type without functions).
pub fn signatures_for(type_name: &str) -> &'static [&'static Signature] {
    match type_name {
        "stepper" => &STEPPER_FUNCTIONS,
        "io" => &IO_FUNCTIONS,
        "axis" => &AXIS_FUNCTIONS,
        "hub" => &HUB_FUNCTIONS,
        _ => &[],
    }
}

/// Fresh functions (and simulated hardware) for a module of type
/// `type_name` on `clock`, in port order; none for a type without functions.
/// An `axis` gets the default [`AxisSpec`]; see [`hardware_for`].
pub fn functions_for(type_name: &str, clock: DriftClock) -> Vec<SimFunction> {
    hardware_for(type_name, &AxisSpec::default(), clock).functions
}

/// A module's simulated hardware: its PIPES functions, in port order, and
/// for an `axis` the motor interrupt and a probe of what it executes.
pub struct SimHardware {
    /// The functions, run as ports from port 1 on.
    pub functions: Vec<SimFunction>,
    pub(crate) motor: Option<AxisMotor>,
    /// An `axis`'s executed states, for scripts and tests.
    pub axis: Option<AxisProbe>,
}

/// Fresh hardware for a module of type `type_name` on `clock`; `axis`
/// configures an `axis` module and is ignored by other types.
pub fn hardware_for(type_name: &str, axis: &AxisSpec, clock: DriftClock) -> SimHardware {
    let functions = |functions| SimHardware {
        functions,
        motor: None,
        axis: None,
    };
    match type_name {
        "stepper" => functions(stepper(clock)),
        "io" => functions(io(clock)),
        "hub" => functions(hub(clock)),
        "axis" => axis_module(axis, clock),
        _ => functions(Vec::new()),
    }
}

fn function(sig: &'static Signature, body: SimBody) -> SimFunction {
    // The signatures above are within the limits; a failure is a bug here.
    PipesFunction::new(FnImpl::new(sig, body))
        .unwrap_or_else(|e| panic!("simulated function {}: {e}", sig.name))
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Inputs of the wrong shape: cannot happen, `PipesFunction` converts them.
const BAD_INPUTS: CallError = CallError::Failed(0xff);

/// A simulated stepper axis, in local µs.
#[derive(Debug, Clone, PartialEq)]
pub struct StepperAxis {
    /// The point it last reached (or stood at when motion started).
    anchor: (Micros, f32),
    points: VecDeque<(Micros, f32)>,
    amps: f32,
}

impl Default for StepperAxis {
    fn default() -> Self {
        StepperAxis {
            anchor: (0, 0.0),
            points: VecDeque::new(),
            amps: 0.0,
        }
    }
}

impl StepperAxis {
    /// Drops the points reached by `now`.
    fn advance(&mut self, now: Micros) {
        while let Some(&(t, p)) = self.points.front() {
            if t > now {
                break;
            }
            self.anchor = (t, p);
            self.points.pop_front();
        }
    }

    /// Queues a control point at local time `now`; the error is the failure code.
    pub fn add_point(&mut self, now: Micros, time: Micros, position: f32) -> Result<(), u8> {
        if !self.enabled() {
            return Err(3);
        }
        if !position.is_finite() {
            return Err(4);
        }
        self.advance(now);
        if self.points.back().is_some_and(|&(t, _)| time < t) {
            return Err(1);
        }
        if self.points.len() >= STEPPER_QUEUE {
            return Err(2);
        }
        if self.points.is_empty() {
            // Motion starts from where the axis stands now.
            self.anchor = (now, self.anchor.1);
        }
        self.points.push_back((time, position));
        Ok(())
    }

    /// The position at local time `now`.
    pub fn position(&mut self, now: Micros) -> f32 {
        self.advance(now);
        let (t0, p0) = self.anchor;
        match self.points.front() {
            Some(&(t1, p1)) if t1 > t0 => {
                let frac = (now.saturating_sub(t0)) as f64 / (t1 - t0) as f64;
                (f64::from(p0) + (f64::from(p1) - f64::from(p0)) * frac.min(1.0)) as f32
            }
            _ => p0,
        }
    }

    /// Sets the current; 0 A disables the axis where it stands. The error
    /// is the failure code.
    pub fn set_current(&mut self, now: Micros, amps: f32) -> Result<(), u8> {
        if !(0.0..=STEPPER_MAX_AMPS).contains(&amps) {
            return Err(1);
        }
        if amps == 0.0 {
            let here = self.position(now);
            self.anchor = (now, here);
            self.points.clear();
        }
        self.amps = amps;
        Ok(())
    }

    /// Control points not yet reached at `now`.
    pub fn queued(&mut self, now: Micros) -> usize {
        self.advance(now);
        self.points.len()
    }

    /// Whether the motor is powered.
    pub fn enabled(&self) -> bool {
        self.amps > 0.0
    }
}

fn stepper(clock: DriftClock) -> Vec<SimFunction> {
    let axis = Arc::new(Mutex::new(StepperAxis::default()));
    let a = axis.clone();
    let add: SimBody = Box::new(move |inputs, _| match inputs {
        [Value::U64(time), Value::F32(position)] => lock(&a)
            .add_point(clock.now_us(), *time, *position)
            .map_err(CallError::Failed),
        _ => Err(BAD_INPUTS),
    });
    let a = axis.clone();
    let get: SimBody = Box::new(move |_, out| {
        let now = clock.now_us();
        let p = lock(&a).position(now);
        out.set(0, &Value::U64(now))?;
        out.set(1, &Value::F32(p))
    });
    let a = axis.clone();
    let current: SimBody = Box::new(move |inputs, _| match inputs {
        [Value::F32(amps)] => lock(&a)
            .set_current(clock.now_us(), *amps)
            .map_err(CallError::Failed),
        _ => Err(BAD_INPUTS),
    });
    let a = axis;
    let status: SimBody = Box::new(move |_, out| {
        let mut axis = lock(&a);
        let n = axis.queued(clock.now_us());
        out.set(0, &Value::U16(n as u16))?;
        out.set(1, &Value::Bool(axis.enabled()))
    });
    vec![
        function(&ADD_CONTROL_POINT, add),
        function(&GET_POSITION, get),
        function(&SET_CURRENT, current),
        function(&GET_STATUS, status),
    ]
}

fn axis_module(spec: &AxisSpec, clock: DriftClock) -> SimHardware {
    let axis: SharedAxis = Arc::new(Mutex::new(SimAxis::new(spec.clone())));
    let a = axis.clone();
    let add: SimBody = Box::new(move |inputs, _| match inputs {
        [Value::U64(time), Value::F32(position)] => axis_lock(&a)
            .add_point(*time, *position)
            .map_err(CallError::Failed),
        _ => Err(BAD_INPUTS),
    });
    let a = axis.clone();
    let get: SimBody = Box::new(move |_, out| {
        let mut axis = axis_lock(&a);
        let t = axis.system_time_at(clock.now_us());
        let s = axis.state_at(t);
        out.set(0, &Value::U64(s.time))?;
        out.set(1, &Value::F32(s.position as f32))
    });
    let a = axis.clone();
    let state: SimBody = Box::new(move |_, out| {
        let mut axis = axis_lock(&a);
        let t = axis.system_time_at(clock.now_us());
        let s = axis.state_at(t);
        out.set(0, &Value::U64(s.time))?;
        out.set(1, &Value::F32(s.position as f32))?;
        out.set(2, &Value::F32(s.velocity as f32))?;
        out.set(3, &Value::U8(s.mode.code()))
    });
    let a = axis.clone();
    let current: SimBody = Box::new(move |inputs, _| match inputs {
        [Value::F32(amps)] => axis_lock(&a)
            .set_current(*amps, STEPPER_MAX_AMPS)
            .map_err(CallError::Failed),
        _ => Err(BAD_INPUTS),
    });
    let a = axis.clone();
    let endstop: SimBody = Box::new(move |_, out| {
        let (time, count) = axis_lock(&a).endstop();
        out.set(0, &Value::U64(time))?;
        out.set(1, &Value::U32(count))
    });
    SimHardware {
        functions: vec![
            function(&ADD_POINT, add),
            function(&GET_POSITION, get),
            function(&GET_STATE, state),
            function(&SET_CURRENT, current),
            function(&ENDSTOP, endstop),
        ],
        motor: Some(AxisMotor {
            axis: axis.clone(),
            next: 0,
        }),
        axis: Some(AxisProbe { axis }),
    }
}

/// The simulated analog input at local time `t`: `sin(2π·t / ANALOG_PERIOD_US)`.
pub fn analog_at(t: Micros) -> f32 {
    let phase = (t % ANALOG_PERIOD_US) as f64 / ANALOG_PERIOD_US as f64;
    (phase * std::f64::consts::TAU).sin() as f32
}

fn io(clock: DriftClock) -> Vec<SimFunction> {
    // Per pin: the local time its pulse ends (high while now < end).
    let pins = Arc::new(Mutex::new([0 as Micros; IO_PINS as usize]));
    let p = pins.clone();
    let read: SimBody = Box::new(move |inputs, out| {
        let [Value::U8(pin)] = inputs else {
            return Err(BAD_INPUTS);
        };
        let now = clock.now_us();
        let end = *lock(&p)
            .get(usize::from(*pin))
            .ok_or(CallError::Failed(1))?;
        out.set(0, &Value::U64(now))?;
        out.set(1, &Value::Bool(now < end))
    });
    let p = pins;
    let pulse: SimBody = Box::new(move |inputs, _| {
        let [Value::U8(pin), Value::U32(us)] = inputs else {
            return Err(BAD_INPUTS);
        };
        let mut pins = lock(&p);
        let end = pins
            .get_mut(usize::from(*pin))
            .ok_or(CallError::Failed(1))?;
        *end = clock.now_us().saturating_add(Micros::from(*us));
        Ok(())
    });
    let analog: SimBody = Box::new(move |_, out| {
        let now = clock.now_us();
        out.set(0, &Value::U64(now))?;
        out.set(1, &Value::F32(analog_at(now)))
    });
    let comparator: SimBody = Box::new(move |inputs, out| {
        let [Value::F32(lower), Value::F32(upper)] = inputs else {
            return Err(BAD_INPUTS);
        };
        if lower.is_nan() || upper.is_nan() || lower > upper {
            return Err(CallError::Failed(1));
        }
        let now = clock.now_us();
        let v = analog_at(now);
        out.set(0, &Value::U64(now))?;
        out.set(1, &Value::Bool((*lower..=*upper).contains(&v)))
    });
    vec![
        function(&READ_PIN, read),
        function(&PULSE, pulse),
        function(&READ_ANALOG, analog),
        function(&COMPARATOR, comparator),
    ]
}

fn hub(clock: DriftClock) -> Vec<SimFunction> {
    let boot = clock.local_us_at(clock.boot());
    let uptime: SimBody =
        Box::new(move |_, out| out.set(0, &Value::U64(clock.now_us().saturating_sub(boot))));
    vec![function(&GET_UPTIME, uptime)]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clock::ClockModel;
    use osap_core::port::Port;
    use std::time::Instant;

    #[test]
    fn axis_follows_points_linearly() {
        let mut a = StepperAxis::default();
        assert_eq!(a.add_point(0, 100, 1.0), Err(3), "disabled at boot");
        a.set_current(0, 1.0).unwrap();
        a.add_point(1_000, 2_000, 10.0).unwrap();
        a.add_point(1_000, 3_000, 0.0).unwrap();
        assert_eq!(a.position(1_000), 0.0);
        assert_eq!(a.position(1_500), 5.0);
        assert_eq!(a.queued(1_500), 2);
        assert_eq!(a.position(2_000), 10.0);
        assert_eq!(a.position(2_250), 7.5);
        assert_eq!(a.position(9_000), 0.0);
        assert_eq!(a.queued(9_000), 0);
        assert_eq!(a.add_point(9_000, 10_000, 4.0), Ok(()));
        assert_eq!(a.add_point(9_000, 9_500, 4.0), Err(1), "before the last");
        assert_eq!(a.add_point(9_000, 11_000, f32::NAN), Err(4));
        assert_eq!(a.position(9_500), 2.0);
        // A point already due is reached at once.
        let mut b = StepperAxis::default();
        b.set_current(0, 0.5).unwrap();
        b.add_point(5_000, 1_000, 3.0).unwrap();
        assert_eq!(b.position(5_000), 3.0);
    }

    #[test]
    fn axis_queue_and_current_limits() {
        let mut a = StepperAxis::default();
        assert_eq!(a.set_current(0, 2.5), Err(1));
        assert_eq!(a.set_current(0, -0.1), Err(1));
        assert_eq!(a.set_current(0, f32::NAN), Err(1));
        a.set_current(0, STEPPER_MAX_AMPS).unwrap();
        for i in 0..STEPPER_QUEUE as u64 {
            a.add_point(0, 1_000 * (i + 1), i as f32).unwrap();
        }
        assert_eq!(a.add_point(0, 1_000_000, 0.0), Err(2));
        // Disabling stops the axis where it stands and drops the queue.
        let here = a.position(1_500);
        a.set_current(1_500, 0.0).unwrap();
        assert!(!a.enabled());
        assert_eq!(a.queued(1_500), 0);
        assert_eq!(a.position(100_000), here);
    }

    #[test]
    fn analog_is_a_slow_sine() {
        assert_eq!(analog_at(0), 0.0);
        assert!((analog_at(ANALOG_PERIOD_US / 4) - 1.0).abs() < 1e-6);
        assert!((analog_at(3 * ANALOG_PERIOD_US / 4) + 1.0).abs() < 1e-6);
    }

    #[test]
    fn function_sets_by_type() {
        let clock = DriftClock::new(Instant::now(), ClockModel::new(0.0, 0.0));
        for ty in ["stepper", "io", "axis", "hub", "spindle"] {
            let fs = functions_for(ty, clock);
            let sigs = signatures_for(ty);
            assert_eq!(fs.len(), sigs.len(), "{ty}");
            for (f, s) in fs.iter().zip(sigs) {
                assert_eq!(f.signature(), *s);
                assert_eq!(f.port_count(), 1 + SIM_PIPES as u16);
                assert_eq!(f.info(0).name, s.name);
            }
            // Every function fits the module's port indices (port 0 included).
            let used: u16 = fs.iter().map(|f| f.port_count()).sum();
            assert!(usize::from(used) < super::super::MODULE_PORTS, "{ty}");
        }
        assert!(functions_for("spindle", clock).is_empty());
    }
}
