//! The machine file: a TOML description of a machine in machine terms.
//!
//! A machine file names the modules a machine is built from, the motors on
//! them, the axes and the kinematics that map axes to motors, the motion
//! limits, soft travel limits, homing, tools, an optional bed mesh and an
//! optional `[sim]` section; what the machine is (`kind`) and how it reads
//! jobs (`[gcode]`, `[work_offsets]`). See `examples/machines/plotter.toml` and
//! `examples/machines/mill.toml` for commented examples of every key.
//!
//! [`MachineFile::parse`] reads and validates a file's text,
//! [`MachineFile::load`] a file on disk. Unknown keys are refused, and every
//! validation error names the key (`axes.x.max`) and how to fix it:
//!
//! ```text
//! machine file plotter.toml: axes.x: min 10 must be below max 5; swap them or fix the travel
//! ```
//!
//! Nothing here panics, whatever the input.

use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};

use serde::Deserialize;

mod accel;
mod extruder;
mod heaters;
mod jobs;
mod motor_model;
mod probe;
mod sim;
mod spindle;
mod step_rate;
pub mod thermistor;
mod validate;

pub use accel::{Accelerometer, AxisShaper, AxisShaperError};
pub use extruder::{
    ExtruderKeys, LoadCellKeys, MeltModelKeys, DEFAULT_CORNER_VELOCITY, DEFAULT_RETRACT_LENGTH,
    DEFAULT_RETRACT_SPEED, DEFAULT_SMOOTH_TIME, MODEL_FORCE_SHARE,
};
pub use heaters::{Heater, Runaway, Sensor, MAX_HEATER_TEMP};
pub use jobs::{Dialect, GcodeSettings, MachineKind, WorkOffsets};
pub use motor_model::{MotorModelKeys, PlannerModel, DEFAULT_TORQUE_MARGIN};
pub use probe::{Probe, ProbeGridError, ProbeLoadCell};
pub use sim::{Sim, SimAxis, SimMelt};
pub use spindle::{SimSpindle, Tach};
pub use step_rate::MAX_STEP_RATE;
pub use thermistor::{SteinhartHart, THERMISTORS};
use validate::is_mechanism_axis;

/// The axis names a machine file may use, in the order
/// [`MachineFile::axis_names`] lists them.
pub const AXIS_NAMES: [&str; 10] = ["x", "y", "z", "a", "b", "c", "u", "v", "w", "e"];

/// The axes whose distance is the path's length, and whose motion the
/// toolhead's `[limits]` bound; the others (rotary, extruder) follow
/// along within their own limits.
pub const TOOLHEAD_AXES: [&str; 3] = ["x", "y", "z"];

/// The most hops a module's route may have (OSAP routes hold 32).
pub const MAX_ROUTE_HOPS: usize = 32;

/// PWM channels a module has (`pwm_write` channel 0..=1).
pub const PWM_CHANNELS: u8 = 2;

/// Digital output pins a module has (`digital_write` pin 0..=3).
pub const DIGITAL_PINS: u8 = 4;

/// An error reading or validating a machine file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ConfigError {
    /// The file could not be read.
    #[error("machine file {}: {source}", .path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// Why it could not be read.
        #[source]
        source: std::io::Error,
    },
    /// The text is not TOML, or does not have the machine file's shape
    /// (an unknown key, a wrong type, a missing key).
    #[error("machine file{}{}: {message}", file_part(.file), line_part(*.line))]
    Parse {
        /// The file, when read with [`MachineFile::load`].
        file: Option<PathBuf>,
        /// The 1-based line the error is on, when known.
        line: Option<usize>,
        /// What is wrong.
        message: String,
    },
    /// The file is well-formed but describes an impossible machine.
    #[error("machine file{}: {key}: {message}", file_part(.file))]
    Invalid {
        /// The file, when read with [`MachineFile::load`].
        file: Option<PathBuf>,
        /// The key path the error is about, e.g. `axes.x` or `motors.a.module`.
        key: String,
        /// What is wrong and how to fix it.
        message: String,
    },
}

