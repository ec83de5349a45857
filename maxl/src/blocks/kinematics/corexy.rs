//! CoreXY and its angled variant, Kaos.

use nalgebra::Vector2;

use super::{positive, KinError, Planar};

/// A CoreXY machine: `a = s·(x + y)`, `b = s·(x − y)`; back,
/// `x = (a + b)/(2s)`, `y = (a − b)/(2s)`.
///
/// Motor A is the one that, turning alone by `Δ`, moves the tool by
/// `(Δ, Δ)/(2s)` (along +x+y); motor B alone moves it by `(Δ, −Δ)/(2s)`.
/// Swap the motors (or negate `b`) if a machine's wiring disagrees.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CoreXy {
    scale: f64,
}

impl CoreXy {
    /// `scale` is joint units per work unit (finite, positive).
    pub fn new(scale: f64) -> Result<CoreXy, KinError> {
        Ok(CoreXy {
            scale: positive(scale, "the CoreXY scale must be finite and positive")?,
        })
    }

    /// The scale (joint units per work unit).
    pub fn scale(&self) -> f64 {
        self.scale
    }
}

impl Planar for CoreXy {
    fn inverse_xy(&self, p: Vector2<f64>) -> Result<Vector2<f64>, KinError> {
        Ok(Vector2::new(p.x + p.y, p.x - p.y) * self.scale)
    }

    fn forward_xy(&self, q: Vector2<f64>) -> Result<Vector2<f64>, KinError> {
        Ok(Vector2::new(q.x + q.y, q.x - q.y) / (2.0 * self.scale))
    }
}

/// An angled CoreXY ("Kaos"): the two belt directions make angles `+θ` and
/// `−θ` with the x axis (a V opening of `2θ`). Each motor's coordinate is the
/// tool position projected on its belt direction, scaled by `√2·s`:
///
/// `a = √2·s·(x·cos θ + y·sin θ)`, `b = √2·s·(x·cos θ − y·sin θ)`, and back
/// `x = (a + b)/(2√2·s·cos θ)`, `y = (a − b)/(2√2·s·sin θ)`.
///
/// Turning motor A alone keeps `b` fixed, so the tool moves square to belt
/// B's direction, at `90° − θ` from +x (and motor B alone at `θ − 90°`).
/// At `θ = 45°` this is [`CoreXy`] with the same scale. θ must lie strictly
/// between 0° and 90°: at either end the belts are parallel and one work
/// direction is lost.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Kaos {
    angle_deg: f64,
    scale: f64,
    // √2·s·cos θ and √2·s·sin θ.
    kc: f64,
    ks: f64,
}

impl Kaos {
    /// The belt angle θ in degrees (in `(0, 90)`) and the scale (joint units
    /// per work unit, finite and positive).
    pub fn new(angle_deg: f64, scale: f64) -> Result<Kaos, KinError> {
        if !(angle_deg.is_finite() && angle_deg > 0.0 && angle_deg < 90.0) {
            return Err(KinError::BadParameter(
                "the Kaos belt angle must be finite, strictly between 0 and 90 degrees",
            ));
        }
        let scale = positive(scale, "the Kaos scale must be finite and positive")?;
        let (s, c) = angle_deg.to_radians().sin_cos();
        let k = core::f64::consts::SQRT_2 * scale;
        Ok(Kaos {
            angle_deg,
            scale,
            kc: k * c,
            ks: k * s,
        })
    }

    /// The belt angle θ in degrees.
    pub fn angle_deg(&self) -> f64 {
        self.angle_deg
    }

    /// The scale (joint units per work unit).
    pub fn scale(&self) -> f64 {
        self.scale
    }
}

impl Planar for Kaos {
    fn inverse_xy(&self, p: Vector2<f64>) -> Result<Vector2<f64>, KinError> {
        Ok(Vector2::new(
            self.kc * p.x + self.ks * p.y,
            self.kc * p.x - self.ks * p.y,
        ))
    }

    fn forward_xy(&self, q: Vector2<f64>) -> Result<Vector2<f64>, KinError> {
        Ok(Vector2::new(
            (q.x + q.y) / (2.0 * self.kc),
            (q.x - q.y) / (2.0 * self.ks),
        ))
    }
}
