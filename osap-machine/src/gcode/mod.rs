//! G-code jobs: a program read into machine moves.
//!
//! The text is parsed by the [`gcode`](https://crates.io/crates/gcode)
//! crate (0.7, whose blocks keep bare words apart from commands); this
//! module interprets it, keeping the modal state a controller
//! keeps (motion mode, units, absolute or relative distances, the G92
//! offset, the feed rate) and turning every block into [`Action`]s in
//! millimetres and seconds:
//!
//! | words | what they do |
//! |---|---|
//! | `G0` | rapid move |
//! | `G1` + `F` | straight move at the feed rate |
//! | `G2`, `G3` with `I J` (centre, relative to the start) or `R` | clockwise, counter-clockwise arc in the XY plane (`Z` makes a helix) |
//! | `G4 P` | dwell: `P` seconds (rs274ngc); `P` milliseconds or `S` seconds (marlin) |
//! | `G17` | the XY plane (the only one) |
//! | `G20`, `G21` | inches, millimetres |
//! | `G53` | this block's move in machine coordinates |
//! | `G54`–`G59` | select a work offset ([`ReadOptions::work_offsets`]) |
//! | `G64` | path blending: the planner always blends within its junction deviation |
//! | `G90`, `G91` | absolute, relative distances |
//! | `G92`, `G92.1` | set the current position to the given coordinates; clear that |
//! | `M3 S`, `M5` | spindle (or laser, pen) on at speed `S`, off |
//! | `M4 S` | laser on with dynamic power: its power follows the speed along the path |
//! | `S` with the tool on | the tool takes the new speed or power from here (`G1 X10 S500`) |
//! | `M2`, `M30` | end of program |
//! | `F` | feed rate, units per minute |
//!
//! Axis words alone on a line (`X10 Y5`) continue the last motion mode.
//! Comments (`( … )`, `;`) may stand anywhere in a block. Any other word
//! (`G28`, `M106`, `T1`, ..) is skipped with a [`Warning`] that names its
//! line. What cannot be carried out safely is an [`GcodeError`] naming the
//! line: a feed move before any `F`, an arc without a centre or with a
//! radius that does not fit its end points, a plane other than XY, a number
//! that is not finite, a work offset the machine file does not set, and
//! what this reader does not interpret ([`Unsupported`]: expressions,
//! parameters, O-words).
//!
//! Positions are machine coordinates: a program position plus the
//! selected work offset (G54 at the start) plus the G92 offset. Where
//! controllers read a word differently, [`ReadOptions::dialect`] says
//! which reading applies ([`Dialect`]).
//!
//! [`Job::check_travel`] refuses a job that leaves the machine's travel
//! before anything moves, naming the offending line.

use thiserror::Error;

pub use crate::config::Dialect;

mod interp;
mod scan;
#[cfg(test)]
mod tests;
mod travel;

use interp::State;

/// Millimetres per inch.
const MM_PER_INCH: f64 = 25.4;
/// How far an arc's end may be off the circle through its start, mm (or
/// this share of the radius, whichever is larger).
const ARC_TOLERANCE_MM: f64 = 0.002;
/// The relative share of [`ARC_TOLERANCE_MM`].
const ARC_TOLERANCE_REL: f64 = 0.001;

