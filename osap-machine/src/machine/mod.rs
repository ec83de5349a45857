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
mod homing;
mod liveness;
pub mod monitor;
pub mod motion;
mod probing;
mod safe;
mod stop;
mod tool;

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use maxl::blocks::planner::Arc as PlanArc;
use maxl::blocks::timer::TimerBlock;
use osap_core::route::Route;
use osap_host::netrunner::{Netrunner, SyncGoal};
use osap_host::som::{FnRef, Manager, PipeOptions, SomError, Value};
use osap_host::{Host, HostConfig};
use osap_sim::machine::{SimMachine, TimeMode};
use pipes_core::control::{ControlError, InputMode, OutputMode};
use tokio::sync::{broadcast, watch};

use crate::config::MachineFile;
use crate::module_limits::{module_limits, ModuleLimits};
pub use drive::{Drive, MAX_AXES};
pub use error::{MachineError, StopReport, Unreached};
pub use events::{MachineEvent, MachineState};
use monitor::{LimitEdge, SharedReports};
use motion::{MotionStatus, SharedMotion};
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
/// A module silent for this long is lost.
const LINK_LOST_AFTER: Duration = Duration::from_millis(1_000);

/// Options of [`Machine::simulate_with`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SimOptions {
    /// Real time, or virtual time (the caller runs on
    /// [`osap_sim::machine::virtual_runtime`]).
    pub time: TimeMode,
}

/// A machine: its modules, its motion graph, its tools.
///
/// Cheap to clone: clones share the machine (a script may hand one to a
/// task serving a control socket).
#[derive(Clone)]
pub struct Machine {
    inner: Arc<Inner>,
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
    /// The module whose switch homing or probing presses now: its press is
    /// expected. A press on any other switch still stops the machine.
    expecting: Mutex<Option<String>>,
    tools: Mutex<BTreeMap<String, tool::ToolState>>,
    sim: Mutex<Option<SimMachine>>,
    /// Modules that stopped answering since the last recovery: they may
    /// have rebooted, losing their set-up and their step count.
    lost: Mutex<std::collections::BTreeSet<String>>,
    /// Timers recorders ask of module functions ([`crate::capture`]).
    capture_holds: crate::capture::Holds,
    /// The controlled stops faults started, until they end.
    stops: Mutex<Vec<tokio::task::JoinHandle<()>>>,
    _links: Vec<osap_host::link::stream::LinkHandle>,
    watchdog: tokio::task::JoinHandle<()>,
    /// The tasks that keep the modules' output watchdogs fed.
    feeders: Vec<tokio::task::JoinHandle<()>>,
}

impl Drop for Inner {
    fn drop(&mut self) {
        self.watchdog.abort();
        for f in &self.feeders {
            f.abort();
        }
    }
}

fn som_refusal(module: &str, function: &str, e: SomError) -> MachineError {
    match e {
        SomError::Remote {
            error: ControlError::CallFailed(code),
            ..
        } => MachineError::ModuleRefused {
            module: module.into(),
            function: function.into(),
            reason: error::module_reason(function, code.code()),
        },
        other => MachineError::Network(other),
    }
}

/// How closely a clock must follow its source before motion starts.
const SYNC_GOAL: SyncGoal = SyncGoal {
    max_offset: Duration::from_micros(200),
    quiet: Duration::from_millis(200),
    timeout: Duration::from_secs(20),
};

impl Machine {
    /// The machine on simulated modules, derived from the machine file
    /// (its `[sim]` section), in real time.
    pub async fn simulate(cfg: &MachineFile) -> Result<Machine, MachineError> {
        Self::simulate_with(cfg, SimOptions::default()).await
    }

    /// [`Machine::simulate`] with options (virtual time).
    pub async fn simulate_with(
        cfg: &MachineFile,
        options: SimOptions,
    ) -> Result<Machine, MachineError> {
        cfg.validate()?;
        let topology =
            crate::sim::topology(cfg).map_err(|e| MachineError::Unsupported(e.to_string()))?;
        let host = Host::start(HostConfig::named(HOST_NAME))?;
        let sim = SimMachine::start_with(&host, &topology, options.time).await?;
        Self::start(cfg, host, Vec::new(), Entry::Host, Some(sim)).await
    }

    /// The machine on hardware, reached over `links`. Over TCP links only
    /// (a machine another process serves) this host follows that
    /// process's clock; with any serial link it is the machine's root.
    pub async fn connect(cfg: &MachineFile, links: &[Link]) -> Result<Machine, MachineError> {
        cfg.validate()?;
        if links.is_empty() {
            return Err(MachineError::Unsupported(
                "no link given: name a serial port or a TCP address".into(),
            ));
        }
        // Over serial the modules are ours and this host is their clock
        // root; over TCP only, the machine is served and its host is the
        // root: follow it, and trust no other link.
        let served = crate::network::served(links);
        let mut config = HostConfig::named(HOST_NAME);
        config.time.root = !served;
        let host = Host::start(config)?;
        let handles = crate::network::open_links(&host, links).await?;
        if served {
            for l in &handles {
                host.trust_time_link(l.index()).await?;
            }
        }
        let entry = Entry::of(links, &handles);
        if served {
            // Points are stamped in this host's time: it must follow the
            // served clock before the first one, and never step after.
            let runner = Netrunner::new(&host).await?;
            let here =
                Route::through_links(&[]).map_err(|e| MachineError::Unsupported(e.to_string()))?;
            runner
                .wait_synchronised(&here, SYNC_GOAL)
                .await
                .map_err(|e| MachineError::NotSynchronised {
                    module: HOST_NAME.into(),
                    detail: e.to_string(),
                })?;
            host.set_motion_active(true).await?;
        }
        Self::start(cfg, host, handles, entry, None).await
    }

