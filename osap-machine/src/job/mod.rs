//! Jobs: a G-code program or an SVG drawing turned into a machine
//! [`Program`] (moves in the machine's axes, tool changes, dwells), checked
//! against the travel before any motion, and run on a [`Machine`].

use std::time::Duration;

use maxl::blocks::planner::{Arc as PlanArc, Planner, VectorLimits};

use crate::config::Dialect;
use crate::config::{MachineFile, ToolKind};
use crate::machine::tool_track::ToolCommand;
use crate::machine::{Machine, MachineError, MAX_AXES};
use crate::svg::Drawing;

mod flow;
mod gcode;

pub use flow::{HotendChoice, HotendTemperature, SlowedMove};
pub use gcode::{from_gcode, from_gcode_with, gcode_options};

/// One thing a program does.
#[derive(Debug, Clone, PartialEq)]
pub enum Move {
    /// A straight move at the machine's fastest (a rapid, or pen-up travel).
    Rapid(Vec<f64>),
    /// A straight move at a feed (units/s).
    Line(Vec<f64>, f64),
    /// An arc in the xy plane around `center`, at a feed.
    Arc {
        /// Where to (axis order).
        to: Vec<f64>,
        /// The centre (x, y).
        center: [f64; 2],
        /// Clockwise seen from +z.
        clockwise: bool,
        /// Units/s.
        feed: f64,
    },
    /// Wait for the moves before to finish, then this long (s).
    Dwell(f64),
    /// The job's tool on at a level (0..=1) or a speed (rpm, for a
    /// spindle with `max_rpm`), or off (`None`).
    Tool(Option<ToolLevel>),
    /// A heater's target, °C (0 off); with `wait`, the moves before
    /// finish and the machine waits until the heater holds it.
    Heater {
        /// The heater's name in `[heaters]`.
        name: String,
        /// The target, °C.
        celsius: f64,
        /// Wait for it (M109, M190).
        wait: bool,
    },
    /// The machine's fan at a duty, 0–1 (M106, M107).
    Fan(f64),
    /// Home these axes (all for none), after the moves before.
    Home(Vec<String>),
    /// The motors off, after the moves before (M84).
    MotorsOff,
    /// The toolhead's speed and acceleration asked by the job, held to
    /// the machine file's.
    Limits {
        /// mm/s.
        velocity: Option<f64>,
        /// mm/s².
        acceleration: Option<f64>,
        /// The G-code that asked (`M204`).
        code: &'static str,
    },
    /// Progress the job reports, % (M73).
    Progress(f64),
    /// A new layer begins (a slicer's layer comment), from 1.
    Layer(usize),
}

/// How far a tool is turned on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ToolLevel {
    /// Full on.
    Full,
    /// A speed from the job (rpm for a spindle with `max_rpm`, power for a
    /// laser: of its `s_max`).
    Speed(f64),
    /// `M4`: a laser's power at `S` (of its `s_max`; full without one),
    /// following its speed along the path (`power × speed / feed`).
    Dynamic(Option<f64>),
}

/// A job, ready to run: moves with where they came from.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Program {
    /// Each move, with its source line (G-code) or path number (SVG), from 1.
    pub moves: Vec<(usize, Move)>,
    /// What the readers skipped or changed, for the user.
    pub warnings: Vec<String>,
    /// The dialect a G-code job was read in (`None` for a drawing).
    pub dialect: Option<Dialect>,
    /// The extruder's slot among the machine's axes, if it has one.
    pub e_slot: Option<usize>,
    /// Where the extruder stood when the program starts, mm.
    pub e_start: f64,
    /// The extruding moves the flow limit slowed, in order.
    pub slowed: Vec<SlowedMove>,
    /// The hotend's temperature when `--temperature` replaced the job's.
    pub hotend: Option<HotendChoice>,
}

