//! `[probe]`, the bed probe, and `[sim.bed]`, the simulated bed it
//! touches (a [`BedSurface`], the one bed model the simulator shares):
//! their keys and checks. Probing itself is the `level` module's.

use maxl::bed::BedSurface;
use maxl::blocks::bedlevel::MeshGrid;
use serde::Deserialize;

use super::{ConfigError, MachineFile};

/// A bed probe, `[probe]` in the machine file: a switch (or a load cell's
/// comparator) on a module's limit input, closing when its tip touches
/// the bed.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Probe {
    /// The module (a key of `[modules]`) whose limit input the probe is
    /// wired to. It may share the input with a homing switch (wired in
    /// parallel) when the two are never pressed together.
    pub module: String,
    /// The probe tip relative to the tool tip, `[x, y, z]` (default 0: the
    /// tool itself touches).
    #[serde(default)]
    pub offset: [f64; 3],
    /// Probe points along x and along y (each at least 2).
    pub grid: [usize; 2],
    /// How far inside the x-y travel the outer probe points lie (default 10).
    #[serde(default = "default_margin")]
    pub margin: f64,
    /// The z every search starts from: above the bed everywhere.
    pub start_z: f64,
    /// How far below `start_z` a search goes before it gives up.
    pub search_depth: f64,
    /// z speed while searching (units/s).
    pub search_speed: f64,
    /// Speed of the moves between points (units/s).
    pub travel_speed: f64,
    /// A load cell on the probe's module that the tip presses (a nozzle
    /// load-cell probe), read by a comparator block on that module which
    /// halts the z axis in its own loop; without it, the probe is a switch
    /// on the module's limit input.
    #[serde(default)]
    pub loadcell: Option<ProbeLoadCell>,
}

/// `[probe] loadcell`: the probe's load cell, an HX711-kind converter on
/// two of the probe module's digital pins.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProbeLoadCell {
    /// The converter's data line.
    pub data_pin: u8,
    /// The converter's clock line.
    pub clock_pin: u8,
    /// Newtons per count of the converter.
    pub newtons_per_count: f64,
    /// The force that means "touching", N (default 1).
    #[serde(default = "default_threshold_n")]
    pub threshold_n: f64,
}

fn default_threshold_n() -> f64 {
    1.0
}

fn default_margin() -> f64 {
    10.0
}

/// `[sim.bed]` as written: the bed's shape, and optionally where it lies
/// (by default centred on the middle of the x-y travel, the dome falling
/// to 0 at the travel's edges).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct BedKeys {
    z: f64,
    #[serde(default)]
    tilt_x: f64,
    #[serde(default)]
    tilt_y: f64,
    #[serde(default)]
    warp: f64,
    #[serde(default)]
    center: Option<[f64; 2]>,
    #[serde(default)]
    half: Option<[f64; 2]>,
}

impl BedKeys {
    /// The bed, and whether its placement (`center`, `half`) was given.
    pub(super) fn surface(self) -> (BedSurface, [bool; 2]) {
        let given = [self.center.is_some(), self.half.is_some()];
        let surface = BedSurface {
            z: self.z,
            tilt_x: self.tilt_x,
            tilt_y: self.tilt_y,
            warp: self.warp,
            center: self.center.unwrap_or([0.0; 2]),
            half: self.half.unwrap_or([1.0; 2]),
        };
        (surface, given)
    }
}

/// Steepest bed slope accepted: a bed tilted more is a mistake in the file.
const MAX_TILT: f64 = 0.05;

fn invalid(key: &str, message: String) -> ConfigError {
    ConfigError::Invalid {
        file: None,
        key: key.to_string(),
        message,
    }
}

