//! Starting a machine, in named phases: find the modules (discover; the
//! waits for their clocks start as soon as the scan places them and run
//! in the background, all at once), set up the motors (configure), build
//! the planner (plan), wire the graph (wire) and its reports (watch), then
//! the rest of the clocks' wait (sync). [`super::phases`] times them.

use maxl::blocks::bedlevel::BedMesh;
use osap_host::HostError;

use super::phases::StartPhases;

use crate::network::modfn::{
    self, add_point, get_counters, get_fault, get_position, level_point, level_read, read_limit,
    set_enable, set_interval, set_limits, set_microsteps, set_scale, ModuleCall,
};

use super::*;

/// How closely a clock must follow its source before motion starts.
pub(super) const SYNC_GOAL: SyncGoal = SyncGoal {
    max_offset: Duration::from_micros(200),
    quiet: Duration::from_millis(200),
    timeout: Duration::from_secs(20),
};

impl Machine {
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

    /// Starts the machine on `host`: its phases in order, then the
    /// machine's own tasks (module watch, output feeding, fault handling).
    /// Each phase is a function of its own, so a caller that wants two to
    /// overlap (clock sync while the motors are configured) can join them.
    pub(crate) async fn start(
        cfg: &MachineFile,
        host: Host,
        links: Vec<osap_host::link::stream::LinkHandle>,
        entry: Entry,
        underneath: Option<Box<dyn Underneath>>,
    ) -> Result<Machine, MachineError> {
        let mut phases = StartPhases::new();
        let start = drive::start_position(cfg);
        let (drive, mesh) = check(cfg, &start)?;
        phases.mark("check");
        // The clocks' waits start as soon as the scan places the modules
        // and run, all at once, while the functions are read and the
        // machine is set up.
        let use_cache = !underneath.as_ref().is_some_and(|u| u.reproducible());
        let (mut manager, modules, waits) =
            discover(cfg, &host, entry, use_cache, &mut phases).await?;
        let motor_at = configure(cfg, &manager, &modules, &drive).await?;
        phases.mark("configure");
        let (motion, status) = plan(cfg, drive, mesh, &start, motor_at)?;
        phases.mark("plan");
        let (events, _) = broadcast::channel(1024);
        let (limit_edges, _) = broadcast::channel(256);
        let reports: SharedReports = Arc::default();
        wire(&mut manager, &modules, &motion).await?;
        phases.mark("wire");
        let monitors = Monitors {
            reports: &reports,
            events: &events,
            limit_edges: &limit_edges,
        };
        watch(cfg, &mut manager, &modules, &motion, monitors).await?;
        phases.mark("watch");
        // Motion is keyed by synchronized time: every module's clock must
        // follow the host's before a point is sent.
        if let Some((began, done)) = sync(&host, waits, &modules).await? {
            phases.synced(began, done);
        }
        phases.mark("clock sync, rest of the wait");
        phases.finish();
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
                expecting_halt: Mutex::default(),
                tools: Mutex::new(tools),
                underneath: Mutex::new(underneath),
                lost: Mutex::default(),
                capture_holds: Default::default(),
                stops: Mutex::default(),
                _links: links,
                watchdog,
                feeders,
                phases,
            }),
        };
        machine.spawn_fault_handler();
        Ok(machine)
    }
}

/// Check: what the machine file asks of the motors fits them, and its bed
/// mesh reads, before any module is touched. Returns the drive
/// (kinematics and motors) at the start position, and the mesh.
fn check(cfg: &MachineFile, start: &[f64]) -> Result<(Drive, Option<BedMesh>), MachineError> {
    let drive = Drive::new(cfg, start).map_err(|e| MachineError::Unsupported(e.to_string()))?;
    let mesh = cfg
        .bed_mesh_path()
        .map(|path| crate::mesh::load(&path))
        .transpose()?;
    Ok((drive, mesh))
}

