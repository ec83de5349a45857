//! Plane geometry shared by the arm mechanisms.

use nalgebra::Vector2;

use super::KinError;

/// Which side of a directed line a point lies on, looking along the line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Side {
    /// Counter-clockwise of the line (positive cross product).
    Left,
    /// Clockwise of the line.
    Right,
}

impl Side {
    /// `Left` for `true`, `Right` for `false`.
    pub fn left_if(left: bool) -> Side {
        if left {
            Side::Left
        } else {
            Side::Right
        }
    }
}

/// The side of the directed line `from → to` that `p` lies on (`Left` when
/// exactly on it; callers reject such points as singular first).
pub(crate) fn side_of(from: Vector2<f64>, to: Vector2<f64>, p: Vector2<f64>) -> Side {
    if (to - from).perp(&(p - from)) >= 0.0 {
        Side::Left
    } else {
        Side::Right
    }
}

/// The intersection of the circle of radius `r0` about `c0` with the circle
/// of radius `r1` about `c1` that lies on `side` of the directed line
/// `c0 → c1`.
///
/// Coincident centres give [`KinError::Singular`] (the answer is a whole
/// circle or nothing); circles that miss each other give
/// [`KinError::Unreachable`].
pub(crate) fn circle_intersection(
    c0: Vector2<f64>,
    r0: f64,
    c1: Vector2<f64>,
    r1: f64,
    side: Side,
) -> Result<Vector2<f64>, KinError> {
    let d_vec = c1 - c0;
    let d = d_vec.norm();
    if !d.is_finite() {
        return Err(KinError::Overflow);
    }
    // Centres this close leave the direction of the line undefined.
    if d <= 1e-12 * (r0 + r1) {
        return Err(KinError::Singular);
    }
    if d > r0 + r1 || d < (r0 - r1).abs() {
        return Err(KinError::Unreachable);
    }
    let u = d_vec / d;
    // Distance from c0 along the centre line to the chord, and half the chord.
    let along = (d * d + r0 * r0 - r1 * r1) / (2.0 * d);
    let half = (r0 * r0 - along * along).max(0.0).sqrt();
    let perp = Vector2::new(-u.y, u.x);
    let sign = match side {
        Side::Left => 1.0,
        Side::Right => -1.0,
    };
    Ok(c0 + u * along + perp * (sign * half))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn intersection_of_unit_circles_picks_the_side() {
        let c0 = Vector2::new(0.0, 0.0);
        let c1 = Vector2::new(1.0, 0.0);
        let l = circle_intersection(c0, 1.0, c1, 1.0, Side::Left).unwrap();
        let r = circle_intersection(c0, 1.0, c1, 1.0, Side::Right).unwrap();
        let h = 0.75f64.sqrt();
        assert!((l - Vector2::new(0.5, h)).norm() < 1e-15);
        assert!((r - Vector2::new(0.5, -h)).norm() < 1e-15);
        assert_eq!(side_of(c0, c1, l), Side::Left);
        assert_eq!(side_of(c0, c1, r), Side::Right);
    }

    #[test]
    fn missing_and_concentric_circles_are_errors() {
        let c0 = Vector2::new(0.0, 0.0);
        assert_eq!(
            circle_intersection(c0, 1.0, Vector2::new(3.0, 0.0), 1.0, Side::Left),
            Err(KinError::Unreachable)
        );
        assert_eq!(
            circle_intersection(c0, 3.0, Vector2::new(0.5, 0.0), 1.0, Side::Left),
            Err(KinError::Unreachable)
        );
        assert_eq!(
            circle_intersection(c0, 1.0, c0, 1.0, Side::Left),
            Err(KinError::Singular)
        );
    }
}
