//! A simulated MAXL axis: the hardware behind an `axis` module.
//!
//! The axis keeps a [`maxl::Track`] of fixed-point (Q16.16 step) control
//! points stamped in synchronized time and, like the firmware's motor
//! interrupt, evaluates it on the module's own synchronized clock every
//! [`AXIS_TICK_US`] (as closely as the host's timers allow). Each evaluation
//! is an executed state: it is kept in a bounded history a script reads
//! through [`AxisProbe`] to compare what ran with what was planned.
//!
//! A minimum endstop can sit at a configured position: when the executed
//! position first reaches it (coming from above), the crossing time is found
//! to the microsecond by bisection on the track, as a switch interrupt would
//! time-stamp it, and reported by the module's `endstop` function. The
//! switch is only a signal; it does not stop the axis.

use maxl::{BackstopLimits, EvalError, Fx, Interval, PushError, Track, TrackStatus};
use osap_core::port::{Delivery, Port, PortInfo, PortTx};
use osap_core::Micros;
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard};

/// Control points an axis queues: enough for a stream sent 16 intervals
/// ahead, with room to spare.
pub const AXIS_QUEUE: usize = 64;
/// Executed states an axis keeps (the oldest are dropped first).
pub const AXIS_HISTORY: usize = 1 << 16;
/// How often the simulated motor interrupt evaluates the track, local µs.
pub const AXIS_TICK_US: Micros = 500;
/// The farthest a new stream may start from where the axis stands, steps.
pub const AXIS_START_TOLERANCE_STEPS: f64 = 1.0;

/// An `axis` module's hardware, from the `[module.axis]` table of a
/// topology file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisSpec {
    /// Steps per user unit (e.g. steps/mm).
    #[serde(default = "default_steps_per_unit")]
    pub steps_per_unit: f32,
    /// The control-point interval, µs: a power of two from 256 to 16384.
    #[serde(default = "default_interval_us")]
    pub interval_us: u32,
    /// Where a minimum endstop sits, in user units; none by default.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub endstop: Option<f32>,
    /// The safety stop's acceleration limit, units/s².
    #[serde(default = "default_stop_acc")]
    pub stop_acc: f32,
    /// The safety stop's jerk limit, units/s³.
    #[serde(default = "default_stop_jerk")]
    pub stop_jerk: f32,
}

fn default_steps_per_unit() -> f32 {
    80.0
}
fn default_interval_us() -> u32 {
    2048
}
fn default_stop_acc() -> f32 {
    2_000.0
}
fn default_stop_jerk() -> f32 {
    200_000.0
}

impl Default for AxisSpec {
    fn default() -> Self {
        AxisSpec {
            steps_per_unit: default_steps_per_unit(),
            interval_us: default_interval_us(),
            endstop: None,
            stop_acc: default_stop_acc(),
            stop_jerk: default_stop_jerk(),
        }
    }
}

impl AxisSpec {
    /// Checks the values; the error says which one is wrong.
    pub fn check(&self) -> Result<(), String> {
        Interval::from_micros(self.interval_us).map_err(|_| {
            format!(
                "axis interval_us {} is not a power of two from 256 to 16384",
                self.interval_us
            )
        })?;
        let positive = |name: &str, v: f32| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(format!("axis {name} must be finite and above 0, not {v}"))
            }
        };
        positive("steps_per_unit", self.steps_per_unit)?;
        positive("stop_acc", self.stop_acc)?;
        positive("stop_jerk", self.stop_jerk)?;
        if let Some(e) = self.endstop {
            if !e.is_finite() {
                return Err(format!("axis endstop must be finite, not {e}"));
            }
        }
        Ok(())
    }

    /// The control-point interval.
    pub fn interval(&self) -> Interval {
        // `check` runs when the topology is validated; fall back to the
        // default rather than panic if a caller skipped it.
        Interval::from_micros(self.interval_us)
            .unwrap_or_else(|_| Interval::from_micros(default_interval_us()).unwrap())
    }
}

/// What the axis is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum AxisMode {
    /// Standing still: no stream, or before its first segment.
    Idle,
    /// Following a stream of control points.
    Tracking,
    /// The stream ran dry: braking within the stop limits, then at rest.
    Backstop,
}

impl AxisMode {
    /// The code the `get_state` function reports: 0 idle, 1 tracking,
    /// 2 backstop.
    pub fn code(self) -> u8 {
        match self {
            AxisMode::Idle => 0,
            AxisMode::Tracking => 1,
            AxisMode::Backstop => 2,
        }
    }
}