fn file_part(file: &Option<PathBuf>) -> String {
    match file {
        Some(path) => format!(" {}", path.display()),
        None => String::new(),
    }
}

fn line_part(line: Option<usize>) -> String {
    match line {
        Some(line) => format!(", line {line}"),
        None => String::new(),
    }
}

impl ConfigError {
    /// The key path a validation error is about (`None` for read and parse
    /// errors).
    pub fn key(&self) -> Option<&str> {
        match self {
            ConfigError::Invalid { key, .. } => Some(key),
            _ => None,
        }
    }

    fn with_file(self, path: &Path) -> ConfigError {
        match self {
            ConfigError::Parse { line, message, .. } => ConfigError::Parse {
                file: Some(path.to_path_buf()),
                line,
                message,
            },
            ConfigError::Invalid { key, message, .. } => ConfigError::Invalid {
                file: Some(path.to_path_buf()),
                key,
                message,
            },
            other => other,
        }
    }
}

fn invalid(key: impl Into<String>, message: impl Into<String>) -> ConfigError {
    ConfigError::Invalid {
        file: None,
        key: key.into(),
        message: message.into(),
    }
}

/// A machine file.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MachineFile {
    /// The machine's name.
    pub name: String,
    /// What the machine is (default: other); chooses the G-code dialect's
    /// default.
    #[serde(default)]
    pub kind: MachineKind,
    /// How G-code jobs are read (`[gcode]`).
    #[serde(default)]
    pub gcode: GcodeSettings,
    /// CNC work zeros for G54–G59 (`[work_offsets]`).
    #[serde(default)]
    pub work_offsets: WorkOffsets,
    /// The modules the machine is built from, by the name this file uses for
    /// them.
    #[serde(default)]
    pub modules: BTreeMap<String, ModuleRef>,
    /// The motors, by name.
    #[serde(default)]
    pub motors: BTreeMap<String, Motor>,
    /// How axes map to motors (default: cartesian).
    #[serde(default)]
    pub kinematics: Kinematics,
    /// The axes, by name (one of [`AXIS_NAMES`]).
    #[serde(default)]
    pub axes: BTreeMap<String, Axis>,
    /// Limits on the toolhead's vector motion.
    pub limits: Limits,
    /// Tools, by name.
    #[serde(default)]
    pub tools: BTreeMap<String, Tool>,
    /// Heaters, by name (`hotend`, `bed`, ..).
    #[serde(default)]
    pub heaters: BTreeMap<String, Heater>,
    /// A bed mesh file, relative to the machine file.
    #[serde(default)]
    pub bed_mesh: Option<PathBuf>,
    /// The folder of the file this was loaded from (for relative paths);
    /// `None` when parsed from text.
    #[serde(skip)]
    pub source_dir: Option<PathBuf>,
    /// Simulation settings, used only when the machine runs in simulation.
    #[serde(default)]
    pub sim: Option<Sim>,
    /// A bed probe, for `osap level` (the `level` module).
    #[serde(default)]
    pub probe: Option<Probe>,
}

/// How to find a module on the network: by name or by route (exactly one).
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModuleRef {
    /// The module's name, as set by `osap rename`.
    #[serde(default)]
    pub name: Option<String>,
    /// The module's route from the machine's entry point (this host, or
    /// the process that serves the machine: see
    /// the network entry): link indices, one per hop.
    #[serde(default)]
    pub route: Option<Vec<u16>>,
    /// How long the module's upstream may stay quiet (no call, no dataflow
    /// message) before the module puts its outputs (tools) to their safe
    /// values by itself, ms ([`DEFAULT_OUTPUT_WATCHDOG_MS`] if not given;
    /// [`OUTPUT_WATCHDOG_MS`] is the range).
    #[serde(default)]
    pub output_watchdog_ms: Option<u32>,
}