/// Discover: the network's functions, and each module of `[modules]` on
/// it, checked to be a kind the machine knows. The clock-sync waits of the
/// modules the scan places start before the functions are read.
async fn discover(
    cfg: &MachineFile,
    host: &Host,
    entry: Entry,
    use_cache: bool,
    phases: &mut StartPhases,
) -> Result<(Manager, BTreeMap<String, ModuleInfo>, Option<SyncWaits>), MachineError> {
    let mut manager = Manager::new(host).await?;
    let netrunner = Netrunner::new(host).await?;
    let mut waits = None;
    let start_waits = |map: &osap_host::map::NetworkMap| {
        let som = osap_host::som::Som::from_map(map);
        let routes = crate::network::module_routes(cfg, &som, entry);
        waits = Some(SyncWaits::spawn(netrunner, routes));
    };
    // What earlier starts read of these modules' builds is taken from the
    // cache; what it did not know is read and kept for the next start.
    let cache_path = if use_cache {
        super::som_cache::path(cfg)
    } else {
        None
    };
    let report = match &cache_path {
        Some(path) => {
            let mut cache = super::som_cache::load(path);
            let (report, learnt) = manager.refresh_cached(&mut cache, start_waits).await?;
            if learnt {
                super::som_cache::save(path, &cache);
            }
            report
        }
        None => manager.refresh_with(start_waits).await?,
    };
    phases.add("scan", report.scanned);
    phases.add(
        "read functions",
        report.elapsed.saturating_sub(report.scanned),
    );
    let modules = crate::network::find_modules(cfg, manager.som(), entry)?;
    phases.mark("find modules");
    Ok((manager, modules, waits))
}

/// The modules' clock-sync waits, one task running them all at once;
/// aborted if dropped (a start that failed meanwhile).
struct SyncWaits {
    /// The routes waited for, by module key.
    routes: BTreeMap<String, Route>,
    /// When the waits began.
    began: tokio::time::Instant,
    /// Each module's outcome, and when the last ended.
    task: tokio::task::JoinHandle<(Vec<WaitOutcome>, tokio::time::Instant)>,
}

/// A module's key and how its clock-sync wait ended.
type WaitOutcome = (String, Result<(), HostError>);

impl SyncWaits {
    /// Starts waiting for every clock of `routes` at once.
    fn spawn(netrunner: Netrunner, routes: BTreeMap<String, Route>) -> SyncWaits {
        let waited = routes.clone();
        let task = tokio::spawn(async move {
            let nr = &netrunner;
            let results =
                futures_util::future::join_all(waited.into_iter().map(|(key, route)| async move {
                    let r = nr.wait_synchronised(&route, SYNC_GOAL).await.map(drop);
                    (key, r)
                }))
                .await;
            (results, tokio::time::Instant::now())
        });
        SyncWaits {
            routes,
            began: tokio::time::Instant::now(),
            task,
        }
    }
}

