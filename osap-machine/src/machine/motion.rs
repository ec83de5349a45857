//! The machine's motion source: the planner and the drive behind one lock,
//! sampled at the timer's stamps by a host PIPES function whose outputs
//! are piped to every motor's `add_point`.
//!
//! One lock holds both so that re-defining where the machine is (homing)
//! changes the planner's coordinates and the drive's offsets between two
//! samples, never across one: no motor ever sees a jump.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard};

use maxl::blocks::planner::{Kin, Limits, Planner, VectorLimits};
use maxl::blocks::pressure_advance::{ExtruderState, PressureAdvance};
use maxl::blocks::shaper::{InputShaper, ShaperConfig};
use osap_host::som::{HostFnError, HostFunction, Value};
use pipes_core::export::{PipesArgs, PipesType};
use pipes_core::types::Type;
use tokio::sync::watch;

use super::drive::{Drive, MAX_AXES};
use super::tool_track::{LevelPoint, ToolTrack};
use super::MachineError;
use crate::config::{AxisKind, MachineFile, ProfileKind, DEFAULT_CORNER_VELOCITY};

/// Failure code of the motion function while the machine is paused (no
/// points are sent, so the motors stand).
pub const PAUSED: u8 = 1;
/// Failure code of the motion function on a stamp the planner refuses.
pub const BAD_STAMP: u8 = 2;

/// How many recent samples are kept to find where the machine was at an
/// event's time (limit edges): 16 s at 2 ms.
const RECENT: usize = 8192;

/// A test signal added to the planned machine position at every stamp
/// (synchronized µs → offset per axis slot), such as the chirp of
/// `osap resonance`.
pub type Excitation = Box<dyn FnMut(u64) -> [f64; MAX_AXES] + Send>;

/// What the motion source reports after each sample.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MotionStatus {
    /// The newest stamp sampled (synchronized µs).
    pub stamp: u64,
    /// Moves are running or queued.
    pub busy: bool,
    /// The first stamp sampled at rest after the last move (0: never).
    pub rest_stamp: u64,
    /// Segments finished since start.
    pub executed: u64,
}

/// A sample kept for a recording: the stamp, the machine position sent to
/// the motors, and the planner's position before input shaping.
pub type Recorded = (u64, [f64; MAX_AXES], [f64; MAX_AXES]);

/// The planner, the drive and what they produced.
pub struct Motion {
    /// The lookahead planner, in machine coordinates (3 slots).
    pub planner: Planner<MAX_AXES>,
    /// Machine coordinates to motor positions.
    pub drive: Drive,
    /// No points are sent while set (recovering motors).
    pub paused: bool,
    /// Samples kept for a recording.
    pub record: Option<Vec<Recorded>>,
    recent: VecDeque<(u64, [f64; MAX_AXES])>,
    /// The motor positions sent last.
    pub last_motors: Vec<f64>,
    /// Why sampling failed last (kinematics), if it did.
    pub error: Option<String>,
    /// Added to the planned position at each stamp, while set.
    pub excitation: Option<Excitation>,
    /// The laser whose level is streamed with the motion, if the machine
    /// has one (see [`super::tool_track`]).
    pub tool: Option<ToolTrack>,
    /// The extruder's pressure advance, if the machine has one.
    advance: Option<Advance>,
    /// The input shaper every sample goes through (after pressure
    /// advance, before the excitation and kinematics).
    shaper: InputShaper<MAX_AXES>,
    status: MotionStatus,
    notify: watch::Sender<MotionStatus>,
}

impl std::fmt::Debug for Motion {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Its parts are tasks, locks and buffers: the name says enough.
        f.debug_struct("Motion").finish_non_exhaustive()
    }
}

/// A shared [`Motion`].
pub type SharedMotion = Arc<Mutex<Motion>>;