/// A module's output watchdog when its `[modules.NAME]` entry gives none, ms.
pub const DEFAULT_OUTPUT_WATCHDOG_MS: u32 = 500;

/// The output watchdog times a machine file may give, ms: the host feeds
/// every module four times per watchdog time, so a shorter one loads the
/// bus, and a longer one leaves a tool on for longer after its host died.
pub const OUTPUT_WATCHDOG_MS: std::ops::RangeInclusive<u32> = 100..=10_000;

impl ModuleRef {
    /// The module's output watchdog time, ms.
    pub fn output_watchdog_ms(&self) -> u32 {
        self.output_watchdog_ms
            .unwrap_or(DEFAULT_OUTPUT_WATCHDOG_MS)
    }
}

/// A stepper motor on a module.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Motor {
    /// The module (a key of `[modules]`) the motor is on.
    pub module: String,
    /// Full steps per unit of motor travel (mm, or radians for arm joints).
    pub full_steps_per_unit: f64,
    /// Microsteps per full step: a power of two, 1 to 256.
    #[serde(default = "default_microsteps")]
    pub microsteps: u16,
    /// Reverse the motor's direction.
    #[serde(default)]
    pub invert: bool,
    /// Enable the driver when the machine starts.
    #[serde(default = "default_true")]
    pub enable: bool,
    /// The limits the module's firmware holds incoming points to, in motor
    /// units. Absent: derived from the axes and `[limits]` (see
    /// the `module_limits` module).
    #[serde(default)]
    pub limits: Option<MotorLimits>,
    /// The motor's datasheet values, for planning from what it can give
    /// (`[limits] model = "motors"`) and for simulating its stalls.
    #[serde(default)]
    pub model: Option<MotorModelKeys>,
}

/// A motor's firmware limits, in motor units (mm or radians) per s, s², s³.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotorLimits {
    /// Most velocity.
    pub velocity: f64,
    /// Most acceleration.
    pub acceleration: f64,
    /// Most jerk; 0 (the default) leaves jerk unchecked.
    #[serde(default)]
    pub jerk: f64,
}

fn default_microsteps() -> u16 {
    16
}

fn default_true() -> bool {
    true
}

/// Which side an arm's elbow (or tool) is on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Side {
    /// Counter-clockwise of the line (looking along it).
    Left,
    /// Clockwise of the line.
    Right,
}

/// How the axes map to motors.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(tag = "type", rename_all = "lowercase", deny_unknown_fields)]
pub enum Kinematics {
    /// Every axis has its own motor (`axes.NAME.motor`).
    Cartesian {},
    /// Two belt motors drive x and y together: x = (a + b) / 2,
    /// y = (a − b) / 2.
    CoreXy {
        /// The two motors (a, b).
        motors: Vec<String>,
    },
    /// A two-link arm with its shoulder at the origin; the motors turn the
    /// shoulder and the elbow (units: radians).
    Scara {
        /// The two motors (shoulder, elbow).
        motors: Vec<String>,
        /// Shoulder-to-elbow link length.
        l1: f64,
        /// Elbow-to-tool link length.
        l2: f64,
        /// The elbow's side of the line from shoulder to tool.
        elbow: Side,
        /// How close (degrees) to stretched or folded the arm may come.
        #[serde(default = "default_margin_deg")]
        margin_deg: f64,
    },
    /// A symmetric five-bar arm: motors at (±span/2, 0), proximal links
    /// `l1`, distal links `l2` joined at the tool (units: radians).
    FiveBar {
        /// The two motors (left, right).
        motors: Vec<String>,
        /// Distance between the two motors.
        span: f64,
        /// Proximal link length.
        l1: f64,
        /// Distal link length.
        l2: f64,
        /// The left elbow's side of the line from the left motor to the tool.
        left_elbow: Side,
        /// The right elbow's side of the line from the right motor to the
        /// tool.
        right_elbow: Side,
        /// The tool's side of the line from the left elbow to the right one.
        tool: Side,
        /// How close (degrees) to a singularity the arm may come.
        #[serde(default = "default_margin_deg")]
        margin_deg: f64,
    },
}

