//! Machine limits and the planner's errors.

use std::fmt;

/// Per-axis limits of a machine, in the path's units (mm, mm/s, mm/s²).
///
/// Build with [`Limits::new`], which checks every value; [`super::Planner::new`]
/// checks again, so a hand-built value with a bad field is refused there.
#[derive(Clone, Debug, PartialEq)]
pub struct Limits<const N: usize> {
    /// Largest speed of each axis (mm/s), finite and > 0.
    pub max_vel: [f64; N],
    /// Largest acceleration of each axis (mm/s²), finite and > 0.
    pub max_acc: [f64; N],
    /// Junction deviation (mm), finite and ≥ 0: how far the path may be
    /// imagined to round a corner when choosing the corner's speed. 0 stops
    /// at every corner.
    pub junction_deviation: f64,
    /// Largest instantaneous velocity change of each axis at a junction
    /// (mm/s), > 0; `f64::INFINITY` leaves the junction to the deviation
    /// model alone.
    pub max_jump: [f64; N],
    /// Largest jerk of each axis (mm/s³), > 0; `f64::INFINITY` (the
    /// default) plans trapezoidal profiles, anything finite jerk-limited
    /// ones (see [`super::Profile`]).
    pub max_jerk: [f64; N],
}

impl<const N: usize> Limits<N> {
    /// Limits with no per-axis velocity-jump limit.
    pub fn new(
        max_vel: [f64; N],
        max_acc: [f64; N],
        junction_deviation: f64,
    ) -> Result<Self, PlanError> {
        let l = Limits {
            max_vel,
            max_acc,
            junction_deviation,
            max_jump: [f64::INFINITY; N],
            max_jerk: [f64::INFINITY; N],
        };
        l.validate()?;
        Ok(l)
    }

    /// The same limits with a per-axis jerk limit: profiles whose
    /// acceleration ramps at most this fast (`f64::INFINITY`: trapezoids).
    pub fn with_max_jerk(mut self, max_jerk: [f64; N]) -> Result<Self, PlanError> {
        self.max_jerk = max_jerk;
        self.validate()?;
        Ok(self)
    }

    /// The same limits with a per-axis velocity-jump limit at junctions.
    pub fn with_max_jump(mut self, max_jump: [f64; N]) -> Result<Self, PlanError> {
        self.max_jump = max_jump;
        self.validate()?;
        Ok(self)
    }

    /// The same limits with the junction deviation Klipper derives from a
    /// square-corner velocity (see [`square_corner_deviation`]).
    pub fn with_square_corner_velocity(
        mut self,
        square_corner_velocity: f64,
        accel: f64,
    ) -> Result<Self, PlanError> {
        self.junction_deviation = square_corner_deviation(square_corner_velocity, accel)?;
        self.validate()?;
        Ok(self)
    }

    /// Checks every value.
    pub fn validate(&self) -> Result<(), PlanError> {
        if N == 0 {
            return Err(PlanError::InvalidLimit {
                name: "axes",
                axis: None,
                value: 0.0,
            });
        }
        let bad = |name, axis, value: f64| PlanError::InvalidLimit { name, axis, value };
        for i in 0..N {
            let v = self.max_vel[i];
            if !(v.is_finite() && v > 0.0) {
                return Err(bad("max_vel", Some(i), v));
            }
            let a = self.max_acc[i];
            if !(a.is_finite() && a > 0.0) {
                return Err(bad("max_acc", Some(i), a));
            }
            let j = self.max_jump[i];
            if j.is_nan() || j <= 0.0 {
                return Err(bad("max_jump", Some(i), j));
            }
            let j = self.max_jerk[i];
            if j.is_nan() || j <= 0.0 {
                return Err(bad("max_jerk", Some(i), j));
            }
        }
        let d = self.junction_deviation;
        if !(d.is_finite() && d >= 0.0) {
            return Err(bad("junction_deviation", None, d));
        }
        Ok(())
    }
}

/// Klipper's junction deviation for a square-corner velocity `scv` (mm/s,
/// finite, ≥ 0) at acceleration `accel` (mm/s², finite, > 0):
/// `scv² · (√2 − 1) / accel` (klippy/toolhead.py), the deviation at which
/// a 90° corner is taken at `scv` when the corner's acceleration is `accel`.
pub fn square_corner_deviation(scv: f64, accel: f64) -> Result<f64, PlanError> {
    let bad = |name, value| PlanError::InvalidLimit {
        name,
        axis: None,
        value,
    };
    if !(scv.is_finite() && scv >= 0.0) {
        return Err(bad("square_corner_velocity", scv));
    }
    if !(accel.is_finite() && accel > 0.0) {
        return Err(bad("accel", accel));
    }
    Ok(scv * scv * (std::f64::consts::SQRT_2 - 1.0) / accel)
}

