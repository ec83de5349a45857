//! [`Machine`]: a machine in machine terms, the same on simulated modules
//! ([`Machine::simulate`]) and on hardware ([`Machine::connect`]).
//!
//! Underneath, the machine is a PIPES graph on the host and its modules:
//!
//! ```text
//! Timer.tick ──► machine.motion (planner + kinematics) ──► <motor>.add_point (each motor)
//! <module>.get_status / get_counters / read_limit / get_position ──► machine.* monitors
//! ```
//!
//! The timer leads the synchronized clock by [`LEAD_US`]; the motion
//! function samples the lookahead planner at each stamp and turns the
//! machine position into motor positions ([`drive::Drive`]). Modules
//! report faults, refused points, limit edges and stepped positions through
//! pipes of their own functions, so waiting ([`Machine::idle`]) and
//! homing are driven by what arrives, not by polling.
//! [`Machine::manager`] reaches the graph for anything the machine API
//! does not cover.

pub mod drive;
pub mod error;
pub mod events;
pub mod heaters;
pub(crate) mod holds;
mod homing;
mod liveness;
pub mod loadcell;
pub mod monitor;
pub mod motion;
pub mod motor_accel;
pub mod phases;
mod probing;
mod safe;
mod som_cache;
pub mod spindle;
mod stop;
mod tool;
pub mod tool_track;

use std::collections::BTreeMap;
use std::future::Future;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use maxl::blocks::planner::Arc as PlanArc;
use maxl::blocks::timer::TimerBlock;
use osap_core::route::Route;
use osap_host::netrunner::{Netrunner, SyncGoal};
use osap_host::som::{FnRef, Manager, PipeOptions, SomError, Value};
use osap_host::{Host, HostConfig};
use pipes_core::control::{ControlError, InputMode, OutputMode};
use tokio::sync::{broadcast, watch};

use crate::config::MachineFile;
use crate::module_limits::{module_limits, ModuleLimits};
pub use drive::{Drive, DriveError, MAX_AXES};
pub use error::{MachineError, StopReport, Unreached};
pub use events::{MachineEvent, MachineState};
pub use heaters::{Heater, HeaterLog, HeaterReading, HeaterRow, HeaterState};
pub use loadcell::{LoadCell, LoadCellReading};
use monitor::{LimitEdge, SharedReports};
use motion::{MotionStatus, SharedMotion};
pub use spindle::SpeedReached;
pub use tool::Tool;

use crate::network::Entry;
pub use crate::network::{Link, ModuleInfo};

/// The control-point interval the machine streams at, µs.
pub const INTERVAL_US: u32 = 2048;
/// How far the timer leads the synchronized clock: 40 intervals (82 ms),
/// room for a busy host to be held up without a motor's stream running
/// dry, within the 64 points a module queues.
pub const LEAD_US: u32 = 40 * INTERVAL_US;
/// The control-point interval in seconds.
const INTERVAL_S: f64 = INTERVAL_US as f64 * 1e-6;
/// The host runtime's name on the network.
pub const HOST_NAME: &str = "machine";
/// Period of the modules' status reports, µs.
const STATUS_PERIOD_US: u32 = 50_000;
/// Period of the modules' fault sources, µs: a fault stops the machine
/// within this and a link's latency.
const FAULT_PERIOD_US: u32 = 5_000;
/// Period of the limit switch and stepped position reports, µs.
const FAST_PERIOD_US: u32 = 1_000;
/// Period of each motor's stepped position while a run is recorded, µs:
/// the control-point interval. At 1 ms a motor module's reports left its
/// link no room to answer calls (a heater on a motor module could not be
/// read while a print was recorded, measured on the simulated printer).
pub const RECORD_PERIOD_US: u32 = INTERVAL_US;
/// A module silent for this long is lost.
const LINK_LOST_AFTER: Duration = Duration::from_millis(1_000);