/// Locks the motion state (a poisoned lock is still the state).
pub fn lock(m: &SharedMotion) -> MutexGuard<'_, Motion> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl Motion {
    /// A motion source for `planner` and `drive`, with the motors at
    /// `motors`; the receiver follows its status.
    pub fn new(
        planner: Planner<MAX_AXES>,
        drive: Drive,
        motors: Vec<f64>,
    ) -> (Motion, watch::Receiver<MotionStatus>) {
        let (notify, rx) = watch::channel(MotionStatus::default());
        (
            Motion {
                planner,
                drive,
                paused: false,
                record: None,
                recent: VecDeque::with_capacity(RECENT),
                last_motors: motors,
                error: None,
                excitation: None,
                tool: None,
                advance: None,
                shaper: InputShaper::unshaped(),
                status: MotionStatus::default(),
                notify,
            },
            rx,
        )
    }

    /// The machine position (axis order) at the tail of the queue: where
    /// the next queued move starts.
    pub fn tail(&self) -> Vec<f64> {
        let n = self.drive.axes().len();
        self.planner.tail()[..n].to_vec()
    }

    /// Tells waiters that moves were queued (so `idle` waits for them).
    pub fn mark_busy(&mut self) {
        if !self.status.busy {
            self.status.busy = true;
            self.notify.send_replace(self.status);
        }
    }

    /// The planned position at synchronized stamp `t` from the recent
    /// samples, interpolated linearly (the modules' B-spline reproduces
    /// straight constant-speed motion exactly); `None` outside them.
    pub fn position_at(&self, t: u64) -> Option<Vec<f64>> {
        let n = self.drive.axes().len();
        let i = self.recent.partition_point(|s| s.0 <= t);
        let (a, b) = (self.recent.get(i.checked_sub(1)?)?, self.recent.get(i)?);
        let f = (t - a.0) as f64 / (b.0 - a.0).max(1) as f64;
        Some((0..n).map(|k| a.1[k] + f * (b.1[k] - a.1[k])).collect())
    }

    /// Shapes every axis slot with its shaper (`None`: only delayed by the
    /// common lag, so the axes stay in step). Refused unless the shaper is
    /// at rest.
    pub fn set_shapers(
        &mut self,
        shapers: [Option<ShaperConfig>; MAX_AXES],
    ) -> Result<(), maxl::blocks::shaper::ShaperError> {
        if !self.shaper.settled() {
            return Err(maxl::blocks::shaper::ShaperError::Moving);
        }
        self.shaper = InputShaper::new(shapers);
        Ok(())
    }

    /// The input shaper's common lag, s: at constant velocity the motors
    /// follow the plan this much later.
    pub fn shaper_lag_s(&self) -> f64 {
        self.shaper.lag_s()
    }

    /// Whether nothing is planned and the shaped output is at rest.
    pub fn is_idle(&self) -> bool {
        self.planner.is_idle() && self.shaper.settled()
    }

    /// Re-defines the planner's coordinates as `p` (a jump the motors must
    /// not follow): the shaper starts afresh at rest there.
    pub fn set_position(
        &mut self,
        p: [f64; MAX_AXES],
    ) -> Result<(), maxl::blocks::planner::PlanError> {
        self.planner.set_position(p)?;
        self.shaper.reset();
        Ok(())
    }

    /// A controlled stop of the planner ([`Planner::halt`]), with the
    /// streamed tool off from the next stamp on: whatever stops the motion
    /// stops the laser too, and nothing it had queued lights it again.
    pub fn halt(&mut self) -> Result<[f64; MAX_AXES], maxl::blocks::planner::PlanError> {
        if let Some(t) = &mut self.tool {
            t.off();
        }
        self.planner.halt()
    }

    /// A controlled stop of the planner that keeps the streamed tool as it
    /// is (a move that replaces the queue: `goto_now`, homing's stops):
    /// only the tool commands of the dropped moves go with them, so none
    /// applies to the moves queued next.
    pub fn halt_path(&mut self) -> Result<[f64; MAX_AXES], maxl::blocks::planner::PlanError> {
        if let Some(t) = &mut self.tool {
            t.drop_queued();
        }
        self.planner.halt()
    }

    /// Replaces the planner (a fault's stop voids what was planned): the
    /// shaper starts afresh at rest at its position.
    pub fn replace_planner(&mut self, planner: Planner<MAX_AXES>) {
        self.planner = planner;
        self.shaper.reset();
    }

    /// Advances the extruder in axis slot `slot` by `pa` from now on
    /// (`None`: no pressure advance).
    pub fn set_pressure_advance(&mut self, pa: Option<(usize, PressureAdvance)>) {
        self.advance = pa.map(|(slot, pa)| Advance {
            slot,
            pa,
            history: VecDeque::new(),
        });
    }

    /// The planner's position at `stamp` and the motor positions for it,
    /// with the streamed tool's level point for it.
    pub fn sample(&mut self, stamp: u64) -> Result<(Vec<f64>, Option<LevelPoint>), u8> {
        if self.paused {
            return Err(PAUSED);
        }
        let kin = self.planner.sample_kin(stamp).map_err(|_| BAD_STAMP)?;
        let level = self
            .tool
            .as_mut()
            .map(|t| t.sample(&self.planner, stamp, u64::from(super::INTERVAL_US)));
        let plan = kin.pos;
        let mut pos = kin.pos;
        if let Some(a) = &mut self.advance {
            pos[a.slot] = a.advanced(&self.planner, stamp, &kin);
        }
        // Stamps only increase and positions are finite here, so the
        // shaper refuses nothing; if it did, the unshaped position is the
        // safe one to send.
        pos = self.shaper.shape(stamp, pos).unwrap_or(pos);
        if let Some(x) = &mut self.excitation {
            for (p, d) in pos.iter_mut().zip(x(stamp)) {
                *p += d;
            }
        }
        let n = self.drive.axes().len();
        let motors = match self.drive.motor_positions(&pos[..n]) {
            Ok(m) => m,
            Err(e) => {
                // Hold where the motors are: the planner's path left the
                // mechanism's reach. The machine faults on it.
                self.error = Some(format!("the path left the kinematics' reach: {e}"));
                self.last_motors.clone()
            }
        };
        self.last_motors.clone_from(&motors);
        if self.recent.len() == RECENT {
            self.recent.pop_front();
        }
        self.recent.push_back((stamp, pos));
        if let Some(rec) = &mut self.record {
            rec.push((stamp, pos, plan));
        }
        let stats = self.planner.stats();
        // Busy until the shaped output has come to rest too.
        let busy = !stats.idle || !self.shaper.settled();
        let was = self.status;
        self.status.stamp = stamp;
        self.status.executed = stats.executed;
        if !busy && (was.busy || was.rest_stamp == 0) {
            self.status.rest_stamp = stamp;
        }
        self.status.busy = busy;
        if was.busy != busy || was.executed != stats.executed || was.rest_stamp == 0 {
            self.notify.send_replace(self.status);
        }
        Ok((motors, level))
    }
}

