//! An extruder's keys in `[axes.e]`: the filament, its limits, pressure
//! advance, firmware retraction, the load cell on its path and the melt
//! model fitted from it.

use serde::Deserialize;

use super::{invalid, ConfigError, MachineFile, DIGITAL_PINS};

/// An extruder's keys in `[axes.e]`; every one is refused on another
/// kind of axis.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
pub struct ExtruderKeys {
    /// The filament's diameter, mm (1.75 or 2.85); required for an
    /// extruder.
    #[serde(default)]
    pub filament_diameter: Option<f64>,
    /// A cap on the melt flow of extruding moves, mm³/s: a move that
    /// would extrude faster is slowed (not retractions).
    #[serde(default)]
    pub max_volumetric_speed: Option<f64>,
    /// The drive's grip on the filament, N (what it can push before it
    /// slips or grinds).
    #[serde(default)]
    pub max_force_n: Option<f64>,
    /// Pressure advance, s (Klipper's `pressure_advance`): the extruder
    /// runs ahead by this times its velocity. Default 0 (off).
    #[serde(default)]
    pub pressure_advance: Option<f64>,
    /// The window pressure advance is smoothed over, s (Klipper's
    /// `pressure_advance_smooth_time`; default 0.040).
    #[serde(default)]
    pub smooth_time: Option<f64>,
    /// The largest change of the extruder's velocity at a corner, mm/s
    /// (Klipper's `instantaneous_corner_velocity`; default 1).
    #[serde(default)]
    pub instantaneous_corner_velocity: Option<f64>,
    /// Firmware retraction (`G10`): filament pulled back, mm (default 0.8).
    #[serde(default)]
    pub retract_length: Option<f64>,
    /// Firmware retraction speed (`G10`, `G11`), mm/s (default 35).
    #[serde(default)]
    pub retract_speed: Option<f64>,
    /// A load cell weighing the filament's push (`[axes.e.loadcell]`).
    #[serde(default)]
    pub loadcell: Option<LoadCellKeys>,
    /// The melt model `osap rheo --write` fitted (`[axes.e.model]`).
    #[serde(default)]
    pub model: Option<MeltModelKeys>,
}

/// The share of the drive's grip (`max_force_n`) a melt model's flow
/// limit lets the filament need: the rest is margin for the melt's
/// scatter, and for its lag during a change of speed.
pub const MODEL_FORCE_SHARE: f64 = 0.8;

/// [`ExtruderKeys::smooth_time`]'s default, s.
pub const DEFAULT_SMOOTH_TIME: f64 = 0.040;
/// [`ExtruderKeys::instantaneous_corner_velocity`]'s default, mm/s.
pub const DEFAULT_CORNER_VELOCITY: f64 = 1.0;
/// [`ExtruderKeys::retract_length`]'s default, mm.
pub const DEFAULT_RETRACT_LENGTH: f64 = 0.8;
/// [`ExtruderKeys::retract_speed`]'s default, mm/s.
pub const DEFAULT_RETRACT_SPEED: f64 = 35.0;

impl ExtruderKeys {
    /// The keys given, by name (to refuse them on a non-extruder axis).
    pub(super) fn given(&self) -> impl Iterator<Item = &'static str> + '_ {
        [
            ("filament_diameter", self.filament_diameter.is_some()),
            ("max_volumetric_speed", self.max_volumetric_speed.is_some()),
            ("max_force_n", self.max_force_n.is_some()),
            ("pressure_advance", self.pressure_advance.is_some()),
            ("smooth_time", self.smooth_time.is_some()),
            (
                "instantaneous_corner_velocity",
                self.instantaneous_corner_velocity.is_some(),
            ),
            ("retract_length", self.retract_length.is_some()),
            ("retract_speed", self.retract_speed.is_some()),
            ("loadcell", self.loadcell.is_some()),
            ("model", self.model.is_some()),
        ]
        .into_iter()
        .filter_map(|(k, given)| given.then_some(k))
    }

