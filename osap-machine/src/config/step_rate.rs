//! The step-rate check: no motor may be asked to step faster than its
//! module's step tick.
//!
//! A module makes at most one step per step tick
//! ([`osap_module::STEP_TICK_US`], 10 µs: 100 000 steps/s). A machine whose
//! speeds need more would send steps late, which the module reports as a
//! fault mid-job; the machine file is refused up front instead, naming the
//! motor, the speed that needs too many steps, and the two fixes (a lower
//! speed, or fewer microsteps).

use super::*;

/// The most microsteps per second a module makes: one per step tick.
pub const MAX_STEP_RATE: f64 = 1e6 / osap_module::STEP_TICK_US as f64;

/// The fastest `motor` turns (motor units/s) at the speeds the file allows,
/// with the key that sets it; `None` for arm motors (their joint speeds
/// are not bounded by the tool's near a singular pose) and unused motors.
fn fastest(cfg: &MachineFile, motor: &str) -> Option<(f64, String)> {
    for (name, axis) in &cfg.axes {
        if axis.motor.as_deref() == Some(motor) {
            // Homing searches within the axis's velocity (checked there).
            return Some((axis.velocity, format!("axes.{name}.velocity")));
        }
    }
    if let Kinematics::CoreXy { motors } = &cfg.kinematics {
        if motors.iter().any(|m| m == motor) {
            // A belt moves at |vx ± vy|: at most vx + vy by the axes, and
            // at most √2 · |v| by the toolhead's limit.
            let vx = cfg.axes.get("x").map_or(0.0, |a| a.velocity);
            let vy = cfg.axes.get("y").map_or(0.0, |a| a.velocity);
            let by_axes = vx + vy;
            let by_toolhead = std::f64::consts::SQRT_2 * cfg.limits.velocity;
            return Some(if by_toolhead < by_axes {
                (by_toolhead, "limits.velocity".to_string())
            } else {
                (by_axes, "axes.x.velocity and axes.y.velocity".to_string())
            });
        }
    }
    None
}

impl MachineFile {
    /// Refuses a motor whose fastest speed needs more microsteps per second
    /// than [`MAX_STEP_RATE`].
    pub(super) fn validate_step_rates(&self) -> Result<(), ConfigError> {
        for (name, motor) in &self.motors {
            let Some((speed, key)) = fastest(self, name) else {
                continue;
            };
            let per_unit = motor.full_steps_per_unit * f64::from(motor.microsteps);
            let rate = speed * per_unit;
            if rate > MAX_STEP_RATE {
                let slowest = MAX_STEP_RATE / per_unit;
                let mut fewer = motor.microsteps;
                while fewer > 1
                    && speed * motor.full_steps_per_unit * f64::from(fewer) > MAX_STEP_RATE
                {
                    fewer /= 2;
                }
                let microsteps_fix =
                    if speed * motor.full_steps_per_unit * f64::from(fewer) <= MAX_STEP_RATE {
                        format!(" or set motors.{name}.microsteps to {fewer}")
                    } else {
                        String::new()
                    };
                return Err(invalid(
                    format!("motors.{name}"),
                    format!(
                        "{key} {speed:.1} needs {rate:.0} microsteps/s ({per_unit} per unit), more than a module's {MAX_STEP_RATE:.0} (one per {} µs step tick); lower {key} to at most {slowest:.1}{microsteps_fix}",
                        osap_module::STEP_TICK_US
                    ),
                ));
            }
        }
        Ok(())
    }
}
