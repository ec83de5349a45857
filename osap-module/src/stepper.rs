//! The stepper axis: a MAXL track of control points in synchronized time,
//! turned into step/direction ticks for the board's step generator.
//!
//! Points arrive over the network as `(time, position)` in user units and
//! are queued in a [`maxl::Track`] of Q16.16 microsteps. The board's step
//! interrupt asks for one word of [`TICKS_PER_WORD`] ticks at a time
//! ([`Stepper::fill_word`]); each tick's position comes from a
//! [`maxl::TickEval`] (three 64-bit adds per tick, no multiply, which an
//! RP2040 core lacks) loaded once per segment, and a [`maxl::StepGen`]
//! turns it into at most one step per tick without ever losing one.
//!
//! When points stop arriving mid-motion the track brakes on its own
//! jerk-limited backstop; that is a fault until the motor is disabled and
//! enabled again. A stream that ends on repeated points stops cleanly, and
//! a new stream may then start where the axis stands.
//!
//! With [`Limits`] set ([`Stepper::set_limits`]; off by default) every
//! incoming point is checked by a [`maxl::Limiter`] before it is queued:
//! one the limiter would change (it is past the velocity, acceleration or
//! jerk limit, as the stream's finite differences at the interval measure
//! them) is refused with [`StepperError::OverLimit`], and the limiter stays
//! where the last accepted point left it. Each stream starts the limiter
//! afresh, at rest where the axis stands.

use maxl::{
    AxisLimits, BackstopLimits, Clamped, Fx, Interval, Limiter, PioPacker, Point, PushError,
    PushOutcome, Rounding, StepGen, TickEval, Track, TrackStatus,
};
use osap_core::{Duration, SystemInstant};

/// Step ticks per second: one tick every [`STEP_TICK_US`] µs (100 kHz).
pub const STEP_TICK_US: u32 = 10;
/// The time `ticks` step ticks after `t`. A plain add, not the saturating
/// one of `SystemInstant + Duration`: this runs for every tick in the step
/// interrupt (a saturating 64-bit add costs a Cortex-M0+ a few cycles more
/// each time), and a tick time near the end of a 64-bit µs count is
/// half a million years away.
#[inline(always)]
fn ticks_after(t: SystemInstant, ticks: u32) -> SystemInstant {
    SystemInstant::from_micros(t.as_micros() + u64::from(ticks * STEP_TICK_US))
}
/// Ticks in one step-generator word (2 bits each, see
/// [`maxl::PioPacker`]).
pub const TICKS_PER_WORD: u32 = 16;
/// Control points an axis queues: a stream sent up to 60 intervals ahead.
pub const QUEUE: usize = 64;
/// The farthest a new stream may start from where the axis stands, in
/// microsteps.
pub const START_TOLERANCE_STEPS: f64 = 1.0;
/// The largest position magnitude in microsteps. Positions on the track
/// wrap every 65 536 microsteps ([`Fx`]) and the step count is an `i64`, so
/// an axis has no end in practice: this bound (2^46) only keeps the
/// conversion from units exact. What limits a long axis is the `f32` unit
/// position on the wire: 24 bits, so at 2^k units a position is known to
/// 2^(k−24) units (at 1 000 mm, 0.06 µm).
pub const MAX_STEPS: f64 = 70_368_744_177_664.0;