/// Klipper's default `minimum_cruise_ratio` (its `[printer]` section).
pub const KLIPPER_MIN_CRUISE_RATIO: f64 = 0.5;

/// Limits of the toolhead as a whole, on top of the per-axis [`Limits`]:
/// the largest path speed |v| and acceleration |a| in any direction
/// (Klipper's `max_velocity` and `max_accel`), and Klipper's minimum cruise
/// ratio.
///
/// A segment's speed and acceleration limits are the smaller of the
/// per-axis ones along its direction and these; a junction's corner
/// acceleration likewise. [`VectorLimits::NONE`] (the default, and what
/// [`super::Planner::new`] uses) bounds nothing: the planner is per-axis
/// only.
///
/// They are a separate value rather than fields of [`Limits`] so that code
/// building `Limits { .. }` literally keeps compiling.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VectorLimits {
    /// Largest toolhead speed |v| (mm/s), > 0; `f64::INFINITY` for none.
    pub max_speed: f64,
    /// Largest toolhead acceleration |a| (mm/s²), > 0; `f64::INFINITY` for
    /// none.
    pub max_accel: f64,
    /// Klipper's `minimum_cruise_ratio`, in [0, 1): each segment reaches at
    /// most the peak speed of a lookahead run at `acc · (1 − ratio)` (its
    /// "accel to decel" limit), so a short move between two slow corners
    /// cruises over about `ratio` of its length instead of accelerating and
    /// braking all the way. 0 (the default) turns it off; Klipper's default
    /// is [`KLIPPER_MIN_CRUISE_RATIO`].
    pub min_cruise_ratio: f64,
    /// How many leading axes are the toolhead's (x, y, z): a segment's
    /// length and feed are measured over them, and these limits bound
    /// their motion. The other axes (an extruder, a rotary table) follow
    /// along, each within its own per-axis limits; a move of those axes
    /// alone (a retraction) is measured over them and is bounded by their
    /// own limits only, as Klipper plans an extruder. 0 (the default):
    /// every axis is the toolhead's.
    pub path_axes: usize,
    /// Largest toolhead jerk |j| (mm/s³), > 0; `f64::INFINITY` for none
    /// (with every axis's jerk infinite too, profiles are trapezoids).
    pub max_jerk: f64,
}

impl Default for VectorLimits {
    fn default() -> Self {
        VectorLimits::NONE
    }
}

impl VectorLimits {
    /// No vector limits and no minimum cruise ratio.
    pub const NONE: VectorLimits = VectorLimits {
        max_speed: f64::INFINITY,
        max_accel: f64::INFINITY,
        min_cruise_ratio: 0.0,
        path_axes: 0,
        max_jerk: f64::INFINITY,
    };

    /// Largest toolhead speed and acceleration (`f64::INFINITY` for none),
    /// minimum cruise ratio 0.
    pub fn new(max_speed: f64, max_accel: f64) -> Result<Self, PlanError> {
        let v = VectorLimits {
            max_speed,
            max_accel,
            min_cruise_ratio: 0.0,
            path_axes: 0,
            max_jerk: f64::INFINITY,
        };
        v.validate()?;
        Ok(v)
    }

    /// The same limits with the first `k` axes as the toolhead's (see
    /// [`VectorLimits::path_axes`]; 0: all of them).
    pub fn with_path_axes(mut self, k: usize) -> Self {
        self.path_axes = k;
        self
    }

    /// The same limits with a toolhead jerk limit (`f64::INFINITY`: none).
    pub fn with_max_jerk(mut self, jerk: f64) -> Result<Self, PlanError> {
        self.max_jerk = jerk;
        self.validate()?;
        Ok(self)
    }

    /// The same limits with a minimum cruise ratio in [0, 1).
    pub fn with_min_cruise_ratio(mut self, ratio: f64) -> Result<Self, PlanError> {
        self.min_cruise_ratio = ratio;
        self.validate()?;
        Ok(self)
    }