/// What a block asks of the machine. Positions are machine coordinates in
/// mm (`[x, y, z]`), speeds mm/s.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Action {
    /// Move as fast as the machine allows (`G0`).
    Rapid {
        /// Where to.
        to: [f64; 3],
    },
    /// Move in a straight line at `feed` (`G1`).
    Line {
        /// Where to.
        to: [f64; 3],
        /// Speed along the path, mm/s.
        feed: f64,
    },
    /// Move along an arc in the XY plane (a helix if Z changes) at `feed`
    /// (`G2`, `G3`).
    Arc {
        /// Where to.
        to: [f64; 3],
        /// The centre, XY.
        center: [f64; 2],
        /// Clockwise seen from +Z (`G2`).
        clockwise: bool,
        /// Speed along the path, mm/s.
        feed: f64,
    },
    /// Wait (`G4`).
    Dwell {
        /// How long, s.
        seconds: f64,
    },
    /// The spindle (or laser, or pen) on at `speed` (`M3`, `M4`; the last
    /// `S`, if any was given; again at each new `S` while on).
    ToolOn {
        /// The speed or power given by `S`, if any.
        speed: Option<f64>,
        /// `M4`: a laser's power follows its speed along the path.
        dynamic: bool,
    },
    /// The tool off (`M5`).
    ToolOff,
    /// End of program (`M2`, `M30`): nothing after it is read.
    End,
    /// A straight move that also drives the extruder (`G1` with `E`).
    Extrude {
        /// Where to, `[x, y, z]`.
        to: [f64; 3],
        /// Where the extruder ends, mm of filament (absolute, after any
        /// `G92 E`).
        e: f64,
        /// Speed along the path (of the extruder alone for a move that
        /// only extrudes or retracts), mm/s.
        feed: f64,
    },
    /// Firmware retraction: pull the filament back (`G10`, marlin) or
    /// push it again (`G11`) by the machine file's `retract_length`.
    Retract {
        /// `true` for G10, `false` for G11.
        retract: bool,
    },
    /// Set a heater's target, °C (`M104`, `M140`; 0 off), and with `wait`
    /// wait until it is reached (`M109`, `M190`).
    Heater {
        /// Which heater.
        heater: HeaterRole,
        /// The target, °C.
        celsius: f64,
        /// Wait for the target (M109, M190).
        wait: bool,
    },
    /// The part fan at a duty, 0–1 (`M106 S0–255`, `M107`).
    Fan {
        /// Duty cycle, 0–1.
        duty: f64,
    },
    /// Home the given axes (`G28`; all of them when none are named).
    Home {
        /// Whether X, Y and Z were named; none named homes every axis.
        axes: [bool; 3],
    },
    /// Follow the machine's bed mesh (`G29`).
    BedMesh,
    /// The motors off (`M84`, `M18`), at the end of a print.
    MotorsOff,
    /// The toolhead's speed or acceleration from the job (`M203`, `M204`,
    /// `M201`), mm/s and mm/s²: held to the machine file's.
    Limits {
        /// Largest toolhead speed asked, mm/s.
        velocity: Option<f64>,
        /// Largest toolhead acceleration asked, mm/s².
        acceleration: Option<f64>,
        /// The words as written, for the message.
        text: &'static str,
    },
    /// Progress the job reports (`M73 P`, %).
    Progress {
        /// Percent done.
        percent: f64,
    },
    /// A new layer begins (a slicer's layer comment).
    Layer {
        /// The layer's number, from 1.
        number: usize,
    },
}

/// The heater a temperature code sets.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HeaterRole {
    /// The hotend (`M104`, `M109`): the machine file's `[heaters.hotend]`.
    Hotend,
    /// The bed (`M140`, `M190`): `[heaters.bed]`.
    Bed,
}

impl HeaterRole {
    /// The heater's name in the machine file.
    pub fn name(self) -> &'static str {
        match self {
            HeaterRole::Hotend => "hotend",
            HeaterRole::Bed => "bed",
        }
    }
}

/// One action and the line (from 1) it came from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Step {
    /// The line in the program, from 1.
    pub line: usize,
    /// What to do.
    pub action: Action,
}

/// A word that was skipped, and why.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Warning {
    /// The line in the program, from 1.
    pub line: usize,
    /// What was skipped.
    pub message: String,
}

impl std::fmt::Display for Warning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "line {}: {}", self.line, self.message)
    }
}

/// Why a program cannot be run.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum GcodeError {
    /// A block asks for something that cannot be carried out.
    #[error("line {line}: {message}")]
    Block {
        /// The line, from 1.
        line: usize,
        /// What is wrong, and the fix.
        message: String,
    },
    /// A construct this reader does not interpret: the program is refused
    /// rather than read differently from what its author meant.
    #[error("line {line}: {text}: {feature} are not supported; {}", feature.fix())]
    Unsupported {
        /// The line, from 1.
        line: usize,
        /// What it is.
        feature: Unsupported,
        /// The word or block, as written.
        text: String,
    },
    /// A block selects a work offset the machine file does not set.
    #[error("line {line}: G{code} selects a work offset the machine file does not set; add {code_key} = [x, y, z] to its [work_offsets], or use G54 (with osap run --origin)", code_key = format!("G{code}"))]
    NoWorkOffset {
        /// The line, from 1.
        line: usize,
        /// 55..=59.
        code: u8,
    },
    /// A move leaves the machine's travel.
    #[error(
        "line {line}: {axis} would reach {value:.3} mm, outside the travel {min:.3} to {max:.3} mm"
    )]
    Travel {
        /// The line, from 1.
        line: usize,
        /// The axis.
        axis: char,
        /// Where the move takes it, mm.
        value: f64,
        /// The travel's lower end, mm.
        min: f64,
        /// The travel's upper end, mm.
        max: f64,
    },
}

/// What the reader refuses to interpret.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum Unsupported {
    /// `[...]` (LinuxCNC's `Y[0.01*2]`).
    Expression,
    /// `#1`, `#<name>`.
    Parameter,
    /// `O100 sub`, `o<name> call`, `O101 while`.
    OWord,
}