/// Why a stepper call was refused: the failure code a caller sees
/// (`CallError::Failed(code)`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
#[non_exhaustive]
pub enum StepperError {
    /// The time is not a multiple of the interval.
    Misaligned = 1,
    /// The time is not after the newest queued point.
    Stale = 2,
    /// Two or more points are missing before this one.
    Gap = 3,
    /// The stream ran dry mid-motion (or the axis was halted): disable and
    /// enable the motor to clear it.
    Faulted = 4,
    /// The position is not finite or is beyond [`MAX_STEPS`] microsteps.
    OutOfRange = 5,
    /// The motor is disabled.
    Disabled = 6,
    /// A new stream must start where the axis stands.
    Discontinuous = 7,
    /// The queue is full of points still to run: the stream is too far
    /// ahead.
    QueueFull = 8,
    /// The setting can only change while no stream is queued.
    Busy = 9,
    /// The value is not allowed (an interval that is not a power of two
    /// from 256 to 16 384 µs, a scale that is not finite and positive, a
    /// microstep mode the board cannot set, limits that are not finite and
    /// non-negative or that round to nothing at the interval and scale).
    BadValue = 10,
    /// The point is past the axis's velocity, acceleration or jerk limit
    /// ([`Stepper::set_limits`]): the limiter would have changed it.
    OverLimit = 11,
    /// The board cannot drive its motor as a torque device: it has no
    /// shaft encoder or cannot set its coils' currents (see
    /// [`crate::torque`]).
    Unsupported = 12,
    /// The call needs the other mode: control points are refused while
    /// the motor is a torque device (`torque_off` first).
    WrongMode = 13,
}

impl StepperError {
    /// Every stepper error, in code order.
    pub const ALL: [StepperError; 13] = [
        StepperError::Misaligned,
        StepperError::Stale,
        StepperError::Gap,
        StepperError::Faulted,
        StepperError::OutOfRange,
        StepperError::Disabled,
        StepperError::Discontinuous,
        StepperError::QueueFull,
        StepperError::Busy,
        StepperError::BadValue,
        StepperError::OverLimit,
        StepperError::Unsupported,
        StepperError::WrongMode,
    ];

    /// The failure code.
    pub const fn code(self) -> u8 {
        self as u8
    }

    /// The error with failure code `code`; `None` for a code that is not a
    /// stepper error (another family's, or a newer firmware's: see
    /// [`crate::failure::Refusal`]).
    pub fn from_code(code: u8) -> Option<StepperError> {
        Self::ALL.into_iter().find(|e| e.code() == code)
    }
}

impl core::fmt::Display for StepperError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            StepperError::Misaligned => "the time is not a multiple of the interval",
            StepperError::Stale => "the time is not after the newest queued point",
            StepperError::Gap => "two or more points are missing before this one",
            StepperError::Faulted => "the axis is faulted or halted",
            StepperError::OutOfRange => "the position is not finite or beyond 2^46 microsteps",
            StepperError::Disabled => "the motor is disabled",
            StepperError::Discontinuous => "a new stream must start where the axis stands",
            StepperError::QueueFull => "the queue is full",
            StepperError::Busy => "the setting can only change while no stream is queued",
            StepperError::BadValue => "the value is not allowed",
            StepperError::OverLimit => "the point is past the axis's limits",
            StepperError::Unsupported => "the board cannot drive its motor as a torque device",
            StepperError::WrongMode => "the motor is a torque device: points are refused",
        })
    }
}

impl core::error::Error for StepperError {}

impl From<StepperError> for pipes_core::FailureCode {
    fn from(e: StepperError) -> Self {
        pipes_core::FailureCode::Other(e.code())
    }
}

impl From<StepperError> for pipes_core::function::CallError {
    fn from(e: StepperError) -> Self {
        pipes_core::function::CallError::Failed(e.into())
    }
}

/// Limits on the stream of incoming points, in user units (those of the
/// points' positions) per s, s² and s³: `set_limits`. A limit of 0 is off;
/// all three 0 (the default) is no limiter at all.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Limits {
    /// Largest velocity, units/s.
    pub max_vel: f32,
    /// Largest acceleration, units/s².
    pub max_acc: f32,
    /// Largest jerk, units/s³.
    pub max_jerk: f32,
}

impl Limits {
    /// No limits: every point passes unchecked.
    pub const OFF: Limits = Limits {
        max_vel: 0.0,
        max_acc: 0.0,
        max_jerk: 0.0,
    };

    /// Whether every limit is off.
    pub fn is_off(&self) -> bool {
        self.max_vel == 0.0 && self.max_acc == 0.0 && self.max_jerk == 0.0
    }

    fn all(&self) -> [f32; 3] {
        [self.max_vel, self.max_acc, self.max_jerk]
    }
}

