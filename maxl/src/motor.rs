//! A stepper motor's torque at speed, from the values on its datasheet.
//!
//! A hybrid stepper's driver regulates each phase's current to the rated
//! current while it can. As the motor turns faster, the supply must also
//! overcome the phase's inductance and the motor's back-EMF, so above some
//! speed the current, and with it the torque, falls. The holding torque is
//! given with both phases at the rated current, so one phase's torque (and
//! back-EMF) constant is `k = T_hold / (√2·I_rated)`. With `p =
//! steps_per_rev / 4` rotor pole pairs, mechanical speed `ω` and electrical
//! speed `p·ω`, the model takes what the supply `V` has left over the
//! back-EMF `E = k·ω` across the phase's impedance:
//!
//! ```text
//! I(ω) = min(I_rated, (V − E) / √(R² + (p·ω·L)²))      T(ω) = T_hold·I(ω)/I_rated
//! ```
//!
//! the holding torque at rest, 0 once the back-EMF reaches the supply.
//! (Taking the back-EMF as opposing the supply head on is the pessimistic
//! case of a driver that does not advance the current's phase; datasheet
//! pull-out curves of 24 V NEMA 17 motors fall about this way.) The model
//! leaves out detent torque, the driver's chopping and mid-band resonance;
//! a planner using it keeps a margin.

use core::f64::consts::PI;

/// Why a [`StepperModel`] was refused: the value's name.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BadMotorValue {
    /// Which value.
    pub name: &'static str,
    /// The value.
    pub value: f64,
}

impl core::fmt::Display for BadMotorValue {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "{} = {} must be finite and positive",
            self.name, self.value
        )
    }
}

impl core::error::Error for BadMotorValue {}

/// A stepper motor's electrical and mechanical values (see the module
/// docs).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct StepperModel {
    /// Holding torque at the rated current, N·m.
    pub holding_torque_nm: f64,
    /// The phase current the driver is set to, A.
    pub rated_current_a: f64,
    /// Phase resistance, Ω.
    pub resistance_ohm: f64,
    /// Phase inductance, H.
    pub inductance_h: f64,
    /// The driver's supply, V.
    pub supply_v: f64,
    /// The rotor's inertia, kg·m².
    pub rotor_inertia_kgm2: f64,
    /// Full steps per revolution (200 for a 1.8° motor).
    pub steps_per_rev: f64,
}

impl StepperModel {
    /// Checks every value: finite and positive.
    pub fn check(&self) -> Result<(), BadMotorValue> {
        for (name, value) in [
            ("holding_torque_nm", self.holding_torque_nm),
            ("rated_current_a", self.rated_current_a),
            ("resistance_ohm", self.resistance_ohm),
            ("inductance_h", self.inductance_h),
            ("supply_v", self.supply_v),
            ("rotor_inertia_kgm2", self.rotor_inertia_kgm2),
            ("steps_per_rev", self.steps_per_rev),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(BadMotorValue { name, value });
            }
        }
        Ok(())
    }

    /// One phase's torque per amp, N·m/A, and back-EMF, V per rad/s.
    pub fn torque_constant(&self) -> f64 {
        self.holding_torque_nm / (core::f64::consts::SQRT_2 * self.rated_current_a)
    }

    /// The phase current the supply can drive at `omega` rad/s (either
    /// direction), A.
    pub fn current_at(&self, omega: f64) -> f64 {
        let w = omega.abs();
        let e = self.torque_constant() * w;
        let v = self.supply_v;
        if e >= v {
            return 0.0;
        }
        let x = 0.25 * self.steps_per_rev * w * self.inductance_h;
        ((v - e) / self.resistance_ohm.hypot(x)).clamp(0.0, self.rated_current_a)
    }

    /// The torque available at `omega` rad/s, N·m.
    pub fn torque_at(&self, omega: f64) -> f64 {
        self.holding_torque_nm * self.current_at(omega) / self.rated_current_a
    }

    /// The small-signal stiffness about a full-step equilibrium, N·m/rad:
    /// the torque rises as `T_hold·sin(π/2 · lag in full steps)`.
    pub fn stiffness(&self) -> f64 {
        self.holding_torque_nm * 0.5 * PI * self.steps_per_rev / (2.0 * PI)
    }

    /// Radians per full step.
    pub fn step_angle(&self) -> f64 {
        2.0 * PI / self.steps_per_rev
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A NEMA 17 (0.45 N·m, 2 A, 1.4 Ω, 3 mH, 54 g·cm²) on 24 V.
    fn nema17() -> StepperModel {
        StepperModel {
            holding_torque_nm: 0.45,
            rated_current_a: 2.0,
            resistance_ohm: 1.4,
            inductance_h: 3.0e-3,
            supply_v: 24.0,
            rotor_inertia_kgm2: 54e-7,
            steps_per_rev: 200.0,
        }
    }

    #[test]
    fn torque_holds_then_falls_with_speed() {
        let m = nema17();
        m.check().unwrap();
        assert_eq!(m.torque_at(0.0), 0.45);
        // Below the corner the driver holds the rated current.
        assert_eq!(m.torque_at(10.0), 0.45);
        let mut last = 0.45;
        for rps in [2.0, 5.0, 10.0, 20.0, 40.0] {
            let t = m.torque_at(2.0 * PI * rps);
            assert!(t <= last && t >= 0.0, "{rps} rev/s: {t}");
            last = t;
        }
        // At 10 rev/s (400 mm/s on a 40 mm pulley), k = 0.159 V·s: (24 −
        // 10.0 V) over 9.5 Ω, 1.47 A: 0.33 N·m, 73 % of holding; at the
        // back-EMF limit (24 V / 0.159 V·s = 151 rad/s, 24 rev/s) nothing.
        let k = 0.45 / (2f64.sqrt() * 2.0);
        let w = 2.0 * PI * 10.0;
        let want = 0.45 / 2.0 * (24.0 - k * w) / 1.4f64.hypot(50.0 * w * 3e-3);
        assert!((m.torque_at(w) - want).abs() < 1e-12);
        assert!((0.32..0.34).contains(&want), "{want}");
        assert_eq!(m.torque_at(24.0 / k + 1.0), 0.0);
    }

    #[test]
    fn bad_values_are_named() {
        let mut m = nema17();
        m.inductance_h = 0.0;
        assert_eq!(m.check().unwrap_err().name, "inductance_h");
        m = nema17();
        m.supply_v = f64::NAN;
        assert!(m.check().unwrap_err().to_string().contains("supply_v"));
    }
}
