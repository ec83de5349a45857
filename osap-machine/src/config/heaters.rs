//! `[heaters.NAME]`: heaters on module PWM outputs, read by thermistors on
//! module analog inputs, controlled and guarded on the module itself.
//!
//! ```toml
//! [heaters.hotend]
//! module = "tool"                   # a key of [modules]
//! output = { pwm = 0 }              # the heater's MOSFET
//! sensor = { analog = 0, thermistor = "EPCOS 100K B57560G104F" }
//! min_temp = 5                      # below: the thermistor reads open
//! max_temp = 290                    # at or above: the module cuts the heater
//! kp = 21.5                         # PID gains in Klipper's units
//! ki = 1.06                         # (osap heater-tune --write finds them)
//! kd = 109.0
//! ```
//!
//! A sensor names its thermistor one of three ways: `thermistor = "NAME"`
//! (a catalogued one, [`THERMISTORS`](super::THERMISTORS)), `beta` and
//! `r25_ohms` (a Beta model; with nothing given, β 3950 and 100 kΩ), or
//! `points = [[°C, Ω], ...]` (three or more datasheet points: see
//! [`super::thermistor`]). `pullup_ohms` defaults to 4 700.
//!
//! The hotend is `[heaters.hotend]` and the bed `[heaters.bed]`: the names
//! `M104`/`M109` and `M140`/`M190` set. Runaway protection takes
//! Klipper's `verify_heater` values (`runaway = { hysteresis_c,
//! max_error, heating_gain_c, check_gain_time_s }`; the bed's check time
//! defaults to 60 s, every other heater's to 20 s).

use std::collections::BTreeMap;

use serde::Deserialize;

use super::thermistor::{Datasheet, SteinhartHart, THERMISTORS};
use super::{invalid, ConfigError, MachineFile, Output, PWM_CHANNELS};

/// A heater.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Heater {
    /// The module (a key of `[modules]`) the heater and its sensor are on.
    pub module: String,
    /// The PWM output that drives it (`{ pwm = N }`).
    pub output: Output,
    /// Its thermistor.
    pub sensor: Sensor,
    /// Below this the sensor reads open, °C (default 0).
    #[serde(default)]
    pub min_temp: f64,
    /// At or above this the module cuts the heater, °C.
    pub max_temp: f64,
    /// Proportional gain (Klipper's `pid_Kp`).
    pub kp: f64,
    /// Integral gain (Klipper's `pid_Ki`).
    pub ki: f64,
    /// Derivative gain (Klipper's `pid_Kd`).
    pub kd: f64,
    /// The largest duty the heater is driven at, (0, 1] (default 1).
    #[serde(default = "one")]
    pub max_power: f64,
    /// Runaway protection (Klipper's `verify_heater` values).
    #[serde(default)]
    pub runaway: Option<Runaway>,
    /// How long a wait for the target (`M109`, `M190`) may take before it
    /// is a fault, s (default 600).
    #[serde(default = "default_wait_timeout_s")]
    pub wait_timeout_s: f64,
}

/// An NTC thermistor to ground on an analog input, with a pullup: a
/// catalogued one, a Beta model, or a table of points.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Sensor {
    /// The analog input it is read on.
    pub analog: u8,
    /// A catalogued thermistor by name (see [`THERMISTORS`]).
    #[serde(default)]
    pub thermistor: Option<String>,
    /// Its β, K (3950, the common "100k NTC 3950", when nothing names the
    /// curve).
    #[serde(default)]
    pub beta: Option<f64>,
    /// Its resistance at 25 °C with `beta`, Ω (default 100 000).
    #[serde(default)]
    pub r25_ohms: Option<f64>,
    /// Three or more (°C, Ω) points of its datasheet.
    #[serde(default)]
    pub points: Option<Vec<[f64; 2]>>,
    /// The pullup to the converter's reference, Ω (default 4 700).
    #[serde(default = "default_pullup")]
    pub pullup_ohms: f64,
}