/// What the axis is doing, as `get_status` reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Mode {
    /// Disabled: the driver is off and no steps are made.
    Disabled = 0,
    /// Enabled and standing: no stream, or before its first segment.
    Idle = 1,
    /// Following a stream of control points.
    Tracking = 2,
    /// The stream ran dry: braking within the stop limits, then at rest.
    Backstop = 3,
    /// Halted by `halt`: standing until the motor is cycled.
    Halted = 4,
    /// A torque device: the module sets the coils' currents from the
    /// shaft's own angle (see [`crate::torque`]); no stream, no steps.
    Torque = 5,
}

/// What happened to the points sent to an axis and to its ticks.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct StepperCounters {
    /// Points accepted.
    pub points: u32,
    /// Single missing points filled from their neighbours.
    pub filled: u32,
    /// Points refused.
    pub refused: u32,
    /// Why the latest refused point was refused (`None`: none yet). On the
    /// wire (`get_counters`) it is the failure code, 0 for none.
    pub last_refused: Option<StepperError>,
    /// Times the backstop latched with the axis still moving.
    pub faults: u32,
    /// Words filled for the step generator.
    pub words: u32,
}

/// The stepper axis logic (no hardware: see [`crate::board::StepperHw`]).
#[derive(Debug, Clone)]
pub struct Stepper {
    track: Track<Fx, QUEUE>,
    tick: Option<TickEval>,
    /// The system time of the tick `tick` yields next, when it is loaded.
    tick_next: Option<SystemInstant>,
    gen: StepGen,
    packer: PioPacker,
    enabled: bool,
    halted: bool,
    full_steps_per_unit: f32,
    microsteps: u16,
    stop_acc: f32,
    stop_jerk: f32,
    /// Where the axis stands when no stream moves it, microsteps.
    rest: Fx,
    /// System time of the latest tick filled.
    last_tick: SystemInstant,
    mode: Mode,
    counters: StepperCounters,
    limits: Limits,
    /// The limiter for `limits` at the interval and scale; its state is the
    /// stream's as of the latest accepted point.
    limiter: Option<Limiter<Fx>>,
    /// The limits the latest `OverLimit` point went past.
    over_limit: Clamped,
    /// In torque mode: the latest shaft reading (synchronized time, Q16.16
    /// full steps); `None` in position mode.
    shaft: Option<(SystemInstant, i64)>,
}

impl Default for Stepper {
    fn default() -> Self {
        Stepper::new()
    }
}

impl Stepper {
    /// A disabled axis at position 0: 80 full steps per unit (a GT2 belt on a
    /// 20-tooth pulley, in mm), no microstepping, 2048 µs intervals.
    pub fn new() -> Self {
        const FULL_STEPS_PER_UNIT: f32 = 80.0;
        const STOP_ACC: f32 = 2_000.0;
        const STOP_JERK: f32 = 200_000.0;
        Stepper {
            track: Track::new(
                DEFAULT_IV,
                stop_limits(FULL_STEPS_PER_UNIT, STOP_ACC, STOP_JERK),
            ),
            tick: tick_eval(DEFAULT_IV),
            tick_next: None,
            gen: StepGen::new(Fx(0), Rounding::Nearest),
            packer: PioPacker::new(),
            enabled: false,
            halted: false,
            full_steps_per_unit: FULL_STEPS_PER_UNIT,
            microsteps: 1,
            stop_acc: STOP_ACC,
            stop_jerk: STOP_JERK,
            rest: Fx(0),
            last_tick: SystemInstant::ZERO,
            mode: Mode::Disabled,
            counters: StepperCounters::default(),
            limits: Limits::OFF,
            limiter: None,
            over_limit: Clamped::default(),
            shaft: None,
        }
    }

    /// Microsteps per user unit.
    pub fn steps_per_unit(&self) -> f32 {
        self.full_steps_per_unit * f32::from(self.microsteps)
    }

    fn steps(&self, units: f32) -> Option<Fx> {
        let s = f64::from(units) * f64::from(self.steps_per_unit());
        if !(s.is_finite() && s.abs() <= MAX_STEPS) {
            return None;
        }
        Fx::wrapping_from_f64(s)
    }

