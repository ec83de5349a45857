//! A G-code job as a machine program: G-code positions placed in the
//! machine's axes, the extruder's moves (with the machine file's flow cap
//! and firmware retraction), and a printer's heater, fan and motor codes.

use super::flow::{limit_flow, Extruding, HotendTemperature};
use super::{JobError, Move, Program, ToolLevel};
use crate::config::{MachineFile, DEFAULT_RETRACT_LENGTH, DEFAULT_RETRACT_SPEED};
use crate::gcode::{Action, GcodeError, Job, ReadOptions};

/// Where a G-code axis (0 x, 1 y, 2 z) is among the machine's axes.
pub(super) fn slots(cfg: &MachineFile) -> [Option<usize>; 3] {
    let names = cfg.axis_names();
    ["x", "y", "z"].map(|a| names.iter().position(|n| *n == a))
}

/// Machine coordinates of a G-code position, checked against the axes the
/// machine has; `from` gives the coordinates of axes the program does not
/// move.
pub(super) fn place_gcode(
    cfg: &MachineFile,
    to: [f64; 3],
    from: &[f64],
    line: usize,
) -> Result<Vec<f64>, JobError> {
    let mut out = from.to_vec();
    for (g, slot) in slots(cfg).iter().enumerate() {
        match slot {
            Some(k) => out[*k] = to[g],
            // G-code starts at 0: an axis the machine lacks may stay there.
            None if to[g].abs() <= 1e-9 => {}
            None => {
                return Err(JobError::NoSuchAxis {
                    place: format!("line {line}"),
                    axis: ["x", "y", "z"][g].into(),
                })
            }
        }
    }
    Ok(out)
}

/// How G-code is read on machine `cfg`: its dialect, and its work offsets
/// with G54 at `origin` (machine coordinates of the work zero, mm) when
/// given (`osap run --origin`), else as its `[work_offsets]` say.
pub fn gcode_options(cfg: &MachineFile, origin: Option<[f64; 3]>) -> ReadOptions {
    let mut work_offsets = cfg.work_offsets.all();
    if origin.is_some() {
        work_offsets[0] = origin;
    }
    ReadOptions {
        dialect: cfg.dialect(),
        work_offsets,
    }
}

/// A G-code job as a program for machine `cfg`, starting at `start`
/// (axis order). Every move, arcs included, is checked against the travel;
/// extruding moves are held to the extruder's flow limit at the job's
/// hotend targets.
pub fn from_gcode(cfg: &MachineFile, job: &Job, start: &[f64]) -> Result<Program, JobError> {
    from_gcode_with(cfg, job, start, HotendTemperature::AsJob)
}