impl Drop for SyncWaits {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// Sync: every module's clock follows the host's. Takes the waits started
/// at the scan (`waits`), and waits for any module they did not cover, all
/// at once. Returns when the waits began and when the last clock was found
/// synchronised (`None` if nothing was waited for).
async fn sync(
    host: &Host,
    waits: Option<SyncWaits>,
    modules: &BTreeMap<String, ModuleInfo>,
) -> Result<Option<(tokio::time::Instant, tokio::time::Instant)>, MachineError> {
    let not_synced = |key: &str, e: HostError| MachineError::NotSynchronised {
        module: key.into(),
        detail: e.to_string(),
    };
    let mut covered = BTreeMap::new();
    let mut window = None;
    if let Some(mut w) = waits {
        let (results, done) = (&mut w.task)
            .await
            .map_err(|e| MachineError::Unsupported(format!("clock-sync wait: {e}")))?;
        for (key, r) in results {
            r.map_err(|e| not_synced(&key, e))?;
        }
        covered = std::mem::take(&mut w.routes);
        window = Some((w.began, done));
    }
    let rest: Vec<(&String, &ModuleInfo)> = modules
        .iter()
        .filter(|(key, m)| covered.get(*key) != Some(&m.route))
        .collect();
    if rest.is_empty() {
        return Ok(window);
    }
    let netrunner = Netrunner::new(host).await?;
    let results = futures_util::future::join_all(
        rest.iter()
            .map(|(_, m)| netrunner.wait_synchronised(&m.route, SYNC_GOAL)),
    )
    .await;
    for ((key, _), r) in rest.iter().zip(results) {
        r.map_err(|e| not_synced(key, e))?;
    }
    let now = tokio::time::Instant::now();
    Ok(Some(window.map_or((now, now), |(began, _)| (began, now))))
}

/// Configure: every module's safe outputs armed, then every motor's
/// scale, microsteps, interval, limits and power. Returns where each motor
/// stands.
async fn configure(
    cfg: &MachineFile,
    manager: &Manager,
    modules: &BTreeMap<String, ModuleInfo>,
    drive: &Drive,
) -> Result<Vec<f64>, MachineError> {
    safe::arm_all(cfg, manager, modules).await?;

    // Motors: scale, microsteps, interval, power; then where they stand.
    let mut motor_at = Vec::new();
    for motor in drive.motors() {
        let runtime = &modules[&motor.module].runtime;
        let limits = module_limits(cfg, &motor.name, INTERVAL_S);
        motor_at.push(configure_motor(manager, runtime, motor, limits).await?);
    }
    heaters::configure_heaters(cfg, manager, modules).await?;
    super::loadcell::configure_loadcell(cfg, manager, modules).await?;
    super::probing::configure_probe_cell(cfg, manager, modules).await?;
    Ok(motor_at)
}

/// Plan: the drive re-based on where the motors stand (and on the bed
/// mesh), under the lookahead planner at the start position.
fn plan(
    cfg: &MachineFile,
    drive: Drive,
    mesh: Option<BedMesh>,
    start: &[f64],
    motor_at: Vec<f64>,
) -> Result<(SharedMotion, watch::Receiver<MotionStatus>), MachineError> {
    let mut drive = drive;
    drive.rebase(start, &motor_at)?;
    if let Some(mesh) = mesh {
        drive = drive
            .with_mesh(mesh, start, &motor_at)
            .map_err(|e| MachineError::Unsupported(e.to_string()))?;
    }
    let planner = motion::machine_planner(cfg)?;
    let (mut motion, status) = motion::Motion::new(planner, drive, motor_at);
    let mut start3 = [0.0; MAX_AXES];
    start3[..start.len()].copy_from_slice(start);
    motion.set_position(start3)?;
    motion.set_pressure_advance(motion::pressure_advance(cfg)?);
    motion
        .set_shapers(motion::shapers(cfg)?)
        .map_err(|e| MachineError::Unsupported(format!("shaper: {e}")))?;
    motion.tool = streamed_tool(cfg);
    Ok((Arc::new(Mutex::new(motion)), status))
}

/// The tool whose level the machine streams with the motion: its first
/// laser on a PWM output (see [`super::tool_track`]).
fn streamed_tool(cfg: &MachineFile) -> Option<super::tool_track::ToolTrack> {
    let (name, t) = cfg.tools.iter().find(|(_, t)| t.streamed())?;
    let crate::config::Output::Pwm(channel) = t.output else {
        return None;
    };
    Some(super::tool_track::ToolTrack::new(
        name,
        &t.module,
        channel,
        (t.off_duty, t.on_duty),
        cfg.toolhead_axes(),
    ))
}

/// Wire: the host's timer into the motion function, and the motion
/// function's outputs into every motor's `add_point`.
async fn wire(
    manager: &mut Manager,
    modules: &BTreeMap<String, ModuleInfo>,
    motion: &SharedMotion,
) -> Result<(), MachineError> {
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
    let n_motors = lock_motion(motion).drive.motors().len();
    let motion_fn = manager
        .define(motion::function(
            "machine.motion",
            motion.clone(),
            n_motors,
        )?)
        .await?;
    let o = PipeOptions::default();
    // The timer's `tick` answers with its `stamp`.
    manager
        .connect_named(&tick, &motion_fn, &[("stamp", motion::STAMP)], o)
        .await?;
    let motors: Vec<_> = lock_motion(motion).drive.motors().to_vec();
    for (i, motor) in motors.iter().enumerate() {
        let runtime = &modules[&motor.module].runtime;
        let position = motion::motor_output(i);
        manager
            .connect_named(
                &motion_fn,
                &add_point::on(runtime),
                &[
                    (motion::STAMP, add_point::input::time),
                    (&position, add_point::input::position),
                ],
                o,
            )
            .await?;
    }
    // The streamed tool's level points, on the motion's stamps, through
    // the tool function, which sends a point only when it changed.
    let tool = lock_motion(motion).tool.as_ref().map(|t| t.module.clone());
    if let Some(key) = tool {
        let runtime = &modules[&key].runtime;
        let tool_fn = manager
            .define(motion::tool_function("machine.tool")?)
            .await?;
        manager
            .set_output_mode(&tool_fn, OutputMode::OnChange)
            .await?;
        // Its inputs are named as the motion's outputs they take.
        let pairs: Vec<(&str, &str)> = motion::TOOL_OUTPUTS.iter().map(|n| (*n, *n)).collect();
        manager
            .connect_named(&motion_fn, &tool_fn, &pairs, o)
            .await?;
        let [time, channel, before, after] = motion::TOOL_POINT;
        manager
            .connect_named(
                &tool_fn,
                &level_point::on(runtime),
                &[
                    (time, level_point::input::time),
                    (channel, level_point::input::channel),
                    (before, level_point::input::before),
                    (after, level_point::input::after),
                ],
                o,
            )
            .await?;
    }

    Ok(())
}

/// Where the monitors report.
struct Monitors<'a> {
    reports: &'a SharedReports,
    events: &'a broadcast::Sender<MachineEvent>,
    limit_edges: &'a broadcast::Sender<(String, LimitEdge)>,
}