    fn units(&self, steps: f64) -> f32 {
        (steps / f64::from(self.steps_per_unit())) as f32
    }

    fn rebuild_track(&mut self, iv: Interval) {
        let limits = stop_limits(self.steps_per_unit(), self.stop_acc, self.stop_jerk);
        self.track = Track::new(iv, limits);
        self.tick = tick_eval(iv);
        self.tick_next = None;
    }

    /// Whether no stream is queued or running (settings may change).
    fn idle(&self) -> bool {
        self.track.is_empty() || (self.track.backstop().is_some() && self.settled())
    }

    /// Queues the control point stamped `time` (system time) at
    /// `position` (user units).
    pub fn add_point(&mut self, time: SystemInstant, position: f32) -> Result<(), StepperError> {
        let result = self.push(time, position);
        match result {
            Ok(()) => self.counters.points = self.counters.points.wrapping_add(1),
            Err(e) => {
                self.counters.refused = self.counters.refused.wrapping_add(1);
                self.counters.last_refused = Some(e);
            }
        }
        result
    }

    fn push(&mut self, time: SystemInstant, position: f32) -> Result<(), StepperError> {
        if !self.enabled {
            return Err(StepperError::Disabled);
        }
        if self.shaft.is_some() {
            return Err(StepperError::WrongMode);
        }
        if self.halted {
            return Err(StepperError::Faulted);
        }
        let p = self.steps(position).ok_or(StepperError::OutOfRange)?;
        if self.track.backstop().is_some() {
            // A stream that ended at rest leaves the axis there and a new one
            // may start; one cut off mid-motion is a fault until the motor
            // is cycled.
            if self.stopped_cleanly() && self.settled() {
                self.rest = self.position_at(self.last_tick);
                self.clear_track();
            } else {
                return Err(StepperError::Faulted);
            }
        }
        if self.track.is_empty() {
            let away = f64::from(p.wrapping_diff(self.rest)).abs() / f64::from(Fx::ONE);
            if away > START_TOLERANCE_STEPS {
                return Err(StepperError::Discontinuous);
            }
        }
        if self.track.len() == QUEUE {
            // The track would drop its oldest point: only if it has run.
            let shift = self.track.interval().shift();
            let newest = self.track.last_time().unwrap_or_default().as_micros() >> shift;
            let oldest = newest + 1 - QUEUE as u64;
            if oldest + 1 >= self.last_tick.as_micros() >> shift {
                return Err(StepperError::QueueFull);
            }
        }
        let limiter = self.check_limits(time, p)?;
        let outcome = match self.track.push(time, p) {
            Ok(PushOutcome::Appended) => Ok(()),
            Ok(PushOutcome::FilledGap) => {
                self.counters.filled = self.counters.filled.wrapping_add(1);
                Ok(())
            }
            Err(PushError::Misaligned) => Err(StepperError::Misaligned),
            Err(PushError::Stale) => Err(StepperError::Stale),
            Err(PushError::Gap { .. }) => Err(StepperError::Gap),
            Err(PushError::Backstopped) => Err(StepperError::Faulted),
            // A refusal a newer track adds: the point is not allowed.
            Err(_) => Err(StepperError::BadValue),
        };
        if outcome.is_ok() && limiter.is_some() {
            self.limiter = limiter;
        }
        outcome
    }

