//! Per-axis limiter: clamps incoming control points to a maximum velocity,
//! acceleration and jerk (a firmware backstop against bad streams).
//!
//! It works on the point sequence at the track's interval Δt with finite
//! differences: `v_i = (P_i − P_{i−1})/Δt`, `a_i = (v_i − v_{i−1})/Δt`,
//! `j_i = (a_i − a_{i−1})/Δt`. Internally these are kept as differences of
//! positions (`d1 = v·Δt`, `d2 = a·Δt²`, `d3 = j·Δt³`), so the `Fx` limiter is
//! exact integer arithmetic (`i64`, saturating) with no FPU.
//!
//! For a new point the limiter chooses the second difference `d2` (and so
//! the point) closest to the requested one inside, in priority order:
//! 1. the jerk window `|d2 − d2_prev| <= J·Δt³`,
//! 2. the acceleration window `|d2| <= A·Δt²`,
//! 3. the velocity window with lookahead: `|d1| <= V·Δt` **and** the axis can
//!    still bring its acceleration back to zero at full jerk without passing
//!    `V` (otherwise a later point would have to break the jerk limit).
//!
//! From rest, and after any accepted point, all three windows overlap (the
//! full-jerk ramp toward zero acceleration is always in them), so the output
//! stream never exceeds any limit. A stream that is within the limits (and,
//! being a real motion, can always stop within them) passes unchanged, bit
//! for bit. Because the B-spline's velocity, acceleration and jerk are
//! B-splines of these differences (convex combinations of them), the
//! evaluated curve stays within the same limits.
//!
//! The first point after [`Limiter::new`] or [`Limiter::reset`] is taken as
//! a rest position and passed unchanged.
//!
//! [`Limiter::push`] takes the point it returns as the stream's newest (a
//! clamped point too). To check a point without taking it (to refuse it
//! rather than clamp it, as osap-module's firmware does), push it into a
//! copy: a `Limiter` is `Copy`, and the copy is kept only if the point is
//! accepted.

use crate::eval::Fx;
use crate::track::Interval;

/// Limits in steps/s, steps/s², steps/s³ (all finite and `> 0`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AxisLimits {
    /// Largest velocity, steps/s.
    pub max_vel: f32,
    /// Largest acceleration, steps/s².
    pub max_acc: f32,
    /// Largest jerk, steps/s³.
    pub max_jerk: f32,
}

/// Limits as per-interval position differences in `Fx` raw units
/// (`vel = V·Δt·65536`, `acc = A·Δt²·65536`, `jerk = J·Δt³·65536`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RawLimits {
    /// Largest first difference per interval, raw `Fx`.
    pub vel: i64,
    /// Largest second difference per interval, raw `Fx`.
    pub acc: i64,
    /// Largest third difference per interval, raw `Fx`.
    pub jerk: i64,
}

/// Why limits were refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum LimitError {
    /// A limit is not finite or not `> 0`.
    Invalid,
    /// A limit rounds to less than one raw unit per interval in `Fx`
    /// (`J·Δt³` is tiny at short intervals): raise it or use a longer interval.
    TooSmall,
}

impl core::fmt::Display for LimitError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            LimitError::Invalid => write!(f, "limits must be finite and > 0"),
            LimitError::TooSmall => {
                write!(f, "a limit is below one Fx raw unit per interval")
            }
        }
    }
}

impl core::error::Error for LimitError {}

/// Which limits a point broke (and so which clamps applied).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Clamped {
    /// The jerk limit applied.
    pub jerk: bool,
    /// The acceleration limit applied.
    pub acc: bool,
    /// The velocity limit applied.
    pub vel: bool,
}

impl Clamped {
    /// True when the point was changed.
    pub fn any(&self) -> bool {
        self.jerk || self.acc || self.vel
    }
}

/// The point to use and what was clamped.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Limited<P> {
    /// The point, clamped where a limit required.
    pub point: P,
    /// Which limits applied.
    pub clamped: Clamped,
}

/// Counters of a [`Limiter`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LimitStats {
    /// Points seen.
    pub points: u64,
    /// Points changed.
    pub clamped: u64,
    /// Points that broke the jerk limit.
    pub jerk: u64,
    /// Points that broke the acceleration limit.
    pub acc: u64,
    /// Points that broke the velocity limit (with lookahead).
    pub vel: u64,
}

mod sealed {
    /// Difference arithmetic of a limiter.
    pub trait Num: Copy + PartialOrd + core::fmt::Debug {
        const ZERO: Self;
        fn add(self, o: Self) -> Self;
        fn sub(self, o: Self) -> Self;
        /// Velocity difference still gained from acceleration difference
        /// `x >= 0` when it ramps to zero at jerk difference `jd` per point:
        /// `Σ_{k>=1} max(0, x − k·jd)`.
        fn overshoot(x: Self, jd: Self) -> Self;
        /// Largest `x` in `[lo, hi]` with `ok(x)`, given `ok(lo)` and `ok`
        /// monotone (true then false).
        fn bisect_max(lo: Self, hi: Self, ok: impl Fn(Self) -> bool) -> Self;
        /// Smallest `x` in `[lo, hi]` with `ok(x)`, given `ok(hi)` and `ok`
        /// monotone (false then true).
        fn bisect_min(lo: Self, hi: Self, ok: impl Fn(Self) -> bool) -> Self;
    }