/// One executed state.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Executed {
    /// Synchronized time of the evaluation, µs: when the module believed it was.
    pub time: u64,
    /// The module's local time of the evaluation, µs (see
    /// [`SimModule::host_time_at`](super::SimModule::host_time_at) for when
    /// it truly was).
    pub local: u64,
    /// Position, user units.
    pub position: f64,
    /// Velocity, user units/s.
    pub velocity: f64,
    /// What produced it.
    pub mode: AxisMode,
}

/// What happened to the points sent to an axis.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct AxisCounters {
    /// Points accepted.
    pub points: u64,
    /// Single missing points filled from their neighbours.
    pub filled: u64,
    /// Points refused (each with its failure code).
    pub refused: u64,
    /// The failure code of the latest refused point (0: none yet).
    pub last_refused: u8,
    /// Times the safety stop latched with the axis still moving.
    pub faults: u64,
    /// Endstop triggers.
    pub endstop_hits: u32,
}

/// The simulated axis hardware, shared by the module's functions and its
/// motor interrupt.
#[derive(Debug)]
pub struct SimAxis {
    spec: AxisSpec,
    track: Track<Fx, AXIS_QUEUE>,
    amps: f32,
    /// Where the axis stands when no stream moves it, steps.
    rest: Fx,
    /// The last (local, system) time pair the interrupt saw.
    clock: (Micros, u64),
    history: VecDeque<Executed>,
    counters: AxisCounters,
    last_hit: u64,
}

/// `add_point` failure codes (see the module docs of [`super::functions`]).
pub mod code {
    /// The time is not a multiple of the interval.
    pub const MISALIGNED: u8 = 1;
    /// The time is not after the newest queued point.
    pub const STALE: u8 = 2;
    /// Two or more points are missing before this one.
    pub const GAP: u8 = 3;
    /// The safety stop latched with the axis moving; cycle the current.
    pub const FAULTED: u8 = 4;
    /// The position is not finite or is beyond ±32767 steps.
    pub const OUT_OF_RANGE: u8 = 5;
    /// The motor is off.
    pub const DISABLED: u8 = 6;
    /// A new stream must start where the axis stands.
    pub const DISCONTINUOUS: u8 = 7;
    /// The queue is full of points still to run: the stream is too far ahead.
    pub const QUEUE_FULL: u8 = 8;
}

impl SimAxis {
    /// A powered-down axis at position 0.
    pub fn new(spec: AxisSpec) -> Self {
        let limits = BackstopLimits {
            max_acc: spec.stop_acc * spec.steps_per_unit,
            max_jerk: spec.stop_jerk * spec.steps_per_unit,
        };
        SimAxis {
            track: Track::new(spec.interval(), limits),
            spec,
            amps: 0.0,
            rest: Fx(0),
            clock: (0, 0),
            history: VecDeque::new(),
            counters: AxisCounters::default(),
            last_hit: 0,
        }
    }

    /// The hardware's configuration.
    pub fn spec(&self) -> &AxisSpec {
        &self.spec
    }

    fn steps(&self, units: f32) -> Option<Fx> {
        let s = f64::from(units) * f64::from(self.spec.steps_per_unit);
        (s.is_finite() && s.abs() < 32767.0).then(|| Fx::from_f64(s))
    }

    fn units(&self, steps: f64) -> f64 {
        steps / f64::from(self.spec.steps_per_unit)
    }

    /// Queues the control point stamped `time` (synchronized µs) at
    /// `position` (units); the error is the failure code.
    pub fn add_point(&mut self, time: u64, position: f32) -> Result<(), u8> {
        let result = self.push(time, position);
        match result {
            Ok(()) => self.counters.points += 1,
            Err(code) => {
                self.counters.refused += 1;
                self.counters.last_refused = code;
            }
        }
        result
    }

