//! `[motors.NAME.model]`, `[axes.NAME] moving_mass_kg` and `[limits] model
//! = "motors"`: planning from what the motors can give.

use maxl::motor::StepperModel;
use serde::Deserialize;

use super::{invalid, ConfigError, Kinematics, MachineFile};

/// The default share of a motor's torque the planner may use.
pub const DEFAULT_TORQUE_MARGIN: f64 = 0.7;

/// `[motors.NAME.model]`: a stepper's datasheet values.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotorModelKeys {
    /// Holding torque at the rated current, N·m.
    pub holding_torque_nm: f64,
    /// The phase current the driver is set to, A.
    pub rated_current_a: f64,
    /// Phase resistance, Ω.
    pub resistance_ohm: f64,
    /// Phase inductance, mH.
    pub inductance_mh: f64,
    /// The driver's supply, V.
    pub supply_v: f64,
    /// Rotor inertia, g·cm² (as datasheets give it).
    pub rotor_inertia_gcm2: f64,
    /// Full steps per revolution; default 200 (1.8°).
    #[serde(default = "default_steps_per_rev")]
    pub steps_per_rev: f64,
}

fn default_steps_per_rev() -> f64 {
    200.0
}

impl MotorModelKeys {
    /// The model in SI units.
    pub fn model(&self) -> StepperModel {
        StepperModel {
            holding_torque_nm: self.holding_torque_nm,
            rated_current_a: self.rated_current_a,
            resistance_ohm: self.resistance_ohm,
            inductance_h: self.inductance_mh * 1e-3,
            supply_v: self.supply_v,
            rotor_inertia_kgm2: self.rotor_inertia_gcm2 * 1e-7,
            steps_per_rev: self.steps_per_rev,
        }
    }
}

/// `[limits] model`: what bounds each move's acceleration.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PlannerModel {
    /// The torque each motor has at the speed it turns
    /// (`[motors.NAME.model]`), over the masses it moves
    /// (`[axes.NAME] moving_mass_kg`) and its rotor, times
    /// `[limits] torque_margin`.
    Motors,
}

impl MachineFile {
    /// Checks the motor models, masses and `[limits] model`.
    pub(super) fn validate_motor_models(&self) -> Result<(), ConfigError> {
        for (name, m) in &self.motors {
            if let Some(k) = &m.model {
                k.model().check().map_err(|e| {
                    let key = match e.name {
                        "inductance_h" => "inductance_mh",
                        "rotor_inertia_kgm2" => "rotor_inertia_gcm2",
                        other => other,
                    };
                    invalid(
                        format!("motors.{name}.model.{key}"),
                        format!("{} must be finite and positive", e.value),
                    )
                })?;
            }
        }
        for (name, a) in &self.axes {
            if let Some(kg) = a.moving_mass_kg {
                if !(kg.is_finite() && kg >= 0.0) {
                    return Err(invalid(
                        format!("axes.{name}.moving_mass_kg"),
                        format!("{kg} must be finite and at least 0 (kg)"),
                    ));
                }
            }
        }
        let m = self.limits.torque_margin;
        if !(m.is_finite() && m > 0.0 && m <= 1.0) {
            return Err(invalid(
                "limits.torque_margin",
                format!("{m} must be in (0, 1], e.g. 0.7"),
            ));
        }
        if self.limits.model != Some(PlannerModel::Motors) {
            return Ok(());
        }
        if !matches!(
            self.kinematics,
            Kinematics::Cartesian {} | Kinematics::CoreXy { .. }
        ) {
            return Err(invalid(
                "limits.model",
                format!(
                    "planning from motor models needs kinematics linear in the motors (cartesian or corexy), not {}; remove model = \"motors\"",
                    self.kinematics.type_name()
                ),
            ));
        }
        for axis in self.axis_names().iter().take(self.toolhead_axes().max(1)) {
            let a = &self.axes[*axis];
            if a.moving_mass_kg.is_none() {
                return Err(invalid(
                    format!("axes.{axis}.moving_mass_kg"),
                    "model = \"motors\" needs the mass each toolhead axis moves, e.g. moving_mass_kg = 0.8",
                ));
            }
        }
        for motor in self.toolhead_motors() {
            if self.motors.get(motor).and_then(|m| m.model).is_none() {
                return Err(invalid(
                    format!("motors.{motor}.model"),
                    "model = \"motors\" needs every toolhead motor's datasheet values: [motors.NAME.model] holding_torque_nm, rated_current_a, resistance_ohm, inductance_mh, supply_v, rotor_inertia_gcm2",
                ));
            }
        }
        Ok(())
    }

    /// The motors that move the toolhead's axes.
    pub fn toolhead_motors(&self) -> Vec<&str> {
        let mut out: Vec<&str> = match &self.kinematics {
            Kinematics::Cartesian {} => Vec::new(),
            k => k.motors().iter().map(|s| s.as_str()).collect(),
        };
        for axis in self.axis_names().iter().take(self.toolhead_axes().max(1)) {
            if let Some(m) = self.motor_for_axis(axis) {
                out.push(m);
            }
        }
        out
    }
}