/// Watch: every module's status, counters, faults and switches, and the
/// motors' stepped positions, piped into the machine's monitors.
async fn watch(
    cfg: &MachineFile,
    manager: &mut Manager,
    modules: &BTreeMap<String, ModuleInfo>,
    motion: &SharedMotion,
    m: Monitors<'_>,
) -> Result<(), MachineError> {
    let Monitors {
        reports,
        events,
        limit_edges,
    } = m;
    let motors: Vec<_> = lock_motion(motion).drive.motors().to_vec();
    // What each motor module's point refusals mean, by its own table.
    for motor in &motors {
        let runtime = &modules[&motor.module].runtime;
        let table = manager
            .function(&add_point::on(runtime))?
            .failure_table()
            .await;
        if let Some(table) = table {
            monitor::lock(reports)
                .point_refusals
                .insert(motor.module.clone(), table);
        }
    }
    // Reports from the modules.
    liveness::status_reports(manager, modules, reports).await?;
    for motor in &motors {
        let runtime = modules[&motor.module].runtime.clone();
        let key = motor.module.as_str();
        let counters_fn = manager
            .define(monitor::counters(key, reports.clone(), events.clone())?)
            .await?;
        source::<get_counters::Inputs>(
            manager,
            &runtime,
            Some(STATUS_PERIOD_US),
            true,
            &counters_fn,
        )
        .await?;
    }
    for (i, motor) in motors.iter().enumerate() {
        let runtime = modules[&motor.module].runtime.clone();
        let f = manager
            .define(monitor::position(&motor.name, i, reports.clone())?)
            .await?;
        // Wired now, run only while recording (start_recording): at
        // 1 kHz per motor it is most of a simulation's work otherwise.
        source::<get_position::Inputs>(manager, &runtime, None, true, &f).await?;
    }
    // What the streamed tool's output drives: wired now, run only while
    // recording, as the stepped positions.
    let tool = lock_motion(motion)
        .tool
        .as_ref()
        .map(|t| (t.name.clone(), t.module.clone(), t.channel));
    if let Some((name, key, channel)) = tool {
        let runtime = modules[&key].runtime.clone();
        let f = manager
            .define(monitor::applied(&name, channel, reports.clone())?)
            .await?;
        source::<level_read::Inputs>(manager, &runtime, None, true, &f).await?;
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
    for (key, m) in modules {
        if manager.function(&get_fault::on(&m.runtime)).is_err() {
            continue;
        }
        let watched = switch_modules.contains(&key.as_str());
        let f = manager
            .define(monitor::fault(
                key,
                watched,
                reports.clone(),
                events.clone(),
            )?)
            .await?;
        source::<get_fault::Inputs>(manager, &m.runtime, Some(FAULT_PERIOD_US), true, &f).await?;
    }
    for key in switch_modules {
        let runtime = modules[key].runtime.clone();
        let f = manager
            .define(monitor::limit(key, reports.clone(), limit_edges.clone())?)
            .await?;
        source::<read_limit::Inputs>(manager, &runtime, Some(FAST_PERIOD_US), true, &f).await?;
    }

    Ok(())
}

/// Pipes module function `C` (on `runtime`) into host function `to`, each
/// output into the input of the same name (`to` takes `C`'s outputs), and
/// runs it as a source on the module's timer every `period_us` (`None`:
/// not yet; a function without inputs idles in its default input mode).
pub(super) async fn source<C: ModuleCall>(
    manager: &mut Manager,
    runtime: &str,
    period_us: Option<u32>,
    on_change: bool,
    to: &FnRef,
) -> Result<(), MachineError> {
    let from = FnRef::new(runtime, C::NAME);
    // Pipe first, then the modes: a run before the pipe exists would count
    // as sent, and "on change" would hold back the first report.
    manager
        .connect_named(
            &from,
            to,
            &modfn::same_names::<C::Outputs>(),
            PipeOptions::default(),
        )
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

/// Sets a motor's module up (scale, microsteps, interval, the limits it
/// holds points to, power) and reads where its steps put it.
pub(super) async fn configure_motor(
    manager: &Manager,
    runtime: &str,
    motor: &drive::DriveMotor,
    limits: Option<ModuleLimits>,
) -> Result<f64, MachineError> {
    let module = motor.module.as_str();
    // Each sets a value or reads one: a lost reply is asked again.
    let call = set_scale::Inputs {
        full_steps_per_unit: motor.full_steps_per_unit as f32,
    };
    call_idempotent(manager, runtime, module, call).await?;
    let call = set_microsteps::Inputs {
        microsteps: motor.microsteps,
    };
    call_idempotent(manager, runtime, module, call).await?;
    let call = set_interval::Inputs {
        interval_us: INTERVAL_US,
    };
    call_idempotent(manager, runtime, module, call).await?;
    // All three 0 turns a module's limiter off (a reconnect may follow a
    // machine file that had limits).
    let l = limits.unwrap_or(ModuleLimits {
        velocity: 0.0,
        acceleration: 0.0,
        jerk: 0.0,
    });
    let call = set_limits::Inputs {
        max_vel: l.velocity as f32,
        max_acc: l.acceleration as f32,
        max_jerk: l.jerk as f32,
    };
    call_idempotent(manager, runtime, module, call).await?;
    let call = set_enable::Inputs { on: motor.enable };
    call_idempotent(manager, runtime, module, call).await?;
    let out = call_idempotent(manager, runtime, module, get_position::Inputs {}).await?;
    stop::stepped_position(&motor.module, &out)
}

/// Calls module function `C` on module `module` (at `runtime`) with
/// `inputs`, asking again if a reply is lost (for calls that set or read a
/// value); a refusal is named as the module names it.
pub(super) async fn call_idempotent<C: ModuleCall>(
    manager: &Manager,
    runtime: &str,
    module: &str,
    inputs: C,
) -> Result<Vec<Value<'static>>, MachineError> {
    manager
        .function(&FnRef::new(runtime, C::NAME))
        .map_err(MachineError::Network)?
        .call_idempotent(&inputs.values())
        .await
        .map_err(|e| som_refusal(module, C::NAME, e))
}