    fn push(&mut self, time: u64, position: f32) -> Result<(), u8> {
        if !self.enabled() {
            return Err(code::DISABLED);
        }
        let p = self.steps(position).ok_or(code::OUT_OF_RANGE)?;
        if self.track.backstop().is_some() {
            // A stream that ended at rest leaves the axis there; a new one may
            // start. One cut off mid-motion is a fault until the current cycles.
            if self.stopped_cleanly() && self.settled() {
                self.rest = self.sample_steps(self.clock.1).map_or(self.rest, |k| k.0);
                self.track.clear();
            } else {
                return Err(code::FAULTED);
            }
        }
        if self.track.is_empty() {
            let away = (p.to_f64() - self.rest.to_f64()).abs();
            if away > AXIS_START_TOLERANCE_STEPS {
                return Err(code::DISCONTINUOUS);
            }
        }
        if self.track.len() == AXIS_QUEUE {
            // The track would drop its oldest point: only if it has run.
            let shift = self.track.interval().shift();
            let newest = self.track.last_time().unwrap_or(0) >> shift;
            let oldest = newest + 1 - AXIS_QUEUE as u64;
            if oldest + 1 >= self.clock.1 >> shift {
                return Err(code::QUEUE_FULL);
            }
        }
        match self.track.push(time, p) {
            Ok(maxl::PushOutcome::Appended) => Ok(()),
            Ok(maxl::PushOutcome::FilledGap) => {
                self.counters.filled += 1;
                Ok(())
            }
            Err(PushError::Misaligned) => Err(code::MISALIGNED),
            Err(PushError::Stale) => Err(code::STALE),
            Err(PushError::Gap { .. }) => Err(code::GAP),
            Err(PushError::Backstopped) => Err(code::FAULTED),
        }
    }

    /// Whether a latched stop has ended with the axis at rest.
    fn settled(&self) -> bool {
        match self.track.backstop() {
            Some((start, duration)) => {
                let end = start + (f64::from(duration) * 1e6).ceil() as u64;
                self.clock.1 >= end
            }
            None => false,
        }
    }

    /// Position (steps), velocity (steps/s) and mode at synchronized `t`.
    fn sample_steps(&mut self, t: u64) -> Option<(Fx, f64, AxisMode)> {
        match self.track.sample(t) {
            Ok(s) => {
                let mode = match s.status {
                    TrackStatus::Tracking => AxisMode::Tracking,
                    TrackStatus::Backstop => AxisMode::Backstop,
                };
                Some((s.kin.pos, s.kin.vel_f64(), mode))
            }
            Err(EvalError::NotStarted | EvalError::TooEarly) => None,
        }
    }

    /// The executed state at synchronized time `t` (not recorded; its
    /// `local` time is estimated from the last tick).
    pub fn state_at(&mut self, t: u64) -> Executed {
        let (pos, vel, mode) = self
            .sample_steps(t)
            .unwrap_or((self.rest, 0.0, AxisMode::Idle));
        let (l, s) = self.clock;
        Executed {
            time: t,
            local: (l as i64 + (t as i64 - s as i64)).max(0) as u64,
            position: self.units(pos.to_f64()),
            velocity: self.units(vel),
            mode,
        }
    }

    /// Synchronized time at local time `local`, from the interrupt's last
    /// reading (the rate error over one tick is far below a microsecond).
    pub fn system_time_at(&self, local: Micros) -> u64 {
        let (l, s) = self.clock;
        s.saturating_add(local.saturating_sub(l))
    }

    /// The motor interrupt: evaluates the track at `(local, system)`,
    /// records the state and watches the endstop.
    pub fn tick(&mut self, local: Micros, system: u64) {
        if system < self.clock.1 {
            // The clock stepped back (a hard resync): keep time monotonic.
            self.clock.0 = local;
            return;
        }
        self.clock = (local, system);
        if !self.enabled() {
            return;
        }
        let was_faulted = self.track.backstop().is_some();
        let now = self.state_at(system);
        if !was_faulted && now.mode == AxisMode::Backstop && !self.stopped_cleanly() {
            self.counters.faults += 1;
        }
        if let (Some(end), Some(prev)) = (self.spec.endstop, self.history.back().copied()) {
            if prev.position > f64::from(end) && now.position <= f64::from(end) {
                self.last_hit = self.crossing(prev.time, system, f64::from(end));
                self.counters.endstop_hits += 1;
            }
        }
        if self.history.len() == AXIS_HISTORY {
            self.history.pop_front();
        }
        self.history.push_back(now);
    }

    /// Whether the latched stop started from rest (the stream ended on
    /// repeated points), as opposed to a stream cut off mid-motion.
    fn stopped_cleanly(&self) -> bool {
        self.track
            .backstop()
            .is_some_and(|(_, duration)| duration <= 1e-6)
    }