/// Why a job cannot run on a machine.
#[derive(Debug, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum JobError {
    /// A move leaves the machine's travel (found before any motion).
    #[error("{place}: axis {axis} would go to {value:.3}, outside its travel [{min}, {max}]")]
    OutOfTravel {
        /// `line N` or `path N`.
        place: String,
        /// The axis.
        axis: String,
        /// The coordinate.
        value: f64,
        /// Travel, low end.
        min: f64,
        /// Travel, high end.
        max: f64,
    },
    /// The job moves an axis the machine does not have.
    #[error("{place}: the job moves {axis}, but the machine has no axis {axis}")]
    NoSuchAxis {
        /// `line N`.
        place: String,
        /// The axis.
        axis: String,
    },
    /// An arc the planner cannot draw.
    #[error("{place}: {reason}")]
    BadArc {
        /// `line N`.
        place: String,
        /// Why.
        reason: String,
    },
    /// A drawing needs x and y.
    #[error("a drawing needs axes x and y; this machine has {0}")]
    NotPlanar(String),
    /// The job sets a heater the machine does not have.
    #[error(
        "{place}: the job sets heater {heater}, but the machine file has no [heaters.{heater}]"
    )]
    NoSuchHeater {
        /// `line N`.
        place: String,
        /// The heater's name.
        heater: String,
    },
    /// A feed rate that is not finite and positive.
    #[error("feed {0} must be finite and positive")]
    BadFeed(f64),
    /// The hotend temperature asked cannot be set.
    #[error("{0}")]
    Temperature(String),
}

fn check(cfg: &MachineFile, p: &[f64], place: &str) -> Result<(), JobError> {
    for (name, v) in cfg.axis_names().iter().zip(p) {
        let a = &cfg.axes[*name];
        // A hair of tolerance for arcs chorded to the edge.
        if !(v.is_finite() && *v >= a.min - 1e-9 && *v <= a.max + 1e-9) {
            return Err(JobError::OutOfTravel {
                place: place.into(),
                axis: name.to_string(),
                value: *v,
                min: a.min,
                max: a.max,
            });
        }
    }
    Ok(())
}

fn pad(p: &[f64]) -> [f64; MAX_AXES] {
    let mut out = [0.0; MAX_AXES];
    for (o, v) in out.iter_mut().zip(p) {
        *o = *v;
    }
    out
}

/// An SVG drawing as a program: for each polyline, tool off, travel to its
/// start, tool on, draw at `feed`; tool off at the end. Checked against the
/// travel.
pub fn from_svg(cfg: &MachineFile, drawing: &Drawing, feed: f64) -> Result<Program, JobError> {
    if !(feed.is_finite() && feed > 0.0) {
        return Err(JobError::BadFeed(feed));
    }
    let names = cfg.axis_names();
    if names.len() < 2 || names[0] != "x" || names[1] != "y" {
        return Err(JobError::NotPlanar(names.join(", ")));
    }
    let n = names.len();
    // Axes beyond x and y stay where homing or the start left them: 0 if
    // within travel, else their min.
    let rest: Vec<f64> = crate::machine::drive::start_position(cfg);
    let mut moves = Vec::new();
    let mut warnings = drawing.warnings.clone();
    let has_tool = cfg
        .tools
        .values()
        .any(|t| matches!(t.kind, ToolKind::Pen | ToolKind::Laser));
    if !has_tool {
        warnings.push(
            "the machine has no pen or laser tool: the drawing runs with no tool switching".into(),
        );
    }
    // A point this close outside the travel is on its edge: the drawing's
    // f32 rounding (a frame at the page's edge on a page the size of the
    // travel), far below a motor step.
    let onto = |v: f64, axis: &str| {
        let a = &cfg.axes[axis];
        if v < a.min && v >= a.min - drawing.precision_mm {
            a.min
        } else if v > a.max && v <= a.max + drawing.precision_mm {
            a.max
        } else {
            v
        }
    };
    for (i, poly) in drawing.polylines.iter().enumerate() {
        let place = format!("path {}", i + 1);
        let mut pts = poly.iter().map(|p| {
            let mut v = rest.clone();
            v[0] = onto(p[0], "x");
            v[1] = onto(p[1], "y");
            v.truncate(n);
            v
        });
        let Some(first) = pts.next() else { continue };
        check(cfg, &first, &place)?;
        if has_tool {
            moves.push((i + 1, Move::Tool(None)));
        }
        moves.push((i + 1, Move::Rapid(first)));
        if has_tool {
            moves.push((i + 1, Move::Tool(Some(ToolLevel::Full))));
        }
        for p in pts {
            check(cfg, &p, &place)?;
            moves.push((i + 1, Move::Line(p, feed)));
        }
    }
    if has_tool {
        moves.push((drawing.polylines.len(), Move::Tool(None)));
    }
    Ok(Program {
        moves,
        warnings,
        ..Program::default()
    })
}

