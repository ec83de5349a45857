//! Pressure advance: the extruder runs ahead of its nominal motion by a
//! time constant times its velocity, so the melt's pressure follows the
//! flow the path asks for, with Klipper's model and its smoothing.
//!
//! For a nominal extruder position `e(t)` and velocity `v(t)`, the
//! advanced position is
//!
//! ```text
//! E(t) = ∫ w(τ) · (e(t + τ) + K · v(t + τ) · a(t + τ)) dτ,   τ ∈ [−h, h]
//! w(τ) = (h − |τ|) / h²                                   (unit area)
//! ```
//!
//! with `K` the pressure advance (s), `h` half the smooth time, and
//! `a(t)` 1 while the move at `t` may advance (it extrudes while the
//! toolhead moves in x or y) and 0 otherwise (retractions, z moves):
//! Klipper's `kin_extruder.c`, so the same `K` and smooth time give the
//! same extruder motion. With no smooth time, `E(t) = e(t) + K·v(t)·a(t)`.
//!
//! [`PressureAdvance::position`] evaluates the integral on a nominal
//! motion given as a function of time. Between its samples the motion is
//! taken as piecewise quadratic (constant acceleration, as the planner's
//! profiles are), which Simpson's rule on each half of the window
//! integrates exactly against the triangle; a change of acceleration
//! inside a panel is the only approximation (3e-6 mm for a printer's numbers
//! with the default panels, see the tests).

use std::fmt;

/// Simpson panels on each half of the smoothing window.
pub const PANELS: usize = 32;

/// Why pressure advance settings were refused.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub enum PressureAdvanceError {
    /// `K` not finite or negative.
    BadAdvance(f64),
    /// The smooth time not finite or negative.
    BadSmoothTime(f64),
}

impl fmt::Display for PressureAdvanceError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PressureAdvanceError::BadAdvance(k) => {
                write!(f, "pressure advance {k} s must be finite and ≥ 0")
            }
            PressureAdvanceError::BadSmoothTime(t) => {
                write!(f, "smooth time {t} s must be finite and ≥ 0")
            }
        }
    }
}

impl std::error::Error for PressureAdvanceError {}

/// The nominal extruder motion at one time: position (mm), velocity
/// (mm/s), and whether the move there may advance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExtruderState {
    /// Nominal position, mm.
    pub position: f64,
    /// Nominal velocity, mm/s.
    pub velocity: f64,
    /// The move extrudes while the toolhead moves in x or y.
    pub advances: bool,
}

/// Klipper's pressure advance with its smoothing window.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PressureAdvance {
    k: f64,
    half: f64,
}

impl PressureAdvance {
    /// Pressure advance `k` (s, Klipper's `pressure_advance`) smoothed
    /// over `smooth_time` (s, Klipper's `pressure_advance_smooth_time`).
    pub fn new(k: f64, smooth_time: f64) -> Result<Self, PressureAdvanceError> {
        if !(k.is_finite() && k >= 0.0) {
            return Err(PressureAdvanceError::BadAdvance(k));
        }
        if !(smooth_time.is_finite() && smooth_time >= 0.0) {
            return Err(PressureAdvanceError::BadSmoothTime(smooth_time));
        }
        Ok(PressureAdvance {
            k,
            half: smooth_time / 2.0,
        })
    }

    /// How far ahead (and behind) of `t` the advanced position at `t`
    /// looks, s: half the smooth time.
    pub fn reach(&self) -> f64 {
        self.half
    }

    /// The advanced extruder position at `t` (s) for the nominal motion
    /// `nominal(t)`.
    pub fn position(&self, t: f64, mut nominal: impl FnMut(f64) -> ExtruderState) -> f64 {
        let k = self.k;
        let mut advanced = |at: f64| {
            let s = nominal(at);
            s.position + if s.advances { k * s.velocity } else { 0.0 }
        };
        let h = self.half;
        if h <= 0.0 {
            return advanced(t);
        }
        // Composite Simpson on [t − h, t] and [t, t + h], where the
        // triangle is linear.
        let step = h / PANELS as f64;
        let mut sum = 0.0;
        for side in [-1.0, 1.0] {
            for p in 0..PANELS {
                let (a, b) = (p as f64 * step, (p + 1) as f64 * step);
                let m = 0.5 * (a + b);
                let w = |tau: f64| (h - tau) / (h * h);
                let f = |tau: f64, value: f64| w(tau) * value;
                let fa = f(a, advanced(t + side * a));
                let fm = f(m, advanced(t + side * m));
                let fb = f(b, advanced(t + side * b));
                sum += step / 6.0 * (fa + 4.0 * fm + fb);
            }
        }
        sum
    }
}
