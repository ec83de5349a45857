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
//! | `G4 P` | dwell, `P` seconds |
//! | `G17` | the XY plane (the only one) |
//! | `G20`, `G21` | inches, millimetres |
//! | `G90`, `G91` | absolute, relative distances |
//! | `G92` | set the current position to the given coordinates |
//! | `M3 S`, `M5` | spindle (or laser, pen) on at speed `S`, off |
//! | `M2`, `M30` | end of program |
//! | `F` | feed rate, units per minute |
//!
//! Axis words alone on a line (`X10 Y5`) continue the last motion mode. Any
//! other word (`G28`, `M106`, `T1`, ..) is skipped with a [`Warning`] that
//! names its line. What cannot be carried out safely is an [`GcodeError`]
//! naming the line: a feed move before any `F`, an arc without a centre or
//! with a radius that does not fit its end points, a plane other than XY,
//! a number that is not finite.
//!
//! [`Job::check_travel`] refuses a job that leaves the machine's travel
//! before anything moves, naming the offending line.

use thiserror::Error;

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

/// A program read into actions.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Job {
    /// The actions, in order.
    pub steps: Vec<Step>,
    /// Words that were skipped.
    pub warnings: Vec<Warning>,
}

/// The modal state between blocks.
struct State {
    motion: Option<u32>,
    inches: bool,
    relative: bool,
    /// Machine position, mm.
    pos: [f64; 3],
    /// Machine position minus program position (G92), mm.
    offset: [f64; 3],
    /// Feed rate, mm/s.
    feed: Option<f64>,
    speed: Option<f64>,
    ended: bool,
}

impl State {
    fn unit(&self) -> f64 {
        if self.inches {
            MM_PER_INCH
        } else {
            1.0
        }
    }
}

/// A word: a letter and its value.
#[derive(Debug, Clone, Copy)]
struct Word {
    letter: char,
    value: f64,
}

/// A command read from a block: `G`, `M` or `T`, its number, its words.
struct Command {
    letter: char,
    major: u32,
    minor: Option<u32>,
    words: Vec<Word>,
}

fn words<'a>(
    line: usize,
    items: impl Iterator<Item = (char, &'a gcode::Value)>,
) -> Result<Vec<Word>, GcodeError> {
    items
        .map(|(letter, v)| match v {
            gcode::Value::Literal(x) if x.is_finite() => Ok(Word {
                letter: letter.to_ascii_uppercase(),
                value: f64::from(*x),
            }),
            gcode::Value::Literal(x) => Err(error(line, format!("{letter}{x} is not a number"))),
            other => Err(error(
                line,
                format!("{letter}{other}: parameters are not supported; write the number"),
            )),
        })
        .collect()
}

/// Reads `text` (a G-code program) into a [`Job`].
pub fn read(text: &str) -> Result<Job, GcodeError> {
    let program = gcode::parse(text).map_err(|d| match d.iter().next() {
        Some(first) => error(first.span.line + 1, format!("cannot parse: {first}")),
        None => error(1, "cannot parse the program"),
    })?;
    let mut state = State {
        motion: None,
        inches: false,
        relative: false,
        pos: [0.0; 3],
        offset: [0.0; 3],
        feed: None,
        speed: None,
        ended: false,
    };
    let mut job = Job::default();
    for block in &program.blocks {
        let line = block.span.line + 1;
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
            let command = Command {
                letter,
                major: number.major(),
                minor: number.minor().map(|m| m.get()),
                words: words(line, args.iter().map(|a| (a.letter, &a.value)))?,
            };
            run(&mut state, &mut job, line, &command)?;
        }
        if !block.word_addresses.is_empty() && !state.ended {
            let bare = words(
                line,
                block.word_addresses.iter().map(|w| (w.letter, &w.value)),
            )?;
            continuation(&mut state, &mut job, line, &bare)?;
        }
    }
    Ok(job)
}

