//! A two-link SCARA arm.

use core::f64::consts::PI;

use nalgebra::Vector2;

use super::geometry::Side;
use super::{margin_sine, positive, KinError, Planar};

/// A two-link planar arm with its shoulder at the origin.
///
/// Joints: `a` is the shoulder angle of the first link from +x, `b` the
/// elbow angle of the second link relative to the first (0 = stretched),
/// both radians, counter-clockwise positive. Forward:
///
/// `elbow = l1·(cos a, sin a)`, `tool = elbow + l2·(cos(a + b), sin(a + b))`.
///
/// Inverse: with `r² = x² + y²`, `cos b = (r² − l1² − l2²)/(2·l1·l2)`; the
/// point is out of reach when that is outside `[−1, 1]` (`r > l1 + l2` or
/// `r < |l1 − l2|`). The elbow side picks the sign of `b`: an elbow on the
/// [`Side::Right`] of the line from shoulder to tool means `b > 0`,
/// [`Side::Left`] means `b < 0`. Then
/// `a = atan2(y, x) − atan2(l2·sin b, l1 + l2·cos b)`, wrapped to `(−π, π]`.
///
/// The arm is singular fully stretched (`b = 0`) or folded (`b = ±π`); the
/// inverse refuses points whose `|sin b|` is at most `sin(margin)`, that is
/// whose elbow angle is within `margin` of either.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scara {
    l1: f64,
    l2: f64,
    elbow: Side,
    margin: f64,
    sin_margin: f64,
}

impl Scara {
    /// Link lengths `l1` (shoulder to elbow) and `l2` (elbow to tool), finite
    /// and positive; the elbow side; the singularity margin in radians, in
    /// `[0, π/2)` (0 still refuses the exactly singular points).
    pub fn new(l1: f64, l2: f64, elbow: Side, margin: f64) -> Result<Scara, KinError> {
        Ok(Scara {
            l1: positive(
                l1,
                "the SCARA shoulder link length must be finite and positive",
            )?,
            l2: positive(
                l2,
                "the SCARA forearm link length must be finite and positive",
            )?,
            elbow,
            margin,
            sin_margin: margin_sine(margin)?,
        })
    }

    /// The link lengths (shoulder, forearm).
    pub fn links(&self) -> (f64, f64) {
        (self.l1, self.l2)
    }

    /// The configured elbow side.
    pub fn elbow(&self) -> Side {
        self.elbow
    }

    /// The singularity margin in radians.
    pub fn margin(&self) -> f64 {
        self.margin
    }

    /// Where the elbow is for joints `q`.
    pub fn elbow_point(&self, q: Vector2<f64>) -> Vector2<f64> {
        Vector2::new(q.x.cos(), q.x.sin()) * self.l1
    }
}

impl Planar for Scara {
    fn inverse_xy(&self, p: Vector2<f64>) -> Result<Vector2<f64>, KinError> {
        let (l1, l2) = (self.l1, self.l2);
        let r2 = p.norm_squared();
        let cos_b = (r2 - l1 * l1 - l2 * l2) / (2.0 * l1 * l2);
        if !cos_b.is_finite() {
            return Err(KinError::Overflow);
        }
        if !(-1.0..=1.0).contains(&cos_b) {
            return Err(KinError::Unreachable);
        }
        let sin_b_abs = (1.0 - cos_b * cos_b).max(0.0).sqrt();
        if sin_b_abs <= self.sin_margin {
            return Err(KinError::Singular);
        }
        let sin_b = match self.elbow {
            Side::Right => sin_b_abs,
            Side::Left => -sin_b_abs,
        };
        let b = sin_b.atan2(cos_b);
        let a = wrap(p.y.atan2(p.x) - (l2 * sin_b).atan2(l1 + l2 * cos_b));
        Ok(Vector2::new(a, b))
    }

    fn forward_xy(&self, q: Vector2<f64>) -> Result<Vector2<f64>, KinError> {
        let ab = q.x + q.y;
        Ok(self.elbow_point(q) + Vector2::new(ab.cos(), ab.sin()) * self.l2)
    }
}

/// `a` wrapped to `(−π, π]`.
fn wrap(a: f64) -> f64 {
    let w = a.rem_euclid(2.0 * PI);
    if w > PI {
        w - 2.0 * PI
    } else {
        w
    }
}