    /// The limiter as it would be after the point `p` stamped `time` is
    /// queued, checked against the limits: `OverLimit` if the limiter would
    /// change the point (or the midpoint the track fills a single gap
    /// with), `None` with no limits or for a point the track refuses
    /// anyway. The axis's own limiter is left as it is.
    fn check_limits(
        &mut self,
        time: SystemInstant,
        p: Fx,
    ) -> Result<Option<Limiter<Fx>>, StepperError> {
        let Some(mut next) = self.limiter else {
            return Ok(None);
        };
        let iv = self.track.interval();
        if time.as_micros() & (u64::from(iv.micros()) - 1) != 0 {
            return Ok(None);
        }
        let mut over = Clamped::default();
        match (self.track.last_time(), self.track.last_point()) {
            // A new stream: it starts at rest where the axis stands.
            (None, _) => next.reset(),
            (Some(last), Some(prev)) if time > last => {
                match (time - last).as_micros() >> iv.shift() {
                    1 => {}
                    2 => over = next.push(Fx::midpoint(prev, p)).clamped,
                    _ => return Ok(None),
                }
            }
            _ => return Ok(None),
        }
        let c = next.push(p).clamped;
        over = Clamped {
            jerk: over.jerk || c.jerk,
            acc: over.acc || c.acc,
            vel: over.vel || c.vel,
        };
        if over.any() {
            self.over_limit = over;
            return Err(StepperError::OverLimit);
        }
        Ok(Some(next))
    }

    fn clear_track(&mut self) {
        self.track.clear();
        self.tick_next = None;
    }

    /// Whether a latched stop has ended with the axis at rest.
    fn settled(&self) -> bool {
        match self.track.backstop() {
            Some((start, duration)) => {
                let end = start + Duration::from_micros((f64::from(duration) * 1e6) as u64 + 1);
                self.last_tick >= end
            }
            None => false,
        }
    }

    /// Whether the latched stop started from rest (the stream ended on
    /// repeated points), as opposed to a stream cut off mid-motion.
    fn stopped_cleanly(&self) -> bool {
        self.track
            .backstop()
            .is_some_and(|(_, duration)| duration <= 1e-6)
    }

    /// The position (microsteps) the track gives at synchronized `t`.
    fn position_at(&mut self, t: SystemInstant) -> Fx {
        if let Some(tick) = self.tick.as_mut() {
            if self.tick_next == Some(t) {
                if let Some(p) = tick.next() {
                    self.tick_next = Some(ticks_after(t, 1));
                    return p;
                }
            }
            if let Some((seg, du)) = self.track.segment_at(t) {
                if tick.load(&seg, du).is_ok() {
                    if let Some(p) = tick.next() {
                        self.tick_next = Some(ticks_after(t, 1));
                        self.mode = Mode::Tracking;
                        return p;
                    }
                }
            }
        }
        self.tick_next = None;
        match self.track.sample(t) {
            Ok(s) => {
                if s.status == TrackStatus::Backstop && self.mode != Mode::Backstop {
                    self.mode = Mode::Backstop;
                    if !self.stopped_cleanly() {
                        self.counters.faults = self.counters.faults.wrapping_add(1);
                    }
                }
                s.kin.pos
            }
            // Not started, too early, or a reason a newer track adds.
            Err(_) => self.rest,
        }
    }

    /// The next step-generator word: [`TICKS_PER_WORD`] ticks, the first at
    /// synchronized time `t0`, [`STEP_TICK_US`] apart, packed as
    /// [`maxl::PioPacker`] packs them. A disabled or halted axis makes no
    /// steps.
    pub fn fill_word(&mut self, t0: SystemInstant) -> u32 {
        self.counters.words = self.counters.words.wrapping_add(1);
        let mut word = 0;
        if self.is_standing() || self.shaft.is_some() {
            // Nothing can move: skip the per-tick evaluation (most of an
            // idle module's step-interrupt time).
            for _ in 0..TICKS_PER_WORD {
                if let Some(w) = self.packer.push(None) {
                    word = w;
                }
            }
            self.last_tick = ticks_after(t0, TICKS_PER_WORD - 1);
            // A stream whose stop has ended stays in its mode until the
            // next stream clears it.
            if self.enabled && !self.halted && self.track.is_empty() && self.shaft.is_none() {
                self.mode = Mode::Idle;
            }
            return word;
        }
        for k in 0..TICKS_PER_WORD {
            let t = ticks_after(t0, k);
            let step = if self.enabled && !self.halted {
                let p = self.position_at(t);
                self.gen.tick(p)
            } else {
                None
            };
            self.last_tick = t;
            if let Some(w) = self.packer.push(step) {
                word = w;
            }
        }
        if self.enabled && !self.halted && self.track.is_empty() {
            self.mode = Mode::Idle;
        }
        word
    }

