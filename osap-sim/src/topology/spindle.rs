//! A spindle on a module's I/O pins (`[module.io.spindle]` in a topology
//! file): a motor and its drive (a VFD or BLDC controller) commanded by a
//! PWM output, with a tachometer whose pulses reach a digital pin.

use serde::{Deserialize, Serialize};

use super::board::BoardError;
use super::{DIGITAL_PINS, PWM_OUTPUTS};

/// A simulated spindle (see
/// [`Spindle`](crate::machine::board::spindle::Spindle)): the drive
/// follows the commanded speed `duty × max_rpm` of PWM output `pwm` as a
/// first-order response of time constant `time_constant_s`, its torque
/// held to `max_torque_nm`, against the rotor's `inertia_kgm2`, a constant
/// `drag_nm` and any load a test applies; a tachometer gives
/// `pulses_per_rev` rising edges a turn on digital pin `tach_pin`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpindleSpec {
    /// The PWM output commanding the speed (through a 0–10 V converter).
    pub pwm: u8,
    /// The speed at full duty, rpm.
    pub max_rpm: f64,
    /// The digital pin the tachometer's pulses reach.
    pub tach_pin: u8,
    /// Tachometer pulses a turn.
    pub pulses_per_rev: u16,
    /// The rotor's inertia with its collet and tool, kg·m².
    pub inertia_kgm2: f64,
    /// The most torque the drive gives, N·m.
    pub max_torque_nm: f64,
    /// The drive's speed response's time constant, s.
    pub time_constant_s: f64,
    /// Bearing and air drag, N·m (default 0).
    #[serde(default)]
    pub drag_nm: f64,
}

impl SpindleSpec {
    /// Checks the values; the message says which and why.
    pub fn check(&self) -> Result<(), BoardError> {
        if self.pwm >= PWM_OUTPUTS {
            return Err(BoardError::new(format!(
                "[module.io.spindle] pwm {} does not exist; a module has {PWM_OUTPUTS}",
                self.pwm
            )));
        }
        if self.tach_pin >= DIGITAL_PINS {
            return Err(BoardError::new(format!(
                "[module.io.spindle] tach_pin {} does not exist; a module has {DIGITAL_PINS}",
                self.tach_pin
            )));
        }
        if self.pulses_per_rev == 0 {
            return Err(BoardError::new(
                "[module.io.spindle] pulses_per_rev must be at least 1",
            ));
        }
        for (name, v) in [
            ("max_rpm", self.max_rpm),
            ("inertia_kgm2", self.inertia_kgm2),
            ("max_torque_nm", self.max_torque_nm),
            ("time_constant_s", self.time_constant_s),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(BoardError::new(format!(
                    "[module.io.spindle] {name} {v} must be finite and positive"
                )));
            }
        }
        if !(self.drag_nm.is_finite() && (0.0..self.max_torque_nm).contains(&self.drag_nm)) {
            return Err(BoardError::new(format!(
                "[module.io.spindle] drag_nm {} must be at least 0 and below max_torque_nm",
                self.drag_nm
            )));
        }
        Ok(())
    }
}