    pub trait Sealed {}
}
use sealed::Num;

impl Num for i64 {
    const ZERO: i64 = 0;
    fn add(self, o: i64) -> i64 {
        self.saturating_add(o)
    }
    fn sub(self, o: i64) -> i64 {
        self.saturating_sub(o)
    }
    fn overshoot(x: i64, jd: i64) -> i64 {
        let n = x / jd;
        // n·(2x − jd(n+1))/2 is exact: the product is even.
        let m = 2 * x - jd * (n + 1);
        n.saturating_mul(m) / 2
    }
    fn bisect_max(mut lo: i64, mut hi: i64, ok: impl Fn(i64) -> bool) -> i64 {
        while lo < hi {
            let mid = lo + (hi - lo + 1) / 2;
            if ok(mid) {
                lo = mid;
            } else {
                hi = mid - 1;
            }
        }
        lo
    }
    fn bisect_min(mut lo: i64, mut hi: i64, ok: impl Fn(i64) -> bool) -> i64 {
        while lo < hi {
            let mid = lo + (hi - lo) / 2;
            if ok(mid) {
                hi = mid;
            } else {
                lo = mid + 1;
            }
        }
        hi
    }
}

impl Num for f32 {
    const ZERO: f32 = 0.0;
    fn add(self, o: f32) -> f32 {
        self + o
    }
    fn sub(self, o: f32) -> f32 {
        self - o
    }
    fn overshoot(x: f32, jd: f32) -> f32 {
        let n = (x / jd) as i64 as f32;
        let m = 2.0 * x - jd * (n + 1.0);
        if m > 0.0 {
            n * m * 0.5
        } else {
            0.0
        }
    }
    fn bisect_max(mut lo: f32, mut hi: f32, ok: impl Fn(f32) -> bool) -> f32 {
        for _ in 0..64 {
            let mid = lo + (hi - lo) * 0.5;
            if mid <= lo || mid >= hi {
                break;
            }
            if ok(mid) {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        lo
    }
    fn bisect_min(mut lo: f32, mut hi: f32, ok: impl Fn(f32) -> bool) -> f32 {
        for _ in 0..64 {
            let mid = lo + (hi - lo) * 0.5;
            if mid <= lo || mid >= hi {
                break;
            }
            if ok(mid) {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        hi
    }
}

/// A control-point type a [`Limiter`] handles: `f32` (steps) or [`Fx`].
pub trait Limitable: Copy + sealed::Sealed {
    /// Difference type: `f32` steps, or `i64` raw `Fx` units.
    #[allow(private_bounds)]
    type D: Num;
    /// `a − b`.
    fn diff(a: Self, b: Self) -> Self::D;
    /// `p + d` (wrapping for `Fx`, whose positions wrap).
    fn offset(p: Self, d: Self::D) -> Self;
}

impl sealed::Sealed for f32 {}
impl Limitable for f32 {
    type D = f32;
    fn diff(a: f32, b: f32) -> f32 {
        a - b
    }
    fn offset(p: f32, d: f32) -> f32 {
        p + d
    }
}

impl sealed::Sealed for Fx {}
impl Limitable for Fx {
    type D = i64;
    fn diff(a: Fx, b: Fx) -> i64 {
        a.wrapping_diff(b) as i64
    }
    fn offset(p: Fx, d: i64) -> Fx {
        // Positions wrap (see `Fx`); a difference is less than 32 768 steps.
        Fx(p.0.wrapping_add(d as i32))
    }
}

/// Clamps a stream of points to velocity, acceleration and jerk limits.
#[derive(Clone, Copy, Debug)]
pub struct Limiter<P: Limitable> {
    vd: P::D,
    ad: P::D,
    jd: P::D,
    prev: Option<P>,
    d1: P::D,
    d2: P::D,
    stats: LimitStats,
}

fn valid(l: &AxisLimits) -> bool {
    [l.max_vel, l.max_acc, l.max_jerk]
        .iter()
        .all(|x| x.is_finite() && *x > 0.0)
}

impl Limiter<f32> {
    /// A limiter for `f32` points at interval `iv`.
    pub fn new(lim: AxisLimits, iv: Interval) -> Result<Self, LimitError> {
        if !valid(&lim) {
            return Err(LimitError::Invalid);
        }
        let dt = iv.micros() as f64 * 1e-6;
        let (vd, ad, jd) = (
            (lim.max_vel as f64 * dt) as f32,
            (lim.max_acc as f64 * dt * dt) as f32,
            (lim.max_jerk as f64 * dt * dt * dt) as f32,
        );
        if !(vd > 0.0 && ad > 0.0 && jd > 0.0) {
            return Err(LimitError::TooSmall);
        }
        Ok(Self::with_diffs(vd, ad, jd))
    }
}

impl Limiter<Fx> {
    /// A limiter for `Fx` points at interval `iv`; the limits are converted
    /// once (rounded down, so they are never exceeded), then everything is
    /// integer.
    pub fn new(lim: AxisLimits, iv: Interval) -> Result<Self, LimitError> {
        if !valid(&lim) {
            return Err(LimitError::Invalid);
        }
        let dt = iv.micros() as f64 * 1e-6;
        let raw = |x: f64| {
            let r = x * 65536.0;
            if r >= i64::MAX as f64 {
                i64::MAX / 4
            } else {
                (r as i64).min(i64::MAX / 4)
            }
        };
        Self::from_raw(RawLimits {
            vel: raw(lim.max_vel as f64 * dt),
            acc: raw(lim.max_acc as f64 * dt * dt),
            jerk: raw(lim.max_jerk as f64 * dt * dt * dt),
        })
    }

    /// A limiter from per-interval raw differences (integer only).
    pub fn from_raw(raw: RawLimits) -> Result<Self, LimitError> {
        if raw.vel <= 0 || raw.acc <= 0 || raw.jerk <= 0 {
            return Err(LimitError::TooSmall);
        }
        // Headroom so sums of differences cannot saturate.
        let cap = |x: i64| x.min(1 << 40);
        Ok(Self::with_diffs(cap(raw.vel), cap(raw.acc), cap(raw.jerk)))
    }

    /// The limits in raw per-interval differences.
    pub fn raw_limits(&self) -> RawLimits {
        RawLimits {
            vel: self.vd,
            acc: self.ad,
            jerk: self.jd,
        }
    }
}

impl<P: Limitable> Limiter<P> {
    fn with_diffs(vd: P::D, ad: P::D, jd: P::D) -> Self {
        Limiter {
            vd,
            ad,
            jd,
            prev: None,
            d1: P::D::ZERO,
            d2: P::D::ZERO,
            stats: LimitStats::default(),
        }
    }

    /// Forget the stream: the next point is a new rest position.
    pub fn reset(&mut self) {
        self.prev = None;
        self.d1 = P::D::ZERO;
        self.d2 = P::D::ZERO;
    }

    /// Counters.
    pub fn stats(&self) -> LimitStats {
        self.stats
    }

    /// Upper velocity test: `d1 + x` plus the overshoot of `x` stays `<= V`.
    fn vel_hi_ok(&self, x: P::D) -> bool {
        let over = if x > P::D::ZERO {
            P::D::overshoot(x, self.jd)
        } else {
            P::D::ZERO
        };
        self.d1.add(x).add(over) <= self.vd
    }

    fn vel_lo_ok(&self, x: P::D) -> bool {
        let over = if x < P::D::ZERO {
            P::D::overshoot(P::D::ZERO.sub(x), self.jd)
        } else {
            P::D::ZERO
        };
        self.d1.add(x).sub(over) >= P::D::ZERO.sub(self.vd)
    }

    /// Limit the next point of the stream.
    pub fn push(&mut self, p: P) -> Limited<P> {
        self.stats.points += 1;
        let Some(prev) = self.prev else {
            self.prev = Some(p);
            return Limited {
                point: p,
                clamped: Clamped::default(),
            };
        };
        let zero = P::D::ZERO;
        let want = P::diff(p, prev).sub(self.d1);
        let (jlo, jhi) = (self.d2.sub(self.jd), self.d2.add(self.jd));
        let mut c = Clamped {
            jerk: want < jlo || want > jhi,
            acc: want < zero.sub(self.ad) || want > self.ad,
            vel: false,
        };
        let (mut lo, mut hi) = (jlo, jhi);
        let (alo, ahi) = (
            if lo > zero.sub(self.ad) {
                lo
            } else {
                zero.sub(self.ad)
            },
            if hi < self.ad { hi } else { self.ad },
        );
        if alo <= ahi {
            (lo, hi) = (alo, ahi);
        }
        let mut x = if want < lo {
            lo
        } else if want > hi {
            hi
        } else {
            want
        };
        if !self.vel_hi_ok(x) {
            c.vel = true;
            if self.vel_hi_ok(lo) {
                x = P::D::bisect_max(lo, x, |y| self.vel_hi_ok(y));
            } else {
                x = lo;
            }
        } else if !self.vel_lo_ok(x) {
            c.vel = true;
            if self.vel_lo_ok(hi) {
                x = P::D::bisect_min(x, hi, |y| self.vel_lo_ok(y));
            } else {
                x = hi;
            }
        }
        let point = if c.any() {
            P::offset(prev, self.d1.add(x))
        } else {
            p
        };
        let d1 = P::diff(point, prev);
        self.d2 = d1.sub(self.d1);
        self.d1 = d1;
        self.prev = Some(point);
        if c.any() {
            self.stats.clamped += 1;
            self.stats.jerk += c.jerk as u64;
            self.stats.acc += c.acc as u64;
            self.stats.vel += c.vel as u64;
        }
        Limited { point, clamped: c }
    }
}