/// [`from_gcode`] with the hotend's temperature set as `hotend` says
/// (`osap run --temperature`), its flow limit at that temperature.
pub fn from_gcode_with(
    cfg: &MachineFile,
    job: &Job,
    start: &[f64],
    hotend: HotendTemperature,
) -> Result<Program, JobError> {
    // The reader's own travel check covers whole arcs; axes the machine
    // lacks are checked by `place_gcode` (they must stay at 0).
    let (mut min, mut max) = ([f64::NEG_INFINITY; 3], [f64::INFINITY; 3]);
    for (g, slot) in slots(cfg).iter().enumerate() {
        if let Some(k) = slot {
            let a = &cfg.axes[cfg.axis_names()[*k]];
            (min[g], max[g]) = (a.min, a.max);
        }
    }
    let mut moves = Vec::new();
    let mut extruding = Vec::new();
    let mut at = start.to_vec();
    let mut retracted = false;
    let mut warnings: Vec<String> = job.warnings.iter().map(|w| w.to_string()).collect();
    let (mut g29_said, mut limits_said, mut model_capped_said) = (false, false, false);
    for step in &job.steps {
        let mv = match step.action {
            Action::Rapid { to } => {
                let p = place_gcode(cfg, to, &at, step.line)?;
                at.clone_from(&p);
                Move::Rapid(p)
            }
            Action::Line { to, feed } => {
                let p = place_gcode(cfg, to, &at, step.line)?;
                at.clone_from(&p);
                Move::Line(p, feed)
            }
            Action::Arc {
                to,
                center,
                clockwise,
                feed,
            } => {
                let p = place_gcode(cfg, to, &at, step.line)?;
                if slots(cfg)[0] != Some(0) || slots(cfg)[1] != Some(1) {
                    return Err(JobError::NotPlanar(cfg.axis_names().join(", ")));
                }
                at.clone_from(&p);
                Move::Arc {
                    to: p,
                    center,
                    clockwise,
                    feed,
                }
            }
            Action::Dwell { seconds } => Move::Dwell(seconds),
            Action::ToolOn {
                speed,
                dynamic: true,
            } => Move::Tool(Some(ToolLevel::Dynamic(speed))),
            Action::ToolOn {
                speed,
                dynamic: false,
            } => Move::Tool(Some(match speed {
                Some(s) => ToolLevel::Speed(s),
                None => ToolLevel::Full,
            })),
            Action::ToolOff => Move::Tool(None),
            Action::End => break,
            Action::Extrude { to, e, feed } => {
                let mut p = place_gcode(cfg, to, &at, step.line)?;
                let k = e_slot(cfg, step.line)?;
                // The reader's e starts at 0 with the job; the extruder
                // goes on from where it stands.
                p[k] = start[k] + e;
                extruding.extend(extruding_move(cfg, &at, &p, k, moves.len()));
                at.clone_from(&p);
                Move::Line(p, feed)
            }
            Action::Retract { retract } => {
                let k = e_slot(cfg, step.line)?;
                if retract == retracted {
                    // A second G10 (or a G11 without one) does nothing,
                    // as firmware retraction does.
                    continue;
                }
                retracted = retract;
                let x = cfg.extruder().map(|a| &a.extruder);
                let length = x
                    .and_then(|x| x.retract_length)
                    .unwrap_or(DEFAULT_RETRACT_LENGTH);
                let speed = x
                    .and_then(|x| x.retract_speed)
                    .unwrap_or(DEFAULT_RETRACT_SPEED);
                at[k] += if retract { -length } else { length };
                Move::Line(at.clone(), speed)
            }
            Action::Heater {
                heater,
                celsius,
                wait,
            } => {
                let name = heater.name();
                if !cfg.heaters.contains_key(name) {
                    return Err(JobError::NoSuchHeater {
                        place: format!("line {}", step.line),
                        heater: name.to_string(),
                    });
                }
                Move::Heater {
                    name: name.to_string(),
                    celsius,
                    wait,
                }
            }
            Action::Fan { duty } => Move::Fan(duty),
            Action::Home { axes } => {
                let names = cfg.axis_names();
                let mut homed = Vec::new();
                for a in ["x", "y", "z"]
                    .into_iter()
                    .zip(axes)
                    .filter_map(|(a, named)| named.then_some(a))
                {
                    let a = a.to_string();
                    if !names.contains(&a.as_str()) {
                        return Err(JobError::NoSuchAxis {
                            place: format!("line {}", step.line),
                            axis: a,
                        });
                    }
                    homed.push(a);
                }
                // Where homing leaves the axes it homes.
                for (k, n) in names.iter().enumerate() {
                    if homed.is_empty() || homed.iter().any(|h| h == n) {
                        if let Some(h) = &cfg.axes[*n].homing {
                            at[k] = h.homed_position(&cfg.axes[*n]);
                        }
                    }
                }
                Move::Home(homed)
            }
            Action::BedMesh => {
                // The machine follows its bed_mesh from the start: G29
                // asks for nothing more, or for a mesh it does not have.
                if cfg.bed_mesh.is_none() && !g29_said {
                    g29_said = true;
                    warnings.push(format!(
                        "line {}: G29: the machine file has no bed_mesh, so the bed is taken as flat (osap level measures one)",
                        step.line
                    ));
                }
                continue;
            }
            Action::MotorsOff => Move::MotorsOff,
            Action::Limits {
                velocity,
                acceleration,
                text,
            } => {
                let model = cfg.limits.model.is_some();
                let asked_more = velocity.is_some_and(|v| v > cfg.limits.velocity)
                    || acceleration.is_some_and(|a| a > cfg.limits.vector_acceleration());
                if model && acceleration.is_some() && !model_capped_said {
                    // The job's own acceleration is honoured as a ceiling,
                    // which may leave the motors' model nothing to do.
                    model_capped_said = true;
                    warnings.push(format!(
                        "line {}: {text} caps the acceleration the motors' model ([limits] model = \"motors\") plans with (said once)",
                        step.line
                    ));
                }
                if asked_more && !limits_said {
                    limits_said = true;
                    warnings.push(format!(
                        "line {}: {text} asks more than the machine file's [limits] (velocity {}, acceleration {}); held to them (said once)",
                        step.line, cfg.limits.velocity, cfg.limits.acceleration
                    ));
                }
                Move::Limits {
                    velocity,
                    acceleration,
                    code: text,
                }
            }
            Action::Progress { percent } => Move::Progress(percent),
            Action::Layer { number } => Move::Layer(number),
        };
        moves.push((step.line, mv));
    }
    job.check_travel(min, max).map_err(|e| match e {
        GcodeError::Travel {
            line,
            axis,
            value,
            min,
            max,
        } => JobError::OutOfTravel {
            place: format!("line {line}"),
            axis: axis.to_ascii_lowercase().to_string(),
            value,
            min,
            max,
        },
        other => JobError::BadArc {
            place: "G-code".into(),
            reason: other.to_string(),
        },
    })?;
    let mut program = Program {
        moves,
        warnings,
        dialect: Some(job.dialect),
        e_slot: cfg.axis_names().iter().position(|n| *n == "e"),
        e_start: cfg
            .axis_names()
            .iter()
            .position(|n| *n == "e")
            .map_or(0.0, |k| start[k]),
        ..Program::default()
    };
    limit_flow(cfg, &mut program, &extruding, hotend)?;
    Ok(program)
}

/// The slot of the machine's extruder, or the error for a job that
/// extrudes on a machine without one.
fn e_slot(cfg: &MachineFile, line: usize) -> Result<usize, JobError> {
    cfg.extruder()
        .and_then(|_| cfg.axis_names().iter().position(|n| *n == "e"))
        .ok_or(JobError::NoSuchAxis {
            place: format!("line {line}"),
            axis: "e".into(),
        })
}

/// Move `index`, from `from` to `to`, if it extrudes (the extruder in slot
/// `k`): its toolhead path and the melt it makes per mm/s of feed,
/// `Δe / path · area`. Moves that only extrude or retract, or that
/// retract, are not extruding moves (the flow limit leaves them).
fn extruding_move(
    cfg: &MachineFile,
    from: &[f64],
    to: &[f64],
    k: usize,
    index: usize,
) -> Option<Extruding> {
    let x = cfg.extruder().map(|a| &a.extruder)?;
    let n = cfg.toolhead_axes();
    let path = (0..n)
        .map(|i| (to[i] - from[i]).powi(2))
        .sum::<f64>()
        .sqrt();
    let de = to[k] - from[k];
    (path > 1e-9 && de > 0.0).then(|| Extruding {
        index,
        path,
        flow_per_feed: de / path * x.filament_area(),
    })
}