/// The extruder's pressure advance: Klipper's smoothed `e + K·v` over a
/// window around each stamp, the past from the stamps sampled, the future
/// from the plan (the planner's [`Planner::state_at`]). A plan that
/// changes within the window (a halt, moves appended to a queue that had
/// run dry) moves the advanced position by what the change makes of the
/// window, a few hundredths of a mm.
struct Advance {
    slot: usize,
    pa: PressureAdvance,
    /// Recent stamps (µs) and the nominal extruder state at each.
    history: VecDeque<(u64, ExtruderState)>,
}

impl Advance {
    fn state(&self, kin: &Kin<MAX_AXES>) -> ExtruderState {
        let v = kin.vel[self.slot];
        ExtruderState {
            position: kin.pos[self.slot],
            velocity: v,
            // Klipper advances moves that extrude while x or y moves.
            advances: v > 0.0 && (kin.vel[0] != 0.0 || kin.vel[1] != 0.0),
        }
    }

    /// The advanced position at `stamp`, whose planned state is `kin`.
    fn advanced(&mut self, planner: &Planner<MAX_AXES>, stamp: u64, kin: &Kin<MAX_AXES>) -> f64 {
        let now = self.state(kin);
        self.history.push_back((stamp, now));
        let keep = (self.pa.reach() * 1e6) as u64 + 2 * u64::from(super::INTERVAL_US);
        while self.history.front().is_some_and(|(t, _)| t + keep < stamp) {
            self.history.pop_front();
        }
        let t_now = stamp as f64 * 1e-6;
        let history = &self.history;
        let nominal = |t: f64| -> ExtruderState {
            let us = t * 1e6;
            if us >= stamp as f64 {
                return self.state(&planner.state_at(us));
            }
            // The past: between two samples, e is quadratic (constant
            // acceleration), fixed by both ends' position and velocity.
            let i = history.partition_point(|(s, _)| (*s as f64) <= us);
            match (
                i.checked_sub(1).and_then(|j| history.get(j)),
                history.get(i),
            ) {
                (Some(&(t0, a)), Some(&(t1, b))) => {
                    let dt = (t1 - t0) as f64 * 1e-6;
                    let s = t - t0 as f64 * 1e-6;
                    let acc = if dt > 0.0 {
                        (b.velocity - a.velocity) / dt
                    } else {
                        0.0
                    };
                    ExtruderState {
                        position: a.position + a.velocity * s + 0.5 * acc * s * s,
                        velocity: a.velocity + acc * s,
                        advances: a.advances,
                    }
                }
                (Some(&(_, a)), None) => a,
                // Before the first sample: where the extruder stood.
                (None, _) => history
                    .front()
                    .map_or(now, |&(_, a)| ExtruderState { velocity: 0.0, ..a }),
            }
        };
        self.pa.position(t_now, nominal)
    }
}

