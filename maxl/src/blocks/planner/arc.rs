//! Circular (or helical) arcs split into chords within a tolerance.

use super::limits::PlanError;

/// A circular arc from the planner's current position, in the plane of two
/// axes; the other axes move linearly (a helix).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Arc<const N: usize> {
    /// Where the arc ends (all axes). If it equals the start in the plane,
    /// the arc is a full circle.
    pub end: [f64; N],
    /// The two axes of the arc's plane (e.g. `(0, 1)` for XY). Angles go
    /// from the first axis towards the second.
    pub plane: (usize, usize),
    /// The centre in the plane (absolute coordinates of the two axes).
    pub center: [f64; 2],
    /// Clockwise when looking from the positive normal (first × second axis).
    pub clockwise: bool,
    /// Largest distance (mm) between a chord and the true arc, > 0.
    pub chord_tolerance: f64,
}

impl<const N: usize> Arc<N> {
    /// The chord end points after `start` (the last is exactly `end`).
    pub fn chords(&self, start: [f64; N]) -> Result<Vec<[f64; N]>, PlanError> {
        let (a, b) = self.plane;
        if a >= N || b >= N || a == b {
            return Err(PlanError::InvalidArc("plane axes out of range or equal"));
        }
        super::check_finite(&self.end)?;
        if !self.center[0].is_finite() {
            return Err(PlanError::NonFiniteCoordinate { axis: a });
        }
        if !self.center[1].is_finite() {
            return Err(PlanError::NonFiniteCoordinate { axis: b });
        }
        let tol = self.chord_tolerance;
        if !(tol.is_finite() && tol > 0.0) {
            return Err(PlanError::InvalidArc(
                "chord tolerance must be finite and > 0",
            ));
        }
        let [cx, cy] = self.center;
        let (sx, sy) = (start[a] - cx, start[b] - cy);
        let (ex, ey) = (self.end[a] - cx, self.end[b] - cy);
        let r0 = sx.hypot(sy);
        let r1 = ex.hypot(ey);
        if r0.is_nan() || r0 <= 1e-9 {
            return Err(PlanError::InvalidArc("the start lies on the centre"));
        }
        if (r1 - r0).abs() > 0.002f64.max(1e-3 * r0) {
            return Err(PlanError::InvalidArc(
                "start and end are at different distances from the centre",
            ));
        }
        let a0 = sy.atan2(sx);
        let a1 = ey.atan2(ex);
        let tau = std::f64::consts::TAU;
        // Sweep in the arc's direction, in (0, 2π]; equal ends mean a circle.
        let mut sweep = if self.clockwise { a0 - a1 } else { a1 - a0 };
        sweep = sweep.rem_euclid(tau);
        if sweep < 1e-9 {
            sweep = tau;
        }
        let rmax = r0.max(r1);
        // A chord spanning φ strays r(1 − cos(φ/2)) from the arc.
        let step = if tol >= rmax {
            std::f64::consts::PI
        } else {
            2.0 * (1.0 - tol / rmax).acos()
        };
        let n = (sweep / step).ceil().max(1.0);
        if n > 1.0e6 {
            return Err(PlanError::InvalidArc(
                "more than a million chords: raise the tolerance",
            ));
        }
        let n = n as usize;
        let sign = if self.clockwise { -1.0 } else { 1.0 };
        let mut out = Vec::with_capacity(n);
        for k in 1..n {
            let f = k as f64 / n as f64;
            let ang = a0 + sign * sweep * f;
            // The radius moves linearly so the last chord lands exactly on `end`.
            let r = r0 + (r1 - r0) * f;
            let mut p = [0.0; N];
            for i in 0..N {
                p[i] = start[i] + (self.end[i] - start[i]) * f;
            }
            p[a] = cx + r * ang.cos();
            p[b] = cy + r * ang.sin();
            out.push(p);
        }
        out.push(self.end);
        Ok(out)
    }
}