impl Sensor {
    /// The thermistor's curve, or which key is wrong and why.
    pub fn curve(&self) -> Result<SteinhartHart, (&'static str, String)> {
        let given = [
            self.thermistor.is_some(),
            self.beta.is_some() || self.r25_ohms.is_some(),
            self.points.is_some(),
        ];
        if given.iter().filter(|g| **g).count() > 1 {
            return Err((
                "thermistor",
                "give one of thermistor, beta (with r25_ohms) or points".into(),
            ));
        }
        if let Some(name) = &self.thermistor {
            let sheet = Datasheet::named(name).ok_or_else(|| {
                let known: Vec<&str> = THERMISTORS.iter().map(|(n, _)| *n).collect();
                (
                    "thermistor",
                    format!(
                        "{name:?} is not catalogued; give one of {known:?}, or its beta                          and r25_ohms, or its datasheet points"
                    ),
                )
            })?;
            return sheet.curve().map_err(|e| ("thermistor", e));
        }
        if let Some(points) = &self.points {
            let points: Vec<(f64, f64)> = points.iter().map(|p| (p[0], p[1])).collect();
            return SteinhartHart::fit(&points).map_err(|e| ("points", e));
        }
        let beta = self.beta.unwrap_or(3950.0);
        let r25 = self.r25_ohms.unwrap_or(100_000.0);
        for (k, v) in [("beta", beta), ("r25_ohms", r25)] {
            if !(v.is_finite() && v > 0.0) {
                return Err((
                    k,
                    format!("{v} must be positive (the thermistor's data sheet gives it)"),
                ));
            }
        }
        Ok(SteinhartHart::from_beta(beta, r25))
    }
}

/// Runaway protection: when the module cuts the heater by itself.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Runaway {
    /// How far below the target the temperature may sag while holding
    /// before the error adds up, °C (default 5).
    #[serde(default = "default_hysteresis")]
    pub hysteresis_c: f64,
    /// How much error (°C·s) may add up before the heater is cut
    /// (default 120).
    #[serde(default = "default_max_error")]
    pub max_error: f64,
    /// How much the temperature must rise while heating, °C (default 2) ...
    #[serde(default = "default_heating_gain")]
    pub heating_gain_c: f64,
    /// ... within this time, s (default 20; 60 for the bed).
    #[serde(default)]
    pub check_gain_time_s: Option<f64>,
}

fn one() -> f64 {
    1.0
}
fn default_wait_timeout_s() -> f64 {
    600.0
}
fn default_pullup() -> f64 {
    4700.0
}
fn default_hysteresis() -> f64 {
    5.0
}
fn default_max_error() -> f64 {
    120.0
}
fn default_heating_gain() -> f64 {
    2.0
}

impl Heater {
    /// The runaway protection in force: the file's, or Klipper's defaults
    /// (a 60 s gain check for the heater named `bed`, 20 s for others).
    pub fn runaway(&self, name: &str) -> Runaway {
        let r = self.runaway.unwrap_or(Runaway {
            hysteresis_c: default_hysteresis(),
            max_error: default_max_error(),
            heating_gain_c: default_heating_gain(),
            check_gain_time_s: None,
        });
        Runaway {
            check_gain_time_s: Some(r.check_gain_time_s.unwrap_or(if name == "bed" {
                60.0
            } else {
                20.0
            })),
            ..r
        }
    }

    /// The PWM channel.
    pub fn pwm(&self) -> u8 {
        match self.output {
            Output::Pwm(c) | Output::Digital(c) => c,
        }
    }
}

/// The highest temperature a heater may be set to, °C.
pub const MAX_HEATER_TEMP: f64 = 500.0;