    /// The largest melt flow an extruding move may need with the hotend's
    /// target at `hotend_c` °C, mm³/s: the melt model's flow at
    /// [`MODEL_FORCE_SHARE`] of the grip, and `max_volumetric_speed`,
    /// whichever is lower; `None` with neither.
    ///
    /// The model is trusted only within its measured `temp_range`: above
    /// it the limit stays at the top of the range's; below it the law is
    /// extrapolated, which only lowers the limit (the melt thickens as it
    /// cools).
    pub fn flow_limit(&self, hotend_c: f64) -> Option<f64> {
        let from_model = self.model.as_ref().zip(self.max_force_n).map(|(m, grip)| {
            m.model()
                .flow_at(MODEL_FORCE_SHARE * grip, hotend_c.min(m.temp_range[1]))
        });
        match (from_model, self.max_volumetric_speed) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// Pressure advance, s: `pressure_advance` as given, else the melt
    /// model's response time (a first-order lag of τ is undone by running
    /// τ·velocity ahead), else 0.
    pub fn pressure_advance_s(&self) -> f64 {
        self.pressure_advance
            .or_else(|| self.model.as_ref().map(|m| m.response_ms / 1000.0))
            .unwrap_or(0.0)
    }

    /// The filament's cross-section, mm² (0 without a diameter).
    pub fn filament_area(&self) -> f64 {
        let d = self.filament_diameter.unwrap_or(0.0);
        std::f64::consts::PI * d * d / 4.0
    }
}

/// A load cell on the filament path (`[axes.e.loadcell]`): an HX711-kind
/// converter on two digital pins of a module.
///
/// ```toml
/// [axes.e.loadcell]
/// module = "e"              # a key of [modules]
/// data_pin = 2              # the converter's DOUT
/// clock_pin = 3             # its SCK
/// newtons_per_count = 0.0005
/// ```
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoadCellKeys {
    /// The module it is wired to.
    pub module: String,
    /// The digital pin of the converter's data line.
    pub data_pin: u8,
    /// The digital pin of its clock.
    pub clock_pin: u8,
    /// Newtons per count (negative for a cell mounted the other way):
    /// calibrate with a known weight.
    pub newtons_per_count: f64,
}

/// The melt model of the filament in use (`[axes.e.model]`), as
/// `osap rheo --write` fits it:
/// `F = flow_k · Q^flow_n · exp(−temp_coeff · (T − t_ref))` N at Q mm³/s
/// and T °C, the outflow lagging the push by `response_ms`. With it the
/// planner limits extruding moves to the flow the model allows at the
/// hotend's target, and pressure advance comes from `response_ms`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeltModelKeys {
    /// Force at 1 mm³/s and `t_ref`, N.
    pub flow_k: f64,
    /// The flow exponent.
    pub flow_n: f64,
    /// The temperature shift, 1/°C.
    pub temp_coeff: f64,
    /// The reference temperature, °C.
    pub t_ref: f64,
    /// The outflow's lag, ms.
    pub response_ms: f64,
    /// The temperatures measured, lowest and highest, °C: the model is
    /// trusted within them.
    pub temp_range: [f64; 2],
    /// The run it was fitted from (its output folder).
    #[serde(default)]
    pub fitted_from: Option<String>,
}

impl MeltModelKeys {
    /// The steady law the keys give.
    pub fn model(&self) -> osap_fit::MeltModel {
        osap_fit::MeltModel {
            flow_k: self.flow_k,
            flow_n: self.flow_n,
            temp_coeff: self.temp_coeff,
            t_ref: self.t_ref,
        }
    }
}