/// What a stop at rest costs besides its wait: the machine waits for the
/// motors to finish (two intervals past the last point), and the next move
/// starts a timer lead after it is queued.
const RESTART_S: f64 =
    (crate::machine::LEAD_US as f64 + 2.0 * crate::machine::INTERVAL_US as f64) * 1e-6;

/// How far a program has come.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Progress {
    /// Moves handed to the machine.
    pub done: usize,
    /// Moves in the program.
    pub total: usize,
    /// Source line or path of the newest move.
    pub line: usize,
}

impl Program {
    /// The filament the job extrudes, net of retractions, mm of e: the
    /// extruder's last position less its first.
    pub fn extruded_mm(&self) -> f64 {
        let Some(k) = self.e_slot else {
            return 0.0;
        };
        let last = self.moves.iter().rev().find_map(|(_, m)| match m {
            Move::Line(p, _) | Move::Rapid(p) | Move::Arc { to: p, .. } => Some(p[k]),
            _ => None,
        });
        last.map_or(0.0, |e| e - self.e_start)
    }

    /// This program with its extruder positions shifted to start at `e`
    /// (where the extruder stands), so a job read for one start runs from
    /// another without pulling the filament back.
    pub fn with_e_start(&self, e: f64) -> Program {
        let mut p = self.clone();
        let Some(k) = self.e_slot else {
            return p;
        };
        let shift = e - self.e_start;
        for (_, m) in &mut p.moves {
            if let Move::Line(to, _) | Move::Rapid(to) | Move::Arc { to, .. } = m {
                if let Some(v) = to.get_mut(k) {
                    *v += shift;
                }
            }
        }
        p.e_start = e;
        p
    }