impl Default for Kinematics {
    /// Cartesian.
    fn default() -> Self {
        Kinematics::Cartesian {}
    }
}

fn default_margin_deg() -> f64 {
    5.0
}

impl Kinematics {
    /// The motors the mechanism drives (empty for cartesian).
    pub fn motors(&self) -> &[String] {
        match self {
            Kinematics::Cartesian {} => &[],
            Kinematics::CoreXy { motors }
            | Kinematics::Scara { motors, .. }
            | Kinematics::FiveBar { motors, .. } => motors,
        }
    }

    /// The kinematics' name as written in the file.
    pub fn type_name(&self) -> &'static str {
        match self {
            Kinematics::Cartesian {} => "cartesian",
            Kinematics::CoreXy { .. } => "corexy",
            Kinematics::Scara { .. } => "scara",
            Kinematics::FiveBar { .. } => "fivebar",
        }
    }
}

/// An axis: travel, limits, homing, and (outside a mechanism) its motor.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Axis {
    /// The motor driving this axis alone; required for axes the kinematics
    /// do not drive, refused for x and y under corexy, scara and fivebar.
    #[serde(default)]
    pub motor: Option<String>,
    /// What the axis is (default: linear).
    #[serde(default)]
    pub kind: AxisKind,
    /// Soft travel limit, low end (required, except for an extruder,
    /// which has no travel: it reads −∞).
    #[serde(default = "no_travel")]
    pub min: f64,
    /// Soft travel limit, high end (required, except for an extruder: +∞).
    #[serde(default = "no_travel")]
    pub max: f64,
    /// Most velocity, units/s.
    pub velocity: f64,
    /// Most acceleration, units/s².
    pub acceleration: f64,
    /// Most jerk, units/s³.
    pub jerk: f64,
    /// How to home the axis (no homing when absent).
    #[serde(default)]
    pub homing: Option<Homing>,
    /// An accelerometer measuring along the axis, for `osap resonance`
    /// (`osap resonance`).
    #[serde(default)]
    pub accelerometer: Option<Accelerometer>,
    /// The axis's input shaper, as `osap resonance --write` puts it; every
    /// move is shaped with it.
    #[serde(default)]
    pub shaper: Option<AxisShaper>,
    /// The mass the axis moves, kg: for `[limits] model = "motors"` and
    /// the simulated motors' load.
    #[serde(default)]
    pub moving_mass_kg: Option<f64>,
    /// The extruder's settings (`kind = "extruder"` only), flattened into
    /// `[axes.e]`.
    #[serde(flatten)]
    pub extruder: ExtruderKeys,
}

/// What an axis is.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum AxisKind {
    /// A linear or rotary axis with a travel.
    #[default]
    Linear,
    /// A filament extruder (axis `e`): no travel, units mm of filament.
    Extruder,
}

fn no_travel() -> f64 {
    f64::NAN
}

/// Which end of its travel an axis homes to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Direction {
    /// Towards `min`.
    Min,
    /// Towards `max`.
    Max,
}

/// How an axis homes: against a module's limit switch or by motor stall.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Homing {
    /// Home on the limit input of this module (a key of `[modules]`).
    #[serde(default)]
    pub switch: Option<String>,
    /// Home by stall detection on this motor (a key of `[motors]`).
    #[serde(default)]
    pub stall: Option<String>,
    /// Home z on the bed with the probe's load cell (`[probe] loadcell`),
    /// downwards: `endstop` is the z of the bed's surface.
    #[serde(default)]
    pub probe: bool,
    /// The end of travel to home to.
    pub direction: Direction,
    /// Speed to seek the switch or stall, units/s.
    pub search_speed: f64,
    /// Speed of the slow second approach to the switch, units/s (required
    /// with `switch`).
    #[serde(default)]
    pub latch_speed: Option<f64>,
    /// Distance to back off after the switch or stall, units: it must
    /// bring the axis from `endstop` back inside the travel.
    #[serde(default)]
    pub backoff: f64,
    /// Homing order: lower first; axes with the same order home together.
    #[serde(default)]
    pub order: u32,
    /// Where the switch (or the stall) triggers, as an absolute axis
    /// position, like Klipper's `position_endstop`: beyond the soft travel
    /// or at its edge, on the homed side. Homing puts the trigger's edge
    /// here. `None`: [`ENDSTOP_BEYOND`] beyond the homed end.
    #[serde(default)]
    pub endstop: Option<f64>,
}