pub(super) fn validate(cfg: &MachineFile) -> Result<(), ConfigError> {
    let mut used: BTreeMap<(&str, u8), String> = BTreeMap::new();
    for (key, tool) in &cfg.tools {
        if let Output::Pwm(c) = tool.output {
            used.insert((tool.module.as_str(), c), format!("tools.{key}"));
        }
    }
    for (name, h) in &cfg.heaters {
        let at = format!("heaters.{name}");
        if !cfg.modules.contains_key(&h.module) {
            return Err(invalid(
                format!("{at}.module"),
                format!(
                    "module {:?} is not in [modules]; add it there or fix the name",
                    h.module
                ),
            ));
        }
        let Output::Pwm(channel) = h.output else {
            return Err(invalid(
                format!("{at}.output"),
                "a heater is driven by PWM: give output = { pwm = N }",
            ));
        };
        if channel >= PWM_CHANNELS {
            return Err(invalid(
                format!("{at}.output.pwm"),
                format!(
                    "PWM channel {channel} does not exist; a module has channels 0 to {}",
                    PWM_CHANNELS - 1
                ),
            ));
        }
        if let Some(other) = used.insert((h.module.as_str(), channel), at.clone()) {
            return Err(invalid(
                format!("{at}.output"),
                format!("duplicate: {other} already uses PWM {channel} of module {:?}; wire each to its own output", h.module),
            ));
        }
        let s = &h.sensor;
        if !(s.pullup_ohms.is_finite() && s.pullup_ohms > 0.0) {
            return Err(invalid(
                format!("{at}.sensor.pullup_ohms"),
                format!(
                    "{} must be positive (the board's schematic gives it)",
                    s.pullup_ohms
                ),
            ));
        }
        s.curve()
            .map_err(|(k, why)| invalid(format!("{at}.sensor.{k}"), why))?;
        if !(h.min_temp.is_finite() && h.max_temp.is_finite())
            || h.min_temp < -50.0
            || h.min_temp >= h.max_temp
            || h.max_temp > MAX_HEATER_TEMP
        {
            return Err(invalid(
                format!("{at}.max_temp"),
                format!(
                    "min_temp {} and max_temp {} must satisfy -50 ≤ min_temp < max_temp ≤ {MAX_HEATER_TEMP} °C",
                    h.min_temp, h.max_temp
                ),
            ));
        }
        for (k, v) in [("kp", h.kp), ("ki", h.ki), ("kd", h.kd)] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(invalid(
                    format!("{at}.{k}"),
                    format!("{v} must be ≥ 0 (osap heater-tune --write finds the gains)"),
                ));
            }
        }
        if !(h.max_power > 0.0 && h.max_power <= 1.0) {
            return Err(invalid(
                format!("{at}.max_power"),
                format!("{} is outside (0, 1]; give the largest duty", h.max_power),
            ));
        }
        if !(h.wait_timeout_s.is_finite() && h.wait_timeout_s > 0.0) {
            return Err(invalid(
                format!("{at}.wait_timeout_s"),
                format!("{} must be positive, s", h.wait_timeout_s),
            ));
        }
        let r = h.runaway(name);
        for (k, v) in [
            ("hysteresis_c", r.hysteresis_c),
            ("max_error", r.max_error),
            ("heating_gain_c", r.heating_gain_c),
            ("check_gain_time_s", r.check_gain_time_s.unwrap_or(1.0)),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(invalid(
                    format!("{at}.runaway.{k}"),
                    format!("{v} must be positive"),
                ));
            }
        }
    }
    let mut per_module: BTreeMap<&str, usize> = BTreeMap::new();
    for (name, h) in &cfg.heaters {
        let n = per_module.entry(h.module.as_str()).or_default();
        *n += 1;
        if *n > usize::from(PWM_CHANNELS) {
            return Err(invalid(
                format!("heaters.{name}.module"),
                format!("module {:?} runs at most {PWM_CHANNELS} heaters; put this one on another module", h.module),
            ));
        }
    }
    Ok(())
}
