//! One axis: point-to-point moves, velocity mode and homing, sampled at the
//! timer's stamps.
//!
//! # Model
//!
//! The axis plans in **axis units** (what its module counts, e.g. steps) and
//! talks to people in **user units** (e.g. mm):
//! `user = axis / scale + offset`, `axis = (user − offset) · scale`. `scale`
//! may be negative (a reversed axis); `offset` is the user coordinate of
//! axis position 0, and homing changes it, never the axis stream. Limits are
//! given in user units and applied as `max_vel·|scale|`, `max_acc·|scale|`.
//!
//! Motion is a piecewise constant-acceleration profile anchored at the last
//! sampled stamp: a command replans from the profile's position and velocity
//! there (points already emitted cannot change), so velocity is continuous.
//! - **Moves** (`move_to`) are trapezoids (triangles when short) from the
//!   current velocity: accelerate to the peak, cruise, decelerate at
//!   `max_acc` to rest exactly at the target at the returned end time. A move
//!   that would overshoot (too fast, or heading away) first stops, then
//!   moves back.
//! - **Velocity mode** (`velocity`, `stop`) ramps to the target velocity at
//!   `max_acc` and holds it.
//!
//! `sample(stamp)` evaluates the profile at a stamp (a multiple of the
//! interval, not before the last one), keeps `(stamp, position)` in a bounded
//! history and returns the axis position: the control point to send to the
//! axis module. The module runs the uniform cubic B-spline through these
//! points, which smooths the profile (by `a·Δt²/6` at most where the
//! acceleration is `a`) without exceeding its velocity or acceleration.
//!
//! # Homing
//!
//! `home(direction, speed)` starts velocity mode toward the switch. The
//! switch is any module's input whose trigger *time* (synchronized µs) is
//! piped into `limit_hit(time)`, however late it arrives. The axis was where
//! the B-spline through the emitted points was at that time, so `limit_hit`
//! evaluates that spline ([`eval_f64`] on the four history points around the
//! time, the modules' convention) and sets `offset` so that this position is
//! the home coordinate (`set_home`, default 0). Then the axis decelerates to
//! rest at `max_acc`; the overshoot is reported, and the axis is homed.
//! Delivery latency does not matter as long as the time is still in the
//! history (`history_len` intervals; the default 1024 is over a second at
//! 1024 µs).
//!
//! # PIPES class `OneDof` ([`OneDofBlock`])
//!
//! Positions are user units, `sample`'s position is axis units (for the
//! module), times are synchronized µs.
//!
//! | member | inputs | outputs |
//! |---|---|---|
//! | constructor `OneDof` | `max_vel: f32, max_acc: f32, scale: f32, offset: f32, interval_us: u32` | |
//! | `OneDof.move_to` | `pos: f32` | `eta_us: u64` (stamp the move ends at) |
//! | `OneDof.velocity` | `v: f32` | |
//! | `OneDof.stop` | | |
//! | `OneDof.sample` | `stamp: u64` | `stamp: u64, position: f32` |
//! | `OneDof.home` | `dir: i8, speed: f32` | |
//! | `OneDof.set_home` | `position: f32` | |
//! | `OneDof.limit_hit` | `time: u64` | `switch: f32` (the switch's axis position) |
//! | `OneDof.set_position` | `pos: f32` | |
//! | `OneDof.status` | | `position: f32, velocity: f32, moving: bool, homed: bool` |
//!
//! Failure codes ([`CallError::Failed`], from [`OneDofError::code`]; the
//! constructor fails with 1 or 2): 1 bad number (not finite, a limit
//! or scale ≤ 0 / = 0, a direction other than ±1), 2 bad interval, 3 not
//! sampled yet (a command needs a stamp to start from), 4 homing in progress,
//! 5 not homing, 6 over the velocity limit, 7 stamp not a multiple of the
//! interval, 8 stamp before the last one, 9 switch time older than the
//! history, 10 switch time not yet covered by emitted points, 11 gap in the
//! history at the switch time, 12 switch time before homing started,
//! 13 moving (`set_position` needs rest).

use std::collections::VecDeque;
use std::fmt;