    /// Whether the axis stands and will stand until a call changes that: it
    /// is disabled or halted, or owes no steps and has no stream or one
    /// whose stop has ended at rest. Step words are then all empty, and
    /// cost what an idle word costs (a simulator need not even clock them
    /// out on time).
    pub fn is_standing(&self) -> bool {
        !self.enabled
            || self.halted
            || (self.shaft.is_none()
                && self.gen.backlog() == 0
                && (self.track.is_empty() || self.settled()))
    }

    /// Powers the motor (`true`) or lets it go limp. Powering down drops
    /// the stream and stops where the axis stands; powering up clears a
    /// fault or a halt.
    pub fn set_enable(&mut self, on: bool) {
        if !on || !self.enabled {
            self.stand_still();
        }
        self.enabled = on;
        self.halted = false;
        self.mode = if on { Mode::Idle } else { Mode::Disabled };
    }

    /// Stops stepping at once and drops the stream: an emergency stop, not
    /// a planned one (a motor at speed may lose steps). The axis refuses
    /// points until the motor is disabled and enabled again.
    pub fn halt(&mut self) {
        self.stand_still();
        self.halted = true;
        self.mode = Mode::Halted;
    }

    /// Drops the stream; the axis stands where its steps put it.
    fn stand_still(&mut self) {
        self.clear_track();
        // Where the motor truly is: the steps sent, not the track's target.
        let index = self.gen.position();
        self.rest = StepGen::index_position(index);
        self.gen = StepGen::at_index(index, Rounding::Nearest);
    }

    /// Sets the control-point interval (a power of two from 256 to
    /// 16 384 µs) while no stream is queued. Refused (`BadValue`) if a limit
    /// would round to nothing at the new interval.
    pub fn set_interval(&mut self, interval_us: u32) -> Result<(), StepperError> {
        let iv = Interval::from_micros(interval_us).map_err(|_| StepperError::BadValue)?;
        self.check_idle()?;
        self.limiter = limiter(self.limits, self.steps_per_unit(), iv)?;
        self.rebuild_track(iv);
        Ok(())
    }

    /// Sets the limits on incoming points (user units per s, s², s³; 0
    /// turns one off, all three 0 turn the limiter off) while no stream is
    /// queued. Refused (`BadValue`) for a limit that is not finite or is
    /// negative, or that rounds to nothing at the interval and scale (a
    /// jerk limit at short intervals: a jerk of `J` steps/s³ is
    /// `J·Δt³·65 536` Q16.16 units per interval³).
    pub fn set_limits(&mut self, limits: Limits) -> Result<(), StepperError> {
        if !limits.all().iter().all(|x| x.is_finite() && *x >= 0.0) {
            return Err(StepperError::BadValue);
        }
        self.check_idle()?;
        self.limiter = limiter(limits, self.steps_per_unit(), self.track.interval())?;
        self.limits = limits;
        Ok(())
    }

    /// The limits on incoming points.
    pub fn limits(&self) -> Limits {
        self.limits
    }

    /// The limits the latest point refused with `OverLimit` went past.
    pub fn over_limit(&self) -> Clamped {
        self.over_limit
    }

    /// The control-point interval, µs.
    pub fn interval_us(&self) -> u32 {
        self.track.interval().micros()
    }

    /// Sets the full steps per user unit while no stream is queued (the
    /// axis keeps its place in user units).
    pub fn set_scale(&mut self, full_steps_per_unit: f32) -> Result<(), StepperError> {
        if !(full_steps_per_unit.is_finite() && full_steps_per_unit > 0.0) {
            return Err(StepperError::BadValue);
        }
        self.rescale(full_steps_per_unit, self.microsteps)
    }

    /// Sets the microstep mode (the board's driver must offer it; `hw_ok`
    /// says whether it did) while no stream is queued.
    pub fn set_microsteps(&mut self, microsteps: u16) -> Result<(), StepperError> {
        if microsteps == 0 || !microsteps.is_power_of_two() || microsteps > 256 {
            return Err(StepperError::BadValue);
        }
        self.rescale(self.full_steps_per_unit, microsteps)
    }