/// Something that runs underneath a machine besides its network (a
/// simulator, in the `sim` feature): kept as long as the machine, and
/// stopped with it by [`Machine::stop`].
pub trait Underneath: Send + Sync + 'static {
    /// Stops it.
    fn stop(self: Box<Self>) -> Pin<Box<dyn Future<Output = Result<(), MachineError>> + Send>>;
    /// Itself, for the layer that put it there to find it again.
    fn as_any(&self) -> &dyn std::any::Any;
    /// Whether a run on it must come out the same every time (simulated
    /// modules in virtual time): the start then reads every module afresh
    /// rather than from the functions cache, whose state would change the
    /// start's timing and so the run (a record's replay must match it).
    fn reproducible(&self) -> bool {
        false
    }
}

/// A machine: its modules, its motion graph, its tools.
///
/// Cheap to clone: clones share the machine (a script may hand one to a
/// task serving a control socket).
#[derive(Clone)]
pub struct Machine {
    inner: Arc<Inner>,
}

impl std::fmt::Debug for Machine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Its parts are tasks, locks and buffers: the name says enough.
        f.debug_struct("Machine").finish_non_exhaustive()
    }
}

struct Inner {
    cfg: MachineFile,
    host: Host,
    manager: tokio::sync::Mutex<Manager>,
    modules: BTreeMap<String, ModuleInfo>,
    motion: SharedMotion,
    status: watch::Receiver<MotionStatus>,
    reports: SharedReports,
    events: broadcast::Sender<MachineEvent>,
    limit_edges: broadcast::Sender<(String, LimitEdge)>,
    state: watch::Sender<MachineState>,
    homed: Mutex<Vec<bool>>,
    /// The modules whose switches homing or probing presses now (the
    /// axes of one homing order press theirs together): their presses are
    /// expected. A press on any other switch still stops the machine.
    expecting: Mutex<Vec<String>>,
    /// The module whose axis a load-cell probe's comparator halts now: its
    /// `BlockHalt`, and the points it refuses as halted, are expected.
    expecting_halt: Mutex<Vec<String>>,
    tools: Mutex<BTreeMap<String, tool::ToolState>>,
    underneath: Mutex<Option<Box<dyn Underneath>>>,
    /// Modules that stopped answering since the last recovery: they may
    /// have rebooted, losing their set-up and their step count.
    lost: Mutex<std::collections::BTreeSet<String>>,
    /// Timers recorders ask of module functions.
    capture_holds: holds::Holds,
    /// The controlled stops faults started, until they end.
    stops: Mutex<Vec<tokio::task::JoinHandle<()>>>,
    _links: Vec<osap_host::link::stream::LinkHandle>,
    watchdog: tokio::task::JoinHandle<()>,
    /// The tasks that keep the modules' output watchdogs fed.
    feeders: Vec<tokio::task::JoinHandle<()>>,
    /// How long each phase of the start took.
    phases: phases::StartPhases,
}

impl Drop for Inner {
    fn drop(&mut self) {
        self.watchdog.abort();
        for f in &self.feeders {
            f.abort();
        }
    }
}

mod calls;
mod faults;
mod moves;
mod recording;
mod start;

use calls::som_refusal;
use start::{configure_motor, source};

impl Machine {
    /// The machine file it was started from.
    pub fn config(&self) -> &MachineFile {
        &self.inner.cfg
    }

    /// The axis names, in the order targets and positions use.
    pub fn axes(&self) -> Vec<String> {
        lock_motion(&self.inner.motion).drive.axes().to_vec()
    }

    /// The host runtime.
    pub fn host(&self) -> &Host {
        &self.inner.host
    }

    /// The PIPES manager of the machine's network: its functions, classes
    /// and pipes, to reach below the machine API.
    pub fn manager(&self) -> &tokio::sync::Mutex<Manager> {
        &self.inner.manager
    }

    /// The modules of `[modules]`, found.
    pub fn modules(&self) -> &BTreeMap<String, ModuleInfo> {
        &self.inner.modules
    }

    /// How long each phase of the machine's start took.
    pub fn start_phases(&self) -> &phases::StartPhases {
        &self.inner.phases
    }

    /// What runs underneath the machine (a simulator), if anything:
    /// runs `f` on it.
    pub fn with_underneath<R>(&self, f: impl FnOnce(&dyn Underneath) -> R) -> Option<R> {
        let u = self
            .inner
            .underneath
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        u.as_deref().map(f)
    }