    async fn start(
        cfg: &MachineFile,
        host: Host,
        links: Vec<osap_host::link::stream::LinkHandle>,
        entry: Entry,
        sim: Option<SimMachine>,
    ) -> Result<Machine, MachineError> {
        let start = drive::start_position(cfg);
        let drive = Drive::new(cfg, &start).map_err(MachineError::Unsupported)?;
        check_track_range(cfg, &drive)?;
        if let Some(path) = cfg.bed_mesh_path() {
            crate::mesh::load(&path).map_err(MachineError::Unsupported)?;
        }
        let mut manager = Manager::new(&host).await?;
        manager.refresh().await?;
        let modules = crate::network::find_modules(cfg, manager.som(), entry)?;

        // Motion is keyed by synchronized time: every module's clock must
        // follow the host's before a point is sent.
        let netrunner = Netrunner::new(&host).await?;
        for (key, m) in &modules {
            netrunner
                .wait_synchronised(&m.route, SYNC_GOAL)
                .await
                .map_err(|e| MachineError::NotSynchronised {
                    module: key.clone(),
                    detail: e.to_string(),
                })?;
        }
        safe::arm_all(cfg, &manager, &modules).await?;

        // Motors: scale, microsteps, interval, power; then where they stand.
        let mut motor_at = Vec::new();
        for motor in drive.motors() {
            let runtime = &modules[&motor.module].runtime;
            let limits = module_limits(cfg, &motor.name, INTERVAL_S);
            motor_at.push(configure_motor(&manager, runtime, motor, limits).await?);
        }
        let mut drive = drive;
        drive.rebase(&start, &motor_at)?;
        if let Some(path) = cfg.bed_mesh_path() {
            let mesh = crate::mesh::load(&path).map_err(MachineError::Unsupported)?;
            drive = drive
                .with_mesh(mesh, &start, &motor_at)
                .map_err(MachineError::Unsupported)?;
        }

        let planner = crate::job::machine_planner(cfg)?;
        let (mut motion, status) = motion::Motion::new(planner, drive, motor_at);
        let mut start3 = [0.0; MAX_AXES];
        start3[..start.len()].copy_from_slice(&start);
        motion.planner.set_position(start3)?;
        let motion = Arc::new(Mutex::new(motion));

        let (events, _) = broadcast::channel(1024);
        let (limit_edges, _) = broadcast::channel(256);
        let reports: SharedReports = Arc::default();

        // The graph.
        let host_name = manager
            .som()
            .runtimes
            .first()
            .map(|r| r.record.name.clone())
            .unwrap_or_else(|| HOST_NAME.into());
        let timer = manager
            .define_class(
                TimerBlock::new(INTERVAL_US, LEAD_US)
                    .map_err(|e| MachineError::Unsupported(format!("timer: {e}")))?,
            )
            .await?;
        let tick = FnRef::new(
            host_name.as_str(),
            timer.member("tick").unwrap_or("Timer.tick"),
        );
        manager
            .set_input_mode(&tick, InputMode::OnTimer(INTERVAL_US / 4))
            .await?;
        manager.set_output_mode(&tick, OutputMode::OnChange).await?;
        let n_motors = lock_motion(&motion).drive.motors().len();
        let motion_fn = manager
            .define(
                motion::function("machine.motion", motion.clone(), n_motors)
                    .map_err(MachineError::Unsupported)?,
            )
            .await?;
        let o = PipeOptions::default();
        manager.connect(&tick, &motion_fn, &[0], &[0], o).await?;
        let motors: Vec<_> = lock_motion(&motion).drive.motors().to_vec();
        for (i, motor) in motors.iter().enumerate() {
            let runtime = &modules[&motor.module].runtime;
            let out = u8::try_from(1 + i)
                .map_err(|_| MachineError::Unsupported("more than 254 motors".into()))?;
            manager
                .connect(
                    &motion_fn,
                    &FnRef::new(runtime.as_str(), "add_point"),
                    &[0, out],
                    &[0, 1],
                    o,
                )
                .await?;
        }

        // Reports from the modules.
        liveness::status_reports(&mut manager, &modules, &reports).await?;
        for motor in &motors {
            let runtime = modules[&motor.module].runtime.clone();
            let key = motor.module.as_str();
            let counters_fn = manager
                .define(
                    monitor::counters(key, reports.clone(), events.clone())
                        .map_err(MachineError::Unsupported)?,
                )
                .await?;
            source(
                &mut manager,
                &runtime,
                "get_counters",
                Some(STATUS_PERIOD_US),
                true,
                &counters_fn,
                4,
            )
            .await?;
        }
        for (i, motor) in motors.iter().enumerate() {
            let runtime = modules[&motor.module].runtime.clone();
            let f = manager
                .define(
                    monitor::position(&motor.name, i, reports.clone())
                        .map_err(MachineError::Unsupported)?,
                )
                .await?;
            // Wired now, run only while recording (start_recording): at
            // 1 kHz per motor it is most of a simulation's work otherwise.
            source(&mut manager, &runtime, "get_position", None, true, &f, 2).await?;
        }
        let mut switch_modules: Vec<&str> = cfg
            .axes
            .values()
            .filter_map(|a| a.homing.as_ref()?.switch.as_deref())
            .chain(cfg.probe.as_ref().map(|p| p.module.as_str()))
            .collect();
        switch_modules.sort();
        switch_modules.dedup();
        // Every module's faults, pushed once each as they happen.
        for (key, m) in &modules {
            if manager
                .function(&FnRef::new(m.runtime.as_str(), "get_fault"))
                .is_err()
            {
                continue;
            }
            let watched = switch_modules.contains(&key.as_str());
            let f = manager
                .define(
                    monitor::fault(key, watched, reports.clone(), events.clone())
                        .map_err(MachineError::Unsupported)?,
                )
                .await?;
            source(
                &mut manager,
                &m.runtime,
                "get_fault",
                Some(FAULT_PERIOD_US),
                true,
                &f,
                4,
            )
            .await?;
        }
        for key in switch_modules {
            let runtime = modules[key].runtime.clone();
            let f = manager
                .define(
                    monitor::limit(key, reports.clone(), limit_edges.clone())
                        .map_err(MachineError::Unsupported)?,
                )
                .await?;
            source(
                &mut manager,
                &runtime,
                "read_limit",
                Some(FAST_PERIOD_US),
                true,
                &f,
                3,
            )
            .await?;
        }

        let (state, _) = watch::channel(MachineState::Idle);
        let homed = cfg
            .axis_names()
            .iter()
            .map(|a| cfg.axes[*a].homing.is_none())
            .collect();
        let tools = cfg
            .tools
            .keys()
            .map(|k| (k.clone(), tool::ToolState::default()))
            .collect();
        let watchdog = tokio::spawn(liveness::watch_modules(
            modules.keys().cloned().collect(),
            reports.clone(),
            events.clone(),
        ));
        let feeders = safe::keep_fed(cfg, &manager, &modules)?;
        let machine = Machine {
            inner: Arc::new(Inner {
                cfg: cfg.clone(),
                host,
                manager: tokio::sync::Mutex::new(manager),
                modules,
                motion,
                status,
                reports,
                events,
                limit_edges,
                state,
                homed: Mutex::new(homed),
                expecting: Mutex::default(),
                tools: Mutex::new(tools),
                sim: Mutex::new(sim),
                lost: Mutex::default(),
                capture_holds: Default::default(),
                stops: Mutex::default(),
                _links: links,
                watchdog,
                feeders,
            }),
        };
        machine.spawn_fault_handler();
        Ok(machine)
    }

