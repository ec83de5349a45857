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

/// Position in steps as signed Q16.16 fixed point: `steps = raw / 65536`,
/// resolution 1/65536 step (1.53e-5 step).
///
/// The value wraps: a position is known modulo 65 536 steps, and every
/// operation on positions (evaluation, the tick evaluator, midpoints, the
/// limiter, step counting) works on differences taken with wrapping
/// arithmetic. So an axis has no end: a track may run through ±32 768 steps
/// and on, as long as neighbouring control points are less than 32 768
/// steps apart (at 100 kHz and 16 ms intervals a point moves at most
/// 1 600 steps). Where the axis is in whole steps is counted by the step
/// generator ([`crate::step::StepGen::position`], an `i64`).
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

    /// Nearest Q16.16 value to `steps`, wrapped modulo 65 536 steps (see
    /// the type's docs): the position of an axis that has gone further.
    /// Exact for any `|steps| < 2^47`; `None` for a value that is not
    /// finite or beyond that.
    pub fn wrapping_from_f64(steps: f64) -> Option<Self> {
        let r = steps * 65536.0;
        if !(r.is_finite() && r.abs() < 9.0e18) {
            return None;
        }
        let r = if r >= 0.0 { r + 0.5 } else { r - 0.5 };
        Some(Fx(r as i64 as i32))
    }

    /// `self − other` in raw units, for positions less than 32 768 steps
    /// apart (wrapping).
    #[inline]
    pub fn wrapping_diff(self, other: Fx) -> i32 {
        self.0.wrapping_sub(other.0)
    }

    /// Value in steps.
    pub fn to_f64(self) -> f64 {
        self.0 as f64 / 65536.0
    }
}

/// Kinematics from the `f32` evaluator: steps, steps/s, steps/s², steps/s³.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct KinF32 {
    /// Position, steps.
    pub pos: f32,
    /// Velocity, steps/s.
    pub vel: f32,
    /// Acceleration, steps/s².
    pub acc: f32,
    /// Jerk, steps/s³.
    pub jerk: f32,
}

/// Kinematics from the `f64` reference evaluator (same units as [`KinF32`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct KinF64 {
    /// Position, steps.
    pub pos: f64,
    /// Velocity, steps/s.
    pub vel: f64,
    /// Acceleration, steps/s².
    pub acc: f64,
    /// Jerk, steps/s³.
    pub jerk: f64,
}

/// Kinematics from the fixed-point evaluator.
///
/// `pos` is Q16.16 steps; `vel`, `acc`, `jerk` are Q16.16 in steps/s,
/// steps/s², steps/s³ held in `i64` (value = raw / 65536), saturating at
/// `i64::MIN..=i64::MAX` for physically absurd inputs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct KinFx {
    /// Position, Q16.16 steps.
    pub pos: Fx,
    /// Velocity, Q16.16 steps/s.
    pub vel: i64,
    /// Acceleration, Q16.16 steps/s².
    pub acc: i64,
    /// Jerk, Q16.16 steps/s³.
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
    floor_div6(x.saturating_add(3))
}

/// `y mod 3` in `0..3` for any `i64`, with shifts and adds only (Cortex-M0+
/// has no divider; a library 64-bit division costs about 1000 cycles).
#[inline]
#[cfg_attr(target_pointer_width = "64", allow(dead_code))]
fn rem3(y: i64) -> u32 {
    let u = y as u64;
    // 2^32 ≡ 2^16 ≡ 2^8 ≡ 2^4 ≡ 2^2 ≡ 1 (mod 3): fold the digits.
    let mut a = (u >> 32) + (u & 0xFFFF_FFFF);
    a = (a >> 32) + (a & 0xFFFF_FFFF);
    a = (a >> 32) + (a & 0xFFFF_FFFF);
    let mut b = a as u32;
    b = (b >> 16) + (b & 0xFFFF);
    b = (b >> 8) + (b & 0xFF);
    b = (b >> 4) + (b & 0xF);
    b = (b >> 2) + (b & 3);
    b = (b >> 2) + (b & 3);
    b = (b >> 2) + (b & 3);
    b = (b >> 2) + (b & 3);
    // b <= 3 now. 2^64 ≡ 1 (mod 3): a negative y is u - 2^64 ≡ u - 1.
    // A table, not `% 3`: the compiler would call a library division.
    const MOD3: [u8; 7] = [0, 1, 2, 0, 1, 2, 0];
    MOD3[(b + 3 - (y < 0) as u32) as usize] as u32
}