use pipes_core::function::CallError;

use crate::eval::eval_f64;
use crate::track::Interval;

/// The default history length, in stamps.
pub const DEFAULT_HISTORY_LEN: usize = 1024;

/// Why a OneDof call was refused. Each maps to a PIPES failure code
/// ([`OneDofError::code`]).
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum OneDofError {
    /// A number is not finite or out of its domain (named).
    BadNumber(&'static str),
    /// The interval is not a power of two in 256..=16384 µs.
    BadInterval(u32),
    /// The axis has not been sampled yet: a command starts at the last
    /// sampled stamp.
    NotSampled,
    /// Homing is in progress (only `stop` and `limit_hit` are accepted).
    Homing,
    /// `limit_hit` while not homing.
    NotHoming,
    /// A velocity beyond `max_vel` (user units/s).
    OverLimit {
        /// Asked for.
        asked: f64,
        /// The limit.
        max: f64,
    },
    /// The stamp is not a multiple of the interval.
    Misaligned(u64),
    /// The stamp is before the last sampled one.
    Stale {
        /// The stamp.
        stamp: u64,
        /// The last sampled stamp.
        last: u64,
    },
    /// The switch time needs points older than the history holds.
    TooOld {
        /// The switch time.
        time: u64,
        /// The oldest stamp held.
        oldest: u64,
    },
    /// The switch time needs points not emitted yet.
    NotYetEmitted {
        /// The switch time.
        time: u64,
        /// The newest stamp emitted.
        newest: u64,
    },
    /// Stamps are missing from the history around the switch time.
    HistoryGap(u64),
    /// The switch time is before homing started.
    SwitchBeforeHoming {
        /// The switch time.
        time: u64,
        /// The stamp homing started at.
        started: u64,
    },
    /// The axis is moving.
    Moving,
}

impl OneDofError {
    /// The PIPES failure code (see the module docs).
    pub fn code(&self) -> u8 {
        match self {
            OneDofError::BadNumber(_) => 1,
            OneDofError::BadInterval(_) => 2,
            OneDofError::NotSampled => 3,
            OneDofError::Homing => 4,
            OneDofError::NotHoming => 5,
            OneDofError::OverLimit { .. } => 6,
            OneDofError::Misaligned(_) => 7,
            OneDofError::Stale { .. } => 8,
            OneDofError::TooOld { .. } => 9,
            OneDofError::NotYetEmitted { .. } => 10,
            OneDofError::HistoryGap(_) => 11,
            OneDofError::SwitchBeforeHoming { .. } => 12,
            OneDofError::Moving => 13,
        }
    }
}

impl fmt::Display for OneDofError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            OneDofError::BadNumber(what) => write!(f, "bad number: {what}"),
            OneDofError::BadInterval(us) => {
                write!(
                    f,
                    "interval {us} µs is not a power of two in 256..=16384 µs"
                )
            }
            OneDofError::NotSampled => {
                write!(
                    f,
                    "the axis has not been sampled yet: commands start at the last sampled stamp"
                )
            }
            OneDofError::Homing => write!(f, "homing in progress: stop it first"),
            OneDofError::NotHoming => write!(f, "limit hit while not homing"),
            OneDofError::OverLimit { asked, max } => {
                write!(f, "velocity {asked} beyond the limit {max}")
            }
            OneDofError::Misaligned(s) => write!(f, "stamp {s} is not a multiple of the interval"),
            OneDofError::Stale { stamp, last } => {
                write!(f, "stamp {stamp} is before the last sampled stamp {last}")
            }
            OneDofError::TooOld { time, oldest } => write!(
                f,
                "switch time {time} is older than the history (oldest point {oldest})"
            ),
            OneDofError::NotYetEmitted { time, newest } => write!(
                f,
                "switch time {time} needs points after the newest emitted one ({newest})"
            ),
            OneDofError::HistoryGap(t) => write!(f, "the history has a gap around {t}"),
            OneDofError::SwitchBeforeHoming { time, started } => {
                write!(f, "switch time {time} is before homing started ({started})")
            }
            OneDofError::Moving => write!(f, "the axis is moving"),
        }
    }
}