    /// Halts the machine and marks it faulted on every fault, limit hit
    /// outside homing, or lost module.
    fn spawn_fault_handler(&self) {
        let weak = Arc::downgrade(&self.inner);
        let mut rx = self.inner.events.subscribe();
        let mut edges = self.inner.limit_edges.subscribe();
        tokio::spawn(async move {
            loop {
                let (reason, crash) = tokio::select! {
                    e = rx.recv() => match e {
                        Ok(MachineEvent::Fault { module, kind, detail, reason, .. }) => {
                            let Some(inner) = weak.upgrade() else { return };
                            if !stops_motion(&inner, &module, kind, detail) {
                                continue;
                            }
                            (format!("module {module} {reason}"), false)
                        }
                        Ok(MachineEvent::LinkLost { module }) => {
                            let Some(inner) = weak.upgrade() else { return };
                            inner.lost.lock().unwrap_or_else(|e| e.into_inner()).insert(module.clone());
                            (format!("module {module} stopped answering"), false)
                        }
                        Ok(_) | Err(broadcast::error::RecvError::Lagged(_)) => continue,
                        Err(broadcast::error::RecvError::Closed) => return,
                    },
                    e = edges.recv() => match e {
                        Ok((module, edge)) => {
                            if !edge.is_edge() {
                                // The switch's state when its pipe began.
                                continue;
                            }
                            let Some(inner) = weak.upgrade() else { return };
                            let expected = inner
                                .expecting
                                .lock()
                                .unwrap_or_else(|e| e.into_inner())
                                .as_deref()
                                == Some(module.as_str());
                            let _ = inner.events.send(MachineEvent::Limit {
                                module: module.clone(),
                                time: edge.time,
                                pressed: edge.pressed,
                                expected,
                            });
                            if expected || !edge.pressed {
                                continue;
                            }
                            (format!("limit switch on module {module} pressed outside homing: every motor stopped at once; home again"), true)
                        }
                        Err(broadcast::error::RecvError::Lagged(_)) => continue,
                        Err(broadcast::error::RecvError::Closed) => return,
                    },
                };
                let Some(inner) = weak.upgrade() else { return };
                let machine = Machine { inner };
                if crash {
                    // The points already sent run a lead ahead: only the
                    // modules can stop at once. Where the axes are is then
                    // known only to a step count, not to the switch: re-home.
                    // The report goes out as an event, and to the log.
                    machine.emergency_stop_as(reason).await;
                    machine
                        .inner
                        .homed
                        .lock()
                        .unwrap_or_else(|e| e.into_inner())
                        .iter_mut()
                        .zip(machine.homing_axes())
                        .for_each(|(h, homes)| *h = !homes);
                } else {
                    machine.fault_and_stop(reason);
                }
            }
        });
    }