/// How far beyond the homed end of the travel a switch triggers when the
/// machine file gives no `endstop`, units (a real switch sits a little
/// past the soft limit, so a job may touch the travel's edge).
pub const ENDSTOP_BEYOND: f64 = 1.0;

impl Homing {
    /// Where the switch triggers on `axis` (the axis this homing belongs
    /// to): `endstop`, or [`ENDSTOP_BEYOND`] past the homed end.
    pub fn endstop(&self, axis: &Axis) -> f64 {
        self.endstop.unwrap_or(match self.direction {
            Direction::Min => axis.min - ENDSTOP_BEYOND,
            Direction::Max => axis.max + ENDSTOP_BEYOND,
        })
    }

    /// Where homing leaves `axis`: the endstop, backed off by `backoff`.
    pub fn homed_position(&self, axis: &Axis) -> f64 {
        match self.direction {
            Direction::Min => self.endstop(axis) + self.backoff,
            Direction::Max => self.endstop(axis) - self.backoff,
        }
    }
}

/// Limits on the toolhead's vector motion.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Limits {
    /// Most vector velocity, units/s.
    pub velocity: f64,
    /// Most vector acceleration, units/s².
    pub acceleration: f64,
    /// Junction deviation for cornering, units.
    pub junction_deviation: f64,
    /// The share of each move kept for cruising, in [0, 1): moves that
    /// cannot cruise accelerate less (the meaning Klipper gives
    /// `minimum_cruise_ratio`; 0.5 is Klipper's default). Default 0: off.
    #[serde(default)]
    pub minimum_cruise_ratio: f64,
    /// How far above what the plan can command the modules' firmware
    /// limits sit (≥ 1; 0 turns the firmware limits off). Default 1.5.
    #[serde(default = "default_module_margin")]
    pub module_margin: f64,
    /// How many steps a module may send late (more than one step period
    /// behind their time, because the axis was asked to step faster than
    /// the module's step rate) before the machine stops on it. Default 0:
    /// any late step stops the machine.
    #[serde(default)]
    pub max_late_steps: u32,
    /// The speed profile of every move: `"trapezoid"` (constant
    /// acceleration, the default) or `"scurve"` (jerk-limited by each
    /// axis's `jerk` and the toolhead's [`Limits::jerk`]).
    #[serde(default)]
    pub profile: ProfileKind,
    /// Most toolhead jerk, units/s³, with `profile = "scurve"`; default:
    /// none beyond the axes' own.
    #[serde(default)]
    pub jerk: Option<f64>,
    /// What bounds each move's acceleration besides the limits above:
    /// `"motors"` plans from the motors' torque at speed (the axes' and
    /// toolhead's `acceleration` then bound only what no model covers).
    #[serde(default)]
    pub model: Option<PlannerModel>,
    /// The share of a motor's torque the motor model may plan with, in
    /// (0, 1]; default 0.7.
    #[serde(default = "default_torque_margin")]
    pub torque_margin: f64,
}

impl Limits {
    /// The toolhead's constant acceleration, units/s²: `acceleration`, or
    /// none (infinite) when the motors' model bounds it instead.
    pub fn vector_acceleration(&self) -> f64 {
        match self.model {
            Some(PlannerModel::Motors) => f64::INFINITY,
            None => self.acceleration,
        }
    }
}

fn default_torque_margin() -> f64 {
    DEFAULT_TORQUE_MARGIN
}