impl core::error::Error for OneDofError {}

impl From<OneDofError> for CallError {
    fn from(e: OneDofError) -> CallError {
        CallError::Failed(e.code().into())
    }
}

/// The axis's limits and units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OneDofConfig {
    /// Velocity limit, user units/s (> 0).
    pub max_vel: f64,
    /// Acceleration limit, user units/s² (> 0).
    pub max_acc: f64,
    /// Axis units per user unit (≠ 0; negative reverses the axis).
    pub scale: f64,
    /// User coordinate of axis position 0.
    pub offset: f64,
    /// The stamp interval.
    pub interval: Interval,
    /// Points kept for homing (≥ 4).
    pub history_len: usize,
}

/// A move as planned.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MovePlan {
    /// The stamp the move starts from (the last sampled one).
    pub start_us: u64,
    /// When the axis is at rest at the target, µs (rounded up).
    pub end_us: u64,
    /// The target, axis units.
    pub target_axis: f64,
}

/// What `limit_hit` found.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HomeReport {
    /// The switch time, µs.
    pub time: u64,
    /// Where the axis was then, axis units (now the home coordinate).
    pub switch_axis: f64,
    /// Where the axis comes to rest, axis units.
    pub rest_axis: f64,
}

/// The axis's state at a stamp.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AxisState {
    /// The stamp.
    pub stamp: u64,
    /// Position, axis units.
    pub pos: f64,
    /// Velocity, axis units/s.
    pub vel: f64,
}

/// A constant-acceleration phase.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Phase {
    dur: f64,
    acc: f64,
}

/// What follows the phases.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Tail {
    /// At rest at this position from `end_us` on (a move or a stop).
    Rest(f64),
    /// Constant velocity forever (velocity mode).
    Cruise(f64),
}

/// Motion from `(pos, vel)` at stamp `t0`: the phases, then the tail.
#[derive(Clone, Debug, PartialEq)]
struct Profile {
    t0: u64,
    p0: f64,
    v0: f64,
    phases: Vec<Phase>,
    /// The phases' total duration, s.
    total_s: f64,
    tail: Tail,
    end_us: u64,
}

impl Profile {
    fn rest(t0: u64, p: f64) -> Profile {
        Profile {
            t0,
            p0: p,
            v0: 0.0,
            phases: Vec::new(),
            total_s: 0.0,
            tail: Tail::Rest(p),
            end_us: t0,
        }
    }

    /// `tail` `None`: rest wherever the phases end.
    fn new(s: AxisState, phases: Vec<Phase>, tail: Option<Tail>) -> Profile {
        let total: f64 = phases.iter().map(|p| p.dur).sum();
        let mut p = Profile {
            t0: s.stamp,
            p0: s.pos,
            v0: s.vel,
            phases,
            total_s: total,
            tail: Tail::Rest(s.pos),
            // Rounded up, forgiving float noise below a nanosecond.
            end_us: s.stamp.saturating_add((total * 1e6 - 1e-3).ceil() as u64),
        };
        p.tail = tail.unwrap_or(Tail::Rest(p.integrate(f64::INFINITY).0));
        p
    }

    /// Position and velocity `dt` seconds into the phases (clamped to
    /// their end).
    fn integrate(&self, dt: f64) -> (f64, f64) {
        let mut rest = dt;
        let (mut p, mut v) = (self.p0, self.v0);
        for ph in &self.phases {
            let tau = rest.min(ph.dur);
            p += v * tau + 0.5 * ph.acc * tau * tau;
            v += ph.acc * tau;
            rest -= tau;
            if rest <= 0.0 {
                break;
            }
        }
        (p, v)
    }

    /// Position and velocity at `t` (µs, not before `t0`).
    fn at(&self, t: u64) -> (f64, f64) {
        match self.tail {
            Tail::Rest(x) if t >= self.end_us => (x, 0.0),
            Tail::Rest(_) => self.integrate(t.saturating_sub(self.t0) as f64 * 1e-6),
            Tail::Cruise(v) => {
                let dt = t.saturating_sub(self.t0) as f64 * 1e-6;
                let total = self.total_s;
                if dt <= total {
                    self.integrate(dt)
                } else {
                    let (p, _) = self.integrate(total);
                    (p + v * (dt - total), v)
                }
            }
        }
    }

