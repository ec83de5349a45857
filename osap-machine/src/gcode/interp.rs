//! The interpreter: the modal state a controller keeps, and what each
//! block does to it and to the job.

use super::{
    Action, Dialect, GcodeError, Job, ReadOptions, Step, Warning, ARC_TOLERANCE_MM,
    ARC_TOLERANCE_REL, MM_PER_INCH,
};

/// The modal state between blocks.
pub(super) struct State {
    motion: Option<u32>,
    inches: bool,
    relative: bool,
    dialect: Dialect,
    /// Machine position, mm.
    pos: [f64; 3],
    /// The work zeros G54–G59 select, machine coordinates, mm.
    work_offsets: [Option<[f64; 3]>; 6],
    /// The selected work offset (0 for G54).
    system: usize,
    /// Machine position minus work position (G92), mm.
    offset: [f64; 3],
    /// This block moves in machine coordinates (G53).
    machine_coordinates: bool,
    /// Feed rate, mm/s.
    feed: Option<f64>,
    speed: Option<f64>,
    pub(super) ended: bool,
}

impl State {
    pub(super) fn new(options: &ReadOptions) -> State {
        State {
            motion: None,
            inches: false,
            relative: false,
            dialect: options.dialect,
            pos: [0.0; 3],
            work_offsets: options.work_offsets,
            system: 0,
            offset: [0.0; 3],
            machine_coordinates: false,
            feed: None,
            speed: None,
            ended: false,
        }
    }

    /// What lasts only for the block (G53) ends with it.
    pub(super) fn end_block(&mut self) {
        self.machine_coordinates = false;
    }

    /// The selected work zero, machine coordinates, mm.
    fn work(&self) -> [f64; 3] {
        self.work_offsets[self.system].unwrap_or([0.0; 3])
    }

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
pub(super) struct Word {
    letter: char,
    value: f64,
}

/// A command read from a block: `G`, `M` or `T`, its number, its words.
pub(super) struct Command {
    pub(super) letter: char,
    pub(super) major: u32,
    pub(super) minor: Option<u32>,
    pub(super) words: Vec<Word>,
}

pub(super) fn words<'a>(
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

pub(super) fn error(line: usize, message: impl Into<String>) -> GcodeError {
    GcodeError::Block {
        line,
        message: message.into(),
    }
}

fn find(words: &[Word], letter: char) -> Option<&Word> {
    words.iter().find(|w| w.letter == letter)
}

pub(super) fn run(
    state: &mut State,
    job: &mut Job,
    line: usize,
    code: &Command,
) -> Result<(), GcodeError> {
    let words = &code.words[..];
    let name = format!("{}{}", code.letter, code.major);
    let known = code.minor.is_none();
    match (code.letter, code.major) {
        ('G', n @ 0..=3) if known => {
            state.motion = Some(n);
            motion(state, job, line, n, words)
        }
        ('G', 4) if known => {
            let seconds = dwell(state.dialect, line, words)?;
            job.steps.push(Step {
                line,
                action: Action::Dwell { seconds },
            });
            Ok(())
        }
        ('G', 10) if known && state.dialect == Dialect::Rs274ngc && find(words, 'L').is_some() => {
            Err(error(
                line,
                "G10 L (setting work offsets or tool tables from the program) is not supported: set the work zeros in the machine file's [work_offsets] or with osap run --origin",
            ))
        }
        ('G', 54..=59) if !known => Err(error(
            line,
            format!(
                "{name}.{} selects a work offset this reader does not have: use G54 to G59",
                code.minor.unwrap_or(0)
            ),
        )),
        ('G', 17 | 20 | 21 | 40 | 49 | 53 | 54..=59 | 64 | 80 | 90 | 91 | 94) if known => {
            match code.major {
                20 => state.inches = true,
                21 => state.inches = false,
                53 => state.machine_coordinates = true,
                n @ 54..=59 => {
                    let k = (n - 54) as usize;
                    if k > 0 && state.work_offsets[k].is_none() {
                        return Err(GcodeError::NoWorkOffset {
                            line,
                            code: n as u8,
                        });
                    }
                    state.system = k;
                }
                90 => state.relative = false,
                91 => state.relative = true,
                // G17 (the XY plane), G40 (no cutter compensation), G49
                // (no tool length offset), G64 (blend the path: the
                // planner always does, within its junction deviation and
                // chord tolerance, so any G64 P tolerance holds), G80 (no
                // canned cycle) and G94 (feed per minute) select what this
                // reader always does. Their words (G64 P) are theirs.
                64 => return Ok(()),
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
            let work = state.work();
            for (i, axis) in ['X', 'Y', 'Z'].into_iter().enumerate() {
                if let Some(w) = find(words, axis) {
                    let program = w.value * state.unit();
                    state.offset[i] = state.pos[i] - work[i] - program;
                }
            }
            Ok(())
        }
        ('G', 92) if code.minor == Some(1) => {
            state.offset = [0.0; 3];
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
pub(super) fn continuation(
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

/// Sets the feed rate and spindle speed a block's bare words give.
pub(super) fn feed_and_speed(
    state: &mut State,
    line: usize,
    words: &[Word],
) -> Result<(), GcodeError> {
    if let Some(f) = find(words, 'F') {
        set_feed(state, line, f)?;
    }
    if let Some(s) = find(words, 'S') {
        state.speed = Some(s.value);
    }
    Ok(())
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
    if state.machine_coordinates && (n > 1 || state.relative) {
        return Err(error(
            line,
            "G53 (machine coordinates) moves with G0 or G1 in absolute distances (G90)",
        ));
    }
    // Machine coordinates: the program's plus the work zero plus G92's
    // offset, or as they are with G53.
    let shift = if state.machine_coordinates {
        [0.0; 3]
    } else {
        let work = state.work();
        [0, 1, 2].map(|i| work[i] + state.offset[i])
    };
    let mut to = state.pos;
    let mut any = false;
    for (i, axis) in ['X', 'Y', 'Z'].into_iter().enumerate() {
        if let Some(w) = find(words, axis) {
            let v = w.value * unit;
            to[i] = if state.relative {
                state.pos[i] + v
            } else {
                v + shift[i]
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

/// A G4's dwell, s, read in `dialect`.
fn dwell(dialect: Dialect, line: usize, words: &[Word]) -> Result<f64, GcodeError> {
    let seconds = match dialect {
        Dialect::Rs274ngc => {
            find(words, 'P')
                .ok_or_else(|| error(line, "G4 needs P, the dwell in seconds (rs274ngc)"))?
                .value
        }
        // Marlin: S (seconds) before P (milliseconds); neither waits for
        // the moves before to finish.
        Dialect::Marlin => match (find(words, 'S'), find(words, 'P')) {
            (Some(s), _) => s.value,
            (None, Some(p)) => p.value / 1000.0,
            (None, None) => 0.0,
        },
    };
    if seconds < 0.0 {
        return Err(error(line, "G4's dwell must not be negative"));
    }
    Ok(seconds)
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