/// Checks `[probe]` and `[sim.bed]`; the error names the key and the fix.
pub(super) fn validate(cfg: &MachineFile) -> Result<(), ConfigError> {
    if let Some(bed) = cfg.sim.as_ref().and_then(|s| s.bed.as_ref()) {
        for (key, v) in [
            ("z", bed.z),
            ("tilt_x", bed.tilt_x),
            ("tilt_y", bed.tilt_y),
            ("warp", bed.warp),
        ] {
            if !v.is_finite() {
                return Err(invalid(
                    &format!("sim.bed.{key}"),
                    format!("{v} is not a finite number; give a number"),
                ));
            }
        }
        for (key, v) in [("tilt_x", bed.tilt_x), ("tilt_y", bed.tilt_y)] {
            if v.abs() > MAX_TILT {
                return Err(invalid(
                    &format!("sim.bed.{key}"),
                    format!("slope {v} is steeper than {MAX_TILT} (units per unit); a bed tilt is a few tenths of a millimetre over the bed, e.g. 0.001"),
                ));
            }
        }
        if let Err(e) = bed.check() {
            return Err(invalid(&format!("sim.bed.{}", e.key()), e.to_string()));
        }
        if cfg.probe.is_none() {
            return Err(invalid(
                "sim.bed",
                "a simulated bed needs a [probe] to touch it; add [probe] or remove [sim.bed]"
                    .into(),
            ));
        }
        for a in ["x", "y", "z"] {
            if !cfg.axes.contains_key(a) {
                return Err(invalid(
                    "sim.bed",
                    format!("a bed needs axes x, y and z; this machine has no axis {a}"),
                ));
            }
        }
    }
    let Some(p) = &cfg.probe else {
        return Ok(());
    };
    if !cfg.modules.contains_key(&p.module) {
        return Err(invalid(
            "probe.module",
            format!(
                "no module {:?} in [modules]; name the module whose limit input the probe is wired to",
                p.module
            ),
        ));
    }
    let z = match (cfg.axes.get("x"), cfg.axes.get("y"), cfg.axes.get("z")) {
        (Some(_), Some(_), Some(z)) => z,
        _ => return Err(invalid("probe", "a bed probe needs axes x, y and z".into())),
    };
    for (k, v) in p.offset.iter().enumerate() {
        if !v.is_finite() {
            return Err(invalid(
                &format!("probe.offset[{k}]"),
                format!(
                    "{v} is not a finite number; give the probe tip's offset from the tool tip"
                ),
            ));
        }
    }
    for (k, n) in p.grid.iter().enumerate() {
        if !(2..=64).contains(n) {
            return Err(invalid(
                &format!("probe.grid[{k}]"),
                format!("{n} probe points: give 2 to 64 along each axis, e.g. grid = [5, 4]"),
            ));
        }
    }
    for (key, v) in [
        ("search_depth", p.search_depth),
        ("search_speed", p.search_speed),
        ("travel_speed", p.travel_speed),
    ] {
        if !(v.is_finite() && v > 0.0) {
            return Err(invalid(
                &format!("probe.{key}"),
                format!("{v} must be positive"),
            ));
        }
    }
    if !(p.margin.is_finite() && p.margin >= 0.0) {
        return Err(invalid(
            "probe.margin",
            format!("{} must be 0 or more", p.margin),
        ));
    }
    if let Some(l) = &p.loadcell {
        for (key, pin) in [("data_pin", l.data_pin), ("clock_pin", l.clock_pin)] {
            if pin >= super::DIGITAL_PINS {
                return Err(invalid(
                    &format!("probe.loadcell.{key}"),
                    format!(
                        "pin {pin} does not exist: a module has digital pins 0 to {}",
                        super::DIGITAL_PINS - 1
                    ),
                ));
            }
        }
        if l.data_pin == l.clock_pin {
            return Err(invalid(
                "probe.loadcell.clock_pin",
                "the converter's data and clock lines need two pins".into(),
            ));
        }
        for (key, v) in [
            ("newtons_per_count", l.newtons_per_count),
            ("threshold_n", l.threshold_n),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(invalid(
                    &format!("probe.loadcell.{key}"),
                    format!("{v} must be positive"),
                ));
            }
        }
        let extruder_cell = cfg
            .extruder()
            .and_then(|e| e.extruder.loadcell.as_ref())
            .is_some_and(|c| c.module == p.module);
        if extruder_cell {
            return Err(invalid(
                "probe.loadcell",
                format!(
                    "module {:?} already reads the extruder's load cell; a module reads one",
                    p.module
                ),
            ));
        }
    }
    if p.search_speed > z.velocity {
        return Err(invalid(
            "probe.search_speed",
            format!(
                "{} is faster than z's velocity limit {}; search slower, e.g. 2",
                p.search_speed, z.velocity
            ),
        ));
    }
    if !(z.min..=z.max).contains(&p.start_z) || p.start_z - p.search_depth < z.min {
        return Err(invalid(
            "probe.start_z",
            format!(
                "a search from z = {} down to {} leaves z's travel [{}, {}]; start lower or search less deep",
                p.start_z,
                p.start_z - p.search_depth,
                z.min,
                z.max
            ),
        ));
    }
    p.grid(cfg)
        .map_err(|e| invalid("probe.grid", e.to_string()))?;
    Ok(())
}

/// Why a [`Probe`] has no grid of points.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ProbeGridError {
    /// The machine has no axis x or y.
    #[error("a bed probe needs axes x and y")]
    NoXy,
    /// The margin leaves no room inside the travel.
    #[error("margin {0} leaves no room to probe in the x-y travel; use a smaller margin")]
    NoRoom(f64),
    /// Fewer than 2 points along an axis.
    #[error("grid [{0}, {1}]: give at least 2 probe points along each axis")]
    TooFewPoints(usize, usize),
    /// The mesh refused the grid.
    #[error("{0}")]
    Mesh(#[from] maxl::blocks::bedlevel::BedError),
}

impl Probe {
    /// The probe points' grid (where the probe tip touches): the x-y travel
    /// the tool can put the probe over, inside by `margin`.
    pub fn grid(&self, cfg: &MachineFile) -> Result<MeshGrid, ProbeGridError> {
        let (Some(x), Some(y)) = (cfg.axes.get("x"), cfg.axes.get("y")) else {
            return Err(ProbeGridError::NoXy);
        };
        let [ox, oy, _] = self.offset;
        let (x0, x1) = (x.min + ox + self.margin, x.max + ox - self.margin);
        let (y0, y1) = (y.min + oy + self.margin, y.max + oy - self.margin);
        if x1 <= x0 || y1 <= y0 {
            return Err(ProbeGridError::NoRoom(self.margin));
        }
        let [nx, ny] = self.grid;
        if nx < 2 || ny < 2 {
            return Err(ProbeGridError::TooFewPoints(nx, ny));
        }
        MeshGrid::new(
            x0,
            y0,
            (x1 - x0) / (nx - 1) as f64,
            (y1 - y0) / (ny - 1) as f64,
            nx,
            ny,
        )
        .map_err(ProbeGridError::from)
    }
}