    /// Where the axis comes to rest, if it does.
    fn rest_position(&self) -> Option<f64> {
        match self.tail {
            Tail::Rest(x) => Some(x),
            Tail::Cruise(_) => None,
        }
    }

    /// Whether the axis is still moving after `t`.
    fn moving_after(&self, t: u64) -> bool {
        match self.tail {
            Tail::Rest(_) => t < self.end_us,
            Tail::Cruise(v) => v != 0.0,
        }
    }
}

/// Phases from velocity `v` to `vt` at acceleration `a`.
fn ramp(v: f64, vt: f64, a: f64) -> Option<Phase> {
    let dv = vt - v;
    (dv != 0.0).then(|| Phase {
        dur: dv.abs() / a,
        acc: a.copysign(dv),
    })
}

/// Phases from `(p, v)` to rest at `target` within `vmax`, `a`.
fn plan_move(p: f64, v: f64, target: f64, vmax: f64, a: f64) -> Vec<Phase> {
    let d = target - p;
    let stop_dist = v * v / (2.0 * a);
    if v != 0.0 && (v * d < 0.0 || stop_dist > d.abs()) {
        // Heading away or too fast to stop in time: stop, then come back.
        let mut out: Vec<Phase> = ramp(v, 0.0, a).into_iter().collect();
        let p_stop = p + v.signum() * stop_dist;
        out.extend(plan_move(p_stop, 0.0, target, vmax, a));
        return out;
    }
    if d == 0.0 {
        return Vec::new();
    }
    let s = d.signum();
    let (u, dist) = (v.abs(), d.abs());
    let peak = vmax.min((a * dist + 0.5 * u * u).sqrt());
    let d1 = (peak * peak - u * u).abs() / (2.0 * a);
    let d3 = peak * peak / (2.0 * a);
    let cruise = (dist - d1 - d3).max(0.0);
    let mut out = Vec::with_capacity(3);
    out.extend(ramp(s * u, s * peak, a));
    if cruise > 0.0 && peak > 0.0 {
        out.push(Phase {
            dur: cruise / peak,
            acc: 0.0,
        });
    }
    out.extend(ramp(s * peak, 0.0, a));
    out
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Mode {
    Idle,
    Homing { started: u64 },
}

fn finite(x: f64, what: &'static str) -> Result<f64, OneDofError> {
    if x.is_finite() {
        Ok(x)
    } else {
        Err(OneDofError::BadNumber(what))
    }
}

fn positive(x: f64, what: &'static str) -> Result<f64, OneDofError> {
    if x.is_finite() && x > 0.0 {
        Ok(x)
    } else {
        Err(OneDofError::BadNumber(what))
    }
}

/// One axis (see the module docs).
#[derive(Clone, Debug)]
pub struct OneDof {
    cfg: OneDofConfig,
    home_at: f64,
    profile: Profile,
    last: Option<AxisState>,
    history: VecDeque<(u64, f64)>,
    mode: Mode,
    homed: bool,
}

impl OneDof {
    /// An axis at rest at axis position 0 (user position `offset`).
    pub fn new(cfg: OneDofConfig) -> Result<OneDof, OneDofError> {
        positive(cfg.max_vel, "max_vel must be finite and > 0")?;
        positive(cfg.max_acc, "max_acc must be finite and > 0")?;
        finite(cfg.offset, "offset must be finite")?;
        if !cfg.scale.is_finite() || cfg.scale == 0.0 {
            return Err(OneDofError::BadNumber("scale must be finite and non-zero"));
        }
        if cfg.history_len < 4 {
            return Err(OneDofError::BadNumber("history_len must be at least 4"));
        }
        Ok(OneDof {
            cfg,
            home_at: 0.0,
            profile: Profile::rest(0, 0.0),
            last: None,
            history: VecDeque::with_capacity(cfg.history_len.min(1 << 16)),
            mode: Mode::Idle,
            homed: false,
        })
    }

    /// An axis from the PIPES constructor's arguments, with the default
    /// history length.
    pub fn from_parts(
        max_vel: f64,
        max_acc: f64,
        scale: f64,
        offset: f64,
        interval_us: u32,
    ) -> Result<OneDof, OneDofError> {
        let interval = Interval::from_micros(interval_us)
            .map_err(|_| OneDofError::BadInterval(interval_us))?;
        OneDof::new(OneDofConfig {
            max_vel,
            max_acc,
            scale,
            offset,
            interval,
            history_len: DEFAULT_HISTORY_LEN,
        })
    }

    /// The configuration (with the current `offset`).
    pub fn config(&self) -> &OneDofConfig {
        &self.cfg
    }

    /// User units to axis units.
    pub fn to_axis(&self, user: f64) -> f64 {
        (user - self.cfg.offset) * self.cfg.scale
    }

    /// Axis units to user units.
    pub fn to_user(&self, axis: f64) -> f64 {
        axis / self.cfg.scale + self.cfg.offset
    }

    fn vmax(&self) -> f64 {
        self.cfg.max_vel * self.cfg.scale.abs()
    }

    fn amax(&self) -> f64 {
        self.cfg.max_acc * self.cfg.scale.abs()
    }

    /// The state at the last sampled stamp.
    pub fn state(&self) -> Option<AxisState> {
        self.last
    }

    /// Whether the axis moves after the last sampled stamp.
    pub fn is_moving(&self) -> bool {
        self.last
            .is_some_and(|s| self.profile.moving_after(s.stamp))
    }

    /// Whether a homing has completed.
    pub fn is_homed(&self) -> bool {
        self.homed
    }

    /// Whether homing is in progress.
    pub fn is_homing(&self) -> bool {
        matches!(self.mode, Mode::Homing { .. })
    }

    /// The emitted points, oldest first: `(stamp, axis position)`.
    pub fn history(&self) -> impl Iterator<Item = (u64, f64)> + '_ {
        self.history.iter().copied()
    }

    /// Sets how many points the history keeps (≥ 4).
    pub fn set_history_len(&mut self, n: usize) -> Result<(), OneDofError> {
        if n < 4 {
            return Err(OneDofError::BadNumber("history_len must be at least 4"));
        }
        self.cfg.history_len = n;
        while self.history.len() > n {
            self.history.pop_front();
        }
        Ok(())
    }

    /// The user coordinate the switch position becomes when homing.
    pub fn set_home(&mut self, user: f64) -> Result<(), OneDofError> {
        self.home_at = finite(user, "home position must be finite")?;
        Ok(())
    }

    /// Redefines the current position as `user` without moving (the axis
    /// must be at rest).
    pub fn set_position(&mut self, user: f64) -> Result<(), OneDofError> {
        finite(user, "position must be finite")?;
        let s = self.last.ok_or(OneDofError::NotSampled)?;
        if self.is_moving() || self.is_homing() {
            return Err(OneDofError::Moving);
        }
        self.cfg.offset = user - s.pos / self.cfg.scale;
        Ok(())
    }

    fn idle_state(&self) -> Result<AxisState, OneDofError> {
        if self.is_homing() {
            return Err(OneDofError::Homing);
        }
        self.last.ok_or(OneDofError::NotSampled)
    }

    /// Moves to `user` (user units), from the state at the last sampled
    /// stamp, arriving at rest at the returned end time.
    pub fn move_to(&mut self, user: f64) -> Result<MovePlan, OneDofError> {
        finite(user, "target must be finite")?;
        let s = self.idle_state()?;
        let target = self.to_axis(user);
        let phases = plan_move(s.pos, s.vel, target, self.vmax(), self.amax());
        self.profile = Profile::new(s, phases, Some(Tail::Rest(target)));
        Ok(MovePlan {
            start_us: s.stamp,
            end_us: self.profile.end_us,
            target_axis: target,
        })
    }

    /// Ramps to velocity `v` (user units/s) at `max_acc` and holds it.
    pub fn velocity(&mut self, v: f64) -> Result<(), OneDofError> {
        finite(v, "velocity must be finite")?;
        let s = self.idle_state()?;
        self.set_velocity(s, v)
    }

    fn set_velocity(&mut self, s: AxisState, v: f64) -> Result<(), OneDofError> {
        if v.abs() > self.cfg.max_vel {
            return Err(OneDofError::OverLimit {
                asked: v,
                max: self.cfg.max_vel,
            });
        }
        let vt = v * self.cfg.scale;
        let phases: Vec<Phase> = ramp(s.vel, vt, self.amax()).into_iter().collect();
        let tail = (vt != 0.0).then_some(Tail::Cruise(vt));
        self.profile = Profile::new(s, phases, tail);
        Ok(())
    }

    /// Decelerates to rest at `max_acc`; ends a move, velocity mode or homing.
    pub fn stop(&mut self) -> Result<(), OneDofError> {
        let s = self.last.ok_or(OneDofError::NotSampled)?;
        self.mode = Mode::Idle;
        self.set_velocity(s, 0.0)
    }

    /// Starts homing: velocity mode at `speed` (user units/s, > 0) in
    /// `direction` (±1, user coordinates) until `limit_hit`.
    pub fn home(&mut self, direction: i8, speed: f64) -> Result<(), OneDofError> {
        if direction != 1 && direction != -1 {
            return Err(OneDofError::BadNumber("direction must be 1 or -1"));
        }
        positive(speed, "homing speed must be finite and > 0")?;
        let s = self.idle_state()?;
        self.set_velocity(s, f64::from(direction) * speed)?;
        self.homed = false;
        self.mode = Mode::Homing { started: s.stamp };
        Ok(())
    }

    /// The switch triggered at `time` (synchronized µs): finds where the
    /// axis was then on the emitted spline, makes that the home coordinate
    /// and stops.
    pub fn limit_hit(&mut self, time: u64) -> Result<HomeReport, OneDofError> {
        let Mode::Homing { started } = self.mode else {
            return Err(OneDofError::NotHoming);
        };
        if time < started {
            return Err(OneDofError::SwitchBeforeHoming { time, started });
        }
        let switch_axis = self.spline_at(time)?;
        self.cfg.offset = self.home_at - switch_axis / self.cfg.scale;
        self.stop()?;
        self.homed = true;
        Ok(HomeReport {
            time,
            switch_axis,
            rest_axis: self.profile.rest_position().unwrap_or(switch_axis),
        })
    }

    /// The position of the emitted spline at `time` (axis units).
    pub fn spline_at(&self, time: u64) -> Result<f64, OneDofError> {
        let iv = self.cfg.interval;
        let step = u64::from(iv.micros());
        let (Some(&(oldest, _)), Some(&(newest, _))) = (self.history.front(), self.history.back())
        else {
            return Err(OneDofError::NotSampled);
        };
        let seg = time & !(step - 1);
        let first = seg.checked_sub(step).filter(|&f| f >= oldest);
        let Some(first) = first else {
            return Err(OneDofError::TooOld { time, oldest });
        };
        let need = seg.saturating_add(2 * step);
        if need > newest {
            return Err(OneDofError::NotYetEmitted { time, newest });
        }
        let p =
            super::four_points(&self.history, first, step).ok_or(OneDofError::HistoryGap(time))?;
        Ok(eval_f64(&p, (time - seg) as u32, iv).pos)
    }

    /// The axis position (axis units) at `stamp`, recorded in the history.
    /// Sampling the last stamp again returns the same point.
    pub fn sample(&mut self, stamp: u64) -> Result<f64, OneDofError> {
        let step = u64::from(self.cfg.interval.micros());
        if stamp & (step - 1) != 0 {
            return Err(OneDofError::Misaligned(stamp));
        }
        let s = match self.last {
            Some(l) if stamp < l.stamp => {
                return Err(OneDofError::Stale {
                    stamp,
                    last: l.stamp,
                })
            }
            Some(l) if stamp == l.stamp => return Ok(l.pos),
            Some(_) => {
                let (pos, vel) = self.profile.at(stamp);
                AxisState { stamp, pos, vel }
            }
            None => {
                // The first stamp anchors the resting axis in time.
                self.profile = Profile::rest(stamp, self.profile.p0);
                AxisState {
                    stamp,
                    pos: self.profile.p0,
                    vel: 0.0,
                }
            }
        };
        self.last = Some(s);
        self.history.push_back((stamp, s.pos));
        while self.history.len() > self.cfg.history_len {
            self.history.pop_front();
        }
        Ok(s.pos)
    }

    /// `(position, velocity, moving, homed)` at the last sampled stamp, in
    /// user units.
    pub fn status(&self) -> (f64, f64, bool, bool) {
        let s = self.last.unwrap_or(AxisState {
            stamp: 0,
            pos: self.profile.p0,
            vel: 0.0,
        });
        (
            self.to_user(s.pos),
            s.vel / self.cfg.scale,
            self.is_moving(),
            self.homed,
        )
    }
}

