//! # osap-machine
//!
//! Machines in machine terms, above `osap-host` and `maxl`:
//!
//! - [`config`]: the machine file (TOML): modules, motors, axes,
//!   kinematics, limits, homing, tools and a `[sim]` section, validated
//!   with errors that name the key and the fix;
//! - [`gcode`]: a G-code job read into machine moves (lines, arcs, dwells,
//!   spindle on and off), with a warning and its line number for every word
//!   it does not carry out;
//! - [`svg`]: an SVG drawing flattened to polylines in millimetres;
//! - [`sim`]: the simulated machine (osap-sim topology) a machine file
//!   describes, with its homing switches;
//! - [`record`]: what a run leaves behind (`osap run --out DIR`): planned
//!   and executed positions as CSV, following error, durations, SVG plots
//!   of path, speed and error, and resampling of per-motor readbacks onto
//!   a common time grid.
//!
//! - [`machine`]: [`Machine`], a machine in machine terms (home, goto,
//!   queued lines and arcs, tools, halt, events, feed override), the same
//!   on simulated modules and on hardware;
//! - [`mesh`]: bed mesh files, which the machine follows in z;
//! - [`level`]: bed levelling: probe a grid, fit and save a mesh, plot it;
//! - [`job`]: a G-code program or SVG drawing as a checked machine
//!   [`job::Program`], and running it.
//! - [`capture`]: any numeric function output recorded beside a job
//!   ([`Machine::record`]) to Parquet or CSV, on the synchronized clock.
//! - [`network`]: how a machine is reached (links, its entry point) and
//!   its modules found and checked, without a [`Machine`];
//! - [`runs`]: run records (`run.json`): what a command ran, on which
//!   machine file, job and firmware, how it ended and what it wrote;
//! - [`halt`]: every module of a machine halted and every tool switched
//!   off from the network alone (`osap halt`).
#![deny(missing_docs)]

#[cfg(feature = "capture")]
pub mod capture;
pub mod config;
pub mod gcode;
pub mod halt;
pub mod heater_tune;
pub mod job;
pub mod level;
pub mod machine;
pub mod mesh;
pub mod module_limits;
pub mod network;
pub mod record;
#[cfg(feature = "resonance")]
pub mod resonance;
#[cfg(feature = "rheo")]
pub mod rheo;
#[cfg(feature = "runs")]
pub mod runs;
#[cfg(feature = "sim")]
pub mod sim;
pub mod svg;

pub use machine::events::FaultKind;
pub use machine::{
    Heater, HeaterReading, HeaterState, Machine, MachineError, MachineEvent, MachineState,
    StopReport,
};