    /// How long the moves take as planned, s: motion, dwells, tool settle
    /// times, and the restart after each stop at rest (a timer lead plus
    /// two intervals). A streamed laser's switches cost nothing: they ride
    /// on the motion.
    pub fn planned_seconds(&self, cfg: &MachineFile, start: &[f64]) -> Result<f64, MachineError> {
        let mut planner = machine_planner(cfg)?;
        planner.set_position(pad(start))?;
        let mut total = 0.0;
        let rapid = cfg.limits.velocity;
        let tool = job_tool(cfg);
        let mut level = 0.0;
        // A clock for the planner (µs): segments start when first sampled,
        // so sample at `now` to start what is queued, then at its end.
        let mut now: u64 = 1;
        let mut run_to =
            |planner: &mut Planner<MAX_AXES>, last: bool| -> Result<f64, MachineError> {
                if planner.is_idle() {
                    return Ok(0.0);
                }
                planner.sample(now)?;
                let plan = planner.plan();
                let seg = if last {
                    plan.segments.last()
                } else {
                    plan.segments.first()
                };
                let end = seg.map_or(now, |s| s.end_us().ceil() as u64 + 1).max(now);
                let took = (end - now) as f64 * 1e-6;
                now = end;
                planner.sample(now)?;
                Ok(took)
            };
        for (_, m) in &self.moves {
            match m {
                Move::Rapid(p) => {
                    planner.line(pad(p), rapid)?;
                }
                Move::Line(p, f) => {
                    planner.line(pad(p), *f)?;
                }
                Move::Arc {
                    to,
                    center,
                    clockwise,
                    feed,
                } => {
                    let arc = PlanArc {
                        end: pad(to),
                        plane: (0, 1),
                        center: *center,
                        clockwise: *clockwise,
                        chord_tolerance: 0.002,
                    };
                    planner.arc(&arc, *feed)?;
                }
                Move::Dwell(s) => {
                    total += run_to(&mut planner, true)? + s.max(0.0) + RESTART_S;
                }
                Move::Tool(l) => {
                    let Some((_, t)) = tool else { continue };
                    let want = tool_level(t, *l);
                    // A streamed tool switches where the path comes to
                    // rest, or on the move: no stop, only a pen's settle
                    // held where the path ends.
                    if t.streamed() {
                        if (want - level).abs() > 1e-9 {
                            level = want;
                            if t.settle_ms > 0 {
                                total +=
                                    run_to(&mut planner, true)? + f64::from(t.settle_ms) * 1e-3;
                            }
                        }
                        continue;
                    }
                    if (want - level).abs() > 1e-9 {
                        level = want;
                        total +=
                            run_to(&mut planner, true)? + f64::from(t.settle_ms) * 1e-3 + RESTART_S;
                    }
                }
                // Heating and homing take what the machine takes: only
                // the stop before them is planned.
                Move::Heater { wait: true, .. } | Move::Home(_) | Move::MotorsOff => {
                    total += run_to(&mut planner, true)? + RESTART_S;
                }
                Move::Limits {
                    velocity,
                    acceleration,
                    ..
                } => {
                    let now = planner.vector_limits();
                    let v = held_limits(
                        cfg,
                        (now.max_speed, now.max_accel),
                        *velocity,
                        *acceleration,
                    );
                    planner.set_vector_limits(VectorLimits {
                        max_speed: v.0,
                        max_accel: v.1,
                        ..*planner.vector_limits()
                    })?;
                }
                Move::Heater { .. } | Move::Fan(_) | Move::Progress(_) | Move::Layer(_) => {}
            }
            if planner.stats().pending >= maxl::blocks::planner::DEFAULT_CAPACITY - 2 {
                // Keep the queue within capacity: run its first segment.
                total += run_to(&mut planner, false)?;
            }
        }
        total += run_to(&mut planner, true)?;
        Ok(total)
    }
}

/// The tool a job switches: the machine's first pen or laser, else its
/// first spindle.
fn job_tool(cfg: &MachineFile) -> Option<(&str, &crate::config::Tool)> {
    let of = |kinds: &[ToolKind]| {
        cfg.tools
            .iter()
            .find(|(_, t)| kinds.contains(&t.kind))
            .map(|(n, t)| (n.as_str(), t))
    };
    of(&[ToolKind::Pen, ToolKind::Laser]).or_else(|| of(&[ToolKind::Spindle]))
}

/// The level (0..=1) a job's tool command asks of `tool`: a speed is
/// scaled by `max_rpm` when the tool has one, a laser's power by its
/// `s_max`.
fn tool_level(tool: &crate::config::Tool, level: Option<ToolLevel>) -> f64 {
    let power = |s: f64| {
        let max = tool.s_max.unwrap_or(crate::config::DEFAULT_S_MAX);
        (s / max).clamp(0.0, 1.0)
    };
    match level {
        None => 0.0,
        Some(ToolLevel::Full | ToolLevel::Dynamic(None)) => 1.0,
        Some(ToolLevel::Speed(s) | ToolLevel::Dynamic(Some(s))) if tool.kind == ToolKind::Laser => {
            power(s)
        }
        Some(ToolLevel::Speed(s) | ToolLevel::Dynamic(Some(s))) => match tool.max_rpm {
            Some(max) if max > 0.0 => (s / max).clamp(0.0, 1.0),
            _ => 1.0,
        },
    }
}