/// A [`OneDof`] axis as the PIPES class `OneDof` (see the module docs).
///
/// Its methods are the class's members, in `f32` and with the failure codes
/// of [`OneDofError::code`]; the axis itself is the public field.
#[derive(Clone, Debug)]
pub struct OneDofBlock(pub OneDof);

#[pipes_core::class(name = "OneDof")]
impl OneDofBlock {
    /// The constructor `OneDof`: limits in user units, `scale` axis units
    /// per user unit, `offset` the user coordinate of axis position 0, the
    /// stamp interval; the default history length.
    #[constructor]
    pub fn new(
        max_vel: f32,
        max_acc: f32,
        scale: f32,
        offset: f32,
        interval_us: u32,
    ) -> Result<OneDofBlock, OneDofError> {
        let f = f64::from;
        OneDof::from_parts(f(max_vel), f(max_acc), f(scale), f(offset), interval_us)
            .map(OneDofBlock)
    }

    /// `OneDof.move_to`: [`OneDof::move_to`]; the stamp the move ends at.
    #[outputs = "eta_us"]
    pub fn move_to(&mut self, pos: f32) -> Result<u64, OneDofError> {
        Ok(self.0.move_to(f64::from(pos))?.end_us)
    }

    /// `OneDof.velocity`: [`OneDof::velocity`].
    pub fn velocity(&mut self, v: f32) -> Result<(), OneDofError> {
        self.0.velocity(f64::from(v))
    }

