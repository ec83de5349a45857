//! Reference spline interpolator: what the axis modules execute, on the host.
//!
//! [`Interpolator<N>`] takes stamped control points of `N` axes and evaluates
//! the same uniform cubic B-spline the modules run (the convention of
//! [`crate::Track`]: for `t` in `[T_i, T_i + Δt)` the points
//! `P_{i−1}..P_{i+2}`, [`eval_f64`] per axis), at any µs. A single missing
//! stamp is filled with the midpoint of its neighbours, as a module's track
//! fills it; a longer gap is accepted but leaves the curve unknown across it
//! (a module would be in its backstop there). The points are kept in a
//! bounded queue (oldest dropped first).
//!
//! It records the executed trajectory so a whole machine can run in
//! simulation: pipe the control points that go to the modules into it too,
//! then compare with the plan ([`Interpolator::executed`],
//! [`Interpolator::max_deviation`]).
//!
//! # PIPES class `Interpolator` ([`InterpolatorBlock`], three axes)
//!
//! | member | inputs | outputs |
//! |---|---|---|
//! | constructor `Interpolator` | `interval_us: u32, capacity: u32` | |
//! | `Interpolator.push` | `stamp: u64, x: f64, y: f64, z: f64` | |
//! | `Interpolator.eval` | `t: u64` | `x: f64, y: f64, z: f64` |
//! | `Interpolator.vel` | `t: u64` | `vx: f64, vy: f64, vz: f64` (units/s) |
//! | `Interpolator.span` | | `points: u32, oldest: u64, newest: u64` (0 when empty) |
//! | `Interpolator.clear` | | |
//!
//! Failure codes ([`InterpError::code`]; the constructor fails with 2 or 6):
//! 1 bad number (not finite), 2 bad interval, 3 stamp not a
//! multiple of the interval, 4 stamp not after the newest point, 5 the curve
//! is not known at `t` (too early, too late, or across a gap), 6 capacity
//! under 4.

use std::collections::VecDeque;
use std::fmt;

use pipes_core::function::CallError;

use crate::eval::eval_f64;
use crate::track::Interval;

/// Why an interpolator call was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum InterpError {
    /// A coordinate is not finite.
    BadNumber,
    /// The interval is not a power of two in 256..=16384 µs.
    BadInterval(u32),
    /// The stamp is not a multiple of the interval.
    Misaligned(u64),
    /// The stamp is not after the newest point.
    Stale {
        /// The stamp.
        stamp: u64,
        /// The newest stamp held.
        newest: u64,
    },
    /// The curve is not known at this time.
    Unknown(u64),
    /// A capacity under 4 points.
    BadCapacity(usize),
    /// A time step of 0.
    BadStep,
}

impl InterpError {
    /// The PIPES failure code (see the module docs).
    pub fn code(&self) -> u8 {
        match self {
            InterpError::BadNumber | InterpError::BadStep => 1,
            InterpError::BadInterval(_) => 2,
            InterpError::Misaligned(_) => 3,
            InterpError::Stale { .. } => 4,
            InterpError::Unknown(_) => 5,
            InterpError::BadCapacity(_) => 6,
        }
    }
}

impl fmt::Display for InterpError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            InterpError::BadNumber => write!(f, "a coordinate is not finite"),
            InterpError::BadInterval(us) => {
                write!(
                    f,
                    "interval {us} µs is not a power of two in 256..=16384 µs"
                )
            }
            InterpError::Misaligned(s) => write!(f, "stamp {s} is not a multiple of the interval"),
            InterpError::Stale { stamp, newest } => {
                write!(f, "stamp {stamp} is not after the newest point ({newest})")
            }
            InterpError::Unknown(t) => write!(f, "the curve is not known at {t} µs"),
            InterpError::BadCapacity(n) => write!(f, "capacity {n} is under 4 points"),
            InterpError::BadStep => write!(f, "the time step must be at least 1 µs"),
        }
    }
}

impl core::error::Error for InterpError {}

impl From<InterpError> for CallError {
    fn from(e: InterpError) -> CallError {
        CallError::Failed(e.code().into())
    }
}