/// Whether a job's tool command asks `tool`'s power to follow its speed:
/// `M4`, or any on command for a laser with `dynamic = true`.
fn tool_dynamic(tool: &crate::config::Tool, level: Option<ToolLevel>) -> bool {
    match level {
        None => false,
        Some(ToolLevel::Dynamic(_)) => true,
        Some(_) => tool.dynamic,
    }
}

pub use crate::machine::motion::machine_planner;

/// A job's toolhead speed and acceleration held to the machine file's; a
/// figure the job did not give keeps its value `now` (an `M203` leaves
/// the acceleration, and an `M204` the speed, as they were).
pub fn held_limits(
    cfg: &MachineFile,
    now: (f64, f64),
    velocity: Option<f64>,
    acceleration: Option<f64>,
) -> (f64, f64) {
    let hold = |asked: Option<f64>, now: f64, file: f64| {
        asked.filter(|v| *v > 0.0).map_or(now, |v| v.min(file))
    };
    (
        hold(velocity, now.0, cfg.limits.velocity),
        hold(acceleration, now.1, cfg.limits.vector_acceleration()),
    )
}

/// What a run measured.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RunStats {
    /// Time spent waiting for heaters to reach their targets, s.
    pub heater_wait_s: f64,
}

impl Machine {
    /// Runs `program`: queues its moves with lookahead, switches the tool
    /// at rest (waiting for it to settle), and waits until the last move
    /// has run. `progress` is told of every move handed over.
    pub async fn run_program(
        &self,
        program: &Program,
        mut progress: impl FnMut(Progress),
    ) -> Result<RunStats, MachineError> {
        // The job's extrusion continues from where the extruder stands,
        // not from where the program was read for.
        let rebased;
        let program = match program.e_slot.map(|k| self.position()[k]) {
            Some(e) if (e - program.e_start).abs() > 1e-9 => {
                rebased = program.with_e_start(e);
                &rebased
            }
            _ => program,
        };
        let mut stats = RunStats::default();
        let in_order = InOrder::start(self);
        let rapid = self.config().limits.velocity;
        let tool = job_tool(self.config()).map(|(name, _)| name.to_string());
        // A streamed laser or pen: its level and whether its power follows
        // the speed, as the job's last tool command left them.
        let mut laser = tool
            .as_deref()
            .filter(|n| self.config().tools[*n].streamed())
            .map(|n| Streamed {
                name: n.to_string(),
                level: 0.0,
                dynamic: false,
            });
        let total = program.moves.len();
        for (i, (line, m)) in program.moves.iter().enumerate() {
            match m {
                Move::Rapid(p) => {
                    // Rapids are travel: a laser is off along them.
                    if laser.is_some() {
                        self.tool_command(ToolCommand::OFF);
                    }
                    self.goto_via_queue(p, rapid).await?
                }
                Move::Line(p, f) => {
                    if let Some(l) = &laser {
                        self.tool_command(l.on_move(*f));
                    }
                    self.goto_via_queue(p, *f).await?
                }
                Move::Arc {
                    to,
                    center,
                    clockwise,
                    feed,
                } => {
                    if let Some(l) = &laser {
                        self.tool_command(l.on_move(*feed));
                    }
                    self.arc(to, *center, *clockwise, *feed).await?
                }
                Move::Dwell(s) => self.dwell(*s).await?,
                Move::Tool(level) if laser.is_some() => {
                    let Some(l) = &mut laser else { continue };
                    let t = &self.config().tools[&l.name];
                    let was = l.level;
                    l.level = tool_level(t, *level);
                    l.dynamic = tool_dynamic(t, *level);
                    // Standing still (a dwell next, or the job's end) the
                    // tool takes it at once; a move that follows carries
                    // its own command from the same place.
                    self.tool_command(l.on_move(0.0));
                    self.note_tool_level(&l.name, l.level);
                    // A pen settles where the path comes to rest.
                    if t.settle_ms > 0 && (l.level - was).abs() > 1e-9 {
                        self.hold_path(f64::from(t.settle_ms) * 1e-3).await?;
                    }
                }
                Move::Tool(level) => {
                    let Some(name) = &tool else { continue };
                    let t = self.tool(name)?;
                    let want = tool_level(&self.config().tools[name], *level);
                    if (t.level() - want).abs() > 1e-9 {
                        self.idle().await?;
                        t.set(want).await?;
                        t.await_ready().await?;
                    }
                }
                Move::Heater {
                    name,
                    celsius,
                    wait: true,
                } => {
                    let h = self.heater(name)?;
                    // Nothing extrudes before the heater is there.
                    self.idle().await?;
                    in_order.flush().await?;
                    h.set_target(*celsius).await?;
                    stats.heater_wait_s += h.wait_for_target().await?.as_secs_f64();
                }
                // Set once the moves before have run, without stopping
                // them (the queue runs far ahead of the motion).
                Move::Heater { .. } | Move::Fan(_) => {
                    self.heater_or_fan(m)?;
                    in_order.send(self.queued_total(), m.clone())?;
                }
                Move::Home(axes) => {
                    self.idle().await?;
                    if axes.is_empty() {
                        self.home().await?;
                    } else {
                        let axes: Vec<&str> = axes.iter().map(String::as_str).collect();
                        self.home_axes(&axes).await?;
                    }
                }
                Move::MotorsOff => {
                    self.idle().await?;
                    self.motors_off().await?;
                }
                Move::Limits {
                    velocity,
                    acceleration,
                    ..
                } => {
                    let (v, a) = held_limits(
                        self.config(),
                        self.toolhead_limits(),
                        *velocity,
                        *acceleration,
                    );
                    self.set_toolhead_limits(v, a)?;
                }
                Move::Progress(_) | Move::Layer(_) => {}
            }
            progress(Progress {
                done: i + 1,
                total,
                line: *line,
            });
        }
        self.idle().await?;
        in_order.flush().await?;
        // Let the last step reports arrive.
        tokio::time::sleep(Duration::from_millis(20)).await;
        Ok(stats)
    }

