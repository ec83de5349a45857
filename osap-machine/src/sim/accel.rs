//! The simulated accelerometer an axis's `accelerometer` key puts on its
//! module.

use osap_sim::topology::AccelSpec;

use crate::config::{Accelerometer, MachineFile};

/// The simulated accelerometer on module `key` (a key of `[modules]`), if
/// an axis's accelerometer is there: `Err((key, message))` when it cannot
/// be simulated.
pub(crate) fn sim_accel(
    cfg: &MachineFile,
    key: &str,
) -> Result<Option<AccelSpec>, (String, String)> {
    let on_key: Vec<(&String, &Accelerometer)> = cfg
        .axes
        .iter()
        .filter_map(|(n, a)| Some((n, a.accelerometer.as_ref().filter(|a| a.module == key)?)))
        .collect();
    let Some(&(axis, acc)) = on_key.first() else {
        return Ok(None);
    };
    if let Some((other, _)) = on_key.get(1) {
        return Err((
            format!("axes.{other}.accelerometer.module"),
            format!(
                "axes {axis} and {other} both have their accelerometer on module {key:?}; the simulator carries one per module: put them on different modules"
            ),
        ));
    }
    let at = format!("axes.{axis}.accelerometer.module");
    let form = super::axis_form(cfg, axis).map_err(|e| (at.clone(), e.to_string()))?;
    let name = super::module_name(cfg, key).unwrap_or(key);
    let Some(&(_, c)) = form.terms.iter().find(|(m, _)| m == name) else {
        return Err((
            at,
            format!(
                "the simulated accelerometer sees its own module's carriage, and module {key:?} drives no motor of axis {axis}; put it on one that does"
            ),
        ));
    };
    // The axis moves by Δ while this carriage moves by Δ/(n·c) (cartesian
    // n = 1; corexy n = 2, c = ±1/2).
    let coef = c * form.terms.len() as f64;
    let (resonance_hz, damping_ratio) = cfg
        .sim
        .as_ref()
        .and_then(|s| s.axes.get(axis.as_str()))
        .and_then(|a| a.resonance())
        .unwrap_or((1000.0, 0.7));
    let spec = AccelSpec {
        channel: acc.channel,
        resonance_hz,
        damping_ratio,
        range: acc.range,
        coef,
    };
    spec.check().map_err(|e| (at, e.to_string()))?;
    Ok(Some(spec))
}