/// `floor(x / 6)`: the compiler's division on 64-bit hosts (a multiply by
/// a magic constant there), [`floor_div6_narrow`] on 32-bit targets.
#[inline]
fn floor_div6(x: i64) -> i64 {
    #[cfg(target_pointer_width = "64")]
    {
        x.div_euclid(6)
    }
    #[cfg(not(target_pointer_width = "64"))]
    {
        floor_div6_narrow(x)
    }
}

/// `floor(x / 6)` without a division: `floor(floor(x/2)/3)`, the last as an
/// exact division by 3 (multiplying by its inverse modulo 2^64).
#[inline]
#[cfg_attr(target_pointer_width = "64", allow(dead_code))]
fn floor_div6_narrow(x: i64) -> i64 {
    let y = x >> 1;
    let e = (y - rem3(y) as i64) as u64;
    // e · 0xAAAA_AAAA_AAAA_AAAB (the inverse of 3) modulo 2^64, from 32-bit
    // halves: the library 64-bit multiply costs over 100 cycles on M0+.
    const LO: u32 = 0xAAAA_AAAB;
    const HI: u32 = 0xAAAA_AAAA;
    let (el, eh) = (e as u32, (e >> 32) as u32);
    let cross = el.wrapping_mul(HI).wrapping_add(eh.wrapping_mul(LO));
    umul_wide(el, LO).wrapping_add((cross as u64) << 32) as i64
}

/// `round(x · 10^6 / 2^shift)` computed as `x · 15625 / 2^(shift - 6)`
/// (exact factorization, `shift >= 8`), saturating.
#[inline]
fn per_second(x: i64, shift: u32) -> i64 {
    let s = shift - 6;
    x.saturating_mul(15625).saturating_add(1 << (s - 1)) >> s
}

/// `P0`, `P2` and `P3` relative to `P1`, by wrapping differences (see
/// [`Fx`]): the segment as every evaluator takes it.
#[inline(always)]
fn relative(p: &[Fx; 4]) -> (i64, i64, i64) {
    let base = p[1];
    (
        p[0].wrapping_diff(base) as i64,
        p[2].wrapping_diff(base) as i64,
        p[3].wrapping_diff(base) as i64,
    )
}

impl Point for Fx {
    type Kin = KinFx;

    fn midpoint(a: Fx, b: Fx) -> Fx {
        // a + ⌊(b − a + 1) / 2⌋ = ⌊(a + b + 1) / 2⌋, round half up, on the
        // wrapping difference.
        Fx(a.0.wrapping_add(((b.wrapping_diff(a) as i64 + 1) >> 1) as i32))
    }

    fn eval(p: &[Fx; 4], du: u32, iv: Interval) -> KinFx {
        // Relative to P1 (wrapping differences), then P1 added back with a
        // wrapping add: exact modulo 2^32 raw, so the track may run through
        // the ends of the i32 range.
        let base = p[1];
        let (p0, p2, p3) = relative(p);
        let p1 = 0i64;
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
            pos: Fx(base.0.wrapping_add(div6(pos6) as i32)),
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
            pos: Fx(edge.pos.0.wrapping_add(q(dp) as i32)),
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

/// Fractional bits of [`TickEval`]'s accumulators below one `Fx` raw unit.
const TICK_FRAC: u32 = 32;

/// Most ticks one segment may hold in a [`TickEval`]: keeps its error
/// within 1/6 raw unit (see [`TickEval`]).
pub const MAX_TICKS_PER_SEGMENT: u32 = 2048;

/// Why a [`TickEval`] refused a configuration or a segment.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum TickEvalError {
    /// The tick period is 0, longer than the interval, or gives more than
    /// [`MAX_TICKS_PER_SEGMENT`] ticks per segment.
    TickPeriod {
        /// The tick period asked for, µs.
        tick_us: u32,
    },
    /// The first tick's offset is not inside the segment (`du0 >= Δt`).
    Offset {
        /// The offset asked for, µs.
        du0: u32,
    },
}

impl core::fmt::Display for TickEvalError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            TickEvalError::TickPeriod { tick_us } => write!(
                f,
                "tick period {tick_us} µs must be 1..=Δt with at most {MAX_TICKS_PER_SEGMENT} ticks per segment"
            ),
            TickEvalError::Offset { du0 } => write!(f, "first tick offset {du0} µs is not inside the segment"),
        }
    }
}