    /// First time in `(lo, hi]` the position is at or below `level`.
    fn crossing(&mut self, mut lo: u64, mut hi: u64, level: f64) -> u64 {
        while hi - lo > 1 {
            let mid = lo + (hi - lo) / 2;
            if self.state_at(mid).position <= level {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        hi
    }

    /// Sets the motor current; 0 A stops the axis where it stands and drops
    /// its stream, and powering up clears a fault. The error is the failure
    /// code (1: not within `0..=max_amps`).
    pub fn set_current(&mut self, amps: f32, max_amps: f32) -> Result<(), u8> {
        if !(0.0..=max_amps).contains(&amps) {
            return Err(1);
        }
        if amps == 0.0 || !self.enabled() {
            let here = self.clock.1;
            self.rest = self.sample_steps(here).map_or(self.rest, |s| s.0);
            self.track.clear();
        }
        self.amps = amps;
        Ok(())
    }

    /// Whether the motor is powered.
    pub fn enabled(&self) -> bool {
        self.amps > 0.0
    }

    /// The endstop's last trigger (synchronized µs, 0: never) and count.
    pub fn endstop(&self) -> (u64, u32) {
        (self.last_hit, self.counters.endstop_hits)
    }

    /// The counters.
    pub fn counters(&self) -> AxisCounters {
        self.counters
    }
}

pub(crate) type SharedAxis = Arc<Mutex<SimAxis>>;

pub(crate) fn lock(axis: &Mutex<SimAxis>) -> MutexGuard<'_, SimAxis> {
    axis.lock().unwrap_or_else(|e| e.into_inner())
}

/// The simulated motor interrupt: a port object serving no port index,
/// polled by the module's runtime every [`AXIS_TICK_US`].
pub(crate) struct AxisMotor {
    pub(crate) axis: SharedAxis,
    pub(crate) next: Micros,
}

impl Port for AxisMotor {
    fn port_count(&self) -> u16 {
        0
    }

    fn info(&self, _offset: u16) -> PortInfo<'_> {
        PortInfo {
            type_name: "axis_motor",
            name: "",
        }
    }

    fn on_packet(&mut self, _delivery: Delivery<'_>, _tx: &mut PortTx<'_>) {}

    fn poll(&mut self, tx: &mut PortTx<'_>) {
        let now = tx.now();
        if now >= self.next {
            lock(&self.axis).tick(now, tx.system_time());
            self.next = now + AXIS_TICK_US;
        }
    }

    fn wake_at(&self) -> Option<Micros> {
        Some(self.next)
    }
}

/// A script's view of a running simulated axis: its executed states and
/// counters (the ground truth a test compares with the plan).
#[derive(Clone)]
pub struct AxisProbe {
    pub(crate) axis: SharedAxis,
}

impl AxisProbe {
    /// The executed states recorded so far, oldest first.
    pub fn history(&self) -> Vec<Executed> {
        lock(&self.axis).history.iter().copied().collect()
    }

    /// Forgets the recorded states.
    pub fn clear_history(&self) {
        lock(&self.axis).history.clear();
    }

    /// The executed state at synchronized time `t`, evaluated now from the
    /// points the axis still holds.
    pub fn state_at(&self, t: u64) -> Executed {
        lock(&self.axis).state_at(t)
    }

    /// The axis's counters.
    pub fn counters(&self) -> AxisCounters {
        lock(&self.axis).counters()
    }

    /// The synchronized time of the axis's last tick, µs.
    pub fn system_time(&self) -> u64 {
        lock(&self.axis).clock.1
    }

    /// The hardware configuration.
    pub fn spec(&self) -> AxisSpec {
        lock(&self.axis).spec.clone()
    }
}

impl std::fmt::Debug for AxisProbe {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("AxisProbe").finish_non_exhaustive()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec() -> AxisSpec {
        AxisSpec {
            endstop: Some(-1.0),
            ..AxisSpec::default()
        }
    }

    fn enabled() -> SimAxis {
        let mut a = SimAxis::new(spec());
        a.set_current(1.0, 2.0).unwrap();
        a
    }

