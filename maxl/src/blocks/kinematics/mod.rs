//! Kinematics: maps between a machine's work coordinates (x, y, z in mm)
//! and its actuator ("joint") coordinates (a, b, c).
//!
//! Every mechanism implements [`Kinematics<N>`] for `N = 2` (x, y) and
//! `N = 3` (x, y, z): `inverse` takes work coordinates to joints, `forward`
//! takes joints back. The planar mechanisms implement [`Planar`] and get both
//! through blanket impls, with z passed through unchanged as c. Geometry is
//! computed in `f64` with nalgebra vectors.
//!
//! | mechanism      | joints                           | inverse errors                 |
//! |----------------|----------------------------------|--------------------------------|
//! | [`Cartesian`]  | `a = sx·x + ox` (per axis)       | non-finite input               |
//! | [`CoreXy`]     | `a = s(x + y)`, `b = s(x − y)`   | non-finite input               |
//! | [`Kaos`]       | CoreXY with belts at ±θ          | non-finite input               |
//! | [`Scara`]      | shoulder and elbow angles (rad)  | unreachable, singular          |
//! | [`FiveBar`]    | left and right motor angles (rad)| unreachable, singular, mode    |
//!
//! Errors are [`KinError`] values; nothing here panics on any input. Angles
//! are radians, counter-clockwise from +x, except the Kaos belt angle, which
//! is a frame dimension given in degrees.
//!
//! Each mechanism is also a PIPES class through [`KinBlock`] (see
//! [`CartesianBlock`], [`CoreXyBlock`], [`KaosBlock`], [`ScaraBlock`],
//! [`FiveBarBlock`]) with the members
//!
//! - `inverse(stamp: u64, x: f32, y: f32, z: f32) -> (stamp: u64, a: f32, b: f32, c: f32)`
//! - `forward(a: f32, b: f32, c: f32) -> (x: f32, y: f32, z: f32)`
//!
//! The stamp passes through untouched, so a planner's sampled output pipes
//! straight into `inverse` and on to the axis modules. A failing member or
//! constructor returns `CallError::Failed(code)` with one of the codes below
//! ([`KinError::code`]; the codes 253..=255 belong to the PIPES class
//! machinery).
//!
//! | code | constant                | meaning                                             |
//! |------|-------------------------|-----------------------------------------------------|
//! | 1    | [`FAIL_NON_FINITE`]     | an input is NaN or infinite                          |
//! | 2    | [`FAIL_UNREACHABLE`]    | the point is outside the mechanism's reach           |
//! | 3    | [`FAIL_SINGULAR`]       | the point is at or within the margin of a singularity|
//! | 4    | [`FAIL_OTHER_MODE`]     | reachable only in another working/assembly mode      |
//! | 5    | [`FAIL_BAD_PARAMETER`]  | the constructor refused its parameters               |
//! | 6    | [`FAIL_OVERFLOW`]       | the result does not fit a finite `f32`               |
//!
//! `docs/kinematics.md` gives every mechanism's conventions and formulas.

use core::fmt;

use nalgebra::{SMatrix, SVector, Vector2};
use pipes_core::function::CallError;

mod cartesian;
mod corexy;
mod fivebar;
mod geometry;
mod scara;
mod wire;

pub use cartesian::Cartesian;
pub use corexy::{CoreXy, Kaos};
pub use fivebar::{FiveBar, FiveBarMode};
pub use geometry::Side;
pub use scara::Scara;
pub use wire::{CartesianBlock, CoreXyBlock, FiveBarBlock, KaosBlock, KinBlock, ScaraBlock};

/// Failure code: an input is NaN or infinite.
pub const FAIL_NON_FINITE: u8 = 1;
/// Failure code: the point is out of the mechanism's reach.
pub const FAIL_UNREACHABLE: u8 = 2;
/// Failure code: the point is at, or within the margin of, a singularity.
pub const FAIL_SINGULAR: u8 = 3;
/// Failure code: the point is reachable only in another working or assembly
/// mode than the one configured.
pub const FAIL_OTHER_MODE: u8 = 4;
/// Failure code: a class constructor refused its parameters.
pub const FAIL_BAD_PARAMETER: u8 = 5;
/// Failure code: the result does not fit a finite value (f64 or, on the
/// wire, f32).
pub const FAIL_OVERFLOW: u8 = 6;

/// Why a kinematic transform refused its input.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum KinError {
    /// An input coordinate is NaN or infinite.
    NonFinite,
    /// The point is outside the mechanism's reach.
    Unreachable,
    /// The point is at, or within the configured margin of, a singularity
    /// (an arm fully stretched or folded, the five-bar's distal links in line).
    Singular,
    /// The point is reachable, but only in another working or assembly mode
    /// than the configured one.
    OtherMode,
    /// A mechanism parameter is invalid; the text names it and the rule.
    BadParameter(&'static str),
    /// The result is not finite (or, on the wire, does not fit an `f32`).
    Overflow,
}

impl KinError {
    /// The PIPES failure code of this error (see the module docs).
    pub fn code(&self) -> u8 {
        match self {
            KinError::NonFinite => FAIL_NON_FINITE,
            KinError::Unreachable => FAIL_UNREACHABLE,
            KinError::Singular => FAIL_SINGULAR,
            KinError::OtherMode => FAIL_OTHER_MODE,
            KinError::BadParameter(_) => FAIL_BAD_PARAMETER,
            KinError::Overflow => FAIL_OVERFLOW,
        }
    }
}