impl core::error::Error for TickEvalError {}

/// Fast fixed-point position evaluator for a fixed tick (e.g. 10 µs = 100 kHz).
///
/// [`TickEval::load`] takes one segment's four `Fx` points and the offset of
/// its first tick, and computes (exactly, in `i128`) the position and its
/// first three forward differences over one tick, rounded once to Q.32 below
/// the `Fx` raw unit (`i64`, Q16.48 steps). Each [`TickEval::next`] then
/// costs three wrapping 64-bit additions and returns the high word: no
/// multiply, no division, no FPU.
///
/// Error: the exact spline of the `Fx` points is a cubic in the tick index
/// `k`, so `p_k = p_0 + k·d1 + C(k,2)·d2 + C(k,3)·d3` with only the four
/// loaded values rounded (each by ≤ 2⁻³³ raw). For `k < 2048` this adds at
/// most `½(1 + k + C(k,2) + C(k,3))·2⁻³² < 0.167` raw units; the output
/// rounding adds ½. So the result is within **0.667 LSB** of the exact spline
/// of the quantized points, and within **1.167 LSB** of `eval_f64` on the
/// unquantized points. Re-loading every segment re-anchors it: nothing
/// accumulates across segments.
///
/// The position accumulator carries a +½ raw bias so the output is its high
/// word (round half up); with the error above it cannot wrap for any `i32`
/// points. The difference accumulators may wrap in absurd inputs (a whole
/// `Fx` range per tick); wrapping arithmetic is exact modulo 2⁶⁴, so the
/// position stays right whenever the true position fits in `Fx`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TickEval {
    p: i64,
    d1: i64,
    d2: i64,
    d3: i64,
    left: u32,
    shift: u32,
    tick_us: u32,
    next_du: u32,
    /// `Δt / tick` and `Δt % tick`: the tick count without a division when
    /// `du0 < tick` (always, after the first segment).
    per_seg: u32,
    rem: u32,
}

/// `round(y · 2^32 / (6 · 2^(3 shift)))`, halves up, truncated to `i64`
/// (wrapping: see [`TickEval`]).
fn to_q32(y: i128, shift: u32) -> i64 {
    let e = 3 * shift as i32 - TICK_FRAC as i32;
    let (num, den) = if e <= 0 {
        (y << (-e) as u32, 6i128)
    } else {
        (y, 6i128 << e as u32)
    };
    (num + den / 2).div_euclid(den) as i64
}

/// `a · b` for 32-bit operands, as four 16×16 products: Cortex-M0+ `MULS`
/// gives only the low 32 bits, and the library 64-bit multiply costs more.
#[inline(always)]
fn umul_wide(a: u32, b: u32) -> u64 {
    let (a0, a1) = (a & 0xFFFF, a >> 16);
    let (b0, b1) = (b & 0xFFFF, b >> 16);
    let (mid, carry) = (a0 * b1).overflowing_add(a1 * b0);
    let lo = (a0 * b0) as u64 + ((mid as u64) << 16);
    lo + (((a1 * b1) as u64 + ((carry as u64) << 16)) << 32)
}

/// `c · k` for `|c| < 2^27`, `k < 2^36` (so `|c·k| < 2^63`).
#[inline(always)]
fn mul_ck(c: i64, k: u64) -> i64 {
    let m = c.unsigned_abs() as u32;
    let p = umul_wide(m, k as u32) + (((m * (k >> 32) as u32) as u64) << 32);
    if c < 0 {
        -(p as i64)
    } else {
        p as i64
    }
}

/// `x << n` for `n < 32` without a library 64-bit shift.
#[inline(always)]
fn shl_wide(x: u32, n: u32) -> u64 {
    if n == 0 {
        x as u64
    } else {
        (((x >> (32 - n)) as u64) << 32) | (x << n) as u64
    }
}