impl Unsupported {
    /// What to do instead.
    fn fix(self) -> &'static str {
        match self {
            Unsupported::Expression | Unsupported::Parameter => {
                "write the value as a number (most CAM post-processors have an option for plain numbers)"
            }
            Unsupported::OWord => {
                "write the program out in full (without subroutines or loops)"
            }
        }
    }
}

impl std::fmt::Display for Unsupported {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Unsupported::Expression => "expressions ([...])",
            Unsupported::Parameter => "parameters (#)",
            Unsupported::OWord => "O-words (subroutines, loops)",
        })
    }
}

/// A program read into actions.
#[derive(Debug, Clone, PartialEq)]
pub struct Job {
    /// The actions, in order.
    pub steps: Vec<Step>,
    /// Words that were skipped.
    pub warnings: Vec<Warning>,
    /// The dialect it was read in.
    pub dialect: Dialect,
}

/// How a program is read.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReadOptions {
    /// Where controllers differ, whose reading applies.
    pub dialect: Dialect,
    /// The work zeros G54–G59 select, machine coordinates `[x, y, z]` in
    /// mm. G54 is selected at the start; G54 not given is the machine's
    /// zero, any other not given is refused when selected.
    pub work_offsets: [Option<[f64; 3]>; 6],
}

impl Default for ReadOptions {
    /// RS274/NGC with no work offsets: the reading of a program before
    /// dialects and work offsets existed.
    fn default() -> Self {
        ReadOptions {
            dialect: Dialect::Rs274ngc,
            work_offsets: [None; 6],
        }
    }
}

/// Reads `text` (a G-code program) into a [`Job`] with the default
/// [`ReadOptions`] (rs274ngc, no work offsets).
pub fn read(text: &str) -> Result<Job, GcodeError> {
    read_with(text, &ReadOptions::default())
}

/// Reads `text` (a G-code program) into a [`Job`] as `options` say.
pub fn read_with(text: &str, options: &ReadOptions) -> Result<Job, GcodeError> {
    let text_in = text;
    let text = scan::clean(text)?;
    let program = gcode::parse(&text).map_err(|d| match d.iter().next() {
        Some(first) => interp::error(first.span.line + 1, format!("cannot parse: {first}")),
        None => interp::error(1, "cannot parse the program"),
    })?;
    let mut state = State::new(options);
    let mut job = Job {
        steps: Vec::new(),
        warnings: Vec::new(),
        dialect: options.dialect,
    };
    let layers = scan::layer_lines(text_in);
    let mut next_layer = 0;
    for block in &program.blocks {
        let line = block.span.line + 1;
        while next_layer < layers.len() && layers[next_layer] < line {
            next_layer += 1;
            job.steps.push(Step {
                line: layers[next_layer - 1],
                action: Action::Layer { number: next_layer },
            });
        }
        let bare = interp::words(
            line,
            block.word_addresses.iter().map(|w| (w.letter, &w.value)),
        )?;
        // A block's own F and S apply before its commands (`S10000 M3`,
        // `F600 G1 X10`), as RS274/NGC orders a block's execution.
        interp::feed_and_speed(&mut state, &mut job, line, &bare)?;
        let mut commands: Vec<interp::Command> = Vec::new();
        for code in &block.codes {
            let (letter, number, args) = match code {
                gcode::Code::General(g) => ('G', g.number, &g.args),
                gcode::Code::Miscellaneous(m) => ('M', m.number, &m.args),
                gcode::Code::ToolChange(t) => ('T', t.number, &t.args),
                other => {
                    job.warnings.push(Warning {
                        line,
                        message: format!("{other} is not supported; skipped"),
                    });
                    continue;
                }
            };
            // A T after an M code on its line is that code's word
            // (`M104 S210 T0`, `M204 P1500 T3000`), not a tool change.
            if let (Some(prev), 'T', None) = (commands.last_mut(), letter, number.minor()) {
                if prev.letter == 'M' {
                    prev.words
                        .push(interp::Word::new('T', f64::from(number.major())));
                    continue;
                }
            }
            commands.push(interp::Command {
                letter,
                major: number.major(),
                minor: number.minor().map(|m| m.get()),
                words: interp::words(line, args.iter().map(|a| (a.letter, &a.value)))?,
            });
        }
        for command in &commands {
            if state.ended {
                return Ok(job);
            }
            interp::run(&mut state, &mut job, line, command)?;
        }
        if !bare.is_empty() && !state.ended {
            interp::continuation(&mut state, &mut job, line, &bare)?;
        }
        state.end_block();
    }
    Ok(job)
}