fn error(line: usize, message: impl Into<String>) -> GcodeError {
    GcodeError::Block {
        line,
        message: message.into(),
    }
}

fn find(words: &[Word], letter: char) -> Option<&Word> {
    words.iter().find(|w| w.letter == letter)
}

fn run(state: &mut State, job: &mut Job, line: usize, code: &Command) -> Result<(), GcodeError> {
    let words = &code.words[..];
    let name = format!("{}{}", code.letter, code.major);
    let known = code.minor.is_none();
    match (code.letter, code.major) {
        ('G', n @ 0..=3) if known => {
            state.motion = Some(n);
            motion(state, job, line, n, words)
        }
        ('G', 4) if known => {
            let p =
                find(words, 'P').ok_or_else(|| error(line, "G4 needs P, the dwell in seconds"))?;
            let seconds = p.value;
            if seconds < 0.0 {
                return Err(error(line, "G4 P must not be negative"));
            }
            job.steps.push(Step {
                line,
                action: Action::Dwell { seconds },
            });
            Ok(())
        }
        ('G', 17 | 20 | 21 | 90 | 91) if known => {
            match code.major {
                20 => state.inches = true,
                21 => state.inches = false,
                90 => state.relative = false,
                91 => state.relative = true,
                _ => {}
            }
            // Words after a mode code on its line (`G91 X-5`) continue the
            // current motion in the new mode.
            if words.is_empty() {
                Ok(())
            } else {
                continuation(state, job, line, words)
            }
        }
        ('G', 18 | 19) if known => Err(error(
            line,
            format!("{name} selects another plane; only XY arcs (G17) are supported"),
        )),
        ('G', 92) if known => {
            for (i, axis) in ['X', 'Y', 'Z'].into_iter().enumerate() {
                if let Some(w) = find(words, axis) {
                    let program = w.value * state.unit();
                    state.offset[i] = state.pos[i] - program;
                }
            }
            Ok(())
        }
        ('M', 3) if known => {
            if let Some(s) = find(words, 'S') {
                state.speed = Some(s.value);
            }
            job.steps.push(Step {
                line,
                action: Action::ToolOn { speed: state.speed },
            });
            Ok(())
        }
        ('M', 5) if known => {
            job.steps.push(Step {
                line,
                action: Action::ToolOff,
            });
            Ok(())
        }
        ('M', 2 | 30) if known => {
            job.steps.push(Step {
                line,
                action: Action::End,
            });
            state.ended = true;
            Ok(())
        }
        _ => {
            let full = match code.minor {
                None => name,
                Some(minor) => format!("{name}.{minor}"),
            };
            job.warnings.push(Warning {
                line,
                message: format!("{full} is not supported; skipped"),
            });
            Ok(())
        }
    }
}

/// Orphan words: a feed rate, a spindle speed, or axis words continuing
/// the last motion mode.
fn continuation(
    state: &mut State,
    job: &mut Job,
    line: usize,
    words: &[Word],
) -> Result<(), GcodeError> {
    let moves = words.iter().any(|w| "XYZIJR".contains(w.letter));
    for w in words {
        match w.letter {
            'F' | 'X' | 'Y' | 'Z' | 'I' | 'J' | 'R' => {}
            'S' => state.speed = Some(w.value),
            other => job.warnings.push(Warning {
                line,
                message: format!("{other}{} is not supported; skipped", w.value),
            }),
        }
    }
    if moves {
        let Some(n) = state.motion else {
            return Err(error(
                line,
                "axis words without a motion mode: start the move with G0, G1, G2 or G3",
            ));
        };
        motion(state, job, line, n, words)
    } else {
        if let Some(f) = find(words, 'F') {
            set_feed(state, line, f)?;
        }
        Ok(())
    }
}

