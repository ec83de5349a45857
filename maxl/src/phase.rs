//! Phase output: two coil amplitudes from a fixed-point position, for driving
//! a stepper's coils directly (microstepping from a sine table), integer only.
//!
//! One full step is 90° electrical, four full steps one electrical period.
//! With `p` in Q16.16 steps, the low 16 bits are the angle inside a quarter
//! period and bits 16–17 the quadrant, so no multiply is needed to find the
//! angle. Coil A follows `cos θ`, coil B `sin θ`.
//!
//! The table [`QUARTER_SINE`] holds `sin` over one quarter period in 256
//! intervals (257 entries, `round(32768 · sin(π/2 · i/256))`, Q15 with 1.0 =
//! 32768), computed at compile time. Between entries the value is linearly
//! interpolated with the next 8 bits of the angle. The unit amplitude
//! ([`unit`]) is within 1.16 Q15 LSB (3.5e-5 of full scale) of the exact
//! sine and cosine: table rounding ½, interpolation `(π/512)²/8 · 32768 =
//! 0.154`, interpolation rounding ½ (tested over every angle of a period;
//! measured 1.001). See `docs/maxl.md`.

use crate::eval::Fx;

/// Table intervals per quarter period.
pub const TABLE_STEPS: usize = 256;
/// Full scale of the table (1.0 in Q15).
pub const UNIT: i32 = 1 << 15;

/// `sin` by its Taylor series, for `x` in `[0, π/2]` (error < 1e-16 there);
/// only used at compile time.
const fn sin_taylor(x: f64) -> f64 {
    let x2 = x * x;
    let mut term = x;
    let mut sum = x;
    let mut n = 1.0;
    let mut k = 0;
    while k < 12 {
        term = -term * x2 / ((n + 1.0) * (n + 2.0));
        sum += term;
        n += 2.0;
        k += 1;
    }
    sum
}

const fn build_table() -> [u16; TABLE_STEPS + 1] {
    let mut t = [0u16; TABLE_STEPS + 1];
    let mut i = 0;
    while i <= TABLE_STEPS {
        let x = core::f64::consts::FRAC_PI_2 * i as f64 / TABLE_STEPS as f64;
        t[i] = (sin_taylor(x) * UNIT as f64 + 0.5) as u16;
        i += 1;
    }
    t
}

/// `sin` over one quarter period, Q15 (`32768 = 1.0`), 257 entries.
pub static QUARTER_SINE: [u16; TABLE_STEPS + 1] = build_table();

/// `sin(π/2 · f / 65536)` in Q15 for `f` in `0..=65536`, interpolated.
#[inline]
fn quarter(f: u32) -> i32 {
    let i = (f >> 8) as usize;
    let frac = (f & 0xFF) as i32;
    let a = QUARTER_SINE[i] as i32;
    if frac == 0 {
        return a;
    }
    let b = QUARTER_SINE[i + 1] as i32;
    a + (((b - a) * frac + 128) >> 8)
}

/// Coil amplitudes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Coils {
    /// Coil A (`cos θ`).
    pub a: i32,
    /// Coil B (`sin θ`).
    pub b: i32,
}

/// Unit amplitudes `(cos θ, sin θ)` in Q15 (±32768) for position `p`.
#[inline]
pub fn unit(p: Fx) -> Coils {
    let f = p.0 as u32 & 0xFFFF;
    let s = quarter(f);
    let c = quarter(0x1_0000 - f);
    match (p.0 >> 16) & 3 {
        0 => Coils { a: c, b: s },
        1 => Coils { a: -s, b: c },
        2 => Coils { a: -c, b: -s },
        _ => Coils { a: s, b: -c },
    }
}

/// Coil amplitudes scaled to a peak value (a current in driver units or a
/// PWM range).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct PhaseOut {
    peak: u16,
}

impl PhaseOut {
    /// Outputs swing between `-peak` and `peak` (e.g. 1000 for a PWM top of
    /// 1000, or a DAC code for the full current).
    pub fn new(peak: u16) -> Self {
        PhaseOut { peak }
    }

    /// The peak value.
    pub fn peak(&self) -> u16 {
        self.peak
    }

    /// Change the peak (e.g. reduce the hold current).
    pub fn set_peak(&mut self, peak: u16) {
        self.peak = peak;
    }

    /// Coil amplitudes for position `p`: `round(unit · peak / 32768)`,
    /// halves rounded up. `|unit · peak| < 2³¹`, so this is one 32-bit
    /// multiply per coil.
    #[inline]
    pub fn coils(&self, p: Fx) -> Coils {
        let u = unit(p);
        let k = self.peak as i32;
        Coils {
            a: (u.a * k + (1 << 14)) >> 15,
            b: (u.b * k + (1 << 14)) >> 15,
        }
    }
}