    /// Stops motion (a controlled stop) and marks the machine faulted;
    /// `true` if this is its first fault. The first fault is the one the
    /// machine reports until it recovers: what follows (refusals behind a
    /// stopped axis) is its consequence. [`Machine::fault_and_stop`] also
    /// halts every module and switches every tool off.
    fn fault(&self, reason: String) -> bool {
        {
            let mut m = lock_motion(&self.inner.motion);
            let _ = m.planner.halt();
            m.mark_busy();
        }
        if matches!(*self.inner.state.borrow(), MachineState::Faulted(_)) {
            tracing::debug!("machine faulted again: {reason}");
            return false;
        }
        tracing::warn!("machine faulted: {reason}");
        let state = MachineState::Faulted(reason);
        self.inner.state.send_replace(state.clone());
        let _ = self.inner.events.send(MachineEvent::State(state));
        true
    }

    /// Whether module `module`'s fault of `kind` with `detail` (a
    /// [`MachineEvent::Fault`]) stops this machine: every fault does but
    /// late steps within `[limits] max_late_steps` and a refusal for a
    /// motor the machine file leaves disabled.
    pub fn fault_stops(&self, module: &str, kind: events::FaultKind, detail: u32) -> bool {
        stops_motion(&self.inner, module, kind, detail)
    }

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

    /// The simulated machine underneath, when simulated: runs `f` on it.
    pub fn with_sim<R>(&self, f: impl FnOnce(&SimMachine) -> R) -> Option<R> {
        let sim = self.inner.sim.lock().unwrap_or_else(|e| e.into_inner());
        sim.as_ref().map(f)
    }