    /// Settings (scale, microsteps, interval) can change now: no stream is
    /// queued or running. A caller that must also ask the board (microstep
    /// pins) checks this first.
    pub fn check_idle(&self) -> Result<(), StepperError> {
        if self.idle() {
            Ok(())
        } else {
            Err(StepperError::Busy)
        }
    }

    fn rescale(&mut self, full: f32, microsteps: u16) -> Result<(), StepperError> {
        self.check_idle()?;
        let here = self.position_units();
        let new_k = f64::from(full) * f64::from(microsteps);
        let steps = f64::from(here) * new_k;
        if !steps.is_finite() || steps.abs() > MAX_STEPS {
            return Err(StepperError::OutOfRange);
        }
        let iv = self.track.interval();
        self.limiter = limiter(self.limits, full * f32::from(microsteps), iv)?;
        self.full_steps_per_unit = full;
        self.microsteps = microsteps;
        // Where the steps put the motor, in the new scale: the whole step
        // nearest to it (half up, as the step generator rounds), and the
        // position exactly.
        self.rest = Fx::wrapping_from_f64(steps).ok_or(StepperError::OutOfRange)?;
        self.gen = StepGen::at_index(floor(steps + 0.5), Rounding::Nearest);
        self.rebuild_track(iv);
        Ok(())
    }

    /// The microstep mode.
    pub fn microsteps(&self) -> u16 {
        self.microsteps
    }

    /// The position the steps sent so far put the motor at, user units, and
    /// the synchronized time of the latest tick they include.
    pub fn position(&self) -> (SystemInstant, f32) {
        match self.shaft {
            Some((at, shaft)) => (at, self.shaft_units(shaft)),
            None => (self.last_tick, self.position_units()),
        }
    }

    /// A shaft angle in Q16.16 full steps, in user units.
    fn shaft_units(&self, shaft: i64) -> f32 {
        (shaft as f64 / 65_536.0 / f64::from(self.full_steps_per_unit)) as f32
    }

    /// Makes the motor a torque device, its shaft at `shaft` (Q16.16 full
    /// steps, read at `at`): the axis must be enabled, not halted or
    /// faulted, and have no stream queued or running. Points are then
    /// refused ([`StepperError::WrongMode`]) and no steps are made until
    /// [`leave_torque`](Self::leave_torque).
    pub fn enter_torque(&mut self, at: SystemInstant, shaft: i64) -> Result<(), StepperError> {
        if !self.enabled {
            return Err(StepperError::Disabled);
        }
        if self.halted || (self.track.backstop().is_some() && !self.stopped_cleanly()) {
            return Err(StepperError::Faulted);
        }
        self.check_idle()?;
        self.clear_track();
        self.shaft = Some((at, shaft));
        self.mode = Mode::Torque;
        Ok(())
    }

    /// A new shaft reading in torque mode (ignored in position mode).
    pub fn read_shaft(&mut self, at: SystemInstant, shaft: i64) {
        if self.shaft.is_some() {
            self.shaft = Some((at, shaft));
        }
    }

    /// Whether the motor is a torque device.
    pub fn is_torque(&self) -> bool {
        self.shaft.is_some()
    }

    /// Back to position mode where the shaft last stood: the axis rests at
    /// the microstep nearest to it (the step generator starts again
    /// there), so a stream may start from where the torque left the shaft.
    /// Nothing in position mode.
    pub fn leave_torque(&mut self) {
        let Some((at, shaft)) = self.shaft.take() else {
            return;
        };
        let micro = shaft as f64 * f64::from(self.microsteps) / 65_536.0;
        self.clear_track();
        self.gen = StepGen::at_index(floor(micro + 0.5), Rounding::Nearest);
        self.rest = StepGen::index_position(self.gen.position());
        self.last_tick = self.last_tick.max(at);
        self.mode = if !self.enabled {
            Mode::Disabled
        } else if self.halted {
            Mode::Halted
        } else {
            Mode::Idle
        };
    }