    /// Events from now on: faults, limit edges, lost modules, refused
    /// points, homing, state changes.
    pub fn events(&self) -> broadcast::Receiver<MachineEvent> {
        self.inner.events.subscribe()
    }

    /// What the machine is doing.
    pub fn state(&self) -> MachineState {
        let s = self.inner.state.borrow().clone();
        match s {
            MachineState::Idle | MachineState::Moving => {
                if lock_motion(&self.inner.motion).is_idle() {
                    MachineState::Idle
                } else {
                    MachineState::Moving
                }
            }
            other => other,
        }
    }

    /// The planned machine position now (axis order): where the motors are
    /// being sent.
    pub fn position(&self) -> Vec<f64> {
        let m = lock_motion(&self.inner.motion);
        let n = m.drive.axes().len();
        match m.planner.last_stamp() {
            Some(t) if !m.planner.is_idle() => {
                m.planner.plan().state_at(t as f64).pos[..n].to_vec()
            }
            _ => m.planner.tail()[..n].to_vec(),
        }
    }

    /// Scales the feed of every move not yet started (1: as given; 0.5:
    /// half speed), never beyond the machine's limits.
    pub fn set_feed_override(&self, scale: f64) -> Result<(), MachineError> {
        Ok(lock_motion(&self.inner.motion)
            .planner
            .set_feed_scale(scale)?)
    }

    /// The toolhead's largest speed (mm/s) and acceleration (mm/s²; infinite
    /// while the motors' model bounds it) now.
    pub fn toolhead_limits(&self) -> (f64, f64) {
        let m = lock_motion(&self.inner.motion);
        let v = m.planner.vector_limits();
        (v.max_speed, v.max_accel)
    }

    /// Sets the toolhead's largest speed (mm/s) and acceleration (mm/s²)
    /// from now on, each held to the machine file's `[limits]` (a job's
    /// `M204`); the queue is replanned.
    pub fn set_toolhead_limits(
        &self,
        velocity: f64,
        acceleration: f64,
    ) -> Result<(), MachineError> {
        let l = &self.inner.cfg.limits;
        let mut m = lock_motion(&self.inner.motion);
        let now = *m.planner.vector_limits();
        m.planner
            .set_vector_limits(maxl::blocks::planner::VectorLimits {
                max_speed: velocity.min(l.velocity),
                max_accel: acceleration.min(l.vector_acceleration()),
                ..now
            })?;
        Ok(())
    }

    /// Powers every motor off (`M84` at a print's end), after the moves
    /// queued; the axes that home are then unhomed (a motor off may be
    /// turned by hand). [`Machine::recover`] powers them again.
    pub async fn motors_off(&self) -> Result<(), MachineError> {
        self.idle().await?;
        // No point may reach a disabled motor: the stream stops first, and
        // the points already sent (a timer lead ahead) run out.
        lock_motion(&self.inner.motion).paused = true;
        let last = self.inner.status.borrow().stamp;
        let until = last + 2 * u64::from(INTERVAL_US);
        loop {
            let now = self.now_us().await?;
            if now >= until {
                break;
            }
            tokio::time::sleep(Duration::from_micros(until - now)).await;
        }
        let modules: std::collections::BTreeSet<String> = lock_motion(&self.inner.motion)
            .drive
            .motors()
            .iter()
            .map(|m| m.module.clone())
            .collect();
        for module in modules {
            let off = crate::network::modfn::set_enable::Inputs { on: false };
            self.call_idempotent(&module, off).await?;
        }
        let homes = self.homing_axes();
        let mut homed = self.inner.homed.lock().unwrap_or_else(|e| e.into_inner());
        for (h, homes) in homed.iter_mut().zip(homes) {
            if homes {
                *h = false;
            }
        }
        Ok(())
    }

    /// The synchronized system time, µs.
    pub async fn now_us(&self) -> Result<u64, MachineError> {
        Ok(self.inner.host.system_time().await?.as_micros())
    }

    /// Which axes have homing configured (axis order).
    fn homing_axes(&self) -> Vec<bool> {
        let cfg = &self.inner.cfg;
        cfg.axis_names()
            .iter()
            .map(|a| cfg.axes[*a].homing.is_some())
            .collect()
    }

