//! `[winch]`: a cable robot's physical world, a point mass held by cables
//! wound on spools on the motors of `stepper` modules (see
//! [`crate::machine::winch`] for the physics).

use super::{ModuleKind, SimSpec};
use maxl::motor::StepperModel;
use serde::{Deserialize, Serialize};

fn default_gravity() -> f64 {
    9.81
}
fn default_stiffness() -> f64 {
    20_000.0
}
fn default_damping() -> f64 {
    20.0
}
fn default_counts() -> u32 {
    16_384
}
fn default_radius() -> f64 {
    12.0
}
fn default_spool_inertia() -> f64 {
    // An aluminium drum 24 mm across and 20 mm long: 24 g, ½·m·r².
    1.7e-6
}
fn default_friction() -> f64 {
    0.002
}
fn default_viscous() -> f64 {
    1e-5
}

/// A cable robot's world, `[winch]` in a topology file (the physics:
/// [`crate::machine::winch`]):
///
/// ```toml
/// [winch]
/// mass_kg = 1.0                    # the point mass
/// start = [0.5, 0.5]               # where it hangs at boot, m (x right, y up)
/// gravity = 9.81                   # optional, m/s² (down, along −y)
/// cable_stiffness_n_per_m = 20000  # optional: the cable's EA / length
/// cable_damping_ns_per_m = 20.0    # optional
/// encoder_counts = 16384           # optional: each motor's encoder, per turn
/// [winch.model]                    # every motor's datasheet values (SI)
/// holding_torque_nm = 0.45
/// rated_current_a = 2.0
/// resistance_ohm = 1.4
/// inductance_h = 0.003
/// supply_v = 24.0
/// rotor_inertia_kgm2 = 54e-7
/// steps_per_rev = 200.0
/// [[winch.spool]]                  # one per cable
/// module = "a"                     # the stepper whose motor turns it
/// anchor = [0.0, 1.0]              # where its cable leaves the frame, m
/// radius_mm = 12.0                 # optional (default 12)
/// inertia_kgm2 = 1.7e-6            # optional: the spool's own (default 1.7e-6)
/// friction_nm = 0.002              # optional: Coulomb friction (default 2 mN·m)
/// viscous_nms = 1e-5               # optional: viscous friction (default 1e-5)
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WinchSpec {
    /// The point mass, kg.
    pub mass_kg: f64,
    /// Where the mass hangs at boot, m, in the frame's vertical plane (x
    /// right, y up).
    pub start: [f64; 2],
    /// Gravity, m/s², along −y.
    #[serde(default = "default_gravity")]
    pub gravity: f64,
    /// Each cable's axial stiffness over its length, N/m.
    #[serde(default = "default_stiffness")]
    pub cable_stiffness_n_per_m: f64,
    /// Each cable's axial damping, N·s/m.
    #[serde(default = "default_damping")]
    pub cable_damping_ns_per_m: f64,
    /// Each motor's shaft encoder, counts per turn (an AS5047P: 16 384).
    #[serde(default = "default_counts")]
    pub encoder_counts: u32,
    /// Every motor's datasheet values.
    pub model: StepperModel,
    /// The spools, one per cable: `[[winch.spool]]`.
    #[serde(rename = "spool")]
    pub spools: Vec<SpoolSpec>,
}

/// One cable's spool, `[[winch.spool]]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpoolSpec {
    /// The `stepper` module whose motor turns it.
    pub module: String,
    /// Where its cable leaves the frame towards the mass, m.
    pub anchor: [f64; 2],
    /// The drum's radius, mm.
    #[serde(default = "default_radius")]
    pub radius_mm: f64,
    /// The drum's own inertia, kg·m² (the rotor's is the model's).
    #[serde(default = "default_spool_inertia")]
    pub inertia_kgm2: f64,
    /// Coulomb friction of the spool's bearings and the cable's guide, N·m.
    #[serde(default = "default_friction")]
    pub friction_nm: f64,
    /// Viscous friction, N·m·s/rad.
    #[serde(default = "default_viscous")]
    pub viscous_nms: f64,
}

impl SimSpec {
    /// Checks `[winch]`: finite, positive values, each spool on a distinct
    /// `stepper`, at least three cables, the mass away from every anchor.
    pub(super) fn check_winch(&self) -> Result<(), String> {
        let Some(w) = &self.winch else {
            return Ok(());
        };
        let bad = |key: &str, why: String| format!("winch.{key}: {why}");
        let positive = [
            ("mass_kg", w.mass_kg),
            ("cable_stiffness_n_per_m", w.cable_stiffness_n_per_m),
            ("cable_damping_ns_per_m", w.cable_damping_ns_per_m),
        ];
        for (key, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(bad(key, format!("{v} must be finite and positive")));
            }
        }
        if !(w.gravity.is_finite() && w.gravity >= 0.0) {
            return Err(bad(
                "gravity",
                format!("{} must be finite and at least 0", w.gravity),
            ));
        }
        if w.encoder_counts < 4 {
            return Err(bad(
                "encoder_counts",
                format!(
                    "{} counts a turn is no encoder; an AS5047P has 16384",
                    w.encoder_counts
                ),
            ));
        }
        w.model
            .check()
            .map_err(|e| bad(&format!("model.{}", e.name), e.to_string()))?;
        if !w.start.iter().all(|v| v.is_finite()) {
            return Err(bad("start", format!("{:?} must be finite", w.start)));
        }
        if w.spools.len() < 3 {
            return Err(bad(
                "spool",
                format!(
                    "{} cables cannot hold a mass in a plane against gravity and keep their tension; give at least 3 [[winch.spool]]",
                    w.spools.len()
                ),
            ));
        }
        for (i, s) in w.spools.iter().enumerate() {
            let key = |k: &str| format!("spool[{i}].{k}");
            match self.module_index(&s.module).map(|m| &self.modules[m]) {
                Some(m) if m.kind() == Some(ModuleKind::Stepper) => {}
                _ => {
                    return Err(bad(
                        &key("module"),
                        format!("{:?} is not a module of type \"stepper\"", s.module),
                    ))
                }
            }
            if w.spools[..i].iter().any(|o| o.module == s.module) {
                return Err(bad(
                    &key("module"),
                    format!("{:?} already turns a spool; one spool per motor", s.module),
                ));
            }
            for (k, v) in [("radius_mm", s.radius_mm), ("inertia_kgm2", s.inertia_kgm2)] {
                if !(v.is_finite() && v > 0.0) {
                    return Err(bad(&key(k), format!("{v} must be finite and positive")));
                }
            }
            for (k, v) in [
                ("friction_nm", s.friction_nm),
                ("viscous_nms", s.viscous_nms),
            ] {
                if !(v.is_finite() && v >= 0.0) {
                    return Err(bad(&key(k), format!("{v} must be finite and at least 0")));
                }
            }
            let d = (s.anchor[0] - w.start[0]).hypot(s.anchor[1] - w.start[1]);
            if !(d.is_finite() && d > 1e-3) {
                return Err(bad(
                    &key("anchor"),
                    format!(
                        "{:?} must be finite and away from start {:?}",
                        s.anchor, w.start
                    ),
                ));
            }
        }
        Ok(())
    }
}
