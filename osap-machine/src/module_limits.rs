//! The limits each motor's module holds incoming points to.
//!
//! A module with limits set (`set_limits`) refuses a control point past its
//! velocity, acceleration or jerk limit, as the stream's finite differences
//! at the control interval measure them, and reports the refusal as a
//! fault. That is a backstop against a stream no plan of this machine
//! could produce (a script's bad point, a corrupted or misrouted stream),
//! so the limits sit a margin (`[limits] module_margin`, default 1.5)
//! above the most the planner can command each motor:
//!
//! - **Velocity**: each axis's velocity, carried to the motor through the
//!   kinematics (a CoreXY belt moves at up to `|vx| + |vy|`).
//! - **Acceleration**: each axis's acceleration, plus the velocity step a
//!   corner takes within one control interval. Profiles are trapezoidal
//!   and junctions are limited by the junction deviation δ, so the
//!   velocity changes by at most `min(√(8·a·δ), 2·v)` at a corner (a
//!   junction at speed `v` between directions `θ` apart changes the
//!   velocity by `2v·sin(θ/2)`, and the junction limit holds
//!   `v² ≤ a·δ·c/(1 − c)` with `c = cos(θ/2)`, so the step is at most
//!   `√(4·a·δ·c·(1 + c)) ≤ √(8·a·δ)`), and that step lands within one
//!   interval.
//! - **Jerk**: unchecked (the profiles step the acceleration, so a
//!   stream's jerk is the acceleration over one interval), unless a motor
//!   gives its own `limits`.
//!
//! A motor's own `[motors.NAME] limits = { velocity, acceleration, jerk }`
//! (motor units) replaces the derived ones. Motors of an arm (SCARA,
//! five-bar) have no derived limits: their joint speeds are not bounded by
//! the tool's, near the arm's singular poses, so only their own `limits`
//! turn the check on.

use crate::config::{Kinematics, MachineFile};

/// A motor's module limits in motor units per s, s² and s³ (0: unchecked).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ModuleLimits {
    /// Most velocity.
    pub velocity: f64,
    /// Most acceleration.
    pub acceleration: f64,
    /// Most jerk (0: unchecked).
    pub jerk: f64,
}

/// The limits `motor`'s module is set to, or `None` if its points go
/// unchecked (`module_margin = 0`, or an arm motor without its own
/// `limits`). `interval_s` is the control-point interval.
pub fn module_limits(cfg: &MachineFile, motor: &str, interval_s: f64) -> Option<ModuleLimits> {
    let own = cfg.motors.get(motor)?.limits;
    if let Some(l) = own {
        return Some(ModuleLimits {
            velocity: l.velocity,
            acceleration: l.acceleration,
            jerk: l.jerk,
        });
    }
    let margin = cfg.limits.module_margin;
    if margin == 0.0 {
        return None;
    }
    // Each axis the motor follows, with the motor's travel per axis unit.
    let mut axes: Vec<(&str, f64)> = Vec::new();
    for (name, axis) in &cfg.axes {
        if axis.motor.as_deref() == Some(motor) {
            axes.push((name, 1.0));
        }
    }
    if let Kinematics::CoreXy { motors } = &cfg.kinematics {
        if motors.iter().any(|m| m == motor) {
            // a = x + y, b = x − y.
            axes.push(("x", 1.0));
            axes.push(("y", 1.0));
        }
    }
    if axes.is_empty() {
        return None;
    }
    let lim = &cfg.limits;
    let mut velocity = 0.0;
    let mut acceleration = 0.0;
    for (name, gain) in axes {
        let axis = cfg.axes.get(name)?;
        let v = axis.velocity.min(lim.velocity);
        let a = axis.acceleration.max(lim.acceleration);
        let corner = (8.0 * a * lim.junction_deviation).sqrt().min(2.0 * v);
        velocity += gain * v;
        acceleration += gain * (axis.acceleration + corner / interval_s);
    }
    Some(ModuleLimits {
        velocity: margin * velocity,
        acceleration: margin * acceleration,
        jerk: 0.0,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::MachineFile;

    fn file(kinematics: &str, axes: &str, extra: &str) -> MachineFile {
        let text = format!(
            r#"
name = "t"
[modules.m1]
name = "m1"
[modules.m2]
name = "m2"
[modules.m3]
name = "m3"
[motors.a]
module = "m1"
full_steps_per_unit = 5.0
[motors.b]
module = "m2"
full_steps_per_unit = 5.0
[motors.z]
module = "m3"
full_steps_per_unit = 5.0
{extra}
[kinematics]
{kinematics}
{axes}
[limits]
velocity = 100.0
acceleration = 1000.0
junction_deviation = 0.05
"#
        );
        MachineFile::parse(&text).unwrap()
    }

    const XY_CORE: &str = r#"
[axes.x]
min = 0.0
max = 100.0
velocity = 100.0
acceleration = 1000.0
jerk = 10000.0
[axes.y]
min = 0.0
max = 100.0
velocity = 50.0
acceleration = 500.0
jerk = 10000.0
[axes.z]
motor = "z"
min = 0.0
max = 10.0
velocity = 10.0
acceleration = 100.0
jerk = 1000.0
"#;

    #[test]
    fn corexy_belts_carry_both_axes_and_z_its_own() {
        let cfg = file("type = \"corexy\"\nmotors = [\"a\", \"b\"]", XY_CORE, "");
        let dt = 0.002048;
        let a = module_limits(&cfg, "a", dt).unwrap();
        assert!((a.velocity - 1.5 * 150.0).abs() < 1e-9);
        let corner = (8.0f64 * 1000.0 * 0.05).sqrt();
        let want = 1.5 * (1000.0 + corner / dt + 500.0 + corner / dt);
        assert!((a.acceleration - want).abs() < 1e-6, "{a:?}");
        assert_eq!(a.jerk, 0.0);
        assert_eq!(module_limits(&cfg, "b", dt), Some(a));
        let z = module_limits(&cfg, "z", dt).unwrap();
        // z's corner step is capped by twice its speed.
        assert!((z.velocity - 15.0).abs() < 1e-9);
        assert!((z.acceleration - 1.5 * (100.0 + 20.0 / dt)).abs() < 1e-6);
    }

    #[test]
    fn a_motors_own_limits_win_and_margin_zero_turns_derived_ones_off() {
        let own = "[motors.a.limits]\nvelocity = 7.0\nacceleration = 8.0\njerk = 9.0\n";
        let cfg = file("type = \"corexy\"\nmotors = [\"a\", \"b\"]", XY_CORE, "");
        let mut cfg2 = file("type = \"corexy\"\nmotors = [\"a\", \"b\"]", XY_CORE, own);
        cfg2.limits.module_margin = 0.0;
        assert_eq!(
            module_limits(&cfg2, "a", 0.002),
            Some(ModuleLimits {
                velocity: 7.0,
                acceleration: 8.0,
                jerk: 9.0
            })
        );
        assert_eq!(module_limits(&cfg2, "b", 0.002), None);
        assert!(module_limits(&cfg, "nobody", 0.002).is_none());
    }
}