    fn position_units(&self) -> f32 {
        self.units(self.gen.position() as f64)
    }

    /// Where the steps put the motor, in microsteps, then the steps up,
    /// steps down and late steps (sent on a later tick than the one they
    /// fell due at: [`maxl::StepStats::late`]) since the step generator
    /// last started (boot, enable, disable, halt, or a scale or microstep
    /// change).
    pub fn step_counts(&self) -> (i64, u64, u64, u64) {
        let s = self.gen.stats();
        (self.gen.position(), s.up, s.down, s.late)
    }

    /// Late steps since the step generator last started (the fourth of
    /// [`step_counts`](Self::step_counts)).
    pub fn late_steps(&self) -> u64 {
        self.gen.late()
    }

    /// The step generator's own counters (ticks, overrun ticks, the
    /// largest backlog, ...) since it last started.
    pub fn step_stats(&self) -> maxl::StepStats {
        self.gen.stats()
    }

    /// Steps the step generator still owes (more than one at a tick is an
    /// overrun).
    pub fn backlog(&self) -> u64 {
        self.gen.backlog()
    }

    /// Whether a backstop or a halt holds the axis (points are refused
    /// until the motor is cycled, or until a stream that ended at rest is
    /// followed by a new one).
    pub fn is_stopped(&self) -> bool {
        matches!(self.mode, Mode::Backstop | Mode::Halted)
    }

    /// What the axis is doing.
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// Whether the motor is powered.
    pub fn enabled(&self) -> bool {
        self.enabled
    }

    /// Points queued.
    pub fn queued(&self) -> u16 {
        self.track.len() as u16
    }

    /// The counters.
    pub fn counters(&self) -> StepperCounters {
        self.counters
    }
}

/// `⌊x⌋` for `|x| < 2^62`, without `std` (no_std has no `f64::floor`).
fn floor(x: f64) -> i64 {
    let i = x as i64;
    if (i as f64) > x {
        i - 1
    } else {
        i
    }
}

/// The backstop's limits in microsteps, from units/s² and units/s³.
fn stop_limits(steps_per_unit: f32, acc: f32, jerk: f32) -> BackstopLimits {
    BackstopLimits {
        max_acc: acc * steps_per_unit,
        max_jerk: jerk * steps_per_unit,
    }
}

/// The limiter for `limits` (user units) at `steps_per_unit` and `iv`;
/// `None` when they are off. A limit that is off is set beyond anything the
/// track holds (differences of Q16.16 positions stay below 2³⁵ raw units;
/// the limiter takes at most 2⁴⁰). `BadValue` if one rounds to nothing.
fn limiter(
    limits: Limits,
    steps_per_unit: f32,
    iv: Interval,
) -> Result<Option<Limiter<Fx>>, StepperError> {
    if limits.is_off() {
        return Ok(None);
    }
    let steps = |x: f32| {
        if x == 0.0 {
            f32::MAX
        } else {
            (f64::from(x) * f64::from(steps_per_unit)).min(f64::from(f32::MAX)) as f32
        }
    };
    let axis = AxisLimits {
        max_vel: steps(limits.max_vel),
        max_acc: steps(limits.max_acc),
        max_jerk: steps(limits.max_jerk),
    };
    Limiter::<Fx>::new(axis, iv)
        .map(Some)
        .map_err(|_| StepperError::BadValue)
}

/// The interval an axis starts with, 2048 µs.
const DEFAULT_IV: Interval = match Interval::from_micros(2048) {
    Ok(iv) => iv,
    Err(_) => panic!("2048 µs is a valid interval"),
};

/// The per-tick evaluator for `iv`. Every interval from 256 to 16 384 µs
/// holds at most 1 639 ticks of 10 µs, within its limit, so this is always
/// `Some`; without one every tick would take the track's slower path.
fn tick_eval(iv: Interval) -> Option<TickEval> {
    TickEval::new(iv, STEP_TICK_US).ok()
}
