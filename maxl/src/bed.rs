//! A model of a machine's bed: a tilted plane plus a dome (or dish), the
//! shape a real bed has after assembly (out of square, warped by heat or
//! by the frame). The machine file's simulated bed, the simulator's probe
//! and the levelling tests all read this one model.
//!
//! Its height at `(x, y)` is
//!
//! ```text
//! z + tilt_x·(x − cx) + tilt_y·(y − cy) + warp·(1 − u²)·(1 − v²)
//! u = (x − cx) / half_x,  v = (y − cy) / half_y
//! ```
//!
//! a plane through `z` at the centre `(cx, cy)` plus a dome `warp` high at
//! the centre that falls to 0 on the edges `cx ± half_x`, `cy ± half_y`
//! (a negative `warp` is a dish).

/// A bed that is tilted and warped (see the [module docs](self)).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(deny_unknown_fields))]
pub struct BedSurface {
    /// Height at the centre (units).
    pub z: f64,
    /// Slope along x (units of height per unit of x).
    #[cfg_attr(feature = "serde", serde(default))]
    pub tilt_x: f64,
    /// Slope along y.
    #[cfg_attr(feature = "serde", serde(default))]
    pub tilt_y: f64,
    /// The dome's height at the centre (units; negative: a dish).
    #[cfg_attr(feature = "serde", serde(default))]
    pub warp: f64,
    /// The centre, `[cx, cy]`.
    pub center: [f64; 2],
    /// Half the bed's size, `[half_x, half_y]` (positive): where the dome
    /// reaches 0.
    pub half: [f64; 2],
}

/// Why a [`BedSurface`] was refused: the key and what it must be.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub enum SurfaceError {
    /// A value that must be a finite number is not.
    NotFinite {
        /// The key (`z`, `tilt_x`, `center[0]`, …).
        key: &'static str,
        /// Its value.
        value: f64,
    },
    /// A half size that must be positive is not.
    NotPositive {
        /// The key (`half[0]` or `half[1]`).
        key: &'static str,
        /// Its value.
        value: f64,
    },
}

impl SurfaceError {
    /// The key the error is about.
    pub fn key(&self) -> &'static str {
        match self {
            SurfaceError::NotFinite { key, .. } | SurfaceError::NotPositive { key, .. } => key,
        }
    }
}

impl core::fmt::Display for SurfaceError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            SurfaceError::NotFinite { key, value } => {
                write!(f, "bed {key} = {value} must be a finite number")
            }
            SurfaceError::NotPositive { key, value } => {
                write!(
                    f,
                    "bed {key} = {value} must be positive: half the bed's size"
                )
            }
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for SurfaceError {}

impl BedSurface {
    /// The bed's height at `(x, y)`.
    pub fn height(&self, x: f64, y: f64) -> f64 {
        let (dx, dy) = (x - self.center[0], y - self.center[1]);
        let (u, v) = (dx / self.half[0], dy / self.half[1]);
        self.z + self.tilt_x * dx + self.tilt_y * dy + self.warp * (1.0 - u * u) * (1.0 - v * v)
    }

    /// Checks the values: all finite, half sizes positive.
    pub fn check(&self) -> Result<(), SurfaceError> {
        for (key, value) in [
            ("z", self.z),
            ("tilt_x", self.tilt_x),
            ("tilt_y", self.tilt_y),
            ("warp", self.warp),
            ("center[0]", self.center[0]),
            ("center[1]", self.center[1]),
        ] {
            if !value.is_finite() {
                return Err(SurfaceError::NotFinite { key, value });
            }
        }
        for (key, value) in [("half[0]", self.half[0]), ("half[1]", self.half[1])] {
            if !(value.is_finite() && value > 0.0) {
                return Err(SurfaceError::NotPositive { key, value });
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bed() -> BedSurface {
        BedSurface {
            z: -70.0,
            tilt_x: 0.001,
            tilt_y: -0.002,
            warp: 0.2,
            center: [150.0, 100.0],
            half: [150.0, 100.0],
        }
    }

    #[test]
    fn a_tilted_warped_bed() {
        let b = bed();
        assert!((b.height(150.0, 100.0) - (-69.8)).abs() < 1e-12);
        // On an edge the dome is 0: only the tilt.
        assert!((b.height(300.0, 100.0) - (-70.0 + 0.15)).abs() < 1e-12);
        assert!((b.height(150.0, 0.0) - (-70.0 + 0.2)).abs() < 1e-12);
        assert!(b.check().is_ok());
    }

    #[test]
    fn bad_beds_say_which_key() {
        let mut b = bed();
        b.half[1] = 0.0;
        assert_eq!(
            b.check(),
            Err(SurfaceError::NotPositive {
                key: "half[1]",
                value: 0.0
            })
        );
        let mut b = bed();
        b.warp = f64::INFINITY;
        assert_eq!(b.check().map_err(|e| e.key()), Err("warp"));
    }
}