fn default_module_margin() -> f64 {
    1.5
}

/// `[limits] profile`: the shape of every move's speed profile.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ProfileKind {
    /// Constant acceleration ramps (Klipper's, Marlin's without S-curve).
    #[default]
    Trapezoid,
    /// Jerk-limited ramps: the acceleration rises and falls at most at the
    /// jerk limit, and is continuous through every junction.
    Scurve,
}

/// What a tool is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ToolKind {
    /// A spindle (speed by PWM duty, or on/off on a digital pin).
    Spindle,
    /// A pen (a servo on PWM, or a solenoid on a digital pin).
    Pen,
    /// A laser (power by PWM duty, or on/off on a digital pin).
    Laser,
    /// A fan (speed by PWM duty): a printer's part fan, set by `M106`
    /// and `M107`.
    Fan,
}

/// A module output a tool is wired to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Deserialize)]
#[serde(rename_all = "lowercase", deny_unknown_fields)]
pub enum Output {
    /// A PWM channel (`pwm_write`, 0..=1).
    Pwm(u8),
    /// A digital pin (`digital_write`, 0..=3).
    Digital(u8),
}

/// A tool on a module's output.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Tool {
    /// What the tool is.
    pub kind: ToolKind,
    /// The module (a key of `[modules]`) the tool is wired to.
    pub module: String,
    /// The output on that module.
    pub output: Output,
    /// PWM duty (0..=1) with the tool on (pen down, full power, full speed).
    #[serde(default = "default_on_duty")]
    pub on_duty: f64,
    /// PWM duty (0..=1) with the tool off (pen up).
    #[serde(default)]
    pub off_duty: f64,
    /// Spindle speed at `on_duty`, rpm (spindles only; scales `S` words).
    #[serde(default)]
    pub max_rpm: Option<f64>,
    /// Time to wait after switching the tool, milliseconds (a spindle
    /// with a `tach` waits for its measured speed instead).
    #[serde(default)]
    pub settle_ms: u32,
    /// A spindle's tachometer: speeds are waited for as measured, and a
    /// stall faults the machine (see [`Tach`]).
    #[serde(default)]
    pub tach: Option<Tach>,
    /// A laser's power follows its speed along the path for every job
    /// (`power = level × speed / feed`, as G-code `M4` asks per job):
    /// constant energy per mm through accelerations and corners. Lasers
    /// on a PWM output only; default false.
    #[serde(default)]
    pub dynamic: bool,
    /// The `S` word that means full power (a laser's; Grbl's `$30`,
    /// LightBurn's "S value max"); default [`DEFAULT_S_MAX`] for a laser.
    #[serde(default)]
    pub s_max: Option<f64>,
}

/// The `S` word of full laser power when a laser gives no `s_max`:
/// Grbl's default `$30`.
pub const DEFAULT_S_MAX: f64 = 1000.0;

impl Tool {
    /// Whether the machine streams this tool's level with the motion
    /// (see `machine::tool_track`): a laser or a pen on a PWM output,
    /// switched (and a laser powered) at its place on the path without
    /// stopping (a `settle_ms`, if it has one, held where the path comes
    /// to rest).
    pub fn streamed(&self) -> bool {
        matches!(self.kind, ToolKind::Laser | ToolKind::Pen)
            && matches!(self.output, Output::Pwm(_))
    }
}

fn default_on_duty() -> f64 {
    1.0
}

/// Where a homing switch sits, derived from an axis's homing.
#[derive(Debug, Clone, PartialEq)]
pub struct SwitchPlacement<'a> {
    /// The axis the switch homes.
    pub axis: &'a str,
    /// The module whose limit input the switch is on.
    pub module: &'a str,
    /// The end of travel the switch is at.
    pub direction: Direction,
    /// The axis position at which the switch closes (the homing's
    /// `endstop`: beyond the travel end, or at it); for a joint switch
    /// ([`SwitchPlacement::joint`]) the joint's angle, radians.
    pub position: f64,
    /// For an arm (scara, fivebar), the index (0 or 1) of the mechanism's
    /// joint whose angle presses the switch: see
    /// [`MachineFile::homed_joint`].
    pub joint: Option<usize>,
}

