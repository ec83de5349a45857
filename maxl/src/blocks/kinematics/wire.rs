//! The mechanisms as PIPES classes: [`KinBlock`] over each mechanism, with
//! one `#[pipes_core::class]` per mechanism (written by [`kin_class!`] so the
//! shared members are spelled once).

use nalgebra::Vector3;

use super::geometry::Side;
use super::{Cartesian, CoreXy, FiveBar, FiveBarMode, Kaos, KinError, Kinematics, Scara};

/// An `f64` result as a finite `f32`, or [`KinError::Overflow`].
fn to_f32(v: f64) -> Result<f32, KinError> {
    let f = v as f32;
    if f.is_finite() {
        Ok(f)
    } else {
        Err(KinError::Overflow)
    }
}

/// A mechanism as a PIPES class (see the module docs): the class
/// `CoreXY` is `KinBlock<CoreXy>` ([`CoreXyBlock`]), and so on.
///
/// Wire members, as methods on each mechanism's block (failure codes from
/// [`KinError::code`]): `inverse(stamp, x, y, z) -> (stamp, a, b, c)` and
/// `forward(a, b, c) -> (x, y, z)`. Each block's constructor `wire_new`
/// refuses invalid parameters with [`KinError::BadParameter`] (code 5).
#[derive(Debug, Clone, PartialEq)]
pub struct KinBlock<K> {
    kin: K,
}

impl<K: Kinematics<3>> KinBlock<K> {
    /// A block over a mechanism built in Rust.
    pub fn new(kin: K) -> Self {
        KinBlock { kin }
    }

    /// The mechanism.
    pub fn kinematics(&self) -> &K {
        &self.kin
    }

    /// `inverse` for every mechanism.
    fn joints(&self, stamp: u64, x: f32, y: f32, z: f32) -> Result<(u64, f32, f32, f32), KinError> {
        let q = self
            .kin
            .inverse(&Vector3::new(x.into(), y.into(), z.into()))?;
        Ok((stamp, to_f32(q.x)?, to_f32(q.y)?, to_f32(q.z)?))
    }

    /// `forward` for every mechanism.
    fn tool(&self, a: f32, b: f32, c: f32) -> Result<(f32, f32, f32), KinError> {
        let p = self
            .kin
            .forward(&Vector3::new(a.into(), b.into(), c.into()))?;
        Ok((to_f32(p.x)?, to_f32(p.y)?, to_f32(p.z)?))
    }
}

/// [`Cartesian`] as the PIPES class `Cartesian`.
pub type CartesianBlock = KinBlock<Cartesian>;
/// [`CoreXy`] as the PIPES class `CoreXY`.
pub type CoreXyBlock = KinBlock<CoreXy>;
/// [`Kaos`] as the PIPES class `Kaos`.
pub type KaosBlock = KinBlock<Kaos>;
/// [`Scara`] as the PIPES class `Scara`.
pub type ScaraBlock = KinBlock<Scara>;
/// [`FiveBar`] as the PIPES class `FiveBar`.
pub type FiveBarBlock = KinBlock<FiveBar>;

/// The PIPES class named `$name` over `KinBlock<$mech>`: the given
/// constructor `wire_new` (its arguments are the constructor's inputs) and
/// the members `inverse` and `forward`.
macro_rules! kin_class {
    (
        $mech:ident as $name:literal;
        $(#[$cdoc:meta])*
        fn wire_new($($arg:ident: $ty:ty),* $(,)?) $body:block
    ) => {
        #[pipes_core::class(name = $name)]
        impl KinBlock<$mech> {
            $(#[$cdoc])*
            #[constructor]
            pub fn wire_new($($arg: $ty),*) -> Result<Self, KinError> $body

            #[doc = concat!(
                "`", $name, ".inverse`: the joints (a, b, c) that put the tool at ",
                "(x, y, z), with the stamp passed through."
            )]
            #[outputs = "stamp, a, b, c"]
            pub fn inverse(
                &self,
                stamp: u64,
                x: f32,
                y: f32,
                z: f32,
            ) -> Result<(u64, f32, f32, f32), KinError> {
                self.joints(stamp, x, y, z)
            }

            #[doc = concat!(
                "`", $name, ".forward`: the tool position (x, y, z) for joints (a, b, c)."
            )]
            #[outputs = "x, y, z"]
            pub fn forward(&self, a: f32, b: f32, c: f32) -> Result<(f32, f32, f32), KinError> {
                self.tool(a, b, c)
            }
        }
    };
}

kin_class! {
    Cartesian as "Cartesian";
    /// The `Cartesian` constructor: per-axis scales and offsets.
    fn wire_new(
        scale_x: f32,
        scale_y: f32,
        scale_z: f32,
        offset_x: f32,
        offset_y: f32,
        offset_z: f32,
    ) {
        let v = |a: f32, b: f32, c: f32| Vector3::new(a.into(), b.into(), c.into());
        Cartesian::new(v(scale_x, scale_y, scale_z), v(offset_x, offset_y, offset_z)).map(Self::new)
    }
}

kin_class! {
    CoreXy as "CoreXY";
    /// The `CoreXY` constructor: joint units per work unit.
    fn wire_new(scale: f32) {
        CoreXy::new(scale.into()).map(Self::new)
    }
}

kin_class! {
    Kaos as "Kaos";
    /// The `Kaos` constructor: belt angle in degrees, joint units per work
    /// unit.
    fn wire_new(angle_deg: f32, scale: f32) {
        Kaos::new(angle_deg.into(), scale.into()).map(Self::new)
    }
}

kin_class! {
    Scara as "Scara";
    /// The `Scara` constructor: link lengths, elbow side (`true` = right,
    /// elbow angle positive) and singularity margin in radians.
    fn wire_new(shoulder: f32, forearm: f32, elbow_right: bool, margin: f32) {
        let side = if elbow_right { Side::Right } else { Side::Left };
        Scara::new(shoulder.into(), forearm.into(), side, margin.into()).map(Self::new)
    }
}

kin_class! {
    FiveBar as "FiveBar";
    /// The `FiveBar` constructor: motor spacing, proximal and distal link
    /// lengths, the mode as three sides (`true` = left, see
    /// [`FiveBarMode`]) and the singularity margin in radians.
    fn wire_new(
        span: f32,
        proximal: f32,
        distal: f32,
        left_elbow_left: bool,
        right_elbow_left: bool,
        tool_left: bool,
        margin: f32,
    ) {
        let mode = FiveBarMode {
            left_elbow: Side::left_if(left_elbow_left),
            right_elbow: Side::left_if(right_elbow_left),
            tool: Side::left_if(tool_left),
        };
        FiveBar::new(span.into(), proximal.into(), distal.into(), mode, margin.into())
            .map(Self::new)
    }
}
