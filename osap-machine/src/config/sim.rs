//! The `[sim]` section: how the machine's simulation starts and behaves.

use std::collections::BTreeMap;

use maxl::bed::BedSurface;
use serde::Deserialize;

use super::{probe, Axis};

/// Simulation settings.
#[derive(Debug, Clone, PartialEq, Deserialize, Default)]
#[serde(from = "SimKeys")]
pub struct Sim {
    /// Per-axis simulation settings, by axis name.
    pub axes: BTreeMap<String, SimAxis>,
    /// A tilted, warped bed that the simulated probe touches
    /// (`[sim.bed]`: `z`, `tilt_x`, `tilt_y`, `warp`, and optionally
    /// `center` and `half`, which default to the middle and half the size
    /// of the x-y travel; see [`Sim::with_bed`]).
    pub bed: Option<BedSurface>,
    /// Which of the bed's `center` and `half` the file gave; the others
    /// are taken from the travel when the file is parsed.
    bed_placed: [bool; 2],
    /// Each heater's thermal model, by the name in `[heaters]`
    /// (`[sim.heaters.NAME]`; a simulated heater needs one).
    pub heaters: BTreeMap<String, SimHeater>,
    /// Each spindle's motor and drive, by the name in `[tools]`
    /// (`[sim.spindles.NAME]`; a simulated spindle with a `tach` needs
    /// one).
    pub spindles: BTreeMap<String, super::SimSpindle>,
}

/// A heater's thermal model in simulation (`[sim.heaters.NAME]`): a block
/// of heat capacity `C` heated by `power_w` at full duty and losing
/// `loss_w_per_k` per kelvin above the room: `C·dT/dt = P·duty − k·(T −
/// T_room)`.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimHeater {
    /// Power at full duty, W (40 for a hotend cartridge, 200–300 for a
    /// bed).
    pub power_w: f64,
    /// Heat capacity, J/K (about 15 for a hotend's block and nozzle, 400
    /// for an aluminium bed plate).
    pub heat_capacity_j_per_k: f64,
    /// Loss to the room per kelvin above it, W/K.
    pub loss_w_per_k: f64,
    /// The room, °C (default 25); the block starts at it.
    #[serde(default = "room")]
    pub ambient_c: f64,
    /// From this many seconds after boot, the thermistor reads open.
    #[serde(default)]
    pub sensor_fails_at_s: Option<f64>,
}

fn room() -> f64 {
    25.0
}

/// `[sim]` as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SimKeys {
    #[serde(default)]
    axes: BTreeMap<String, SimAxis>,
    #[serde(default)]
    bed: Option<probe::BedKeys>,
    #[serde(default)]
    heaters: BTreeMap<String, SimHeater>,
    #[serde(default)]
    spindles: BTreeMap<String, super::SimSpindle>,
}

impl From<SimKeys> for Sim {
    fn from(k: SimKeys) -> Self {
        let (bed, bed_placed) = match k.bed.map(probe::BedKeys::surface) {
            Some((bed, placed)) => (Some(bed), placed),
            None => (None, [true; 2]),
        };
        Sim {
            axes: k.axes,
            bed,
            bed_placed,
            heaters: k.heaters,
            spindles: k.spindles,
        }
    }
}

impl Sim {
    /// The same settings with `bed` as the simulated bed, placed as given.
    pub fn with_bed(mut self, bed: BedSurface) -> Self {
        self.bed = Some(bed);
        self.bed_placed = [true; 2];
        self
    }

    /// Centres the bed on the middle of the x-y travel and sizes it to the
    /// travel where the file left that out.
    pub(super) fn place_bed(&mut self, axes: &BTreeMap<String, Axis>) {
        let (Some(bed), Some(x), Some(y)) = (&mut self.bed, axes.get("x"), axes.get("y")) else {
            return;
        };
        if !self.bed_placed[0] {
            bed.center = [(x.min + x.max) / 2.0, (y.min + y.max) / 2.0];
        }
        if !self.bed_placed[1] {
            bed.half = [(x.max - x.min) / 2.0, (y.max - y.min) / 2.0];
        }
        self.bed_placed = [true; 2];
    }
}

