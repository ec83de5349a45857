//! The interpreter: the modal state a controller keeps, and what each
//! block does to it and to the job.

use std::collections::BTreeSet;

use super::{
    Action, Dialect, GcodeError, HeaterRole, Job, ReadOptions, Step, Warning, ARC_TOLERANCE_MM,
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
    /// The tool is on (`M3`, `M4`), and whether its power follows the
    /// speed (`M4`); `None` after `M5`.
    tool_on: Option<bool>,
    /// The extruder's position, mm of filament (machine).
    e: f64,
    /// `E` words are relative (M83, or G91 until an M82).
    e_relative: bool,
    /// Machine e minus program e (`G92 E`), mm.
    e_offset: f64,
    /// The words already warned about (each is said once).
    warned: BTreeSet<String>,
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
            tool_on: None,
            e: 0.0,
            e_relative: false,
            e_offset: 0.0,
            warned: BTreeSet::new(),
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

impl Word {
    pub(super) fn new(letter: char, value: f64) -> Word {
        Word { letter, value }
    }
}

/// The decimal a parsed `f32` was written as, as `f64`: `0.1` is 0.1, not
/// 0.100000001 (the shortest text that reads back as the same `f32` is
/// what the program said, to the f32's 7 digits).
fn as_written(x: f32) -> f64 {
    x.to_string().parse().unwrap_or(f64::from(x))
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
                value: as_written(*x),
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

/// Warns about `key` the first time it is met, naming the line.
fn warn_once(state: &mut State, job: &mut Job, line: usize, key: &str, message: String) {
    if state.warned.insert(key.to_string()) {
        job.warnings.push(Warning { line, message });
    }
}

fn push(job: &mut Job, line: usize, action: Action) {
    job.steps.push(Step { line, action });
}

/// `M104 S`/`M109 S|R`, `M140`/`M190`: a heater's target.
fn heater(
    state: &mut State,
    job: &mut Job,
    line: usize,
    heater: HeaterRole,
    wait: bool,
    words: &[Word],
) -> Result<(), GcodeError> {
    if let Some(t) = find(words, 'T') {
        if t.value != 0.0 {
            return Err(error(
                line,
                format!(
                    "T{} selects a second extruder; this machine has one",
                    t.value
                ),
            ));
        }
    }
    let Some(target) = find(words, 'S').or_else(|| find(words, 'R')) else {
        if wait {
            return Err(error(line, "a wait for a temperature needs S (°C)"));
        }
        warn_once(
            state,
            job,
            line,
            "M104 without S",
            "a temperature code without S sets nothing; skipped".into(),
        );
        return Ok(());
    };
    if !(0.0..=500.0).contains(&target.value) {
        return Err(error(
            line,
            format!(
                "{} °C is not a temperature a heater is set to",
                target.value
            ),
        ));
    }
    push(
        job,
        line,
        Action::Heater {
            heater,
            celsius: target.value,
            wait,
        },
    );
    Ok(())
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
        ('G', 10 | 11) if known && state.dialect == Dialect::Marlin && find(words, 'L').is_none() => {
            push(
                job,
                line,
                Action::Retract {
                    retract: code.major == 10,
                },
            );
            Ok(())
        }
        ('G', 28) if known => {
            let axes = ['X', 'Y', 'Z'].map(|a| find(words, a).is_some());
            push(job, line, Action::Home { axes });
            Ok(())
        }
        ('G', 29) if known => {
            push(job, line, Action::BedMesh);
            Ok(())
        }
        // One extruder: selecting it is nothing to do.
        ('T', 0) if known => Ok(()),
        ('M', 82) if known => {
            state.e_relative = false;
            Ok(())
        }
        ('M', 83) if known => {
            state.e_relative = true;
            Ok(())
        }
        ('M', 104) if known => heater(state, job, line, HeaterRole::Hotend, false, words),
        ('M', 109) if known => heater(state, job, line, HeaterRole::Hotend, true, words),
        ('M', 140) if known => heater(state, job, line, HeaterRole::Bed, false, words),
        ('M', 190) if known => heater(state, job, line, HeaterRole::Bed, true, words),
        ('M', 106 | 107) if known => {
            if find(words, 'P').is_some_and(|p| p.value != 0.0) {
                warn_once(state, job, line, "M106 P", "a fan other than the part fan (M106 P1..) is not supported; skipped".into());
                return Ok(());
            }
            let duty = if code.major == 107 {
                0.0
            } else {
                (find(words, 'S').map_or(255.0, |s| s.value) / 255.0).clamp(0.0, 1.0)
            };
            push(job, line, Action::Fan { duty });
            Ok(())
        }
        ('M', 18 | 84) if known => {
            if find(words, 'S').is_some() || words.iter().any(|w| "XYZE".contains(w.letter)) {
                warn_once(state, job, line, "M84 S", format!("{name} with words (an idle timeout, some motors) is not supported; skipped"));
            } else {
                push(job, line, Action::MotorsOff);
            }
            Ok(())
        }
        ('M', 201 | 203 | 204) if known => {
            // The smallest toolhead figure the words give; e's (E) are
            // the machine file's alone.
            let pick = |letters: &str| {
                words
                    .iter()
                    .filter(|w| letters.contains(w.letter))
                    .map(|w| w.value)
                    .fold(None, |m: Option<f64>, v| Some(m.map_or(v, |m| m.min(v))))
            };
            let (velocity, acceleration, text) = match code.major {
                201 => (None, pick("XY"), "M201"),
                203 => (pick("XY"), None, "M203"),
                _ => (None, pick("PS"), "M204"),
            };
            if velocity.is_some() || acceleration.is_some() {
                push(
                    job,
                    line,
                    Action::Limits {
                        velocity,
                        acceleration,
                        text,
                    },
                );
            }
            Ok(())
        }
        ('M', 205) if known => {
            warn_once(state, job, line, "M205", "M205 (jerk, junction deviation) is kept at the machine file's [limits]; skipped".into());
            Ok(())
        }
        ('M', 73) if known => {
            if let Some(p) = find(words, 'P') {
                push(job, line, Action::Progress { percent: p.value });
            }
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
                90 => {
                    state.relative = false;
                    state.e_relative = false;
                }
                91 => {
                    state.relative = true;
                    state.e_relative = true;
                }
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
            if let Some(e) = find(words, 'E') {
                state.e_offset = state.e - e.value * state.unit();
            }
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
            state.e_offset = 0.0;
            Ok(())
        }
        ('M', 3 | 4) if known => {
            if let Some(s) = find(words, 'S') {
                state.speed = Some(s.value);
            }
            let dynamic = code.major == 4;
            state.tool_on = Some(dynamic);
            job.steps.push(Step {
                line,
                action: Action::ToolOn {
                    speed: state.speed,
                    dynamic,
                },
            });
            Ok(())
        }
        ('M', 5) if known => {
            state.tool_on = None;
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
            let message = format!("{full} is not supported; skipped (said once)");
            warn_once(state, job, line, &full, message);
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
    let moves = words.iter().any(|w| "XYZIJRE".contains(w.letter));
    for w in words {
        match w.letter {
            'F' | 'X' | 'Y' | 'Z' | 'I' | 'J' | 'R' | 'E' => {}
            'S' => set_speed(state, job, line, w.value),
            other => {
                let message = format!("{other}{} is not supported; skipped (said once)", w.value);
                warn_once(state, job, line, &other.to_string(), message);
            }
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
    job: &mut Job,
    line: usize,
    words: &[Word],
) -> Result<(), GcodeError> {
    if let Some(f) = find(words, 'F') {
        set_feed(state, line, f)?;
    }
    if let Some(s) = find(words, 'S') {
        set_speed(state, job, line, s.value);
    }
    Ok(())
}

/// A new `S`: with the tool on, the tool takes it from here (a laser's
/// power changing between two moves of a cut, as LightBurn writes `G1 X..
/// S..`), as Grbl applies an `S` word at once.
fn set_speed(state: &mut State, job: &mut Job, line: usize, value: f64) {
    let changed = state.speed != Some(value);
    state.speed = Some(value);
    if let (true, Some(dynamic)) = (changed, state.tool_on) {
        job.steps.push(Step {
            line,
            action: Action::ToolOn {
                speed: state.speed,
                dynamic,
            },
        });
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
    // A laser's power on the move's own line applies to the move.
    if let Some(s) = find(words, 'S') {
        set_speed(state, job, line, s.value);
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
    if let Some(w) = find(words, 'E') {
        if n >= 2 {
            return Err(error(
                line,
                "an arc with E (a slicer's arc fitting) is not supported: turn arc fitting off",
            ));
        }
        let v = w.value * unit;
        let e = if state.e_relative {
            state.e + v
        } else {
            v + state.e_offset
        };
        let feed = feed(state, line, if n == 0 { "G0 with E" } else { "G1" })?;
        let action = Action::Extrude { to, e, feed };
        state.pos = to;
        state.e = e;
        job.steps.push(Step { line, action });
        return Ok(());
    }
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