/// How a point was taken.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pushed {
    /// The next stamp (or the first point).
    Appended,
    /// One stamp was missing and was filled with the midpoint.
    FilledGap,
    /// This many stamps were missing; the curve is unknown across them.
    Gap {
        /// Missing stamps.
        missing: u64,
    },
}

/// Position (units) and velocity (units/s) of every axis at one time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Kin<const N: usize> {
    /// Position.
    pub pos: [f64; N],
    /// Velocity, units/s.
    pub vel: [f64; N],
}

/// The largest distance between the executed and the planned path.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Deviation<const N: usize> {
    /// Euclidean distance over the axes.
    pub max: f64,
    /// When, µs.
    pub at: u64,
    /// The executed position then.
    pub executed: [f64; N],
    /// The planned position then.
    pub planned: [f64; N],
}

/// The reference interpolator (see the module docs).
#[derive(Clone, Debug)]
pub struct Interpolator<const N: usize> {
    iv: Interval,
    capacity: usize,
    points: VecDeque<(u64, [f64; N])>,
}

impl<const N: usize> Interpolator<N> {
    /// An empty interpolator holding at most `capacity` (≥ 4) points.
    pub fn new(interval: Interval, capacity: usize) -> Result<Self, InterpError> {
        if capacity < 4 {
            return Err(InterpError::BadCapacity(capacity));
        }
        Ok(Interpolator {
            iv: interval,
            capacity,
            points: VecDeque::with_capacity(capacity.min(1 << 16)),
        })
    }

    /// The interval.
    pub fn interval(&self) -> Interval {
        self.iv
    }

    /// Points held (filled ones included).
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether no point is held.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The oldest and newest stamps held.
    pub fn span(&self) -> Option<(u64, u64)> {
        Some((self.points.front()?.0, self.points.back()?.0))
    }

    /// The points held, oldest first.
    pub fn points(&self) -> impl Iterator<Item = (u64, [f64; N])> + '_ {
        self.points.iter().copied()
    }

    /// Forgets every point.
    pub fn clear(&mut self) {
        self.points.clear();
    }

    fn step(&self) -> u64 {
        u64::from(self.iv.micros())
    }

    fn append(&mut self, stamp: u64, p: [f64; N]) {
        self.points.push_back((stamp, p));
        while self.points.len() > self.capacity {
            self.points.pop_front();
        }
    }

    /// Adds the point stamped `stamp`.
    pub fn push(&mut self, stamp: u64, point: [f64; N]) -> Result<Pushed, InterpError> {
        if point.iter().any(|x| !x.is_finite()) {
            return Err(InterpError::BadNumber);
        }
        let step = self.step();
        if stamp & (step - 1) != 0 {
            return Err(InterpError::Misaligned(stamp));
        }
        let Some(&(newest, prev)) = self.points.back() else {
            self.append(stamp, point);
            return Ok(Pushed::Appended);
        };
        if stamp <= newest {
            return Err(InterpError::Stale { stamp, newest });
        }
        let missing = (stamp - newest) / step - 1;
        let out = match missing {
            0 => Pushed::Appended,
            1 => {
                let mid = core::array::from_fn(|k| 0.5 * (prev[k] + point[k]));
                self.append(newest + step, mid);
                Pushed::FilledGap
            }
            m => Pushed::Gap { missing: m },
        };
        self.append(stamp, point);
        Ok(out)
    }

    /// The four points of the segment holding `t`, if all are held.
    fn segment(&self, t: u64) -> Option<[[f64; N]; 4]> {
        let step = self.step();
        let seg = t & !(step - 1);
        super::four_points(&self.points, seg.checked_sub(step)?, step)
    }

    /// Position and velocity at `t` (µs), where the curve is known.
    pub fn eval(&self, t: u64) -> Option<Kin<N>> {
        let seg = self.segment(t)?;
        let du = (t & (self.step() - 1)) as u32;
        let axis = |k: usize| eval_f64(&seg.map(|p| p[k]), du, self.iv);
        let each: [_; N] = core::array::from_fn(axis);
        Some(Kin {
            pos: each.map(|e| e.pos),
            vel: each.map(|e| e.vel),
        })
    }

    /// The executed positions from `from` to `to` (inclusive) every `step`
    /// µs, where the curve is known.
    pub fn executed(
        &self,
        from: u64,
        to: u64,
        step: u64,
    ) -> Result<Vec<(u64, [f64; N])>, InterpError> {
        if step == 0 {
            return Err(InterpError::BadStep);
        }
        let times = (from..=to).step_by(usize::try_from(step).unwrap_or(usize::MAX));
        Ok(times.filter_map(|t| Some((t, self.eval(t)?.pos))).collect())
    }

    /// The largest Euclidean distance between the executed path and
    /// `planned(t)` from `from` to `to` every `step` µs, over the times
    /// where the curve is known (`None` if there are none).
    pub fn max_deviation(
        &self,
        planned: impl Fn(u64) -> [f64; N],
        from: u64,
        to: u64,
        step: u64,
    ) -> Result<Option<Deviation<N>>, InterpError> {
        let mut worst: Option<Deviation<N>> = None;
        for (t, x) in self.executed(from, to, step)? {
            let p = planned(t);
            let d = x
                .iter()
                .zip(&p)
                .map(|(a, b)| (a - b) * (a - b))
                .sum::<f64>()
                .sqrt();
            if worst.is_none_or(|w| d > w.max) {
                worst = Some(Deviation {
                    max: d,
                    at: t,
                    executed: x,
                    planned: p,
                });
            }
        }
        Ok(worst)
    }
}

