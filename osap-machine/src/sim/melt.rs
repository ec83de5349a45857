//! The simulated melt `[sim.axes.e]`'s melt keys put behind the
//! extruder, on the extruder motor's module, in its hotend's block, with
//! the load cell of `[axes.e.loadcell]` weighing it.

use osap_sim::topology::MeltSpec;

use crate::config::{MachineFile, Output};

/// The simulated melt on module `key` (a key of `[modules]`), if the
/// extruder's motor is there and `[sim.axes.e]` gives a melt:
/// `Err((key, message))` when it cannot be simulated.
pub(crate) fn sim_melt(cfg: &MachineFile, key: &str) -> Result<Option<MeltSpec>, (String, String)> {
    let Some(melt) = cfg
        .sim
        .as_ref()
        .and_then(|s| s.axes.get("e"))
        .and_then(|a| a.melt)
    else {
        return Ok(None);
    };
    let Some(e) = cfg.extruder() else {
        return Ok(None);
    };
    let on_key = cfg
        .motor_for_axis("e")
        .and_then(|m| cfg.motors.get(m))
        .is_some_and(|m| m.module == key);
    if !on_key {
        return Ok(None);
    }
    let Some(hotend) = cfg.heaters.iter().find(|(_, h)| h.module == key) else {
        return Err((
            "sim.axes.e.flow_k".into(),
            format!(
                "the simulated melt is in the hotend's block: put a heater ([heaters.hotend]) on the extruder's module {key:?}"
            ),
        ));
    };
    let (data_pin, clock_pin) = match &e.extruder.loadcell {
        Some(l) if l.module != key => {
            return Err((
                "axes.e.loadcell.module".into(),
                format!(
                    "the simulated load cell weighs the extruder's filament: put it on the extruder's module {key:?}"
                ),
            ))
        }
        Some(l) => (l.data_pin, l.clock_pin),
        // No load cell: the converter sits on two pins no tool uses.
        None => {
            let used = |p: u8| {
                cfg.tools
                    .values()
                    .any(|t| t.module == key && matches!(t.output, Output::Digital(d) if d == p))
            };
            let mut free = (0..crate::config::DIGITAL_PINS).rev().filter(|p| !used(*p));
            match (free.next(), free.next()) {
                (Some(c), Some(d)) => (d, c),
                _ => {
                    return Err((
                        "sim.axes.e.flow_k".into(),
                        format!("module {key:?} has no two digital pins free for the simulated load cell"),
                    ))
                }
            }
        }
    };
    let counts_per_newton = e
        .extruder
        .loadcell
        .as_ref()
        .map_or(2_000.0, |l| 1.0 / l.newtons_per_count);
    Ok(Some(MeltSpec {
        filament_diameter: e.extruder.filament_diameter.unwrap_or(1.75),
        heater_pwm: hotend.1.pwm(),
        flow_k: melt.flow_k,
        flow_n: melt.flow_n,
        temp_coeff: melt.temp_coeff,
        t_ref: melt.t_ref,
        response_ms: melt.response_ms,
        noise_n: melt.noise_n,
        grip_n: e.extruder.max_force_n.unwrap_or(f64::INFINITY),
        data_pin,
        clock_pin,
        counts_per_newton,
        ..MeltSpec::default()
    }))
}