/// How far a joint homing searches for its switch: a full turn, radians.
pub const JOINT_SEARCH: f64 = std::f64::consts::TAU;

impl MachineFile {
    /// Parses and validates a machine file's text.
    pub fn parse(text: &str) -> Result<MachineFile, ConfigError> {
        let mut file: MachineFile = toml::from_str(text).map_err(|e| {
            let line = e
                .span()
                .map(|span| line_of(text, span.start))
                .filter(|_| !text.is_empty());
            let mut message = e.message().trim().to_string();
            if let Some(quoted) = line.and_then(|n| quote_line(text, n)) {
                message = format!("{message} (at `{quoted}`)");
            }
            ConfigError::Parse {
                file: None,
                line,
                message,
            }
        })?;
        for axis in file.axes.values_mut() {
            if axis.kind == AxisKind::Extruder && axis.min.is_nan() && axis.max.is_nan() {
                (axis.min, axis.max) = (f64::NEG_INFINITY, f64::INFINITY);
            }
        }
        if let Some(sim) = &mut file.sim {
            sim.place_bed(&file.axes);
        }
        file.validate()?;
        Ok(file)
    }

    /// Reads, parses and validates a machine file; errors name the file.
    pub fn load(path: impl AsRef<Path>) -> Result<MachineFile, ConfigError> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let mut file = MachineFile::parse(&text).map_err(|e| e.with_file(path))?;
        file.source_dir = path.parent().map(Path::to_path_buf);
        Ok(file)
    }

    /// The bed mesh file's path, resolved against the machine file's
    /// folder.
    pub fn bed_mesh_path(&self) -> Option<PathBuf> {
        let mesh = self.bed_mesh.as_ref()?;
        Some(match &self.source_dir {
            Some(dir) if mesh.is_relative() => dir.join(mesh),
            _ => mesh.clone(),
        })
    }

    /// The axis names in order (x, y, z, a, b, c, u, v, w, e).
    pub fn axis_names(&self) -> Vec<&str> {
        AXIS_NAMES
            .iter()
            .copied()
            .filter(|name| self.axes.contains_key(*name))
            .collect()
    }

    /// How many of [`MachineFile::axis_names`] lead as the toolhead's
    /// ([`TOOLHEAD_AXES`]); the rest follow along.
    pub fn toolhead_axes(&self) -> usize {
        self.axis_names()
            .iter()
            .take_while(|a| TOOLHEAD_AXES.contains(a))
            .count()
    }

    /// The extruder axis (`[axes.e]`), if the machine has one.
    pub fn extruder(&self) -> Option<&Axis> {
        self.axes.get("e").filter(|a| a.kind == AxisKind::Extruder)
    }

    /// The motor driving `axis` alone (`None` for an unknown axis or one the
    /// kinematics drive).
    pub fn motor_for_axis(&self, axis: &str) -> Option<&str> {
        self.axes.get(axis)?.motor.as_deref()
    }

    /// The motors that move when `axis` moves: its own motor, or both of a
    /// mechanism's motors for x and y under corexy, scara and fivebar.
    pub fn motors_for_axis(&self, axis: &str) -> Vec<&str> {
        let Some(entry) = self.axes.get(axis) else {
            return Vec::new();
        };
        match &entry.motor {
            Some(motor) => vec![motor.as_str()],
            None if is_mechanism_axis(&self.kinematics, axis) => self
                .kinematics
                .motors()
                .iter()
                .map(String::as_str)
                .collect(),
            None => Vec::new(),
        }
    }

    /// Axes with homing, grouped by `order` (lower first; each group homes
    /// together, axes in [`MachineFile::axis_names`] order).
    pub fn homing_order(&self) -> Vec<Vec<&str>> {
        let mut groups: BTreeMap<u32, Vec<&str>> = BTreeMap::new();
        for name in self.axis_names() {
            if let Some(homing) = self.axes.get(name).and_then(|a| a.homing.as_ref()) {
                groups.entry(homing.order).or_default().push(name);
            }
        }
        groups.into_values().collect()
    }

    /// The mechanism joint that `axis`'s switch homing homes, on an arm:
    /// under scara and fivebar kinematics, x's homing homes joint 0 (the
    /// first of `[kinematics] motors`: the shoulder, or the left motor)
    /// and y's joint 1 (the elbow, or the right motor), each on a switch
    /// pressed by that joint's angle, in the joint's units (radians:
    /// `endstop`, `backoff`; rad/s: `search_speed`, `latch_speed`). An
    /// arm's x and y are not linear in its motors, so they cannot home
    /// one at a time; the joints can, and the machine position follows
    /// from them. `None` for any other axis or kinematics.
    pub fn homed_joint(&self, axis: &str) -> Option<usize> {
        // Switch homing only (an arm has no other way yet).
        self.axes.get(axis)?.homing.as_ref()?.switch.as_ref()?;
        match (&self.kinematics, axis) {
            (Kinematics::Scara { .. } | Kinematics::FiveBar { .. }, "x") => Some(0),
            (Kinematics::Scara { .. } | Kinematics::FiveBar { .. }, "y") => Some(1),
            _ => None,
        }
    }

    /// Where the homing switches sit, for placing simulated limit switches:
    /// one per axis that homes on a switch, at its endstop (beyond the
    /// travel end it homes to, by default [`ENDSTOP_BEYOND`]).
    pub fn switch_placements(&self) -> Vec<SwitchPlacement<'_>> {
        let mut placements = Vec::new();
        for name in self.axis_names() {
            let Some(axis) = self.axes.get(name) else {
                continue;
            };
            let Some(homing) = &axis.homing else {
                continue;
            };
            let Some(module) = &homing.switch else {
                continue;
            };
            placements.push(SwitchPlacement {
                axis: name,
                module,
                direction: homing.direction,
                position: homing.endstop(axis),
                joint: self.homed_joint(name),
            });
        }
        placements
    }

    /// Checks the file describes a possible machine; the error names the
    /// first offending key and the fix.
    pub fn validate(&self) -> Result<(), ConfigError> {
        if self.name.trim().is_empty() {
            return Err(invalid(
                "name",
                "the machine name is empty; give the machine a name",
            ));
        }
        self.validate_modules()?;
        self.validate_kinematics()?;
        self.validate_motors()?;
        self.validate_axes()?;
        self.validate_limits()?;
        self.validate_motor_models()?;
        self.validate_step_rates()?;
        self.validate_tools()?;
        self.validate_spindles()?;
        heaters::validate(self)?;
        self.validate_sim()?;
        accel::validate(self)?;
        probe::validate(self)?;
        jobs::validate(self)?;
        if let Some(mesh) = &self.bed_mesh {
            if mesh.as_os_str().is_empty() {
                return Err(invalid(
                    "bed_mesh",
                    "the bed mesh path is empty; name a mesh file or remove the key",
                ));
            }
        }
        Ok(())
    }
}

/// Line `n` (1-based) of `text`, trimmed and cut to 60 characters; `None`
/// when blank.
fn quote_line(text: &str, n: usize) -> Option<String> {
    let line = text.lines().nth(n.checked_sub(1)?)?.trim();
    if line.is_empty() {
        return None;
    }
    let mut quoted: String = line.chars().take(60).collect();
    if quoted.len() < line.len() {
        quoted.push('…');
    }
    Some(quoted)
}

fn line_of(text: &str, offset: usize) -> usize {
    let end = offset.min(text.len());
    text.as_bytes()[..end]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        + 1
}

impl fmt::Display for Direction {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Direction::Min => "min",
            Direction::Max => "max",
        })
    }
}