    /// Checks a heater or fan command can be carried out.
    fn heater_or_fan(&self, m: &Move) -> Result<(), MachineError> {
        if let Move::Heater { name, .. } = m {
            self.heater(name)?;
        }
        Ok(())
    }
}

/// A streamed laser or pen as a job's tool commands leave it.
struct Streamed {
    /// Its key in `[tools]`.
    name: String,
    /// Its level, 0..=1.
    level: f64,
    /// Its power follows the speed.
    dynamic: bool,
}

impl Streamed {
    /// What it does along a move at `feed` (units/s; 0 at rest).
    fn on_move(&self, feed: f64) -> ToolCommand {
        if self.level <= 0.0 {
            return ToolCommand::OFF;
        }
        ToolCommand {
            level: self.level,
            dynamic: self.dynamic,
            // Only dynamic power depends on the feed.
            feed: if self.dynamic { feed } else { 0.0 },
        }
    }
}

/// Heater targets and fan speeds a job sets between moves, applied in
/// order, each once the motors have finished the moves queued before it.
struct InOrder {
    machine: Machine,
    tx: tokio::sync::mpsc::UnboundedSender<Deferred>,
    task: tokio::task::JoinHandle<Result<(), MachineError>>,
}

enum Deferred {
    /// Apply the move once `mark` segments have run.
    At(u64, Move),
    /// Tell when everything before has been applied.
    Flush(tokio::sync::oneshot::Sender<()>),
}

impl InOrder {
    fn start(machine: &Machine) -> InOrder {
        let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
        let owner = machine.clone();
        let machine = machine.clone();
        let fan = machine.tool_of_kind(ToolKind::Fan);
        let task = tokio::spawn(async move {
            while let Some(d) = rx.recv().await {
                match d {
                    Deferred::Flush(done) => {
                        let _ = done.send(());
                    }
                    Deferred::At(mark, m) => {
                        machine.wait_executed(mark).await?;
                        match m {
                            Move::Heater { name, celsius, .. } => {
                                machine.heater(&name)?.set_target(celsius).await?
                            }
                            Move::Fan(duty) => {
                                if let Some(f) = &fan {
                                    f.set(duty.clamp(0.0, 1.0)).await?;
                                }
                            }
                            _ => {}
                        }
                    }
                }
            }
            Ok(())
        });
        InOrder {
            machine: owner,
            tx,
            task,
        }
    }