fn set_feed(state: &mut State, line: usize, f: &Word) -> Result<(), GcodeError> {
    let per_minute = f.value;
    if per_minute <= 0.0 {
        return Err(error(line, "F must be positive (units per minute)"));
    }
    state.feed = Some(per_minute * state.unit() / 60.0);
    Ok(())
}

/// A G0–G3 move with `words`.
fn motion(
    state: &mut State,
    job: &mut Job,
    line: usize,
    n: u32,
    words: &[Word],
) -> Result<(), GcodeError> {
    if let Some(f) = find(words, 'F') {
        set_feed(state, line, f)?;
    }
    let unit = state.unit();
    let mut to = state.pos;
    let mut any = false;
    for (i, axis) in ['X', 'Y', 'Z'].into_iter().enumerate() {
        if let Some(w) = find(words, axis) {
            let v = w.value * unit;
            to[i] = if state.relative {
                state.pos[i] + v
            } else {
                v + state.offset[i]
            };
            any = true;
        }
    }
    let from = state.pos;
    let action = match n {
        0 => Action::Rapid { to },
        1 => Action::Line {
            to,
            feed: feed(state, line, "G1")?,
        },
        _ => {
            let clockwise = n == 2;
            let center = arc_center(line, from, to, words, unit, clockwise)?;
            Action::Arc {
                to,
                center,
                clockwise,
                feed: feed(state, line, if clockwise { "G2" } else { "G3" })?,
            }
        }
    };
    if !any && n < 2 {
        // A mode change without a target: nothing moves.
        return Ok(());
    }
    state.pos = to;
    job.steps.push(Step { line, action });
    Ok(())
}

fn feed(state: &State, line: usize, what: &str) -> Result<f64, GcodeError> {
    state.feed.ok_or_else(|| {
        error(
            line,
            format!(
                "{what} before any feed rate: give F (units per minute) on this line or before"
            ),
        )
    })
}

/// An arc's centre from `I J` (relative to the start) or `R`, checked
/// against both end points.
fn arc_center(
    line: usize,
    from: [f64; 3],
    to: [f64; 3],
    words: &[Word],
    unit: f64,
    clockwise: bool,
) -> Result<[f64; 2], GcodeError> {
    let (i, j, r) = (find(words, 'I'), find(words, 'J'), find(words, 'R'));
    let center = if i.is_some() || j.is_some() {
        let di = i.map_or(0.0, |w| w.value) * unit;
        let dj = j.map_or(0.0, |w| w.value) * unit;
        [from[0] + di, from[1] + dj]
    } else if let Some(r) = r {
        let r = r.value * unit;
        let (dx, dy) = (to[0] - from[0], to[1] - from[1]);
        let chord = dx.hypot(dy);
        if chord == 0.0 {
            return Err(error(
                line,
                "an R arc needs distinct end points: give I and J for a full circle",
            ));
        }
        let h2 = r * r - chord * chord / 4.0;
        if h2 < -(ARC_TOLERANCE_MM * ARC_TOLERANCE_MM) {
            return Err(error(
                line,
                format!(
                    "R {:.4} mm is shorter than half the chord ({:.4} mm)",
                    r.abs(),
                    chord / 2.0
                ),
            ));
        }
        let h = h2.max(0.0).sqrt();
        // Left of the chord for a counter-clockwise arc under 180°; a
        // negative R asks for the long way round.
        let side = if clockwise == (r < 0.0) { 1.0 } else { -1.0 };
        let (mx, my) = (from[0] + dx / 2.0, from[1] + dy / 2.0);
        [mx - side * h * dy / chord, my + side * h * dx / chord]
    } else {
        return Err(error(
            line,
            "an arc needs its centre: give I and J (relative to the start) or R",
        ));
    };
    let r0 = (from[0] - center[0]).hypot(from[1] - center[1]);
    let r1 = (to[0] - center[0]).hypot(to[1] - center[1]);
    if r0 == 0.0 {
        return Err(error(line, "the arc's centre is its start point"));
    }
    let tolerance = ARC_TOLERANCE_MM.max(ARC_TOLERANCE_REL * r0);
    if (r0 - r1).abs() > tolerance {
        return Err(error(
            line,
            format!(
                "the arc's end is {:.4} mm from its centre but its start {:.4} mm: fix I, J or the end point",
                r1, r0
            ),
        ));
    }
    Ok(center)
}

