//! `[axes.NAME] accelerometer` and `shaper`: the sensor `osap resonance`
//! measures an axis with, and the input shaper fitted from it.

use maxl::blocks::shaper::{ShaperConfig, ShaperError, ShaperKind};
use serde::Deserialize;

use super::{ConfigError, MachineFile};

/// `[axes.NAME] accelerometer`: an analog input measuring the axis's
/// acceleration, for `osap resonance`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Accelerometer {
    /// The module it is wired to (a key of `[modules]`).
    pub module: String,
    /// The module's analog input.
    #[serde(default)]
    pub channel: u8,
    /// Acceleration at full scale, machine units/s².
    pub range: f64,
}

/// `[axes.NAME] shaper`: the input shaper for the axis's mode.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisShaper {
    /// `zv`, `mzv`, `ei`, `2hump_ei`, `zvd` or `3hump_ei`.
    pub kind: String,
    /// The mode's frequency, Hz.
    pub freq_hz: f64,
    /// The mode's damping ratio.
    pub damping: f64,
    /// The run record of the measurement it was fitted from (`osap
    /// resonance --write` sets it).
    #[serde(default)]
    pub fitted_from: Option<String>,
}

/// Why an [`AxisShaper`] names no shaper.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum AxisShaperError {
    /// `kind` is none of the shapers.
    #[error("unknown shaper kind {0:?}; use one of zv, mzv, ei, 2hump_ei, zvd, 3hump_ei")]
    UnknownKind(String),
    /// The frequency or damping is out of range.
    #[error("{0}")]
    Shaper(#[from] ShaperError),
}

impl AxisShaper {
    /// The shaper it names, checked.
    pub fn config(&self) -> Result<ShaperConfig, AxisShaperError> {
        let kind = ShaperKind::ALL
            .into_iter()
            .find(|k| k.name() == self.kind)
            .ok_or_else(|| AxisShaperError::UnknownKind(self.kind.clone()))?;
        Ok(ShaperConfig::new(kind, self.freq_hz, self.damping)?)
    }
}

fn invalid(key: String, message: String) -> ConfigError {
    ConfigError::Invalid {
        file: None,
        key,
        message,
    }
}

/// Checks `[axes.NAME] accelerometer` and `shaper` of every axis.
pub(super) fn validate(cfg: &MachineFile) -> Result<(), ConfigError> {
    for (name, axis) in &cfg.axes {
        if let Some(a) = &axis.accelerometer {
            let at = format!("axes.{name}.accelerometer");
            if !cfg.modules.contains_key(&a.module) {
                return Err(invalid(
                    format!("{at}.module"),
                    format!(
                        "module {:?} is not in [modules]; name the module the accelerometer is wired to",
                        a.module
                    ),
                ));
            }
            if !(a.range.is_finite() && a.range > 0.0) {
                return Err(invalid(
                    format!("{at}.range"),
                    format!(
                        "range {} must be a positive acceleration at full scale (units/s²), e.g. 160000 for ±16 g in mm",
                        a.range
                    ),
                ));
            }
        }
        if let Some(s) = &axis.shaper {
            s.config()
                .map_err(|e| invalid(format!("axes.{name}.shaper"), e.to_string()))?;
        }
    }
    Ok(())
}
