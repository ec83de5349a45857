//! A spindle's speed feedback (`[tools.NAME] tach = { .. }`) and its
//! simulated motor (`[sim.spindles.NAME]`).
//!
//! A spindle with a tachometer reports its measured speed through its
//! module's `tach_read`: setting a speed then waits until the measured
//! speed is within `tolerance` of it (never a fixed settle time), and a
//! speed that falls below `stall_fraction` of the commanded one while the
//! spindle runs is a stall, which faults the machine.

use serde::Deserialize;

use super::validate::{finite_in, positive};
use super::{invalid, ConfigError, MachineFile, ToolKind, DIGITAL_PINS};

/// A spindle's tachometer: a hall sensor or encoder on a digital pin of
/// the tool's module.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Tach {
    /// The digital pin its pulses come in on (0..=3).
    pub pin: u8,
    /// Pulses a turn (a BLDC's hall sensor gives its pole pairs, a slotted
    /// disc its slots), 1 to 1 000.
    pub pulses_per_rev: u16,
    /// How close to the commanded speed counts as at speed, a fraction of
    /// it (default 0.02).
    #[serde(default = "default_tolerance")]
    pub tolerance: f64,
    /// How long a speed change may take before it is an error, s (default
    /// 15).
    #[serde(default = "default_timeout")]
    pub timeout_s: f64,
    /// Below this fraction of the commanded speed, a running spindle has
    /// stalled (default 0.7).
    #[serde(default = "default_stall_fraction")]
    pub stall_fraction: f64,
}

fn default_tolerance() -> f64 {
    0.02
}

fn default_timeout() -> f64 {
    15.0
}

fn default_stall_fraction() -> f64 {
    0.7
}

/// A simulated spindle (`[sim.spindles.NAME]`, NAME a spindle of
/// `[tools]`): a rotor of inertia `J` behind a drive (a VFD or BLDC
/// controller) that follows the commanded speed `ω_c = duty × max_rpm`
/// (through the tool's duties) as a first-order response of time constant
/// `τ`, with its torque held to `max_torque_nm` and a drag always acting:
/// the drive asks `J·(ω_c − ω)/τ + drag`, gives at most the torque
/// limit, and `J·dω/dt = T − drag − load`. A load beyond the torque limit
/// stalls it.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimSpindle {
    /// The rotor's inertia with its collet and tool, kg·m².
    pub inertia_kgm2: f64,
    /// The most torque the drive gives, N·m.
    pub max_torque_nm: f64,
    /// The drive's speed response's time constant, s.
    pub time_constant_s: f64,
    /// The bearings' and air's drag, N·m (default 0).
    #[serde(default)]
    pub drag_nm: f64,
}

impl MachineFile {
    /// Checks each tool's `tach` and each `[sim.spindles.NAME]`.
    pub(super) fn validate_spindles(&self) -> Result<(), ConfigError> {
        for (key, tool) in &self.tools {
            let Some(tach) = &tool.tach else { continue };
            let at = format!("tools.{key}.tach");
            if tool.kind != ToolKind::Spindle || tool.max_rpm.is_none() {
                return Err(invalid(
                    at,
                    "a tachometer measures a spindle's speed: give it to a kind = \"spindle\" tool with max_rpm",
                ));
            }
            if tach.pin >= DIGITAL_PINS {
                return Err(invalid(
                    format!("{at}.pin"),
                    format!(
                        "digital pin {} does not exist; a module has pins 0 to {}",
                        tach.pin,
                        DIGITAL_PINS - 1
                    ),
                ));
            }
            if matches!(tool.output, super::Output::Digital(p) if p == tach.pin) {
                return Err(invalid(
                    format!("{at}.pin"),
                    "the spindle's own output is on that pin: give the tachometer an input pin of its own",
                ));
            }
            if !(1..=1000).contains(&tach.pulses_per_rev) {
                return Err(invalid(
                    format!("{at}.pulses_per_rev"),
                    format!("{} pulses a turn: give 1 to 1000", tach.pulses_per_rev),
                ));
            }
            finite_in(&format!("{at}.tolerance"), tach.tolerance, 0.001, 0.5)?;
            positive(&format!("{at}.timeout_s"), tach.timeout_s, "s")?;
            finite_in(
                &format!("{at}.stall_fraction"),
                tach.stall_fraction,
                0.05,
                1.0 - tach.tolerance,
            )?;
        }
        let Some(sim) = &self.sim else {
            return Ok(());
        };
        for (name, s) in &sim.spindles {
            let at = format!("sim.spindles.{name}");
            if self
                .tools
                .get(name)
                .is_none_or(|t| t.kind != ToolKind::Spindle || t.max_rpm.is_none())
            {
                return Err(invalid(
                    at,
                    format!("{name:?} is not a spindle of [tools] with max_rpm; name one"),
                ));
            }
            positive(&format!("{at}.inertia_kgm2"), s.inertia_kgm2, "kg·m²")?;
            positive(&format!("{at}.max_torque_nm"), s.max_torque_nm, "N·m")?;
            positive(&format!("{at}.time_constant_s"), s.time_constant_s, "s")?;
            finite_in(&format!("{at}.drag_nm"), s.drag_nm, 0.0, s.max_torque_nm)?;
        }
        Ok(())
    }
}
