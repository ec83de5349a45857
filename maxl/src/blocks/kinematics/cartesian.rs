//! Cartesian machines: each joint follows one work axis, `a = sx·x + ox`.

use nalgebra::{SVector, Vector3};

use super::{finite, finite_input, KinError, Kinematics};

/// A Cartesian machine: joint i is `scale_i · p_i + offset_i` (for example
/// steps per mm and a home offset), independently per axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cartesian {
    scale: Vector3<f64>,
    offset: Vector3<f64>,
}

impl Cartesian {
    /// The identity map: joints equal work coordinates.
    pub fn identity() -> Cartesian {
        Cartesian {
            scale: Vector3::new(1.0, 1.0, 1.0),
            offset: Vector3::zeros(),
        }
    }

    /// Per-axis scales (joint units per work unit; finite and non-zero, a
    /// negative scale reverses an axis) and offsets (joint units; finite).
    pub fn new(scale: Vector3<f64>, offset: Vector3<f64>) -> Result<Cartesian, KinError> {
        if !scale.iter().all(|s| s.is_finite() && *s != 0.0) {
            return Err(KinError::BadParameter(
                "Cartesian scales must be finite and non-zero",
            ));
        }
        if !offset.iter().all(|o| o.is_finite()) {
            return Err(KinError::BadParameter("Cartesian offsets must be finite"));
        }
        Ok(Cartesian { scale, offset })
    }

    /// The per-axis scales.
    pub fn scale(&self) -> Vector3<f64> {
        self.scale
    }

    /// The per-axis offsets.
    pub fn offset(&self) -> Vector3<f64> {
        self.offset
    }

    fn inverse_n<const N: usize>(&self, p: &SVector<f64, N>) -> Result<SVector<f64, N>, KinError> {
        let mut q = finite_input(p)?;
        for (i, v) in q.iter_mut().enumerate() {
            *v = *v * self.scale[i] + self.offset[i];
        }
        finite(q)
    }

    fn forward_n<const N: usize>(&self, q: &SVector<f64, N>) -> Result<SVector<f64, N>, KinError> {
        let mut p = finite_input(q)?;
        for (i, v) in p.iter_mut().enumerate() {
            *v = (*v - self.offset[i]) / self.scale[i];
        }
        finite(p)
    }
}

impl Default for Cartesian {
    fn default() -> Self {
        Cartesian::identity()
    }
}

impl Kinematics<2> for Cartesian {
    fn inverse(&self, p: &SVector<f64, 2>) -> Result<SVector<f64, 2>, KinError> {
        self.inverse_n(p)
    }

    fn forward(&self, q: &SVector<f64, 2>) -> Result<SVector<f64, 2>, KinError> {
        self.forward_n(q)
    }
}

impl Kinematics<3> for Cartesian {
    fn inverse(&self, p: &SVector<f64, 3>) -> Result<SVector<f64, 3>, KinError> {
        self.inverse_n(p)
    }

    fn forward(&self, q: &SVector<f64, 3>) -> Result<SVector<f64, 3>, KinError> {
        self.forward_n(q)
    }
}