    /// `OneDof.stop`: [`OneDof::stop`].
    pub fn stop(&mut self) -> Result<(), OneDofError> {
        self.0.stop()
    }

    /// `OneDof.sample`: the stamp and the axis position there (axis units),
    /// [`OneDof::sample`].
    #[outputs = "stamp, position"]
    pub fn sample(&mut self, stamp: u64) -> Result<(u64, f32), OneDofError> {
        Ok((stamp, self.0.sample(stamp)? as f32))
    }

    /// `OneDof.home`: [`OneDof::home`].
    pub fn home(&mut self, dir: i8, speed: f32) -> Result<(), OneDofError> {
        self.0.home(dir, f64::from(speed))
    }

    /// `OneDof.set_home`: [`OneDof::set_home`].
    pub fn set_home(&mut self, position: f32) -> Result<(), OneDofError> {
        self.0.set_home(f64::from(position))
    }

    /// `OneDof.limit_hit`: the switch's axis position,
    /// [`OneDof::limit_hit`].
    #[outputs = "switch"]
    pub fn limit_hit(&mut self, time: u64) -> Result<f32, OneDofError> {
        Ok(self.0.limit_hit(time)?.switch_axis as f32)
    }

    /// `OneDof.set_position`: [`OneDof::set_position`].
    pub fn set_position(&mut self, pos: f32) -> Result<(), OneDofError> {
        self.0.set_position(f64::from(pos))
    }

    /// `OneDof.status`: [`OneDof::status`] in `f32`.
    #[outputs = "position, velocity, moving, homed"]
    pub fn status(&self) -> (f32, f32, bool, bool) {
        let (p, v, m, h) = self.0.status();
        (p as f32, v as f32, m, h)
    }
}
