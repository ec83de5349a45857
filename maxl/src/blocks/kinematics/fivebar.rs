//! A five-bar parallel arm (two motors, two proximal and two distal links).

use nalgebra::Vector2;

use super::geometry::{circle_intersection, side_of, Side};
use super::{margin_sine, positive, KinError, Planar};

/// How a [`FiveBar`] is assembled: which side each elbow and the tool sit on.
///
/// - `left_elbow`: the left elbow's side of the directed line from the left
///   motor to the tool;
/// - `right_elbow`: the right elbow's side of the line from the right motor to
///   the tool;
/// - `tool`: the tool's side of the directed line from the left elbow to the
///   right elbow.
///
/// The two elbow choices are the working mode (four of them), the tool
/// choice the assembly mode (two). The mechanism cannot leave a mode without
/// passing through a singularity, which the transforms refuse.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FiveBarMode {
    /// Side of the left elbow, seen from the left motor towards the tool.
    pub left_elbow: Side,
    /// Side of the right elbow, seen from the right motor towards the tool.
    pub right_elbow: Side,
    /// Side of the tool, seen from the left elbow towards the right elbow.
    pub tool: Side,
}

impl FiveBarMode {
    /// The usual drawing-machine layout with the tool above (+y) the motors:
    /// both elbows bent outwards and the tool beyond the elbows.
    pub const OUTWARD: FiveBarMode = FiveBarMode {
        left_elbow: Side::Left,
        right_elbow: Side::Right,
        tool: Side::Left,
    };
}

/// A symmetric five-bar parallel arm, as used by two-motor drawing machines.
///
/// The left motor sits at `(−d/2, 0)`, the right one at `(d/2, 0)`. Each
/// turns a proximal link of length `l1`; distal links of length `l2` join
/// the two elbows at the tool. Joints: `a` is the left proximal link's angle
/// from +x, `b` the right one's, radians counter-clockwise.
///
/// Inverse: each elbow is where the circle of radius `l1` about its motor
/// meets the circle of radius `l2` about the tool, on the side the
/// [`FiveBarMode`] names; the joint is that elbow's angle about its motor.
/// Forward: the elbows follow from the angles and the tool is where the two
/// circles of radius `l2` about the elbows meet, on the configured side.
///
/// Errors: [`KinError::Unreachable`] when the circles miss;
/// [`KinError::Singular`] when a proximal and its distal link are within
/// `margin` of being in line (serial singularity: the arm's reach boundary)
/// or the two distal links are (parallel singularity: the tool loses
/// stiffness); [`KinError::OtherMode`] when the solution found does not have
/// every element on its configured side.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FiveBar {
    span: f64,
    l1: f64,
    l2: f64,
    mode: FiveBarMode,
    margin: f64,
    sin_margin: f64,
}

impl FiveBar {
    /// Motor spacing `span`, proximal and distal link lengths (all finite and
    /// positive), the mode, and the singularity margin in radians (in
    /// `[0, π/2)`).
    pub fn new(
        span: f64,
        l1: f64,
        l2: f64,
        mode: FiveBarMode,
        margin: f64,
    ) -> Result<FiveBar, KinError> {
        Ok(FiveBar {
            span: positive(
                span,
                "the five-bar motor spacing must be finite and positive",
            )?,
            l1: positive(
                l1,
                "the five-bar proximal link length must be finite and positive",
            )?,
            l2: positive(
                l2,
                "the five-bar distal link length must be finite and positive",
            )?,
            mode,
            margin,
            sin_margin: margin_sine(margin)?,
        })
    }

    /// Motor spacing, proximal and distal link lengths.
    pub fn dimensions(&self) -> (f64, f64, f64) {
        (self.span, self.l1, self.l2)
    }

    /// The configured mode.
    pub fn mode(&self) -> FiveBarMode {
        self.mode
    }

    /// The singularity margin in radians.
    pub fn margin(&self) -> f64 {
        self.margin
    }

    /// The motor positions (left, right).
    pub fn motors(&self) -> (Vector2<f64>, Vector2<f64>) {
        let h = self.span / 2.0;
        (Vector2::new(-h, 0.0), Vector2::new(h, 0.0))
    }

    /// The elbow positions (left, right) for joints `q`.
    pub fn elbows(&self, q: Vector2<f64>) -> (Vector2<f64>, Vector2<f64>) {
        let (ml, mr) = self.motors();
        (
            ml + Vector2::new(q.x.cos(), q.x.sin()) * self.l1,
            mr + Vector2::new(q.y.cos(), q.y.sin()) * self.l1,
        )
    }

    /// Checks a whole configuration: no singularity within the margin and
    /// every element on its configured side.
    fn check(&self, el: Vector2<f64>, er: Vector2<f64>, p: Vector2<f64>) -> Result<(), KinError> {
        let (ml, mr) = self.motors();
        // Sines of the angle at each elbow and at the tool (`perp` is the z
        // component of the 2D cross product).
        let s_left = (el - ml).perp(&(p - el)) / (self.l1 * self.l2);
        let s_right = (er - mr).perp(&(p - er)) / (self.l1 * self.l2);
        let s_tool = (el - p).perp(&(er - p)) / (self.l2 * self.l2);
        if [s_left, s_right, s_tool]
            .iter()
            .any(|s| s.abs() <= self.sin_margin)
        {
            return Err(KinError::Singular);
        }
        let mode = FiveBarMode {
            left_elbow: side_of(ml, p, el),
            right_elbow: side_of(mr, p, er),
            tool: side_of(el, er, p),
        };
        if mode != self.mode {
            return Err(KinError::OtherMode);
        }
        Ok(())
    }
}

impl Planar for FiveBar {
    fn inverse_xy(&self, p: Vector2<f64>) -> Result<Vector2<f64>, KinError> {
        let (ml, mr) = self.motors();
        let el = circle_intersection(ml, self.l1, p, self.l2, self.mode.left_elbow)?;
        let er = circle_intersection(mr, self.l1, p, self.l2, self.mode.right_elbow)?;
        self.check(el, er, p)?;
        let (dl, dr) = (el - ml, er - mr);
        Ok(Vector2::new(dl.y.atan2(dl.x), dr.y.atan2(dr.x)))
    }

    fn forward_xy(&self, q: Vector2<f64>) -> Result<Vector2<f64>, KinError> {
        let (el, er) = self.elbows(q);
        let p = circle_intersection(el, self.l2, er, self.l2, self.mode.tool)?;
        self.check(el, er, p)?;
        Ok(p)
    }
}