/// The motion function's input, and its first output: the timer's stamp
/// it sampled at.
pub const STAMP: &str = "stamp";

/// The motion function's input: the stamp to sample at.
#[derive(Debug, Clone, Copy, PartialEq, Eq, pipes_core::PipesArgs)]
pub struct Stamp {
    /// Synchronized µs.
    pub stamp: u64,
}

/// The motion function's outputs for the streamed tool's `level_point`
/// (time, channel, duty, ramp), present when the machine streams one.
pub const TOOL_OUTPUTS: [&str; 4] = ["tool_time", "tool_channel", "tool_before", "tool_after"];

/// The tool function's outputs, piped to the tool module's `level_point`.
pub const TOOL_POINT: [&str; 4] = ["time", "channel", "before", "after"];

/// The host function `name(tool_time, tool_channel, tool_before,
/// tool_after) -> (time, channel, before, after)` between the motion
/// function's tool outputs and the tool module's `level_point`: it passes
/// each point on, and with its output mode "on change" a point repeated
/// (the track's way of saying nothing changed, [`ToolTrack::sample`])
/// sends nothing. The motion's other outputs change every stamp, so this
/// is where a tool at rest stops costing its module a datagram an
/// interval.
pub fn tool_function(name: &str) -> Result<HostFunction, MachineError> {
    let types = [u64::TYPE, u8::TYPE, f32::TYPE, f32::TYPE];
    let inputs: Vec<(&str, Type)> = TOOL_OUTPUTS.iter().copied().zip(types).collect();
    let outputs: Vec<(&str, Type)> = TOOL_POINT.iter().copied().zip(types).collect();
    Ok(HostFunction::new(
        name,
        &inputs,
        &outputs,
        |ins: &[Value<'static>]| Ok(ins.to_vec()),
    )?)
}

/// The name of the motion function's output for motor `index` (machine
/// motor order): `m0`, `m1`, ..
pub fn motor_output(index: usize) -> String {
    format!("m{index}")
}

/// The host function `name(stamp) -> (stamp, m0, m1, ..)` that samples
/// `motion`: its outputs are piped to each motor's `add_point`
/// ([`STAMP`] to `time`, [`motor_output`] to `position`). Its input is
/// [`Stamp`]; its outputs are one per motor, a list only known at run
/// time.
pub fn function(
    name: &str,
    motion: SharedMotion,
    motors: usize,
) -> Result<HostFunction, MachineError> {
    let inputs: Vec<(&str, Type)> = Stamp::ARGS.iter().map(|a| (a.name, a.ty)).collect();
    let out_names: Vec<String> = (0..motors).map(motor_output).collect();
    let wraps: Vec<Option<f64>> = lock(&motion)
        .drive
        .motors()
        .iter()
        .map(|m| m.wrap)
        .collect();
    let tool_channel = lock(&motion).tool.as_ref().map(|t| t.channel);
    let mut outputs: Vec<(&str, Type)> = vec![(STAMP, u64::TYPE)];
    outputs.extend(out_names.iter().map(|n| (n.as_str(), f32::TYPE)));
    if tool_channel.is_some() {
        let types = [u64::TYPE, u8::TYPE, f32::TYPE, f32::TYPE];
        outputs.extend(TOOL_OUTPUTS.iter().copied().zip(types));
    }
    Ok(HostFunction::new(
        name,
        &inputs,
        &outputs,
        move |ins: &[Value<'static>]| {
            let Ok(Stamp { stamp }) = Stamp::from_values(ins) else {
                return Err(HostFnError::new(BAD_STAMP));
            };
            let (m, level) = lock(&motion).sample(stamp)?;
            let mut out = Vec::with_capacity(5 + m.len());
            out.push(Value::U64(stamp));
            out.extend(
                m.iter()
                    .zip(wraps.iter().chain(std::iter::repeat(&None)))
                    .map(|(&v, wrap)| Value::F32(wire_position(v, *wrap))),
            );
            if let (Some(channel), Some(p)) = (tool_channel, level) {
                out.extend([
                    Value::U64(p.time),
                    Value::U8(channel),
                    Value::F32(p.before),
                    Value::F32(p.after),
                ]);
            }
            Ok(out)
        },
    )?)
}

/// A motor position as the wire carries it (`f32`, motor units): less a
/// whole number of `wrap` periods for a motor that never stops turning
/// (see [`super::drive::DriveMotor::wrap`]).
pub fn wire_position(v: f64, wrap: Option<f64>) -> f32 {
    match wrap {
        Some(p) => v.rem_euclid(p) as f32,
        None => v as f32,
    }
}

/// The planner a machine plans with: each axis's own velocity and
/// acceleration (and with `[limits] profile = "scurve"` its jerk, and the
/// toolhead's `[limits] jerk`), an extruder's velocity jump at a corner held to its
/// `instantaneous_corner_velocity`, the toolhead's (x, y, z) vector limits
/// and minimum cruise ratio from `[limits]`, and its junction deviation (with the centripetal limit on
/// chorded curves that maxl's planner always applies).
pub fn machine_planner(cfg: &MachineFile) -> Result<Planner<MAX_AXES>, MachineError> {
    let mut vel = [1.0; MAX_AXES];
    let mut acc = [1.0; MAX_AXES];
    let mut jump = [f64::INFINITY; MAX_AXES];
    let mut jerk = [f64::INFINITY; MAX_AXES];
    let scurve = cfg.limits.profile == ProfileKind::Scurve;
    for (k, name) in cfg.axis_names().iter().enumerate().take(MAX_AXES) {
        let a = &cfg.axes[*name];
        vel[k] = a.velocity;
        acc[k] = a.acceleration;
        if scurve {
            jerk[k] = a.jerk;
        }
        if a.kind == AxisKind::Extruder {
            jump[k] = a
                .extruder
                .instantaneous_corner_velocity
                .unwrap_or(DEFAULT_CORNER_VELOCITY);
        }
    }
    let limits = Limits::new(vel, acc, cfg.limits.junction_deviation)?
        .with_max_jump(jump)?
        .with_max_jerk(jerk)?;
    // Planning from the motors, the toolhead's constant acceleration gives
    // way to the model; each axis's own stays as a ceiling.
    let model = match cfg.limits.model {
        Some(crate::config::PlannerModel::Motors) => super::motor_accel::MotorAccel::new(cfg)?,
        None => None,
    };
    if let Some(m) = &model {
        // Every toolhead axis must keep some torque at its own speed limit.
        for (k, name) in cfg
            .axis_names()
            .iter()
            .enumerate()
            .take(cfg.toolhead_axes())
        {
            let mut u = [0.0; MAX_AXES];
            u[k] = 1.0;
            let v = cfg.axes[*name].velocity;
            if maxl::blocks::planner::AccelModel::max_accel(m, &u, &u, v) <= 0.0 {
                return Err(MachineError::Unsupported(format!(
                    "axes.{name}.velocity: at {v} units/s its motor has no torque left (the back-EMF reaches [motors.NAME.model] supply_v): lower the velocity or raise the supply"
                )));
            }
        }
    }
    let vector_accel = cfg.limits.vector_acceleration();
    // The toolhead's axes carry the path; a machine without x, y or z
    // (a rotary stage) plans over all its axes.
    let vector = VectorLimits::new(cfg.limits.velocity, vector_accel)?
        .with_min_cruise_ratio(cfg.limits.minimum_cruise_ratio)?
        .with_max_jerk(match (scurve, cfg.limits.jerk) {
            (true, Some(j)) => j,
            _ => f64::INFINITY,
        })?
        .with_path_axes(cfg.toolhead_axes());
    let mut planner =
        Planner::with_vector_limits(limits, vector, maxl::blocks::planner::DEFAULT_CAPACITY)?;
    if let Some(m) = model {
        planner.set_accel_model(Some(std::sync::Arc::new(m)));
    }
    Ok(planner)
}

/// The input shaper of each axis slot, from `[axes.NAME] shaper` (`None`
/// for an axis without one).
pub fn shapers(cfg: &MachineFile) -> Result<[Option<ShaperConfig>; MAX_AXES], MachineError> {
    let mut out = [None; MAX_AXES];
    for (slot, name) in cfg.axis_names().iter().enumerate().take(MAX_AXES) {
        if let Some(s) = &cfg.axes[*name].shaper {
            out[slot] = Some(
                s.config()
                    .map_err(|e| MachineError::Unsupported(format!("axes.{name}.shaper: {e}")))?,
            );
        }
    }
    Ok(out)
}

/// The extruder's pressure advance from its `[axes.e]` (`pressure_advance`,
/// else its melt model's response time; and `smooth_time`) with its axis
/// slot; `None` without an extruder or with pressure advance 0.
pub fn pressure_advance(
    cfg: &MachineFile,
) -> Result<Option<(usize, PressureAdvance)>, MachineError> {
    let Some(e) = cfg.extruder() else {
        return Ok(None);
    };
    let k = e.extruder.pressure_advance_s();
    if k == 0.0 {
        return Ok(None);
    }
    let smooth = e
        .extruder
        .smooth_time
        .unwrap_or(crate::config::DEFAULT_SMOOTH_TIME);
    let pa = PressureAdvance::new(k, smooth)
        .map_err(|err| MachineError::Unsupported(format!("axes.e: {err}")))?;
    let slot = cfg.axis_names().iter().position(|n| *n == "e");
    Ok(slot.map(|slot| (slot, pa)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use maxl::Fx;

    /// After 100 m of filament at 400 microsteps/mm, the position sent
    /// modulo the extruder's period lands the module's track on the same
    /// microstep fraction as the whole position would, where the whole
    /// position as `f32` is 3 microsteps off.
    #[test]
    fn an_extruder_far_along_is_sent_to_a_fraction_of_a_microstep() {
        let cfg = MachineFile::load(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../examples/machines/printer.toml"
        ))
        .unwrap();
        let d = super::super::Drive::new(&cfg, &[0.0; 4]).unwrap();
        let e = d.motors().iter().find(|m| m.name == "e").unwrap();
        let period = e.wrap.unwrap();
        assert!((period - 163.84).abs() < 1e-12, "{period}");
        assert!(d
            .motors()
            .iter()
            .filter(|m| m.name != "e")
            .all(|m| m.wrap.is_none()));
        let spu = 400.0;
        for v in [
            0.0,
            163.83,
            163.85,
            100_000.123_456,
            -2_500.5,
            1.0e6 + 0.0025,
        ] {
            let track = |units: f64| Fx::wrapping_from_f64(units * spu).unwrap();
            let exact = track(v);
            let sent = track(f64::from(wire_position(v, Some(period))));
            let diff = f64::from(sent.wrapping_diff(exact)).abs() / 65_536.0;
            assert!(diff < 0.01, "{v}: {diff} microsteps off");
            if v.abs() > 50_000.0 {
                let whole = track(f64::from(v as f32));
                let off = f64::from(whole.wrapping_diff(exact)).abs() / 65_536.0;
                assert!(off > 0.5, "{v}: f32 alone is only {off} microsteps off");
            }
        }
    }
}