impl fmt::Display for KinError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            KinError::NonFinite => f.write_str("an input coordinate is NaN or infinite"),
            KinError::Unreachable => f.write_str("the point is out of the mechanism's reach"),
            KinError::Singular => {
                f.write_str("the point is at or too close to a singular configuration")
            }
            KinError::OtherMode => f.write_str(
                "the point is reachable only in another working or assembly mode than the configured one",
            ),
            KinError::BadParameter(what) => write!(f, "invalid mechanism parameter: {what}"),
            KinError::Overflow => f.write_str("the result is not a finite number"),
        }
    }
}

impl core::error::Error for KinError {}

impl From<KinError> for CallError {
    fn from(e: KinError) -> CallError {
        CallError::Failed(e.code().into())
    }
}

/// A mechanism's map between work coordinates and joint coordinates, over
/// `N`-vectors (`N = 2`: x, y; `N = 3`: x, y, z).
pub trait Kinematics<const N: usize> {
    /// Joint coordinates that put the tool at `p`.
    fn inverse(&self, p: &SVector<f64, N>) -> Result<SVector<f64, N>, KinError>;

    /// The tool position for joint coordinates `q`.
    fn forward(&self, q: &SVector<f64, N>) -> Result<SVector<f64, N>, KinError>;

    /// The Jacobian `∂p/∂q` of [`forward`](Self::forward) at `q`, by central
    /// differences with a step of `1e-6·max(1, |q_i|)` per joint (the tests
    /// check it against the SCARA's analytic Jacobian to 1e-6 relative).
    /// Fails where `forward` fails at `q` or at a neighbouring sample.
    fn jacobian(&self, q: &SVector<f64, N>) -> Result<SMatrix<f64, N, N>, KinError> {
        finite_input(q)?;
        self.forward(q)?;
        let mut j = SMatrix::<f64, N, N>::zeros();
        for i in 0..N {
            let h = 1e-6 * q[i].abs().max(1.0);
            let mut lo = *q;
            let mut hi = *q;
            lo[i] -= h;
            hi[i] += h;
            let d = (self.forward(&hi)? - self.forward(&lo)?) / (hi[i] - lo[i]);
            j.set_column(i, &d);
        }
        Ok(j)
    }

    /// Joint velocities that move the tool at `v` (work units per second)
    /// when it is at `p`: solves `J(q)·q̇ = v` with `q = inverse(p)`. Fails with
    /// [`KinError::Singular`] where the Jacobian cannot be inverted.
    fn joint_velocity(
        &self,
        p: &SVector<f64, N>,
        v: &SVector<f64, N>,
    ) -> Result<SVector<f64, N>, KinError> {
        finite_input(v)?;
        let q = self.inverse(p)?;
        let j = self.jacobian(&q)?;
        let qd = j.try_inverse().ok_or(KinError::Singular)? * v;
        finite(qd)
    }
}

/// A mechanism that moves the tool in the xy-plane; z passes through as c.
/// Implementing it gives [`Kinematics<2>`] and [`Kinematics<3>`].
pub trait Planar {
    /// Joint coordinates (a, b) that put the tool at `p` (already checked
    /// finite).
    fn inverse_xy(&self, p: Vector2<f64>) -> Result<Vector2<f64>, KinError>;

    /// The tool position for joints `q` (already checked finite).
    fn forward_xy(&self, q: Vector2<f64>) -> Result<Vector2<f64>, KinError>;
}

impl<T: Planar> Kinematics<2> for T {
    fn inverse(&self, p: &SVector<f64, 2>) -> Result<SVector<f64, 2>, KinError> {
        finite(self.inverse_xy(finite_input(p)?)?)
    }

    fn forward(&self, q: &SVector<f64, 2>) -> Result<SVector<f64, 2>, KinError> {
        finite(self.forward_xy(finite_input(q)?)?)
    }
}

impl<T: Planar> Kinematics<3> for T {
    fn inverse(&self, p: &SVector<f64, 3>) -> Result<SVector<f64, 3>, KinError> {
        if !p.z.is_finite() {
            return Err(KinError::NonFinite);
        }
        let ab = Kinematics::<2>::inverse(self, &p.xy())?;
        Ok(SVector::<f64, 3>::new(ab.x, ab.y, p.z))
    }

    fn forward(&self, q: &SVector<f64, 3>) -> Result<SVector<f64, 3>, KinError> {
        if !q.z.is_finite() {
            return Err(KinError::NonFinite);
        }
        let xy = Kinematics::<2>::forward(self, &q.xy())?;
        Ok(SVector::<f64, 3>::new(xy.x, xy.y, q.z))
    }
}

/// `v` if every element is finite, else [`KinError::Overflow`]: the check
/// on results.
fn finite<const N: usize>(v: SVector<f64, N>) -> Result<SVector<f64, N>, KinError> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(v)
    } else {
        Err(KinError::Overflow)
    }
}

/// `v` if every element is finite, else [`KinError::NonFinite`]: the check
/// on inputs.
fn finite_input<const N: usize>(v: &SVector<f64, N>) -> Result<SVector<f64, N>, KinError> {
    finite(*v).map_err(|_| KinError::NonFinite)
}

/// Checks a length parameter: finite and strictly positive.
fn positive(v: f64, what: &'static str) -> Result<f64, KinError> {
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        Err(KinError::BadParameter(what))
    }
}

/// Checks a singularity margin (radians, in `[0, π/2)`) and returns its sine.
fn margin_sine(margin: f64) -> Result<f64, KinError> {
    if margin.is_finite() && (0.0..core::f64::consts::FRAC_PI_2).contains(&margin) {
        Ok(margin.sin())
    } else {
        Err(KinError::BadParameter(
            "the singularity margin must be finite, in [0, π/2) radians",
        ))
    }
}
