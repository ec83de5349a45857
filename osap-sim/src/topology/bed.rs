//! A simulated bed surface and a probe that touches it ([`BedContact`] on a
//! [`SwitchSpec`](super::SwitchSpec)).
//!
//! A bed levelling probe is a switch (or a load cell's comparator) on a
//! module's limit input that closes when the probe tip reaches the bed. The
//! tip's height is a linear form of carriage positions (the z axis), as for
//! any [`SwitchSpec`](super::SwitchSpec); the height it closes at is the
//! bed's height under the tip, whose x and y are two more linear forms. So
//! the switch is pressed while
//!
//! ```text
//! Σ coef·position + offset ≤ at + surface.height(x, y)
//! ```
//!
//! with `x` and `y` the contact's forms. The edge is stamped with the tick
//! of the z step that made the tip reach the bed, exactly as an endstop's.
//! The bed itself is [`maxl::bed::BedSurface`], the one bed model the
//! machine file, the simulator and levelling share.

pub use maxl::bed::BedSurface;
use serde::{Deserialize, Serialize};

/// Where a probe touches a bed: the x and y of its tip as linear forms of
/// carriage positions (`Σ coef·position + offset`, as a switch's own form),
/// and the bed's surface.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BedContact {
    /// The tip's x: terms (a `stepper` module and its coefficient).
    pub x_terms: Vec<(String, f64)>,
    /// Added to the tip's x.
    #[serde(default)]
    pub x_offset: f64,
    /// The tip's y: terms.
    pub y_terms: Vec<(String, f64)>,
    /// Added to the tip's y.
    #[serde(default)]
    pub y_offset: f64,
    /// The bed.
    pub surface: BedSurface,
}

impl BedContact {
    /// The bed's height under the tip with carriages at `position(module)`.
    pub fn height(&self, mut position: impl FnMut(&str) -> f64) -> f64 {
        let x = self.x_offset
            + self
                .x_terms
                .iter()
                .map(|(m, c)| c * position(m))
                .sum::<f64>();
        let y = self.y_offset
            + self
                .y_terms
                .iter()
                .map(|(m, c)| c * position(m))
                .sum::<f64>();
        self.surface.height(x, y)
    }

    /// The modules its forms name.
    pub fn modules(&self) -> impl Iterator<Item = &str> {
        self.x_terms
            .iter()
            .chain(&self.y_terms)
            .map(|(m, _)| m.as_str())
    }

    /// Checks the values; the message names the key and the fix.
    pub(crate) fn check(&self) -> Result<(), String> {
        self.surface.check().map_err(|e| e.to_string())?;
        for (key, v) in [("x_offset", self.x_offset), ("y_offset", self.y_offset)] {
            if !v.is_finite() {
                return Err(format!("bed contact {key} = {v} must be finite"));
            }
        }
        for (key, terms) in [("x_terms", &self.x_terms), ("y_terms", &self.y_terms)] {
            if let Some((m, c)) = terms.iter().find(|(_, c)| !c.is_finite()) {
                return Err(format!(
                    "bed contact {key}: coefficient {c} of {m:?} must be finite"
                ));
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
    fn the_contact_reads_x_and_y_from_the_carriages() {
        let c = BedContact {
            x_terms: vec![("x".into(), 1.0)],
            x_offset: 150.0,
            y_terms: vec![("y".into(), -1.0)],
            y_offset: 100.0,
            surface: bed(),
        };
        // Carriages at 0: the tip at the centre.
        assert!((c.height(|_| 0.0) - (-69.8)).abs() < 1e-12);
        // y inverted: y's carriage at -100 puts the tip at y = 200.
        let h = c.height(|m| if m == "y" { -100.0 } else { 150.0 });
        assert!((h - bed().height(300.0, 200.0)).abs() < 1e-12);
        assert_eq!(c.modules().collect::<Vec<_>>(), ["x", "y"]);
    }
}
