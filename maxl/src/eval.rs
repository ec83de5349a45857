//! Equation 2.1 evaluators: `f32`, integer-only fixed point ([`Fx`]) and an
//! `f64` reference.
//!
//! Segment convention: for `t` in `[T_i, T_i + Δt)` the curve uses the control
//! points `P_{i-1}, P_i, P_{i+1}, P_{i+2}` with `u = (t - T_i) / Δt`.
//! With `c0 = P0 + 4P1 + P2`, `c1 = 3(P2 - P0)`, `c2 = 3(P0 - 2P1 + P2)`,
//! `c3 = -P0 + 3P1 - 3P2 + P3`:
//!
//! ```text
//! 6·p(u) = c0 + c1 u + c2 u² + c3 u³
//! 6·p'(u) = c1 + 2 c2 u + 3 c3 u²        v = p'(u) / Δt
//! 6·p''(u) = 2 c2 + 6 c3 u               a = p''(u) / Δt²
//! 6·p'''(u) = 6 c3                       j = p'''(u) / Δt³
//! ```

use crate::track::Interval;

/// Position in steps as signed Q16.16 fixed point: `steps = raw / 65536`.
///
/// Range ±32768 steps, resolution 1/65536 step (1.53e-5 step).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Fx(pub i32);

impl Fx {
    /// Number of fractional bits.
    pub const FRAC_BITS: u32 = 16;
    /// One step.
    pub const ONE: i32 = 1 << 16;

    /// Nearest Q16.16 value to `steps` (saturating). Uses the FPU or soft float;
    /// meant for hosts and tests, not for the integer-only hot path.
    pub fn from_f64(steps: f64) -> Self {
        let r = steps * 65536.0;
        let r = if r >= 0.0 { r + 0.5 } else { r - 0.5 };
        Fx(r as i32)
    }

    /// Value in steps.
    pub fn to_f64(self) -> f64 {
        self.0 as f64 / 65536.0
    }
}

/// Kinematics from the `f32` evaluator: steps, steps/s, steps/s², steps/s³.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct KinF32 {
    pub pos: f32,
    pub vel: f32,
    pub acc: f32,
    pub jerk: f32,
}

/// Kinematics from the `f64` reference evaluator (same units as [`KinF32`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct KinF64 {
    pub pos: f64,
    pub vel: f64,
    pub acc: f64,
    pub jerk: f64,
}

/// Kinematics from the fixed-point evaluator.
///
/// `pos` is Q16.16 steps; `vel`, `acc`, `jerk` are Q16.16 in steps/s,
/// steps/s², steps/s³ held in `i64` (value = raw / 65536), saturating at
/// `i64::MIN..=i64::MAX` for physically absurd inputs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct KinFx {
    pub pos: Fx,
    pub vel: i64,
    pub acc: i64,
    pub jerk: i64,
}

impl KinFx {
    /// Velocity in steps/s.
    pub fn vel_f64(&self) -> f64 {
        self.vel as f64 / 65536.0
    }
    /// Acceleration in steps/s².
    pub fn acc_f64(&self) -> f64 {
        self.acc as f64 / 65536.0
    }
    /// Jerk in steps/s³.
    pub fn jerk_f64(&self) -> f64 {
        self.jerk as f64 / 65536.0
    }
}

/// A control-point type a [`crate::Track`] can store and evaluate.
pub trait Point: Copy + Default {
    /// What an evaluation returns.
    type Kin: Copy + core::fmt::Debug;
    /// The point synthesized for a single missing stamp.
    fn midpoint(a: Self, b: Self) -> Self;
    /// Evaluate the segment `p` at `du` µs after its start, `0 <= du <= interval`.
    fn eval(p: &[Self; 4], du: u32, iv: Interval) -> Self::Kin;
    /// Velocity and acceleration (steps/s, steps/s²) as `f32`, to start a stop profile.
    fn vel_acc_f32(k: &Self::Kin) -> (f32, f32);
    /// `edge` moved by `dp` steps, with velocity, acceleration and jerk replaced.
    fn with_offset(edge: &Self::Kin, dp: f32, vel: f32, acc: f32, jerk: f32) -> Self::Kin;
}

impl Point for f32 {
    type Kin = KinF32;

    fn midpoint(a: f32, b: f32) -> f32 {
        0.5 * (a + b)
    }

    fn eval(p: &[f32; 4], du: u32, iv: Interval) -> KinF32 {
        let [p0, p1, p2, p3] = *p;
        let c0 = p0 + 4.0 * p1 + p2;
        let c1 = 3.0 * (p2 - p0);
        let c2 = 3.0 * (p0 - 2.0 * p1 + p2);
        let c3 = -p0 + 3.0 * p1 - 3.0 * p2 + p3;
        // du < 2^15 and the interval is a power of two: u is exact in f32.
        let u = du as f32 / iv.micros() as f32;
        let inv = 1.0e6 / iv.micros() as f32;
        let sixth = 1.0 / 6.0;
        KinF32 {
            pos: (c0 + u * (c1 + u * (c2 + u * c3))) * sixth,
            vel: (c1 + u * (2.0 * c2 + u * 3.0 * c3)) * sixth * inv,
            acc: (2.0 * c2 + 6.0 * c3 * u) * sixth * inv * inv,
            jerk: c3 * inv * inv * inv,
        }
    }