    fn send(&self, mark: u64, m: Move) -> Result<(), MachineError> {
        self.tx
            .send(Deferred::At(mark, m))
            .map_err(|_| MachineError::Stopped)
    }

    /// Waits until every command sent has been applied; the first error
    /// applying one is returned.
    async fn flush(&self) -> Result<(), MachineError> {
        let (done, wait) = tokio::sync::oneshot::channel();
        if self.tx.send(Deferred::Flush(done)).is_ok() && wait.await.is_ok() {
            return Ok(());
        }
        // The task ended on an error: a fault names itself; anything else
        // (a refused target) was checked before it was sent.
        self.machine.check_running()?;
        Err(MachineError::Stopped)
    }
}

impl Drop for InOrder {
    fn drop(&mut self) {
        self.task.abort();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg(name: &str) -> MachineFile {
        MachineFile::load(format!(
            "{}/../examples/machines/{name}.toml",
            env!("CARGO_MANIFEST_DIR")
        ))
        .unwrap()
    }

    #[test]
    fn gcode_outside_travel_is_refused_with_its_line() {
        let mill = cfg("mill");
        let job = crate::gcode::read("G21 G90\nG1 X10 Y10 F600\nG1 X400\n").unwrap();
        let e = from_gcode(&mill, &job, &[0.0; 3]).unwrap_err();
        assert!(
            matches!(&e, JobError::OutOfTravel { place, axis, .. } if place == "line 3" && axis == "x"),
            "{e}"
        );
    }

    #[test]
    fn gcode_arc_bulging_out_of_travel_is_refused() {
        let mill = cfg("mill");
        // A half circle from (10, 5) to (10, 45) around (10, 25):
        // counter-clockwise it bulges to x = 30, clockwise to x = -10
        // (outside).
        let ok = crate::gcode::read("G0 X10 Y5\nG3 X10 Y45 I0 J20 F300\n").unwrap();
        assert!(from_gcode(&mill, &ok, &[0.0; 3]).is_ok());
        let bad = crate::gcode::read("G0 X10 Y5\nG2 X10 Y45 I0 J20 F300\n").unwrap();
        let e = from_gcode(&mill, &bad, &[0.0; 3]).unwrap_err();
        assert!(
            matches!(&e, JobError::OutOfTravel { place, .. } if place == "line 2"),
            "{e}"
        );
    }

    #[test]
    fn a_cam_file_above_its_work_is_placed_by_its_origin() {
        // LinuxCNC-style: z = +1 in is the clearance above the work, above
        // the mill's travel (z up to 0) until the work zero is placed.
        let mill = cfg("mill");
        let text = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../examples/jobs/slot.ngc"
        ))
        .unwrap();
        let read = |origin| crate::gcode::read_with(&text, &gcode_options(&mill, origin)).unwrap();
        let e = from_gcode(&mill, &read(None), &[0.0; 3]).unwrap_err();
        assert!(
            matches!(&e, JobError::OutOfTravel { place, axis, value, .. }
                if place == "line 12" && axis == "z" && (value - 25.4).abs() < 1e-9),
            "{e}"
        );
        let p = from_gcode(&mill, &read(Some([20.0, 20.0, -60.0])), &[0.0; 3]).unwrap();
        assert_eq!(p.dialect, Some(Dialect::Rs274ngc));
        let lowest = p
            .moves
            .iter()
            .filter_map(|(_, m)| match m {
                Move::Line(to, _) | Move::Rapid(to) | Move::Arc { to, .. } => Some(to[2]),
                _ => None,
            })
            .fold(f64::INFINITY, f64::min);
        assert!((lowest - (-60.0 - 0.05 * 25.4)).abs() < 1e-6, "{lowest}");
        // The same work zero from the machine file's [work_offsets].
        let mut placed = mill.clone();
        placed.work_offsets.g54 = Some([20.0, 20.0, -60.0]);
        let job = crate::gcode::read_with(&text, &gcode_options(&placed, None)).unwrap();
        assert_eq!(from_gcode(&placed, &job, &[0.0; 3]).unwrap().moves, p.moves);
        // --origin wins over the file's G54.
        placed.work_offsets.g54 = Some([0.0, 0.0, 0.0]);
        let o = gcode_options(&placed, Some([20.0, 20.0, -60.0]));
        assert_eq!(o.work_offsets[0], Some([20.0, 20.0, -60.0]));
    }

    #[test]
    fn gcode_z_on_a_plotter_is_refused() {
        let plotter = cfg("plotter");
        let job = crate::gcode::read("G1 X10 Y10 Z-1 F600\n").unwrap();
        let e = from_gcode(&plotter, &job, &[0.0; 2]).unwrap_err();
        assert!(matches!(e, JobError::NoSuchAxis { .. }), "{e}");
    }

    #[test]
    fn svg_framed_at_the_page_edge_fits_a_travel_of_the_page_size() {
        // The plotter's travel is 200 × 150 mm; usvg's f32 puts the
        // frame's top at 150.0000011.
        let plotter = cfg("plotter");
        let svg = r#"<svg xmlns="http://www.w3.org/2000/svg" width="200mm" height="150mm" viewBox="0 0 200 150"><path d="M0 0 H200 V150 H0 Z" stroke="black" fill="none"/></svg>"#;
        let d = crate::svg::read(svg, &Default::default()).unwrap();
        assert!(
            d.precision_mm > 0.0 && d.precision_mm < 1e-3,
            "{}",
            d.precision_mm
        );
        let p = from_svg(&plotter, &d, 50.0).unwrap();
        let mut corners: Vec<[f64; 2]> = p
            .moves
            .iter()
            .filter_map(|(_, m)| match m {
                Move::Rapid(v) | Move::Line(v, _) => Some([v[0], v[1]]),
                _ => None,
            })
            .collect();
        corners.sort_by(|a, b| a.partial_cmp(b).unwrap());
        corners.dedup();
        assert_eq!(
            corners,
            [[0.0, 0.0], [0.0, 150.0], [200.0, 0.0], [200.0, 150.0]]
        );
        // One micrometre out is out.
        let bigger = svg.replace("H200", "H200.001");
        let d = crate::svg::read(&bigger, &Default::default()).unwrap();
        let e = from_svg(&plotter, &d, 50.0).unwrap_err();
        assert!(matches!(e, JobError::OutOfTravel { .. }), "{e}");
    }

    #[test]
    fn svg_becomes_pen_moves() {
        let plotter = cfg("plotter");
        let svg = r#"<svg xmlns="http://www.w3.org/2000/svg" width="100mm" height="100mm" viewBox="0 0 100 100"><path d="M10 10 L90 10 L90 90" stroke="black" fill="none"/></svg>"#;
        let d = crate::svg::read(svg, &Default::default()).unwrap();
        let p = from_svg(&plotter, &d, 50.0).unwrap();
        let kinds: Vec<&str> = p
            .moves
            .iter()
            .map(|(_, m)| match m {
                Move::Tool(None) => "up",
                Move::Tool(Some(_)) => "down",
                Move::Rapid(_) => "rapid",
                Move::Line(..) => "line",
                _ => "other",
            })
            .collect();
        assert_eq!(kinds, ["up", "rapid", "down", "line", "line", "up"]);
        let secs = p.planned_seconds(&plotter, &[0.0, 0.0]).unwrap();
        // 160 mm of drawing at 50 mm/s plus travel and two pen settles.
        assert!(secs > 3.2 + 0.3 && secs < 6.0, "{secs}");
    }
}