    /// Checks every value: speed and acceleration > 0 (not NaN, infinite
    /// allowed), ratio finite in [0, 1).
    pub fn validate(&self) -> Result<(), PlanError> {
        let bad = |name, value| PlanError::InvalidLimit {
            name,
            axis: None,
            value,
        };
        if self.max_speed.is_nan() || self.max_speed <= 0.0 {
            return Err(bad("max_speed", self.max_speed));
        }
        if self.max_accel.is_nan() || self.max_accel <= 0.0 {
            return Err(bad("max_accel", self.max_accel));
        }
        if self.max_jerk.is_nan() || self.max_jerk <= 0.0 {
            return Err(bad("max_jerk", self.max_jerk));
        }
        let r = self.min_cruise_ratio;
        if !(r.is_finite() && (0.0..1.0).contains(&r)) {
            return Err(bad("min_cruise_ratio", r));
        }
        Ok(())
    }
}

/// Why the planner refused a call.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum PlanError {
    /// A limit is not finite, or not > 0 (≥ 0 for the junction deviation; the
    /// vector speed and acceleration may be infinite; the minimum cruise
    /// ratio must lie in [0, 1)).
    InvalidLimit {
        /// Which limit.
        name: &'static str,
        /// The axis, for per-axis limits.
        axis: Option<usize>,
        /// The refused value.
        value: f64,
    },
    /// A coordinate (target, or arc centre) is NaN or infinite.
    NonFiniteCoordinate {
        /// The axis.
        axis: usize,
    },
    /// The feed rate is not finite and > 0.
    InvalidFeed(f64),
    /// The arc cannot be built (see the reason).
    InvalidArc(&'static str),
    /// The queue holds `capacity` segments not yet started.
    QueueFull {
        /// The queue's capacity.
        capacity: usize,
    },
    /// A stamp before the previous one.
    StampNotMonotonic {
        /// The refused stamp.
        stamp: u64,
        /// The previous stamp.
        last: u64,
    },
    /// The call needs the planner idle (nothing running or queued).
    Busy,
    /// The queue capacity is 0.
    InvalidCapacity,
    /// The feed scale is not finite and in (0, [`super::MAX_FEED_SCALE`]].
    InvalidFeedScale(f64),
    /// A move whose length overflows (finite coordinates whose differences
    /// do not fit an `f64`).
    MoveTooLong,
}

impl PlanError {
    /// The [`pipes_core::function::CallError::Failed`] code of this error on
    /// the wire (see the module docs).
    pub fn code(&self) -> u8 {
        match self {
            PlanError::InvalidLimit { .. } => 1,
            PlanError::NonFiniteCoordinate { .. } => 2,
            PlanError::InvalidFeed(_) => 3,
            PlanError::InvalidArc(_) => 4,
            PlanError::QueueFull { .. } => 5,
            PlanError::StampNotMonotonic { .. } => 6,
            PlanError::Busy => 7,
            PlanError::InvalidCapacity => 8,
            PlanError::InvalidFeedScale(_) => 9,
            PlanError::MoveTooLong => 10,
        }
    }
}

impl fmt::Display for PlanError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PlanError::InvalidLimit {
                name,
                axis: Some(i),
                value,
            } => write!(f, "limit {name}[{i}] = {value} is not allowed"),
            PlanError::InvalidLimit {
                name,
                axis: None,
                value,
            } => write!(f, "limit {name} = {value} is not allowed"),
            PlanError::NonFiniteCoordinate { axis } => {
                write!(f, "coordinate of axis {axis} is not finite")
            }
            PlanError::InvalidFeed(v) => write!(f, "feed rate {v} is not finite and > 0"),
            PlanError::InvalidArc(why) => write!(f, "invalid arc: {why}"),
            PlanError::QueueFull { capacity } => {
                write!(f, "planner queue full ({capacity} segments waiting)")
            }
            PlanError::StampNotMonotonic { stamp, last } => {
                write!(f, "stamp {stamp} µs is before the previous stamp {last} µs")
            }
            PlanError::Busy => write!(f, "the planner is not idle"),
            PlanError::InvalidCapacity => write!(f, "queue capacity must be > 0"),
            PlanError::InvalidFeedScale(k) => write!(
                f,
                "feed scale {k} is not finite and in (0, {}]",
                super::MAX_FEED_SCALE
            ),
            PlanError::MoveTooLong => write!(f, "the move's length overflows"),
        }
    }
}

impl core::error::Error for PlanError {}