impl Job {
    /// Refuses the job if any move would take an axis outside `min..=max`
    /// (mm, per axis X, Y, Z), naming the first offending line. Arcs are
    /// checked over their whole sweep, not only their end points. The
    /// machine starts at the origin.
    pub fn check_travel(&self, min: [f64; 3], max: [f64; 3]) -> Result<(), GcodeError> {
        let mut pos = [0.0f64; 3];
        for step in &self.steps {
            let (to, extra) = match step.action {
                Action::Rapid { to } | Action::Line { to, .. } => (to, None),
                Action::Arc {
                    to,
                    center,
                    clockwise,
                    ..
                } => (to, Some(arc_extremes(pos, to, center, clockwise))),
                _ => continue,
            };
            let mut points = vec![to];
            if let Some(e) = extra {
                points.extend(e);
            }
            for p in points {
                for (i, axis) in ['X', 'Y', 'Z'].into_iter().enumerate() {
                    let v = p[i];
                    if v < min[i] - 1e-9 || v > max[i] + 1e-9 {
                        return Err(GcodeError::Travel {
                            line: step.line,
                            axis,
                            value: v,
                            min: min[i],
                            max: max[i],
                        });
                    }
                }
            }
            pos = to;
        }
        Ok(())
    }
}

/// The points where an arc from `from` to `to` around `center` crosses the
/// axis directions (its extremes in X and Y), with Z interpolated.
fn arc_extremes(from: [f64; 3], to: [f64; 3], center: [f64; 2], clockwise: bool) -> Vec<[f64; 3]> {
    use std::f64::consts::{FRAC_PI_2, TAU};
    let r = (from[0] - center[0]).hypot(from[1] - center[1]);
    let a0 = (from[1] - center[1]).atan2(from[0] - center[0]);
    let a1 = (to[1] - center[1]).atan2(to[0] - center[0]);
    // The sweep, positive counter-clockwise; equal ends are a full circle.
    let mut sweep = if clockwise { a0 - a1 } else { a1 - a0 };
    sweep = sweep.rem_euclid(TAU);
    if sweep < 1e-12 {
        sweep = TAU;
    }
    let mut out = Vec::new();
    for k in 0..4 {
        let a = f64::from(k) * FRAC_PI_2;
        let along = if clockwise { a0 - a } else { a - a0 }.rem_euclid(TAU);
        if along <= sweep {
            let s = along / sweep;
            out.push([
                center[0] + r * a.cos(),
                center[1] + r * a.sin(),
                from[2] + (to[2] - from[2]) * s,
            ]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn actions(text: &str) -> Vec<Action> {
        read(text)
            .unwrap()
            .steps
            .into_iter()
            .map(|s| s.action)
            .collect()
    }

    #[test]
    fn lines_units_modes_and_feed() {
        let a = actions("G21 G90\nG0 X10 Y5\nG1 X20 F600\nY15\nG91 X-5\nG20 G1 X1 F60\n");
        assert_eq!(
            a[0],
            Action::Rapid {
                to: [10.0, 5.0, 0.0]
            }
        );
        assert_eq!(
            a[1],
            Action::Line {
                to: [20.0, 5.0, 0.0],
                feed: 10.0
            }
        );
        assert_eq!(
            a[2],
            Action::Line {
                to: [20.0, 15.0, 0.0],
                feed: 10.0
            }
        );
        assert_eq!(
            a[3],
            Action::Line {
                to: [15.0, 15.0, 0.0],
                feed: 10.0
            }
        );
        let Action::Line { to, feed } = a[4] else {
            panic!("{:?}", a[4])
        };
        assert!((to[0] - 40.4).abs() < 1e-4, "{to:?}");
        assert!((feed - 25.4).abs() < 1e-9);
    }

    #[test]
    fn g92_offsets_later_moves() {
        let a = actions("G0 X10\nG92 X0\nG0 X5\n");
        assert_eq!(
            a[1],
            Action::Rapid {
                to: [15.0, 0.0, 0.0]
            }
        );
    }

    #[test]
    fn arcs_from_ij_and_r_agree() {
        let ij = actions("G1 F60\nG0 X10 Y0\nG3 X0 Y10 I-10 J0\n");
        let r = actions("G1 F60\nG0 X10 Y0\nG3 X0 Y10 R10\n");
        let (Action::Arc { center: c1, .. }, Action::Arc { center: c2, .. }) = (ij[1], r[1]) else {
            panic!("{ij:?} {r:?}")
        };
        assert!(
            (c1[0] - c2[0]).abs() < 1e-9 && (c1[1] - c2[1]).abs() < 1e-9,
            "{c1:?} {c2:?}"
        );
        assert!(c1[0].abs() < 1e-9 && c1[1].abs() < 1e-9);
    }

    #[test]
    fn bad_blocks_name_their_line() {
        let e = read("G0 X1\n\nG1 X2\n").unwrap_err();
        assert_eq!(e.to_string().split(':').next(), Some("line 3"));
        assert!(e.to_string().contains("give F"), "{e}");
        let e = read("G1 F100\nG2 X10 Y0\n").unwrap_err();
        assert!(e.to_string().starts_with("line 2"), "{e}");
        let e = read("G1 F100\nG2 X10 Y0 I3 J0\n").unwrap_err();
        assert!(e.to_string().contains("fix I, J"), "{e}");
        let e = read("G18\n").unwrap_err();
        assert!(e.to_string().contains("only XY"), "{e}");
        let e = read("X5\n").unwrap_err();
        assert!(e.to_string().contains("motion mode"), "{e}");
    }

    #[test]
    fn unsupported_words_warn_with_their_line() {
        let job = read("G28\n(comment) G0 X1 ; note\nM106 S255\nT2\nG0 X2\n").unwrap();
        let lines: Vec<usize> = job.warnings.iter().map(|w| w.line).collect();
        assert_eq!(lines, vec![1, 3, 4], "{:?}", job.warnings);
        assert_eq!(job.steps.len(), 2);
    }

    #[test]
    fn spindle_dwell_and_end() {
        let a = actions("M3 S12000\nG4 P1.5\nM5\nM30\nG0 X100\n");
        assert_eq!(
            a,
            vec![
                Action::ToolOn {
                    speed: Some(12_000.0)
                },
                Action::Dwell { seconds: 1.5 },
                Action::ToolOff,
                Action::End
            ]
        );
    }

    #[test]
    fn travel_is_checked_over_arcs_before_motion() {
        // A half circle from (10, 0) to (-10, 0) through (0, 10): inside a
        // 20 mm high window only if the top of the arc is.
        let job = read("G0 X10 Y0\nG1 F600\nG3 X-10 Y0 I-10 J0\n").unwrap();
        job.check_travel([-20.0, -20.0, -1.0], [20.0, 20.0, 1.0])
            .unwrap();
        let e = job
            .check_travel([-20.0, -20.0, -1.0], [20.0, 9.0, 1.0])
            .unwrap_err();
        assert!(
            matches!(
                e,
                GcodeError::Travel {
                    line: 3,
                    axis: 'Y',
                    ..
                }
            ),
            "{e}"
        );
        let e = read("G0 X300\n")
            .unwrap()
            .check_travel([0.0; 3], [200.0; 3])
            .unwrap_err();
        assert!(
            e.to_string().starts_with("line 1: X would reach 300.000"),
            "{e}"
        );
    }
}