/// `round(Σ c_j·k_j · 2^32 / (6·2^(3s)))`, halves up, in `i64`: valid for
/// `|c_j| < 2^27` and `Σ k_j <= 14·2^(3s)` (so no sum exceeds 14·2^59).
fn q32_small(c: &[i64; 4], k: &[u64; 4], shift: u32) -> i64 {
    let z = 3 * shift as i32 - TICK_FRAC as i32;
    let x = if z <= 0 {
        let sh = (-z) as u32;
        let mut acc = 3i64;
        for j in 0..4 {
            if k[j] != 0 {
                acc += mul_ck(c[j], k[j] << sh);
            }
        }
        acc
    } else {
        // Split k_j = 2^z·q_j + r_j so the products stay small:
        // floor((Σ c k + 3·2^z) / 2^z) = Σ c q + floor((Σ c r + 3·2^z) / 2^z).
        let z = z as u32;
        let mask = (1u64 << z) - 1;
        let (mut q, mut r) = (0i64, 3i64 << z);
        for j in 0..4 {
            if k[j] != 0 {
                q += mul_ck(c[j], k[j] >> z);
                r += mul_ck(c[j], k[j] & mask);
            }
        }
        q + (r >> z)
    };
    floor_div6(x)
}

impl TickEval {
    /// An evaluator for ticks every `tick_us` µs on segments of `iv`.
    pub fn new(iv: Interval, tick_us: u32) -> Result<Self, TickEvalError> {
        if tick_us == 0
            || tick_us > iv.micros()
            || iv.micros().div_ceil(tick_us) > MAX_TICKS_PER_SEGMENT
        {
            return Err(TickEvalError::TickPeriod { tick_us });
        }
        Ok(TickEval {
            p: 0,
            d1: 0,
            d2: 0,
            d3: 0,
            left: 0,
            shift: iv.shift(),
            tick_us,
            next_du: 0,
            per_seg: iv.micros() / tick_us,
            rem: iv.micros() % tick_us,
        })
    }

    /// The tick period in µs.
    pub fn tick_us(&self) -> u32 {
        self.tick_us
    }

    /// Load the segment `p` (`P_{i-1}..P_{i+2}`) with its first tick `du0`
    /// µs after the segment's start. Per-segment setup, `i128` arithmetic.
    pub fn load(&mut self, p: &[Fx; 4], du0: u32) -> Result<(), TickEvalError> {
        let len = 1u32 << self.shift;
        if du0 >= len {
            return Err(TickEvalError::Offset { du0 });
        }
        if !self.load_fast(p, du0) {
            self.load_wide(p, du0);
        }
        // ceil((Δt − du0) / tick) = per_seg + (rem > du0) when du0 < tick.
        let n = if du0 < self.tick_us {
            self.per_seg + (self.rem > du0) as u32
        } else {
            (len - du0).div_ceil(self.tick_us)
        };
        self.left = n;
        self.next_du = du0 + n * self.tick_us - len;
        Ok(())
    }

    /// Setup in `i64` when the segment's differences are below 2^27 raw
    /// (2048 steps): then every sum below is under 14·2^59 (no overflow).
    /// Same results as [`TickEval::load_wide`], bit for bit.
    fn load_fast(&mut self, p: &[Fx; 4], du0: u32) -> bool {
        // Relative to P1 by wrapping differences (see [`Fx`]).
        let base = p[1];
        let (p0, p2, p3) = relative(p);
        let p1 = 0i64;
        // e0 = c0 − 6·P1: the position relative to P1 keeps the sums small.
        let c = [
            p0 - 2 * p1 + p2,
            3 * (p2 - p0),
            3 * (p0 - 2 * p1 + p2),
            -p0 + 3 * p1 - 3 * p2 + p3,
        ];
        const LIM: i64 = 1 << 27;
        if c.iter().any(|x| *x >= LIM || *x <= -LIM) {
            return false;
        }
        let s = self.shift;
        // d, h < 2^15: products of two fit in u32 (one MULS on Cortex-M0+);
        // powers of two are shifts.
        let (d, h) = (du0, self.tick_us);
        let (d2, dh, h2) = (d * d, d * h, h * h);
        let h3 = umul_wide(h2, h);
        let k0 = [
            1u64 << (3 * s),
            shl_wide(d, 2 * s),
            shl_wide(d2, s),
            umul_wide(d2, d),
        ];
        let k1 = [
            0,
            shl_wide(h, 2 * s),
            shl_wide(2 * dh + h2, s),
            // The small factors go into the 32-bit operands (3·d², 3·dh,
            // 6·dh, 6·h² < 2^31): a 64-bit multiply by a constant would be a
            // library call on M0+.
            umul_wide(3 * d2, h) + umul_wide(3 * dh, h) + h3,
        ];
        let h3x6 = umul_wide(6 * h2, h);
        let k2 = [0, 0, shl_wide(h2, s + 1), umul_wide(6 * dh, h) + h3x6];
        let k3 = [0, 0, 0, h3x6];
        let base = (base.0 as i64) << TICK_FRAC;
        self.p = base
            .wrapping_add(q32_small(&c, &k0, s))
            .wrapping_add(1 << (TICK_FRAC - 1));
        self.d1 = q32_small(&c, &k1, s);
        self.d2 = q32_small(&c, &k2, s);
        self.d3 = q32_small(&c, &k3, s);
        true
    }