    /// Whether every axis that homes is homed.
    pub fn is_homed(&self) -> bool {
        self.homed()
            .iter()
            .zip(self.homing_axes())
            .all(|(homed, homes)| *homed || !homes)
    }

    /// Which axes are homed (axis order).
    pub fn homed(&self) -> Vec<bool> {
        self.inner
            .homed
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    /// Declares where the machine is (axis order), without moving, and
    /// counts every axis as homed. Only at rest.
    pub fn set_position(&self, at: impl AsRef<[f64]>) -> Result<(), MachineError> {
        let at = at.as_ref();
        let axes = self.axes();
        if at.len() != axes.len() {
            return Err(MachineError::WrongAxisCount {
                expected: axes.len(),
                axes: axes.join(", "),
                got: at.len(),
            });
        }
        self.rebase(at)?;
        self.inner
            .homed
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .iter_mut()
            .for_each(|h| *h = true);
        Ok(())
    }

    /// Re-defines the machine position as `at` where the motors stand.
    fn rebase(&self, at: &[f64]) -> Result<(), MachineError> {
        let mut m = lock_motion(&self.inner.motion);
        if !m.is_idle() {
            return Err(MachineError::Plan(maxl::blocks::planner::PlanError::Busy));
        }
        let mut p = [0.0; MAX_AXES];
        p[..at.len()].copy_from_slice(at);
        let motors = m.last_motors.clone();
        m.drive.rebase(at, &motors)?;
        m.set_position(p)?;
        Ok(())
    }

    /// Clears a fault: waits for the fault's stop to end, powers every
    /// motor off and on (which a module needs after its backstop or a
    /// halt), takes the machine to be where the motors' steps put them,
    /// and resumes. Homing is kept when the motors counted every step: a
    /// module that stopped answering may have rebooted, so its set-up
    /// (outputs' safe values and watchdog too) and pipes are installed
    /// again, and every homed axis must be homed again.
    pub async fn recover(&self) -> Result<(), MachineError> {
        self.await_stops().await;
        lock_motion(&self.inner.motion).paused = true;
        let result = self.recover_paused().await;
        lock_motion(&self.inner.motion).paused = false;
        result?;
        self.inner.state.send_replace(MachineState::Idle);
        let _ = self
            .inner
            .events
            .send(MachineEvent::State(MachineState::Idle));
        Ok(())
    }

    async fn recover_paused(&self) -> Result<(), MachineError> {
        // Let the points in flight land (the timer's lead) before cycling.
        tokio::time::sleep(Duration::from_micros(u64::from(LEAD_US + 4 * INTERVAL_US))).await;
        let motors: Vec<_> = lock_motion(&self.inner.motion).drive.motors().to_vec();
        let lost: Vec<String> = self
            .inner
            .lost
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .iter()
            .cloned()
            .collect();
        if !lost.is_empty() {
            let mut manager = self.inner.manager.lock().await;
            for key in &lost {
                let runtime = &self.inner.modules[key].runtime;
                manager.reinstate(runtime).await?;
                monitor::lock(&self.inner.reports).reset_baselines(key);
                safe::arm_module(&self.inner.cfg, &manager, key, runtime).await?;
                for motor in motors.iter().filter(|m| &m.module == key) {
                    let limits = module_limits(&self.inner.cfg, &motor.name, INTERVAL_S);
                    configure_motor(&manager, runtime, motor, limits).await?;
                }
            }
            drop(manager);
            // A motor's module that may have rebooted lost its step count;
            // a tool's module lost no position.
            if motors.iter().any(|m| lost.contains(&m.module)) {
                let mut homed = self.inner.homed.lock().unwrap_or_else(|e| e.into_inner());
                for (h, axis) in homed.iter_mut().zip(self.inner.cfg.axis_names()) {
                    *h = self.inner.cfg.axes[axis].homing.is_none();
                }
            }
        }
        self.rearm_motors(true).await?;
        let mut gone = self.inner.lost.lock().unwrap_or_else(|e| e.into_inner());
        for key in &lost {
            gone.remove(key);
        }
        Ok(())
    }
}

fn lock_motion(m: &SharedMotion) -> std::sync::MutexGuard<'_, motion::Motion> {
    motion::lock(m)
}