/// An axis in simulation (`[sim.axes.NAME]`): where its carriage stands at
/// boot, and optionally a mass-spring resonance (`resonance_hz` and
/// `damping_ratio`, both or neither).
#[derive(Debug, Clone, PartialEq, Deserialize, Default)]
#[serde(from = "SimAxisKeys")]
pub struct SimAxis {
    /// Natural frequency, Hz; 0 when the axis has no resonance (read both
    /// values with [`SimAxis::resonance`]).
    pub resonance_hz: f64,
    /// Damping ratio (0 undamped, 1 critically damped); 0 when the axis has
    /// no resonance.
    pub damping_ratio: f64,
    /// Where the simulated carriage stands at boot, in axis units, within
    /// `[min, max]`; `None`: the middle of the travel (so homing has to
    /// find the switch). The simulator's `start_position` gives the position
    /// in effect.
    pub start: Option<f64>,
    /// Which of `resonance_hz` and `damping_ratio` the file gave.
    pub(super) given: [bool; 2],
    /// The extruder's melt (`[sim.axes.e]` `flow_k`, `flow_n`,
    /// `temp_coeff`, `t_ref`, `response_ms`, `noise_n`): a melt the
    /// software has never seen, for `osap rheo --sim` and printing.
    pub melt: Option<SimMelt>,
    /// The first melt key missing when some were given.
    pub(super) melt_missing: Option<String>,
}

/// A simulated melt behind the extruder (see
/// `osap_sim::machine::board::melt`): the filament needs `F = flow_k ·
/// Q^flow_n · exp(−temp_coeff · (T − t_ref))` newtons at Q mm³/s and the
/// hotend's T °C, the outflow lags the push by `response_ms`, and the
/// load cell reads it with `noise_n` newtons of noise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimMelt {
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
    /// The load cell's noise, N (default 0.05).
    pub noise_n: f64,
}

/// `[sim.axes.NAME]` as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SimAxisKeys {
    #[serde(default)]
    resonance_hz: Option<f64>,
    #[serde(default)]
    damping_ratio: Option<f64>,
    #[serde(default)]
    start: Option<f64>,
    #[serde(default)]
    flow_k: Option<f64>,
    #[serde(default)]
    flow_n: Option<f64>,
    #[serde(default)]
    temp_coeff: Option<f64>,
    #[serde(default)]
    t_ref: Option<f64>,
    #[serde(default)]
    response_ms: Option<f64>,
    #[serde(default)]
    noise_n: Option<f64>,
}

impl From<SimAxisKeys> for SimAxis {
    fn from(k: SimAxisKeys) -> Self {
        let required = [
            ("flow_k", k.flow_k),
            ("flow_n", k.flow_n),
            ("temp_coeff", k.temp_coeff),
            ("t_ref", k.t_ref),
            ("response_ms", k.response_ms),
        ];
        let any = required.iter().any(|(_, v)| v.is_some()) || k.noise_n.is_some();
        let melt_missing = required
            .iter()
            .find(|(_, v)| any && v.is_none())
            .map(|(key, _)| key.to_string());
        let melt = match (any, &melt_missing, required.map(|(_, v)| v.unwrap_or(0.0))) {
            (true, None, [flow_k, flow_n, temp_coeff, t_ref, response_ms]) => Some(SimMelt {
                flow_k,
                flow_n,
                temp_coeff,
                t_ref,
                response_ms,
                noise_n: k.noise_n.unwrap_or(0.05),
            }),
            _ => None,
        };
        SimAxis {
            resonance_hz: k.resonance_hz.unwrap_or(0.0),
            damping_ratio: k.damping_ratio.unwrap_or(0.0),
            start: k.start,
            given: [k.resonance_hz.is_some(), k.damping_ratio.is_some()],
            melt,
            melt_missing,
        }
    }
}

impl SimAxis {
    /// An axis with no resonance, starting at `start` (`None`: the middle
    /// of its travel).
    pub fn new(start: Option<f64>) -> Self {
        SimAxis {
            start,
            ..SimAxis::default()
        }
    }

    /// The same axis with a resonance at `resonance_hz`, damped by
    /// `damping_ratio`.
    pub fn with_resonance(mut self, resonance_hz: f64, damping_ratio: f64) -> Self {
        self.resonance_hz = resonance_hz;
        self.damping_ratio = damping_ratio;
        self.given = [true, true];
        self
    }

    /// The resonance, `(resonance_hz, damping_ratio)`, if the axis has one.
    pub fn resonance(&self) -> Option<(f64, f64)> {
        (self.given == [true, true]).then_some((self.resonance_hz, self.damping_ratio))
    }
}
