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
    /// The spindle (or laser, or pen) on at `speed` (`M3`; the last `S`,
    /// if any was given).
    ToolOn {
        /// The speed or power given by `S`, if any.
        speed: Option<f64>,
    },
    /// The tool off (`M5`).
    ToolOff,
    /// End of program (`M2`, `M30`): nothing after it is read.
    End,
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
    for block in &program.blocks {
        let line = block.span.line + 1;
        let bare = interp::words(
            line,
            block.word_addresses.iter().map(|w| (w.letter, &w.value)),
        )?;
        // A block's own F and S apply before its commands (`S10000 M3`,
        // `F600 G1 X10`), as RS274/NGC orders a block's execution.
        interp::feed_and_speed(&mut state, line, &bare)?;
        for code in &block.codes {
            if state.ended {
                return Ok(job);
            }
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
            let command = interp::Command {
                letter,
                major: number.major(),
                minor: number.minor().map(|m| m.get()),
                words: interp::words(line, args.iter().map(|a| (a.letter, &a.value)))?,
            };
            interp::run(&mut state, &mut job, line, &command)?;
        }
        if !bare.is_empty() && !state.ended {
            interp::continuation(&mut state, &mut job, line, &bare)?;
        }
        state.end_block();
    }
    Ok(job)
}