/// Checks `[axes.e.loadcell]` and `[axes.e.model]`; the error names the
/// key and the fix.
pub(super) fn validate_rheo(
    cfg: &MachineFile,
    at: &str,
    e: &ExtruderKeys,
) -> Result<(), ConfigError> {
    if let Some(l) = &e.loadcell {
        let at = format!("{at}.loadcell");
        if !cfg.modules.contains_key(&l.module) {
            return Err(invalid(
                format!("{at}.module"),
                format!(
                    "module {:?} is not in [modules]; add it there or fix the name",
                    l.module
                ),
            ));
        }
        for (key, pin) in [("data_pin", l.data_pin), ("clock_pin", l.clock_pin)] {
            if pin >= DIGITAL_PINS {
                return Err(invalid(
                    format!("{at}.{key}"),
                    format!(
                        "digital pin {pin} does not exist; a module has pins 0 to {}",
                        DIGITAL_PINS - 1
                    ),
                ));
            }
        }
        if l.data_pin == l.clock_pin {
            return Err(invalid(
                format!("{at}.clock_pin"),
                "the converter's data and clock need two pins",
            ));
        }
        if let Some((name, _)) = cfg.tools.iter().find(|(_, t)| {
            t.module == l.module
                && matches!(t.output, super::Output::Digital(p) if p == l.data_pin || p == l.clock_pin)
        }) {
            return Err(invalid(
                format!("{at}.data_pin"),
                format!("tools.{name} drives that pin; wire each to its own"),
            ));
        }
        if !(l.newtons_per_count.is_finite() && l.newtons_per_count != 0.0) {
            return Err(invalid(
                format!("{at}.newtons_per_count"),
                format!(
                    "{} must be finite and not 0: hang a known weight on the cell and divide \
                     its newtons by the counts it adds",
                    l.newtons_per_count
                ),
            ));
        }
    }
    if let Some(m) = &e.model {
        let at = format!("{at}.model");
        for (key, v) in [
            ("flow_k", m.flow_k),
            ("flow_n", m.flow_n),
            ("response_ms", m.response_ms),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(invalid(
                    format!("{at}.{key}"),
                    format!("{v} must be positive (osap rheo --write fits it)"),
                ));
            }
        }
        if !(m.temp_coeff.is_finite() && m.temp_coeff >= 0.0 && m.t_ref.is_finite()) {
            return Err(invalid(
                format!("{at}.temp_coeff"),
                "temp_coeff must be 0 or more and t_ref finite (osap rheo --write fits them)",
            ));
        }
        let [lo, hi] = m.temp_range;
        if !(lo.is_finite() && hi.is_finite() && lo <= hi) {
            return Err(invalid(
                format!("{at}.temp_range"),
                format!("[{lo}, {hi}] must be [lowest, highest] °C measured"),
            ));
        }
        if e.max_force_n.is_none() {
            return Err(invalid(
                at,
                "a melt model limits flow to a share of the drive's grip: give max_force_n too",
            ));
        }
    }
    Ok(())
}

/// Checks `[sim.axes.NAME]`'s melt keys: on the extruder only, all of them
/// or none, physical values, and a drive grip to slip against.
pub(super) fn validate_sim_melt(
    cfg: &MachineFile,
    at: &str,
    name: &str,
    axis: &super::SimAxis,
) -> Result<(), ConfigError> {
    if let Some(key) = &axis.melt_missing {
        return Err(invalid(
            format!("{at}.{key}"),
            "missing: a simulated melt needs flow_k, flow_n, temp_coeff, t_ref and response_ms",
        ));
    }
    let Some(m) = &axis.melt else {
        return Ok(());
    };
    if name != "e" {
        return Err(invalid(
            format!("{at}.flow_k"),
            "a melt is simulated behind the extruder: move the keys to [sim.axes.e]",
        ));
    }
    let e = &cfg.axes[name].extruder;
    if e.max_force_n.is_none() {
        return Err(invalid(
            format!("axes.{name}.max_force_n"),
            "missing: the simulated filament slips past the drive's grip; give max_force_n",
        ));
    }
    let checks = [
        ("flow_k", m.flow_k, m.flow_k > 0.0, "N at 1 mm³/s, e.g. 8"),
        (
            "flow_n",
            m.flow_n,
            m.flow_n > 0.0 && m.flow_n <= 1.5,
            "within (0, 1.5], e.g. 0.6",
        ),
        (
            "temp_coeff",
            m.temp_coeff,
            m.temp_coeff >= 0.0,
            "1/°C, 0 or more, e.g. 0.02",
        ),
        ("t_ref", m.t_ref, true, "°C, e.g. 210"),
        (
            "response_ms",
            m.response_ms,
            m.response_ms > 0.0,
            "ms, e.g. 60",
        ),
        (
            "noise_n",
            m.noise_n,
            m.noise_n >= 0.0,
            "N, 0 or more, e.g. 0.05",
        ),
    ];
    for (key, v, ok, hint) in checks {
        if !(ok && v.is_finite()) {
            return Err(invalid(format!("{at}.{key}"), format!("{v}: give {hint}")));
        }
    }
    Ok(())
}