    /// Setup in `i128`, for any `Fx` points.
    fn load_wide(&mut self, p: &[Fx; 4], du0: u32) {
        // Relative to P1 by wrapping differences, P1 added back below.
        let base = p[1];
        let (p0, p2, p3) = relative(p);
        let (p0, p1, p2, p3) = (p0 as i128, 0i128, p2 as i128, p3 as i128);
        let c0 = p0 + 4 * p1 + p2;
        let c1 = 3 * (p2 - p0);
        let c2 = 3 * (p0 - 2 * p1 + p2);
        let c3 = -p0 + 3 * p1 - 3 * p2 + p3;
        let s = self.shift;
        let (s1, s2, s3) = (1i128 << s, 1i128 << (2 * s), 1i128 << (3 * s));
        let (d, h) = (du0 as i128, self.tick_us as i128);
        // 6·2^(3s)·p at t = d + k h is an integer cubic in k; these are its
        // value and forward differences at k = 0, exactly.
        let y0 = c0 * s3 + c1 * d * s2 + c2 * d * d * s1 + c3 * d * d * d;
        let y1 = c1 * h * s2
            + c2 * (2 * d * h + h * h) * s1
            + c3 * (3 * d * d * h + 3 * d * h * h + h * h * h);
        let y2 = c2 * 2 * h * h * s1 + c3 * (6 * d * h * h + 6 * h * h * h);
        let y3 = 6 * c3 * h * h * h;
        self.p = ((base.0 as i64) << TICK_FRAC)
            .wrapping_add(to_q32(y0, s))
            .wrapping_add(1 << (TICK_FRAC - 1));
        self.d1 = to_q32(y1, s);
        self.d2 = to_q32(y2, s);
        self.d3 = to_q32(y3, s);
    }

    /// Ticks left in the loaded segment.
    pub fn remaining(&self) -> u32 {
        self.left
    }

    /// Offset (µs) of the first tick in the following segment; meaningful
    /// once [`TickEval::remaining`] is 0.
    pub fn next_offset(&self) -> u32 {
        self.next_du
    }
}

/// Each item is the position at the current tick (then the evaluator
/// advances one tick); `None` when the loaded segment has no tick left: load
/// the next one and iterate again.
impl Iterator for TickEval {
    type Item = Fx;

    #[inline]
    fn next(&mut self) -> Option<Fx> {
        if self.left == 0 {
            return None;
        }
        self.left -= 1;
        let out = (self.p >> TICK_FRAC) as i32;
        self.p = self.p.wrapping_add(self.d1);
        self.d1 = self.d1.wrapping_add(self.d2);
        self.d2 = self.d2.wrapping_add(self.d3);
        Some(Fx(out))
    }
}

#[cfg(test)]
#[allow(unreachable_pub)] // the shared test generators below are `pub` for the integration tests
mod tests {
    use super::*;
    use osap_core::time::SystemInstant;
    use std::vec::Vec;