    /// Where the simulated machine's carriage really is on `axis`, axis
    /// units, from its motors' steps (not from the plan): what a dial
    /// gauge on the real machine would read. `None` when the machine is
    /// not simulated, for an axis it does not have, or for scara and
    /// fivebar x and y (not linear in the motors).
    pub fn sim_axis_position(&self, axis: &str) -> Option<f64> {
        let form = crate::sim::axis_form(self.config(), axis).ok()?;
        self.with_sim(|s| {
            form.value(|module| {
                s.module(module)
                    .and_then(|sm| sm.module())
                    .map_or(f64::NAN, |sm| sm.lock(|mm| mm.board().motor().position()))
            })
        })
        .filter(|v| v.is_finite())
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
                if lock_motion(&self.inner.motion).planner.is_idle() {
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

    /// The synchronized system time, µs.
    pub async fn now_us(&self) -> Result<u64, MachineError> {
        Ok(self.inner.host.system_time().await?.as_micros())
    }

    fn check_running(&self) -> Result<(), MachineError> {
        match &*self.inner.state.borrow() {
            MachineState::Faulted(r) => Err(MachineError::Faulted(r.clone())),
            MachineState::Stopped => Err(MachineError::Stopped),
            _ => Ok(()),
        }
    }

    /// Checks a target: one coordinate per axis, within travel, homed.
    fn check_target(&self, target: &[f64]) -> Result<[f64; MAX_AXES], MachineError> {
        let axes = self.axes();
        if target.len() != axes.len() {
            return Err(MachineError::WrongAxisCount {
                expected: axes.len(),
                axes: axes.join(", "),
                got: target.len(),
            });
        }
        let homed = self.inner.homed.lock().unwrap_or_else(|e| e.into_inner());
        let mut out = [0.0; MAX_AXES];
        for (k, (name, &v)) in axes.iter().zip(target).enumerate() {
            let a = &self.inner.cfg.axes[name];
            if !homed[k] {
                return Err(MachineError::NotHomed(name.clone()));
            }
            if !(v.is_finite() && a.min <= v && v <= a.max) {
                return Err(MachineError::OutOfTravel {
                    axis: name.clone(),
                    value: v,
                    min: a.min,
                    max: a.max,
                });
            }
            out[k] = v;
        }
        Ok(out)
    }

    fn check_rate(rate: f64) -> Result<f64, MachineError> {
        if rate.is_finite() && rate > 0.0 {
            Ok(rate)
        } else {
            Err(MachineError::BadRate(rate))
        }
    }

    /// Waits until the planner has room for `n` more segments.
    async fn wait_for_room(&self, n: usize) -> Result<(), MachineError> {
        let room = maxl::blocks::planner::DEFAULT_CAPACITY - 1;
        self.wait_queued_at_most(room.saturating_sub(n)).await
    }

    /// Segments queued and not yet handed to the motors (a straight move
    /// is one; an arc is one per chord).
    pub fn queued_moves(&self) -> usize {
        lock_motion(&self.inner.motion).planner.stats().pending
    }

    /// Waits until at most `n` segments are queued ahead of the motors.
    /// The queue holds thousands of moves; a script that generates motion
    /// without end (a soak, a jog, a sensor-driven path) waits here to stay
    /// a few moves ahead rather than minutes ahead. Fails if the machine
    /// stops meanwhile.
    pub async fn wait_queued_at_most(&self, n: usize) -> Result<(), MachineError> {
        let mut status = self.inner.status.clone();
        loop {
            self.check_running()?;
            if self.queued_moves() <= n {
                return Ok(());
            }
            status.changed().await.map_err(|_| MachineError::Stopped)?;
        }
    }

    /// Queues a straight move to `target` (one coordinate per axis) at up to
    /// `rate` units/s, planned with lookahead after the moves queued before
    /// it. Returns once queued (waiting for room in the queue if needed).
    pub async fn goto_via_queue(
        &self,
        target: impl AsRef<[f64]>,
        rate: f64,
    ) -> Result<(), MachineError> {
        let to = self.check_target(target.as_ref())?;
        let rate = Self::check_rate(rate)?;
        self.wait_for_room(1).await?;
        self.check_running()?;
        let mut m = lock_motion(&self.inner.motion);
        m.planner.line(to, rate)?;
        m.mark_busy();
        Ok(())
    }

    /// [`Machine::goto_via_queue`]: a queued straight line.
    pub async fn line(&self, target: impl AsRef<[f64]>, rate: f64) -> Result<(), MachineError> {
        self.goto_via_queue(target, rate).await
    }

    /// Queues an arc in the xy plane around `center` (x, y) to `target`
    /// (other axes move linearly), chorded within 2 µm.
    pub async fn arc(
        &self,
        target: impl AsRef<[f64]>,
        center: [f64; 2],
        clockwise: bool,
        rate: f64,
    ) -> Result<(), MachineError> {
        let to = self.check_target(target.as_ref())?;
        let rate = Self::check_rate(rate)?;
        if self.axes().len() < 2 {
            return Err(MachineError::Unsupported(
                "arcs need two axes (x and y)".into(),
            ));
        }
        let arc = PlanArc {
            end: to,
            plane: (0, 1),
            center,
            clockwise,
            chord_tolerance: 0.002,
        };
        // The arc's bulge must stay within travel too.
        let tail = lock_motion(&self.inner.motion).planner.tail();
        let chords = arc.chords(tail)?;
        let n = target.as_ref().len();
        for p in &chords {
            self.check_target(&p[..n])?;
        }
        self.wait_for_room(chords.len()).await?;
        self.check_running()?;
        let mut m = lock_motion(&self.inner.motion);
        m.planner.arc(&arc, rate)?;
        m.mark_busy();
        Ok(())
    }

    /// Waits until every queued move has run and the motors stand, then
    /// `seconds` longer.
    pub async fn dwell(&self, seconds: f64) -> Result<(), MachineError> {
        self.idle().await?;
        if seconds.is_finite() && seconds > 0.0 {
            tokio::time::sleep(Duration::from_secs_f64(seconds)).await;
        }
        Ok(())
    }

    /// Moves to `target` now and waits until the machine stands there:
    /// moves still queued are stopped first (a controlled stop).
    pub async fn goto_now(&self, target: impl AsRef<[f64]>, rate: f64) -> Result<(), MachineError> {
        let to = self.check_target(target.as_ref())?;
        let rate = Self::check_rate(rate)?;
        self.check_running()?;
        {
            let mut m = lock_motion(&self.inner.motion);
            m.planner.halt()?;
            m.planner.line(to, rate)?;
            m.mark_busy();
        }
        self.idle().await
    }

    /// Waits until every queued move has run and the motors stand at the
    /// end. Woken by the motion source's reports, not by polling; fails if
    /// the machine faults meanwhile.
    pub async fn idle(&self) -> Result<(), MachineError> {
        let mut status = self.inner.status.clone();
        let mut state = self.inner.state.subscribe();
        let rest = loop {
            self.check_running()?;
            let s = *status.borrow_and_update();
            let idle = lock_motion(&self.inner.motion).planner.is_idle();
            if idle && !s.busy && s.rest_stamp != 0 {
                break s.rest_stamp;
            }
            tokio::select! {
                r = status.changed() => r.map_err(|_| MachineError::Stopped)?,
                r = state.changed() => r.map_err(|_| MachineError::Stopped)?,
            }
        };
        self.wait_motors_past(rest).await?;
        self.check_running()
    }

    /// Stops motion: every axis decelerates within its limits along the
    /// path and queued moves are dropped. Returns once the motors stand
    /// (homing and probing stop a seek this way; [`Machine::halt`] also
    /// halts every module and switches every tool off).
    pub(crate) async fn stop_motion(&self) -> Result<(), MachineError> {
        {
            let mut m = lock_motion(&self.inner.motion);
            m.planner.halt()?;
            m.mark_busy();
        }
        let mut status = self.inner.status.clone();
        loop {
            let s = *status.borrow_and_update();
            if lock_motion(&self.inner.motion).planner.is_idle() && !s.busy {
                break;
            }
            status.changed().await.map_err(|_| MachineError::Stopped)?;
        }
        let rest = status.borrow().rest_stamp;
        self.wait_motors_past(rest).await
    }

    /// Sleeps until the motors have run the points up to stamp `rest`: a
    /// module evaluates a point two intervals after its stamp.
    async fn wait_motors_past(&self, rest: u64) -> Result<(), MachineError> {
        let done = rest + 2 * u64::from(INTERVAL_US);
        let now = self.now_us().await?;
        if done > now {
            tokio::time::sleep(Duration::from_micros(done - now)).await;
        }
        self.confirm_motors_report().await
    }

    /// Waits for a status report from every motor module sent after now:
    /// the time alone says the motion should have run, a report says the
    /// module was there to run it. A module silent for the link-loss time
    /// faults the machine, as the watchdog would.
    async fn confirm_motors_report(&self) -> Result<(), MachineError> {
        let since = tokio::time::Instant::now();
        let deadline = since + LINK_LOST_AFTER;
        let keys: Vec<String> = lock_motion(&self.inner.motion)
            .drive
            .motors()
            .iter()
            .map(|m| m.module.clone())
            .collect();
        loop {
            self.check_running()?;
            let silent = {
                let r = monitor::lock(&self.inner.reports);
                keys.iter()
                    .find(|k| r.seen.get(*k).is_none_or(|s| s.2 < since))
                    .cloned()
            };
            let Some(key) = silent else {
                return Ok(());
            };
            if tokio::time::Instant::now() >= deadline {
                let _ = self.inner.events.send(MachineEvent::LinkLost {
                    module: key.clone(),
                });
                let reason = format!("module {key} stopped answering");
                self.fault_and_stop(reason.clone());
                return Err(MachineError::Faulted(reason));
            }
            // Reports come every status period; look again at half that.
            tokio::time::sleep(Duration::from_micros(u64::from(STATUS_PERIOD_US / 2))).await;
        }
    }

    /// Moves one axis by `delta` and waits until it stands. A homed axis
    /// stays within its travel; an axis not yet homed moves relative to
    /// wherever it is (the machine cannot know its travel then: watch it).
    pub async fn jog(&self, axis: &str, delta: f64, rate: f64) -> Result<(), MachineError> {
        let k = self
            .axes()
            .iter()
            .position(|a| a == axis)
            .ok_or_else(|| MachineError::UnknownAxis(axis.into()))?;
        let rate = Self::check_rate(rate)?;
        if !delta.is_finite() {
            return Err(MachineError::OutOfTravel {
                axis: axis.into(),
                value: delta,
                min: f64::NEG_INFINITY,
                max: f64::INFINITY,
            });
        }
        self.check_running()?;
        self.idle().await?;
        let homed = self.inner.homed.lock().unwrap_or_else(|e| e.into_inner())[k];
        {
            let mut m = lock_motion(&self.inner.motion);
            let mut to = m.planner.tail();
            to[k] += delta;
            if homed {
                let a = &self.inner.cfg.axes[axis];
                if !(a.min..=a.max).contains(&to[k]) {
                    return Err(MachineError::OutOfTravel {
                        axis: axis.into(),
                        value: to[k],
                        min: a.min,
                        max: a.max,
                    });
                }
            }
            m.planner.line(to, rate)?;
            m.mark_busy();
        }
        self.idle().await
    }

    /// Which axes have homing configured (axis order).
    fn homing_axes(&self) -> Vec<bool> {
        let cfg = &self.inner.cfg;
        cfg.axis_names()
            .iter()
            .map(|a| cfg.axes[*a].homing.is_some())
            .collect()
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
        if !m.planner.is_idle() {
            return Err(MachineError::Plan(maxl::blocks::planner::PlanError::Busy));
        }
        let mut p = [0.0; MAX_AXES];
        p[..at.len()].copy_from_slice(at);
        let motors = m.last_motors.clone();
        m.drive.rebase(at, &motors)?;
        m.planner.set_position(p)?;
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

    /// Calls function `function` on module `key` (of `[modules]`).
    pub async fn call(
        &self,
        key: &str,
        function: &str,
        args: &[Value<'static>],
    ) -> Result<Vec<Value<'static>>, MachineError> {
        self.call_as(key, function, args, false).await
    }

    /// [`call`](Self::call) for a function that sets or reads a value,
    /// asked again if its reply is lost (a noisy link must not fail a
    /// recovery).
    async fn call_idempotent(
        &self,
        key: &str,
        function: &str,
        args: &[Value<'static>],
    ) -> Result<Vec<Value<'static>>, MachineError> {
        self.call_as(key, function, args, true).await
    }

    async fn call_as(
        &self,
        key: &str,
        function: &str,
        args: &[Value<'static>],
        idempotent: bool,
    ) -> Result<Vec<Value<'static>>, MachineError> {
        let runtime = &self
            .inner
            .modules
            .get(key)
            .ok_or_else(|| MachineError::ModuleNotFound {
                key: key.into(),
                wanted: key.into(),
                found: self
                    .inner
                    .modules
                    .keys()
                    .cloned()
                    .collect::<Vec<_>>()
                    .join(", "),
            })?
            .runtime;
        let h = self
            .inner
            .manager
            .lock()
            .await
            .function(&FnRef::new(runtime.as_str(), function))?;
        let result = if idempotent {
            h.call_idempotent(args).await
        } else {
            h.call(args).await
        };
        result.map_err(|e| som_refusal(key, function, e))
    }

    /// Adds `excitation(stamp)` to the planned machine position at every
    /// control-point stamp from now on (a test signal such as the chirp of
    /// [`crate::resonance`]; the planner does not see it, so keep the
    /// machine at rest meanwhile); `None` removes it.
    pub fn set_excitation(&self, excitation: Option<motion::Excitation>) {
        lock_motion(&self.inner.motion).excitation = excitation;
    }

    /// Starts keeping what was planned and what the motors stepped, for
    /// [`Machine::take_recording`].
    pub async fn start_recording(&self) -> Result<(), MachineError> {
        lock_motion(&self.inner.motion).record = Some(Vec::new());
        let n = lock_motion(&self.inner.motion).drive.motors().len();
        monitor::lock(&self.inner.reports).positions = Some(vec![Vec::new(); n]);
        self.position_reports(InputMode::OnTimer(FAST_PERIOD_US))
            .await
    }

    /// Sets the input mode of every motor module's `get_position` source:
    /// on a timer while recording, idle otherwise (or a recorder's timer,
    /// while one samples it).
    async fn position_reports(&self, mode: InputMode) -> Result<(), MachineError> {
        let motors: Vec<_> = lock_motion(&self.inner.motion).drive.motors().to_vec();
        let mut manager = self.inner.manager.lock().await;
        for m in motors {
            let runtime = &self.inner.modules[&m.module].runtime;
            let f = FnRef::new(runtime.as_str(), "get_position");
            let mode = self.inner.capture_holds.machine_sets(&f, mode);
            manager.set_input_mode(&f, mode).await?;
        }
        Ok(())
    }

    /// Who holds which module function's timer: the recorders'
    /// ([`crate::capture`]) beside the machine's own reports.
    pub(crate) fn capture_holds(&self) -> &crate::capture::Holds {
        &self.inner.capture_holds
    }

    /// What was planned and stepped since [`Machine::start_recording`],
    /// from synchronized time `from_us` on, as machine positions: planned
    /// at every stamp, executed read back from the motors' stepped
    /// positions on a 1 kHz grid. Stops recording.
    pub async fn take_recording(
        &self,
        from_us: u64,
    ) -> Result<crate::record::Recording, MachineError> {
        self.position_reports(InputMode::OnAnyFresh).await?;
        let (planned, drive_axes) = {
            let mut m = lock_motion(&self.inner.motion);
            (m.record.take().unwrap_or_default(), m.drive.axes().to_vec())
        };
        let positions = monitor::lock(&self.inner.reports)
            .positions
            .take()
            .unwrap_or_default();
        let n = drive_axes.len();
        let secs = |t: u64| (t as f64 - from_us as f64) * 1e-6;
        let planned: Vec<crate::record::Sample> = planned
            .iter()
            .filter(|s| s.0 >= from_us)
            .map(|s| crate::record::Sample {
                t: secs(s.0),
                pos: s.1[..n].to_vec(),
            })
            .collect();
        let mut executed = Vec::new();
        let end = positions
            .iter()
            .filter_map(|p| p.last().map(|l| l.0))
            .min()
            .unwrap_or(0);
        if end > from_us && positions.iter().all(|p| !p.is_empty()) {
            let dt = 1e-3;
            let count = ((secs(end) / dt).floor() as usize).saturating_add(1);
            let series: Vec<Vec<f64>> = positions
                .iter()
                .map(|p| {
                    let pts: Vec<(f64, f64)> = p.iter().map(|s| (secs(s.0), s.1)).collect();
                    crate::record::resample_linear(&pts, 0.0, dt, count)
                })
                .collect();
            let m = lock_motion(&self.inner.motion);
            for i in 0..count {
                let motors: Vec<f64> = series.iter().map(|s| s[i]).collect();
                if let Ok(pos) = m.drive.machine_position(&motors) {
                    executed.push(crate::record::Sample {
                        t: i as f64 * dt,
                        pos,
                    });
                }
            }
        }
        Ok(crate::record::Recording {
            axes: drive_axes,
            planned,
            executed,
        })
    }
}

fn lock_motion(m: &SharedMotion) -> std::sync::MutexGuard<'_, motion::Motion> {
    motion::lock(m)
}

/// Pipes module function `function` into host function `to`, outputs
/// `0..n` to inputs `0..n`, and runs it as a source on the module's timer
/// every `period_us` (`None`: not yet; a function without inputs idles in
/// its default input mode).
async fn source(
    manager: &mut Manager,
    runtime: &str,
    function: &str,
    period_us: Option<u32>,
    on_change: bool,
    to: &FnRef,
    n: u8,
) -> Result<(), MachineError> {
    let from = FnRef::new(runtime, function);
    // Pipe first, then the modes: a run before the pipe exists would count
    // as sent, and "on change" would hold back the first report.
    let map: Vec<u8> = (0..n).collect();
    manager
        .connect(&from, to, &map, &map, PipeOptions::default())
        .await?;
    let mode = if on_change {
        OutputMode::OnChange
    } else {
        OutputMode::Always
    };
    manager.set_output_mode(&from, mode).await?;
    if let Some(period) = period_us {
        manager
            .set_input_mode(&from, InputMode::OnTimer(period))
            .await?;
    }
    Ok(())
}

/// Whether a module's fault stops the machine: every kind but late steps
/// within `[limits] max_late_steps`, and a refusal for a disabled motor
/// only when the machine file enables a motor of that module.
fn stops_motion(inner: &Inner, module: &str, kind: events::FaultKind, detail: u32) -> bool {
    use events::FaultKind as K;
    use osap_module::stepper::StepperError as E;
    let code = |e: E| u32::from(e.code());
    match kind {
        K::None => false,
        // Late steps stall a real motor: more than the file allows stop.
        K::StepOverrun => detail > inner.cfg.limits.max_late_steps,
        K::Refused if detail == code(E::Disabled) => lock_motion(&inner.motion)
            .drive
            .motors()
            .iter()
            .any(|m| m.module == module && m.enable),
        K::Refused | K::Backstop | K::LimitHit | K::Halted | K::OverLimit | K::OutputWatchdog => {
            true
        }
    }
}

/// Sets a motor's module up (scale, microsteps, interval, the limits it
/// holds points to, power) and reads where its steps put it.
async fn configure_motor(
    manager: &Manager,
    runtime: &str,
    motor: &drive::DriveMotor,
    limits: Option<ModuleLimits>,
) -> Result<f64, MachineError> {
    let call = |f: &'static str, args: Vec<Value<'static>>| {
        let h = manager.function(&FnRef::new(runtime, f));
        let module = motor.module.clone();
        async move {
            // Each sets a value or reads one: a lost reply is asked again.
            h.map_err(MachineError::Network)?
                .call_idempotent(&args)
                .await
                .map_err(|e| som_refusal(&module, f, e))
        }
    };
    call(
        "set_scale",
        vec![Value::F32(motor.full_steps_per_unit as f32)],
    )
    .await?;
    call("set_microsteps", vec![Value::U16(motor.microsteps)]).await?;
    call("set_interval", vec![Value::U32(INTERVAL_US)]).await?;
    // All three 0 turns a module's limiter off (a reconnect may follow a
    // machine file that had limits).
    let l = limits.unwrap_or(ModuleLimits {
        velocity: 0.0,
        acceleration: 0.0,
        jerk: 0.0,
    });
    call(
        "set_limits",
        [l.velocity, l.acceleration, l.jerk]
            .map(|x| Value::F32(x as f32))
            .to_vec(),
    )
    .await?;
    call("set_enable", vec![Value::Bool(motor.enable)]).await?;
    let out = call("get_position", vec![]).await?;
    stop::stepped_position(&motor.module, &out)
}

/// Room kept beyond a motor's span over the travel: stopping past a
/// switch, backing off.
const RANGE_MARGIN: f64 = 1.05;

/// A module's track holds ±32 767 microsteps: refuse a machine whose
/// travel would not fit.
fn check_track_range(cfg: &MachineFile, drive: &Drive) -> Result<(), MachineError> {
    // The motor's span over the whole travel box (a grid over it, for
    // arms). A motor reads 0 where it booted, somewhere in that box, so
    // it stays within ±span (plus a little for stopping past a switch).
    let axes = drive.axes();
    let n = axes.len();
    let steps = 8usize;
    let mut lo = vec![f64::INFINITY; drive.motors().len()];
    let mut hi = vec![f64::NEG_INFINITY; drive.motors().len()];
    let total = (steps + 1).pow(n as u32);
    for idx in 0..total {
        let mut k = idx;
        let mut p = vec![0.0; n];
        for (j, name) in axes.iter().enumerate() {
            let a = &cfg.axes[name];
            let f = (k % (steps + 1)) as f64 / steps as f64;
            k /= steps + 1;
            p[j] = a.min + f * (a.max - a.min);
        }
        if let Ok(m) = drive.motor_positions(&p) {
            for (i, v) in m.iter().enumerate() {
                lo[i] = lo[i].min(*v);
                hi[i] = hi[i].max(*v);
            }
        }
    }
    for (i, motor) in drive.motors().iter().enumerate() {
        let span = (hi[i] - lo[i]).max(0.0);
        let per_unit = motor.full_steps_per_unit * f64::from(motor.microsteps);
        let need = RANGE_MARGIN * span * per_unit;
        let room = osap_module::stepper::MAX_STEPS;
        if need > room {
            let fit = (room / (RANGE_MARGIN * span * motor.full_steps_per_unit)).floor();
            let fit = (0..9)
                .map(|e| 1u32 << e)
                .filter(|m| f64::from(*m) <= fit)
                .max();
            return Err(MachineError::Unsupported(format!(
                "motors.{}: the travel spans {span:.1} units of this motor: {:.0} microsteps at {} full steps × {} microsteps per unit, and a module's track holds ±{room:.0} microsteps from where it booted. {}",
                motor.name,
                span * per_unit,
                motor.full_steps_per_unit,
                motor.microsteps,
                match fit {
                    Some(m) => format!("Set microsteps = {m} (or fewer)."),
                    None => "Use a coarser drive (fewer full steps per unit).".into(),
                }
            )));
        }
    }
    Ok(())
}