    #[test]
    fn follows_a_ramp_and_records_it() {
        let mut a = enabled();
        let iv = 2048u64;
        let t0 = 1_000 * iv;
        // From rest at 0: three repeats, a ramp at 1 unit per interval, then hold.
        let mut pts: Vec<f32> = vec![0.0; 3];
        pts.extend((1..=20).map(|k| k as f32));
        pts.extend([20.0; 4]);
        for (k, p) in pts.iter().enumerate() {
            assert_eq!(a.add_point(t0 + k as u64 * iv, *p), Ok(()));
        }
        // Mid-ramp the curve passes through the points exactly.
        let t = t0 + 10 * iv;
        a.tick(0, t);
        let s = a.history.back().copied().unwrap();
        assert_eq!(s.mode, AxisMode::Tracking);
        assert!((s.position - 8.0).abs() < 1e-3, "{s:?}");
        assert!((s.velocity - 1.0 / 2048e-6).abs() < 0.5, "{s:?}");
        // After the stream: at rest on the last point, a clean stop.
        a.tick(1, t0 + 60 * iv);
        let s = a.history.back().copied().unwrap();
        assert_eq!(s.mode, AxisMode::Backstop);
        assert!((s.position - 20.0).abs() < 1e-3);
        assert_eq!(a.counters().faults, 0);
        // A new stream may start where it stands, not elsewhere.
        let t1 = t0 + 100 * iv;
        assert_eq!(a.add_point(t1, 25.0), Err(code::DISCONTINUOUS));
        assert_eq!(a.add_point(t1, 20.0), Ok(()));
    }

    #[test]
    fn refuses_bad_points_with_codes() {
        let mut a = SimAxis::new(spec());
        assert_eq!(a.add_point(0, 0.0), Err(code::DISABLED));
        a.set_current(1.0, 2.0).unwrap();
        assert_eq!(a.add_point(0, f32::NAN), Err(code::OUT_OF_RANGE));
        assert_eq!(a.add_point(0, 1e6), Err(code::OUT_OF_RANGE));
        assert_eq!(a.add_point(7, 0.0), Err(code::MISALIGNED));
        assert_eq!(a.add_point(2048, 0.0), Ok(()));
        assert_eq!(a.add_point(2048, 0.0), Err(code::STALE));
        assert_eq!(a.add_point(4 * 2048, 0.0), Err(code::GAP));
        assert_eq!(a.counters().refused, 6);
        assert_eq!(a.counters().points, 1);
        // A stream too far ahead fills the queue and is refused, not dropped.
        for k in 2..=AXIS_QUEUE as u64 {
            assert_eq!(a.add_point(k * 2048, 0.0), Ok(()));
        }
        assert_eq!(a.add_point(65 * 2048, 0.0), Err(code::QUEUE_FULL));
        // Once the oldest points have run, the stream goes on.
        a.tick(0, 10 * 2048);
        assert_eq!(a.add_point(65 * 2048, 0.0), Ok(()));
    }

    #[test]
    fn a_stream_cut_mid_motion_faults_and_brakes() {
        let mut a = enabled();
        let iv = 2048u64;
        let mut pts: Vec<f32> = vec![0.0; 3];
        pts.extend((1..=10).map(|k| k as f32 * 0.5));
        for (k, p) in pts.iter().enumerate() {
            a.add_point(k as u64 * iv, *p).unwrap();
        }
        for k in 0..400u64 {
            a.tick(k, k * 500);
        }
        assert_eq!(a.counters().faults, 1);
        let last = a.history.back().copied().unwrap();
        assert_eq!(last.mode, AxisMode::Backstop);
        assert_eq!(last.velocity, 0.0);
        assert_eq!(
            a.add_point(200 * iv, last.position as f32),
            Err(code::FAULTED)
        );
        // Cycling the current clears the fault where the axis stands.
        a.set_current(0.0, 2.0).unwrap();
        a.set_current(1.0, 2.0).unwrap();
        assert_eq!(a.add_point(200 * iv, last.position as f32), Ok(()));
    }

    #[test]
    fn endstop_time_is_found_to_the_microsecond() {
        let mut a = enabled();
        let iv = 2048u64;
        // Down a ramp at -0.25 units per interval, through the endstop at -1.
        let mut pts: Vec<f32> = vec![0.0; 3];
        pts.extend((1..=12).map(|k| k as f32 * -0.25));
        pts.extend([-3.0; 4]);
        for (k, p) in pts.iter().enumerate() {
            a.add_point(k as u64 * iv, *p).unwrap();
        }
        for k in 0..120u64 {
            a.tick(k, k * 500);
        }
        let (hit, count) = a.endstop();
        assert_eq!(count, 1);
        // On the straight run the curve is the ramp: -1 at point 2 + 4 = stamp 6.
        let expected = 6 * iv;
        assert!(
            hit.abs_diff(expected) <= 1,
            "hit at {hit}, expected {expected}"
        );
    }
}