    fn vel_acc_f32(k: &KinF32) -> (f32, f32) {
        (k.vel, k.acc)
    }

    fn with_offset(edge: &KinF32, dp: f32, vel: f32, acc: f32, jerk: f32) -> KinF32 {
        KinF32 {
            pos: edge.pos + dp,
            vel,
            acc,
            jerk,
        }
    }
}

/// `round(x · u / 2^16)` with `u` a Q16 fraction in `0..=65536`; halves round up.
#[inline]
fn mul_q16(x: i64, u: i64) -> i64 {
    (x * u + (1 << 15)) >> 16
}

/// `round(x / 6)`; halves round up.
#[inline]
fn div6(x: i64) -> i64 {
    (x + 3).div_euclid(6)
}

/// `round(x · 10^6 / 2^shift)` computed as `x · 15625 / 2^(shift - 6)`
/// (exact factorization, `shift >= 8`), saturating.
#[inline]
fn per_second(x: i64, shift: u32) -> i64 {
    let s = shift - 6;
    x.saturating_mul(15625).saturating_add(1 << (s - 1)) >> s
}

impl Point for Fx {
    type Kin = KinFx;

    fn midpoint(a: Fx, b: Fx) -> Fx {
        // Exact in i64, then round half up.
        Fx(((a.0 as i64 + b.0 as i64 + 1) >> 1) as i32)
    }

    fn eval(p: &[Fx; 4], du: u32, iv: Interval) -> KinFx {
        let (p0, p1, p2, p3) = (p[0].0 as i64, p[1].0 as i64, p[2].0 as i64, p[3].0 as i64);
        let c0 = p0 + 4 * p1 + p2;
        let c1 = 3 * (p2 - p0);
        let c2 = 3 * (p0 - 2 * p1 + p2);
        let c3 = -p0 + 3 * p1 - 3 * p2 + p3;
        let shift = iv.shift();
        // The interval is 2^shift µs, shift <= 14: u in Q16 is a shift, exact.
        let u = (du as i64) << (16 - shift);
        // Horner, every product rounded: |error| <= 1.5 raw units in 6·p.
        let h = c2 + mul_q16(c3, u);
        let h = c1 + mul_q16(h, u);
        let pos6 = c0 + mul_q16(h, u);
        let vel6 = c1 + mul_q16(2 * c2 + mul_q16(3 * c3, u), u);
        let acc6 = 2 * c2 + mul_q16(6 * c3, u);
        let jerk6 = 6 * c3;
        KinFx {
            pos: Fx(div6(pos6) as i32),
            vel: div6(per_second(vel6, shift)),
            acc: div6(per_second(per_second(acc6, shift), shift)),
            jerk: div6(per_second(
                per_second(per_second(jerk6, shift), shift),
                shift,
            )),
        }
    }

    fn vel_acc_f32(k: &KinFx) -> (f32, f32) {
        (k.vel as f32 / 65536.0, k.acc as f32 / 65536.0)
    }

    fn with_offset(edge: &KinFx, dp: f32, vel: f32, acc: f32, jerk: f32) -> KinFx {
        let q = |x: f32| (x * 65536.0) as i64;
        KinFx {
            pos: Fx((edge.pos.0 as i64 + q(dp)).clamp(i32::MIN as i64, i32::MAX as i64) as i32),
            vel: q(vel),
            acc: q(acc),
            jerk: q(jerk),
        }
    }
}

/// `f64` reference evaluator on unquantized control points (steps), used to
/// measure the other two.
pub fn eval_f64(p: &[f64; 4], du: u32, iv: Interval) -> KinF64 {
    let [p0, p1, p2, p3] = *p;
    let c0 = p0 + 4.0 * p1 + p2;
    let c1 = 3.0 * (p2 - p0);
    let c2 = 3.0 * (p0 - 2.0 * p1 + p2);
    let c3 = -p0 + 3.0 * p1 - 3.0 * p2 + p3;
    let u = du as f64 / iv.micros() as f64;
    let inv = 1.0e6 / iv.micros() as f64;
    KinF64 {
        pos: (c0 + u * (c1 + u * (c2 + u * c3))) / 6.0,
        vel: (c1 + u * (2.0 * c2 + u * 3.0 * c3)) / 6.0 * inv,
        acc: (2.0 * c2 + 6.0 * c3 * u) / 6.0 * inv * inv,
        jerk: c3 * inv * inv * inv,
    }
}