/// A three-axis [`Interpolator`] as the PIPES class `Interpolator` (see the
/// module docs).
///
/// Its methods are the class's members; the interpolator itself is the
/// public field.
#[derive(Clone, Debug)]
pub struct InterpolatorBlock(pub Interpolator<3>);

#[pipes_core::class(name = "Interpolator")]
impl InterpolatorBlock {
    /// The constructor `Interpolator`: an empty interpolator at
    /// `interval_us` holding at most `capacity` (≥ 4) points.
    #[constructor]
    pub fn new(interval_us: u32, capacity: u32) -> Result<InterpolatorBlock, InterpError> {
        let iv = Interval::from_micros(interval_us)
            .map_err(|_| InterpError::BadInterval(interval_us))?;
        let capacity = usize::try_from(capacity).unwrap_or(usize::MAX);
        Interpolator::new(iv, capacity).map(InterpolatorBlock)
    }

    /// `Interpolator.push`: [`Interpolator::push`] of `(x, y, z)`.
    pub fn push(&mut self, stamp: u64, x: f64, y: f64, z: f64) -> Result<(), InterpError> {
        self.0.push(stamp, [x, y, z]).map(drop)
    }

    /// `Interpolator.eval`: the position at `t`.
    #[outputs = "x, y, z"]
    pub fn eval(&self, t: u64) -> Result<(f64, f64, f64), InterpError> {
        let k = self.0.eval(t).ok_or(InterpError::Unknown(t))?;
        Ok((k.pos[0], k.pos[1], k.pos[2]))
    }

    /// `Interpolator.vel`: the velocity at `t`, units/s.
    #[outputs = "vx, vy, vz"]
    pub fn vel(&self, t: u64) -> Result<(f64, f64, f64), InterpError> {
        let k = self.0.eval(t).ok_or(InterpError::Unknown(t))?;
        Ok((k.vel[0], k.vel[1], k.vel[2]))
    }

    /// `Interpolator.span`: the points held and the oldest and newest
    /// stamps (0 when empty).
    #[outputs = "points, oldest, newest"]
    pub fn span(&self) -> (u32, u64, u64) {
        let (a, b) = self.0.span().unwrap_or((0, 0));
        (u32::try_from(self.0.len()).unwrap_or(u32::MAX), a, b)
    }

    /// `Interpolator.clear`: forgets every point.
    pub fn clear(&mut self) {
        self.0.clear();
    }
}