    // The test generators the integration tests share (`Lcg` here).
    include!(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/common/rng.rs"));

    /// `3·|out·M − Y|` and `3·M`, `M = 6·2^(3s)`: the exact spline of the
    /// `Fx` points at `du` compared with `out` in thirds of a raw unit.
    fn exact_gap(p: &[Fx; 4], du: u32, s: u32, out: Fx) -> (i128, i128) {
        let q = |i: usize| p[i].0 as i128;
        let c0 = q(0) + 4 * q(1) + q(2);
        let c1 = 3 * (q(2) - q(0));
        let c2 = 3 * (q(0) - 2 * q(1) + q(2));
        let c3 = -q(0) + 3 * q(1) - 3 * q(2) + q(3);
        let t = du as i128;
        let y = (c0 << (3 * s)) + ((c1 * t) << (2 * s)) + ((c2 * t * t) << s) + c3 * t * t * t;
        let m = 6i128 << (3 * s);
        (3 * (out.0 as i128 * m - y).abs(), 3 * m)
    }

    #[test]
    fn division_by_six_without_a_divider() {
        let mut rng = Lcg(5);
        let mut xs = std::vec![
            0i64,
            1,
            2,
            3,
            5,
            6,
            -1,
            -2,
            -3,
            -5,
            -6,
            -7,
            i64::MAX,
            i64::MIN,
            i64::MAX - 3
        ];
        for _ in 0..200_000 {
            let x = ((rng.next() << 31) ^ rng.next() ^ (rng.next() << 62)) as i64;
            xs.push(x);
            xs.push(x >> (rng.next() % 63));
        }
        for x in xs {
            assert_eq!(rem3(x) as i64, x.rem_euclid(3), "rem3 {x}");
            assert_eq!(floor_div6_narrow(x), x.div_euclid(6), "floor_div6 {x}");
            assert_eq!(floor_div6(x), x.div_euclid(6));
            if x < i64::MAX - 3 {
                assert_eq!(div6(x), (x + 3).div_euclid(6));
            }
        }
    }

    /// The `i64` setup gives the `i128` setup's values, bit for bit, over
    /// every interval, several tick periods and differences up to its limit.
    #[test]
    fn fast_setup_matches_wide_setup() {
        let mut rng = Lcg(21);
        let mut fast_used = 0;
        for round in 0..20_000u64 {
            let s = 8 + (round % 7) as u32;
            let iv = Interval::from_micros(1 << s).unwrap();
            let min_h = (1u32 << s).div_ceil(MAX_TICKS_PER_SEGMENT);
            let h = min_h + (rng.next() % ((1u64 << s) - min_h as u64 + 1)) as u32;
            let h = if round % 4 == 0 { min_h } else { h };
            let span = 1u64 << (10 + rng.next() % 17);
            let base = rng.next() as i64 - (1 << 31);
            let p: [Fx; 4] = core::array::from_fn(|_| {
                Fx((base + (rng.next() % span) as i64 - (span / 2) as i64)
                    .clamp(i32::MIN as i64, i32::MAX as i64) as i32)
            });
            let du0 = if round % 5 == 0 {
                (1 << s) - 1
            } else {
                (rng.next() % (1 << s)) as u32
            };
            let mut a = TickEval::new(iv, h).unwrap();
            let mut b = a;
            if a.load_fast(&p, du0) {
                fast_used += 1;
                b.load_wide(&p, du0);
                assert_eq!(
                    (a.p, a.d1, a.d2, a.d3),
                    (b.p, b.d1, b.d2, b.d3),
                    "s={s} h={h} du0={du0} {p:?}"
                );
            }
        }
        assert!(fast_used > 15_000, "{fast_used}");
    }

    #[test]
    fn tick_eval_config_errors() {
        let iv = Interval::from_micros(16384).unwrap();
        assert_eq!(
            TickEval::new(iv, 0),
            Err(TickEvalError::TickPeriod { tick_us: 0 })
        );
        assert_eq!(
            TickEval::new(iv, 7),
            Err(TickEvalError::TickPeriod { tick_us: 7 })
        );
        assert!(TickEval::new(iv, 8).is_ok());
        let iv = Interval::from_micros(256).unwrap();
        assert!(TickEval::new(iv, 257).is_err());
        let mut e = TickEval::new(iv, 1).unwrap();
        assert_eq!(
            e.load(&[Fx(0); 4], 256),
            Err(TickEvalError::Offset { du0: 256 })
        );
        assert_eq!(e.next(), None);
    }

    /// Random segments over the whole `Fx` range, every tick compared with
    /// the exact spline (≤ 2/3 raw) and `eval_f64` on the unquantized points
    /// (≤ 1.167 raw), and the tick bookkeeping.
    /// Positions wrap (see `Fx`): a segment through the end of the `i32`
    /// range evaluates, by either evaluator, to the same positions as the
    /// same segment moved away from it, moved back (modulo 2^32 raw).
    #[test]
    fn a_segment_through_the_end_of_the_range_wraps_exactly() {
        let iv = Interval::from_micros(1 << 12).unwrap();
        let mut rng = Lcg(23);
        for _ in 0..500 {
            // Four points around the wrap, up to 2 048 steps apart.
            let near = [0, 1, 2, 3].map(|_| rng.range(1 << 28) as i64 - (1 << 27));
            let shift = rng.range(1 << 32) as i64;
            let at = |off: i64| near.map(|v| Fx((v + off) as i32));
            let wrapped = at(i32::MAX as i64 + shift);
            let plain = at(0);
            let moved = |x: Fx| Fx(x.0.wrapping_sub((i32::MAX as i64 + shift) as i32));
            let du0 = rng.range(1 << 12) as u32;
            let (mut a, mut b) = (
                TickEval::new(iv, 10).unwrap(),
                TickEval::new(iv, 10).unwrap(),
            );
            a.load(&wrapped, du0).unwrap();
            b.load(&plain, du0).unwrap();
            for (x, y) in a.by_ref().zip(b.by_ref()) {
                assert_eq!(moved(x), y);
            }
            let du = rng.range(1 << 12) as u32;
            let (kw, kp) = (Fx::eval(&wrapped, du, iv), Fx::eval(&plain, du, iv));
            assert_eq!(moved(kw.pos), kp.pos);
            assert_eq!((kw.vel, kw.acc, kw.jerk), (kp.vel, kp.acc, kp.jerk));
            assert_eq!(
                moved(Fx::midpoint(wrapped[0], wrapped[1])),
                Fx::midpoint(plain[0], plain[1])
            );
        }
    }

    #[test]
    fn tick_eval_error_bound_random_segments() {
        let mut rng = Lcg(11);
        let mut worst_exact = 0.0f64;
        let mut worst_f64 = 0.0f64;
        for round in 0..3000 {
            let s = 8 + (round % 7) as u32;
            let iv = Interval::from_micros(1 << s).unwrap();
            let min_h = (1u32 << s).div_ceil(MAX_TICKS_PER_SEGMENT);
            let h = match round % 3 {
                0 => 10.max(min_h),
                1 => min_h,
                _ => min_h + rng.range((1u64 << s) - min_h as u64 + 1) as u32,
            };
            let mut e = TickEval::new(iv, h).unwrap();
            // Wide points for some rounds (up to 16 384 steps apart, half
            // the most neighbouring points may be apart: positions wrap,
            // see `Fx`), small moves for others.
            let span = if round % 2 == 0 { 1u64 << 30 } else { 1 << 24 };
            let base = rng.range(3 << 30) as i64 - (1 << 31);
            let mut f = [0.0f64; 4];
            let mut p = [Fx(0); 4];
            for i in 0..4 {
                let v = base + rng.range(span) as i64;
                let v = v.clamp(i32::MIN as i64 + 1, i32::MAX as i64 - 1);
                // Unquantized point within ½ raw of the stored one.
                f[i] = (v as f64 + (rng.range(1001) as f64 - 500.0) / 1000.0) / 65536.0;
                p[i] = Fx::from_f64(f[i]);
            }
            let du0 = rng.range(1 << s) as u32;
            e.load(&p, du0).unwrap();
            let n = ((1u32 << s) - du0).div_ceil(h);
            assert_eq!(e.remaining(), n);
            let mut k = 0;
            for out in e.by_ref() {
                let du = du0 + k * h;
                assert!(du < 1 << s);
                let (gap, m3) = exact_gap(&p, du, s, out);
                assert!(gap * 3 <= 2 * m3, "exact gap {gap}/{m3} s={s} h={h} k={k}");
                worst_exact = worst_exact.max(gap as f64 / m3 as f64);
                let r = eval_f64(&f, du, iv).pos;
                let err = (out.to_f64() - r).abs() * 65536.0;
                assert!(err <= 1.167, "f64 error {err} LSB s={s} h={h} k={k}");
                worst_f64 = worst_f64.max(err);
                k += 1;
            }
            assert_eq!(k, n);
            assert_eq!(e.next_offset(), du0 + n * h - (1 << s));
            assert!(e.next_offset() < h);
        }
        std::println!("worst vs exact {worst_exact:.4} LSB, vs f64 {worst_f64:.4} LSB");
    }

    /// `TickEval` driven across segments of a track (re-anchored each
    /// segment, tick grid not aligned with the segments): agrees with
    /// `eval_f64` to ≤ 1.167 LSB from the first segment to the last.
    fn tick_stream(n_points: u64, us: u32, tick_us: u32) -> (f64, f64, Vec<Fx>) {
        use crate::{BackstopLimits, Track};
        let iv = Interval::from_micros(us).unwrap();
        let dt = us as f64 * 1e-6;
        let sig = |k: u64| {
            let t = k as f64 * dt;
            12000.0 * (0.37 * t).sin() + 6000.0 * (2.3 * t + 1.0).sin() + 800.0 * (19.0 * t).sin()
        };
        let lim = BackstopLimits {
            max_acc: 1e4,
            max_jerk: 1e6,
        };
        let mut tr: Track<Fx, 16> = Track::new(iv, lim);
        let mut e = TickEval::new(iv, tick_us).unwrap();
        let t0 = (1u64 << 40) & !(us as u64 - 1);
        let mut next = 0u64;
        let mut t = t0 + us as u64;
        let (mut e_first, mut e_last) = (0.0f64, 0.0f64);
        let mut out = Vec::new();
        let end = t0 + (n_points - 3) * us as u64;
        while t < end {
            while next * (us as u64) + t0 <= t + 2 * us as u64 {
                tr.push(
                    SystemInstant::from_micros(t0 + next * us as u64),
                    Fx::from_f64(sig(next)),
                )
                .unwrap();
                next += 1;
            }
            let pos = match e.next() {
                Some(p) => p,
                None => {
                    let (seg, du) = tr.segment_at(SystemInstant::from_micros(t)).unwrap();
                    if e.next_offset() != 0 || du != 0 {
                        // After the first load the grid carries over exactly.
                        assert!(t == t0 + us as u64 || du == e.next_offset());
                    }
                    e.load(&seg, du).unwrap();
                    e.next().unwrap()
                }
            };
            let i = (t - t0) / us as u64;
            let du = ((t - t0) % us as u64) as u32;
            let r = eval_f64(&[sig(i - 1), sig(i), sig(i + 1), sig(i + 2)], du, iv).pos;
            let err = (pos.to_f64() - r).abs() * 65536.0;
            let frac = (t - t0) as f64 / (end - t0) as f64;
            if frac < 0.1 {
                e_first = e_first.max(err);
            }
            if frac > 0.9 {
                e_last = e_last.max(err);
            }
            if out.len() < 4096 {
                out.push(pos);
            }
            t += tick_us as u64;
        }
        (e_first, e_last, out)
    }

    #[test]
    fn tick_eval_stream_bound() {
        for (us, tick) in [(256, 10), (1024, 10), (1024, 7), (16384, 10), (16384, 8)] {
            let n = 4_000_000 / us as u64 + 20;
            let (a, b, _) = tick_stream(n, us, tick);
            std::println!("{us} µs / {tick} µs ticks: first {a:.3} last {b:.3} LSB");
            assert!(a <= 1.167 && b <= 1.167, "{a} {b}");
        }
    }

    /// One hour at 1024 µs with 100 kHz ticks (360 M ticks). Run with
    /// `cargo test -p maxl --release --lib -- --ignored tick_eval_hour --nocapture`.
    #[test]
    #[ignore]
    fn tick_eval_hour() {
        let (a, b, _) = tick_stream(3_600_000_000 / 1024, 1024, 10);
        std::println!("1 h: first {a:.3} last {b:.3} LSB");
        assert!(a <= 1.167 && b <= 1.167);
    }

    #[test]
    fn tick_eval_matches_point_eval_closely() {
        let iv = Interval::from_micros(1024).unwrap();
        let p = [Fx(-7 << 16), Fx(3 << 16), Fx(40 << 16), Fx(41 << 16)];
        let mut e = TickEval::new(iv, 10).unwrap();
        e.load(&p, 3).unwrap();
        let mut du = 3;
        for x in e.by_ref() {
            let y = Fx::eval(&p, du, iv).pos;
            assert!((x.0 - y.0).abs() <= 1, "{x:?} {y:?} at {du}");
            du += 10;
        }
        assert_eq!(du, 1033);
        assert_eq!(e.next_offset(), 9);
    }
}
