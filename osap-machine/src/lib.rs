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
//!   describes, with its homing switches.
//!
//! Work in progress toward the `Machine` API and `osap run`: nothing here
//! drives modules yet.
#![deny(missing_docs)]

pub mod config;
pub mod gcode;
pub mod sim;
pub mod svg;
