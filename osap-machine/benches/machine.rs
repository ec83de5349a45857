//! The machine layer on `examples/machines/plotter.toml`, simulated:
//!
//! 1. **Time to first motion, real time**: from no host at all to the
//!    machine's first planned move being sampled by its motion source, as a
//!    script (or `osap move --sim`) sees it: `Machine::simulate` on a
//!    multi-thread tokio runtime with 2 workers, `set_position` (no
//!    homing), `goto_via_queue` 10 mm in x, then waiting (1 ms polls) until
//!    the planned position moves off the start (`Machine::position`: the
//!    motion source sampled the move, to within one 2 ms interval) and
//!    until a simulated motor takes its first step (the timer's lead
//!    later). Then `Machine::simulate` taken apart: the same steps done with
//!    the public APIs `Machine::start` is built from (host, simulated
//!    modules, scan, clock-sync waits, motor set-up calls, the graph), each
//!    timed; every module's clock traced from boot against the machine's
//!    `SyncGoal`; round trips to a module.
//! 2. **A 10-minute job in virtual time**, run as `osap run --sim --fast`
//!    runs it: a generated G-code hatch over 180 × 130 mm (1 mm chords, the
//!    pen lifted between rows) whose planned duration is at least 600 s, on
//!    `virtual_runtime` with `Machine::simulate_with(.., Virtual)`, homed,
//!    `start_recording`, `run_program`, `take_recording`; wall time and
//!    machine seconds per wall second. With `--variants`, the same job again
//!    with parts of the simulation changed (no homing, the 1 kHz position
//!    reports slowed to 50 Hz, no homing switches), to price them.
//!
//! `cargo bench -p osap-machine --bench machine` (options after `--`):
//! `--quick` (2 start-ups, a 1-minute job), `--reps N` (start-ups),
//! `--rows N` (rows of the hatch; 101 by default), `--only
//! first-motion|job`, `--variants`, `--variant
//! standard|no-home|slow-position-reports|no-switches` (one job run, e.g.
//! under `perf record`).

use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use maxl::blocks::timer::TimerBlock;
use osap_core::clock::SyncState;
use osap_core::route::Route;
use osap_host::netrunner::{self, Netrunner, ScanOptions, SyncGoal};
use osap_host::som::{FnRef, Manager, PipeOptions, Value};
use osap_host::{Host, HostConfig};
use osap_machine::config::MachineFile;
use osap_machine::job::{self, Program};
use osap_machine::machine::monitor::{self, SharedReports};
use osap_machine::machine::motion::{self, Motion};
use osap_machine::machine::{drive, Drive, HOST_NAME, INTERVAL_US, LEAD_US};
use osap_machine::sim::SimOptions;
use osap_machine::{Machine, MachineEvent, MachineState};
use osap_sim::machine::{virtual_runtime, SimMachine, TimeMode};
use pipes_core::control::{InputMode, OutputMode};
use tokio::sync::broadcast;

/// The hatch: x from `X0` to `X0 + W`, rows `PITCH` apart from `Y0`.
const X0: f64 = 10.0;
const W: f64 = 180.0;
const Y0: f64 = 10.0;
const H: f64 = 130.0;
/// Row spacing, mm: 101 rows over 130 mm.
const PITCH: f64 = 1.3;
/// Chord length along a row, mm.
const CHORD: f64 = 1.0;
/// Drawing feed, mm/min (30 mm/s).
const FEED_MM_MIN: f64 = 1800.0;

/// The clock-sync goal `Machine::start` waits for on every module.
const GOAL: SyncGoal = SyncGoal {
    max_offset: Duration::from_micros(200),
    quiet: Duration::from_millis(200),
    timeout: Duration::from_secs(20),
};

struct Args {
    reps: usize,
    rows: usize,
    first_motion: bool,
    job: bool,
    variants: Vec<Variant>,
}

fn args() -> Args {
    let mut a = Args {
        reps: 5,
        rows: (H / PITCH).round() as usize + 1,
        first_motion: true,
        job: true,
        variants: vec![Variant::Standard],
    };
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        match arg.as_str() {
            "--quick" => {
                a.reps = 2;
                a.rows = 10;
            }
            "--reps" => a.reps = it.next().and_then(|v| v.parse().ok()).unwrap_or(a.reps),
            "--rows" => a.rows = it.next().and_then(|v| v.parse().ok()).unwrap_or(a.rows),
            "--only" => match it.next().as_deref() {
                Some("first-motion") => a.job = false,
                Some("job") => a.first_motion = false,
                other => panic!("--only first-motion|job, not {other:?}"),
            },
            "--variants" => a.variants = Variant::ALL.to_vec(),
            "--variant" => {
                let v = it.next();
                a.variants = vec![v.as_deref().and_then(Variant::parse).unwrap_or_else(|| {
                    panic!(
                        "--variant standard|no-home|slow-position-reports|no-switches, not {v:?}"
                    )
                })];
            }
            // `cargo bench` passes `--bench`; ignore anything else too.
            _ => {}
        }
    }
    a.reps = a.reps.max(1);
    a.rows = a.rows.max(1);
    a
}

fn plotter() -> MachineFile {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../examples/machines/plotter.toml");
    MachineFile::load(&path).expect("the example plotter loads")
}

fn multi_thread() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("a tokio runtime")
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// min / median / max of `v`, ms.
fn stats(v: &[f64]) -> (f64, f64, f64) {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    (s[0], s[s.len() / 2], s[s.len() - 1])
}

fn row(name: &str, v: &[f64]) {
    let (lo, med, hi) = stats(v);
    println!("| {name} | {lo:.0} | {med:.0} | {hi:.0} |");
}

/// Milestones of one start-up, from before `Machine::simulate`.
struct FirstMotion {
    /// `Machine::simulate` returned.
    ready: Duration,
    /// `set_position` and `goto_via_queue` returned.
    queued: Duration,
    /// `state()` reported `Moving`.
    moving: Duration,
    /// `position()` left the start: the motion source sampled the move.
    sampled: Duration,
    /// A simulated motor (a or b) took its first step.
    stepped: Duration,
    /// The move faulted after its first step (a host starved by other
    /// load falls behind its timer lead); it does not void the figures
    /// above, and the table says so.
    fault: Option<String>,
    /// `Machine::start_phases`, as `osap run -v` prints them.
    phases: String,
}

/// Steps taken so far by the simulated belt motors.
fn steps(machine: &Machine) -> i64 {
    machine
        .with_sim(|sim| {
            ["a", "b"]
                .iter()
                .filter_map(|n| sim.module(n)?.module())
                .map(|m| m.lock(|m| m.board().motor().steps().abs()))
                .sum()
        })
        .unwrap_or(0)
}

async fn first_motion(cfg: &MachineFile) -> FirstMotion {
    let t0 = Instant::now();
    let machine = Machine::simulate(cfg).await.expect("the machine starts");
    let ready = t0.elapsed();
    let phases = machine.start_phases().to_string();
    let start = drive::start_position(cfg);
    machine.set_position(&start).expect("set_position");
    let mut to = start.clone();
    to[0] += 10.0;
    machine.goto_via_queue(&to, 100.0).await.expect("queued");
    let queued = t0.elapsed();
    assert_eq!(machine.state(), MachineState::Moving);
    let moving = t0.elapsed();
    let mut sampled = None;
    let stepped = loop {
        if sampled.is_none() && (machine.position()[0] - start[0]).abs() > 1e-9 {
            sampled = Some(t0.elapsed());
        }
        if steps(&machine) != 0 {
            break t0.elapsed();
        }
        assert!(t0.elapsed() < Duration::from_secs(30), "no motion in 30 s");
        tokio::time::sleep(Duration::from_millis(1)).await;
    };
    let fault = machine.idle().await.err().map(|e| e.to_string());
    machine.stop().await.expect("stop");
    FirstMotion {
        ready,
        queued,
        moving,
        // A step before the sample was seen: the sample is no later.
        sampled: sampled.unwrap_or(stepped),
        stepped,
        fault,
        phases,
    }
}

/// `Machine::simulate`'s start-up taken apart: the same steps, with the
/// public APIs `Machine::start` is built from, each timed.
struct Phases {
    host: Duration,
    sim: Duration,
    scan: Duration,
    /// `wait_synchronised` on a, b and z one after another, as
    /// `Machine::start` waits.
    sync_sequential: Duration,
    /// The motors' set-up calls (scale, microsteps, interval, enable,
    /// position).
    motor_calls: Duration,
    /// The graph: timer class, motion function, pipes to `add_point`, the
    /// modules' report sources and their modes.
    graph: Duration,
    /// Per module: its clock as polled every 10 ms from the moment the
    /// simulated modules started.
    clocks: Vec<(String, ClockTrace)>,
    /// The three waits at once, on a second machine.
    sync_parallel: Duration,
    /// On that second machine: the network scan alone
    /// (`netrunner::scan`), then `refresh` (scan again, and every PIPES
    /// function's signature, modes and pipes), and how many functions
    /// and runtimes it read.
    network_scan: Duration,
    refresh: Duration,
    functions: usize,
    runtimes: usize,
    /// Round trips to module a once synchronized: a function call
    /// (`get_position`), a control request (`set_output_mode`), a
    /// netresponder query (`clock_status`).
    rtt_call: Duration,
    rtt_control: Duration,
    rtt_query: Duration,
    /// CPU the idle simulated machine and host take, in cores.
    idle_cores: f64,
}

/// What a module's clock did from boot, as the sync goal sees it.
#[derive(Default, Clone)]
struct ClockTrace {
    /// First poll synced (or root) and within the goal's offset.
    first_close: Option<Duration>,
    /// Start of the last stretch of polls that were all synced, within the
    /// offset and without a new hard jump, and that lasted the goal's
    /// quiet time: the earliest a `wait_synchronised` could have returned,
    /// less the quiet time.
    settled_from: Option<Duration>,
    /// Hard jumps, and polls out of the offset bound after `first_close`.
    jumps: u32,
    out_after_close: u32,
    /// The largest |offset| after `first_close`, µs.
    worst_after_close_us: f64,
    /// When each new hard jump was first seen.
    jump_times: Vec<Duration>,
}

/// Polls `route`'s clock every 10 ms for `span`, from `t0`.
async fn trace_clock(host: Host, route: Route, t0: Instant, span: Duration) -> ClockTrace {
    let nr = Netrunner::new(&host).await.expect("netrunner");
    let mut tr = ClockTrace::default();
    let mut good_since: Option<Duration> = None;
    let mut jumps = None;
    while t0.elapsed() < span {
        let Ok(s) = nr.clock_status(&route).await else {
            tokio::time::sleep(Duration::from_millis(10)).await;
            continue;
        };
        let at = t0.elapsed();
        let following = matches!(s.state, SyncState::Synced | SyncState::Root);
        let close = s.offset_ns.unsigned_abs() <= GOAL.max_offset.as_nanos() as u64;
        let jumped = jumps.is_some_and(|j| j != s.stats.jumps);
        if jumped {
            tr.jump_times.push(at);
        }
        jumps = Some(s.stats.jumps);
        tr.jumps = s.stats.jumps;
        if following && close && tr.first_close.is_none() {
            tr.first_close = Some(at);
        }
        if tr.first_close.is_some() {
            if !close {
                tr.out_after_close += 1;
            }
            tr.worst_after_close_us = tr
                .worst_after_close_us
                .max(s.offset_ns.unsigned_abs() as f64 * 1e-3);
        }
        if following && close && !jumped {
            let since = *good_since.get_or_insert(at);
            if tr.settled_from.is_none() && at - since >= GOAL.quiet {
                tr.settled_from = Some(since);
            }
        } else {
            good_since = None;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    tr
}

/// The mean of `n` runs of `f`.
async fn mean<F: std::future::Future<Output = ()>>(n: u32, mut f: impl FnMut() -> F) -> Duration {
    let t = Instant::now();
    for _ in 0..n {
        f().await;
    }
    t.elapsed() / n
}

async fn sim_up(cfg: &MachineFile) -> (Host, SimMachine, Duration, Duration, Instant) {
    let topology = osap_machine::sim::spec(cfg).expect("topology");
    let t = Instant::now();
    let host = Host::start(HostConfig::named(HOST_NAME)).expect("host");
    let host_t = t.elapsed();
    let t = Instant::now();
    let sim = SimMachine::start_with(&host, &topology, TimeMode::RealTime)
        .await
        .expect("simulated modules");
    (host, sim, host_t, t.elapsed(), t)
}

async fn scan(host: &Host) -> (Manager, Duration) {
    let t = Instant::now();
    let mut manager = Manager::new(host).await.expect("manager");
    manager.refresh().await.expect("scan");
    (manager, t.elapsed())
}

/// Pipes module function `function` into host function `to` and sets the
/// source's modes, as `Machine::start` does for each report.
async fn source(m: &mut Manager, runtime: &str, function: &str, period_us: u32, to: &FnRef, n: u8) {
    let from = FnRef::new(runtime, function);
    let map: Vec<u8> = (0..n).collect();
    m.connect(&from, to, &map, &map, PipeOptions::default())
        .await
        .expect("report pipe");
    m.set_output_mode(&from, OutputMode::OnChange)
        .await
        .expect("output mode");
    m.set_input_mode(&from, InputMode::OnTimer(period_us))
        .await
        .expect("input mode");
}

/// `Machine::start` after the clock-sync waits: the motors' set-up calls,
/// then the graph. Returns the two durations.
async fn set_up(cfg: &MachineFile, m: &mut Manager) -> (Duration, Duration) {
    let start = drive::start_position(cfg);
    let mut drv = Drive::new(cfg, &start).expect("drive");
    let motors = drv.motors().to_vec();
    let t = Instant::now();
    let mut at = Vec::new();
    for motor in &motors {
        let call = |f: &str, args: Vec<Value<'static>>| {
            let h = m
                .function(&FnRef::new(motor.module.as_str(), f))
                .expect("function");
            async move { h.call(&args).await.expect("set-up call") }
        };
        call(
            "set_scale",
            vec![Value::F32(motor.full_steps_per_unit as f32)],
        )
        .await;
        call("set_microsteps", vec![Value::U16(motor.microsteps)]).await;
        call("set_interval", vec![Value::U32(INTERVAL_US)]).await;
        call("set_enable", vec![Value::Bool(motor.enable)]).await;
        let out = call("get_position", vec![]).await;
        at.push(out.get(1).and_then(Value::as_f64).unwrap_or(0.0));
    }
    drv.rebase(&start, &at).expect("rebase");
    let calls = t.elapsed();

    let t = Instant::now();
    let planner = job::machine_planner(cfg).expect("planner");
    let (motion, _status) = Motion::new(planner, drv, at);
    let motion = Arc::new(Mutex::new(motion));
    let (events, _) = broadcast::channel::<MachineEvent>(1024);
    let (edges, _) = broadcast::channel(256);
    let reports: SharedReports = Arc::default();
    let timer = m
        .define_class(TimerBlock::new(INTERVAL_US, LEAD_US).expect("timer"))
        .await
        .expect("timer class");
    let tick = FnRef::new(HOST_NAME, timer.member("tick").expect("tick"));
    m.set_input_mode(&tick, InputMode::OnTimer(INTERVAL_US / 4))
        .await
        .expect("tick mode");
    m.set_output_mode(&tick, OutputMode::OnChange)
        .await
        .expect("tick mode");
    let motion_fn = m
        .define(motion::function("machine.motion", motion, motors.len()).expect("motion"))
        .await
        .expect("motion function");
    let o = PipeOptions::default();
    m.connect(&tick, &motion_fn, &[0], &[0], o)
        .await
        .expect("tick pipe");
    for (i, motor) in motors.iter().enumerate() {
        let add_point = FnRef::new(motor.module.as_str(), "add_point");
        let out = u8::try_from(1 + i).expect("few motors");
        m.connect(&motion_fn, &add_point, &[0, out], &[0, 1], o)
            .await
            .expect("motion pipe");
    }
    for motor in &motors {
        let key = motor.module.as_str();
        let f = m
            .define(monitor::status(key, reports.clone()).expect("status"))
            .await
            .expect("define");
        source(m, key, "get_status", 50_000, &f, 4).await;
        let f = m
            .define(monitor::fault(key, false, reports.clone(), events.clone()).expect("fault"))
            .await
            .expect("define");
        source(m, key, "get_fault", 5_000, &f, 4).await;
        let f = m
            .define(monitor::counters(key, reports.clone(), events.clone()).expect("counters"))
            .await
            .expect("define");
        source(m, key, "get_counters", 50_000, &f, 4).await;
    }
    for (i, motor) in motors.iter().enumerate() {
        let f = m
            .define(monitor::position(&motor.name, i, reports.clone()).expect("position"))
            .await
            .expect("define");
        source(m, &motor.module, "get_position", 1_000, &f, 2).await;
    }
    let mut switches: Vec<&str> = cfg
        .axes
        .values()
        .filter_map(|a| a.homing.as_ref()?.switch.as_deref())
        .collect();
    switches.sort();
    switches.dedup();
    for key in switches {
        let f = m
            .define(monitor::limit(key, reports.clone(), edges.clone()).expect("limit"))
            .await
            .expect("define");
        source(m, key, "read_limit", 1_000, &f, 3).await;
    }
    (calls, t.elapsed())
}

async fn phases(cfg: &MachineFile) -> Phases {
    let names: Vec<String> = cfg.modules.keys().cloned().collect();

    // As `Machine::start` does it, with every module's clock traced from
    // the modules' boot (polled every 10 ms) alongside.
    let (host, sim, host_t, sim_t, booted) = sim_up(cfg).await;
    let traces: Vec<_> = names
        .iter()
        .map(|n| {
            let route = sim.route_to(n).expect("route");
            tokio::spawn(trace_clock(
                host.clone(),
                route,
                booted,
                Duration::from_millis(3000),
            ))
        })
        .collect();
    let (mut manager, scan_t) = scan(&host).await;
    let nr = Netrunner::new(&host).await.expect("netrunner");
    let t = Instant::now();
    for n in &names {
        let route = sim.route_to(n).expect("route");
        nr.wait_synchronised(&route, GOAL).await.expect("synced");
    }
    let sync_sequential = t.elapsed();
    let (motor_calls, graph) = set_up(cfg, &mut manager).await;

    let get_position = manager
        .function(&FnRef::new("a", "get_position"))
        .expect("a.get_position");
    let rtt_call = mean(20, || async {
        get_position.call(&[]).await.expect("call");
    })
    .await;
    let get_status = FnRef::new("a", "get_status");
    let t = Instant::now();
    for _ in 0..20 {
        manager
            .set_output_mode(&get_status, OutputMode::Always)
            .await
            .expect("set_output_mode");
    }
    let rtt_control = t.elapsed() / 20;
    let route_a = sim.route_to("a").expect("route");
    let rtt_query = mean(20, || async {
        nr.clock_status(&route_a).await.expect("clock status");
    })
    .await;
    let mut clocks = Vec::new();
    for (n, tr) in names.iter().zip(traces) {
        clocks.push((n.clone(), tr.await.expect("trace")));
    }
    // The graph runs now (timer, motion source, 1 kHz reports): what
    // does the machine at rest cost?
    let cpu = cpu_time();
    let t = Instant::now();
    tokio::time::sleep(Duration::from_secs(1)).await;
    let idle_cores = (cpu_time() - cpu).as_secs_f64() / t.elapsed().as_secs_f64();
    sim.stop().await.expect("stop");
    drop(manager);
    drop(host);

    // The same waits all at once.
    let (host, sim, _, _, _) = sim_up(cfg).await;
    let t = Instant::now();
    netrunner::scan(&host, &ScanOptions::default())
        .await
        .expect("network scan");
    let network_scan = t.elapsed();
    let (manager, refresh) = scan(&host).await;
    let functions = manager
        .som()
        .runtimes
        .iter()
        .map(|r| r.functions.len())
        .sum();
    let runtimes = manager.som().runtimes.len();
    let t = Instant::now();
    let waits: Vec<_> = names
        .iter()
        .map(|n| {
            let host = host.clone();
            let route = sim.route_to(n).expect("route");
            tokio::spawn(async move {
                let nr = Netrunner::new(&host).await.expect("netrunner");
                nr.wait_synchronised(&route, GOAL).await.expect("synced");
            })
        })
        .collect();
    for w in waits {
        w.await.expect("wait");
    }
    let sync_parallel = t.elapsed();
    sim.stop().await.expect("stop");

    Phases {
        host: host_t,
        sim: sim_t,
        scan: scan_t,
        sync_sequential,
        motor_calls,
        graph,
        clocks,
        sync_parallel,
        network_scan,
        refresh,
        functions,
        runtimes,
        rtt_call,
        rtt_control,
        rtt_query,
        idle_cores,
    }
}

fn bench_first_motion(cfg: &MachineFile, reps: usize) {
    println!("## Time to first motion, real time ({reps} start-ups, 2 tokio workers)\n");
    let mut runs = Vec::new();
    for _ in 0..reps {
        let rt = multi_thread();
        runs.push(rt.block_on(first_motion(cfg)));
        rt.shutdown_timeout(Duration::from_secs(1));
    }
    let col = |f: fn(&FirstMotion) -> Duration| runs.iter().map(|r| ms(f(r))).collect::<Vec<_>>();
    let diff = |f: fn(&FirstMotion) -> Duration, g: fn(&FirstMotion) -> Duration| {
        runs.iter().map(|r| ms(f(r) - g(r))).collect::<Vec<_>>()
    };
    println!("| from nothing to | min ms | median ms | max ms |");
    println!("|---|---|---|---|");
    row("`Machine::simulate` returned", &col(|r| r.ready));
    row(
        "move queued (`set_position`, `goto_via_queue`)",
        &col(|r| r.queued),
    );
    row("`state() == Moving`", &col(|r| r.moving));
    row(
        "**first move sampled by the motion source** (`position()` moves)",
        &col(|r| r.sampled),
    );
    row("first step of a simulated motor", &col(|r| r.stepped));
    row("(sampled − queued)", &diff(|r| r.sampled, |r| r.queued));
    row(
        "(stepped − sampled: the timer's lead)",
        &diff(|r| r.stepped, |r| r.sampled),
    );
    let (_, med, _) = stats(&col(|r| r.sampled));
    println!(
        "\ntarget < 2000 ms to the first sampled move: {}\n",
        if med < 2000.0 { "met" } else { "MISSED" }
    );
    for (i, fault) in runs
        .iter()
        .enumerate()
        .filter_map(|(i, r)| Some((i, r.fault.as_ref()?)))
    {
        println!("note: a move faulted after its first step (run {i}): {fault}\n");
    }
    println!("`Machine::start_phases` of each start-up:\n");
    for r in &runs {
        println!("- {}", r.phases);
    }
    println!();

    let n = reps.min(3);
    println!("### `Machine::simulate` taken apart ({n} runs)\n");
    let mut ph = Vec::new();
    for _ in 0..n {
        let rt = multi_thread();
        ph.push(rt.block_on(phases(cfg)));
        rt.shutdown_timeout(Duration::from_secs(1));
    }
    let each = |f: &dyn Fn(&Phases) -> f64| ph.iter().map(f).collect::<Vec<_>>();
    let line = |name: &str, f: &dyn Fn(&Phases) -> f64| {
        let v = each(f);
        let (lo, med, hi) = stats(&v);
        println!("| {name} | {lo:.1} | {med:.1} | {hi:.1} |");
        med
    };
    println!("| phase | min ms | median ms | max ms |");
    println!("|---|---|---|---|");
    let mut total = 0.0;
    total += line("`Host::start`", &|p| ms(p.host));
    total += line(
        "`SimMachine::start_with` (hub + 3 steppers)",
        &|p| ms(p.sim),
    );
    total += line("scan (`Manager::new` + `refresh`)", &|p| ms(p.scan));
    total += line("clock sync: `wait_synchronised` on a, b, z in turn", &|p| {
        ms(p.sync_sequential)
    });
    total += line("motor set-up: 5 calls × 2 motors", &|p| ms(p.motor_calls));
    total += line(
        "graph: timer, motion function, 3 pipes, 8 report sources (pipe + 2 modes each)",
        &|p| ms(p.graph),
    );
    println!("| sum of medians | | {total:.1} | |");
    line("(clock sync: the three waits at once instead)", &|p| {
        ms(p.sync_parallel)
    });
    line("(the network scan alone, `netrunner::scan`)", &|p| {
        ms(p.network_scan)
    });
    line(
        &format!(
            "(`refresh` after it: scan + signature, input mode, output mode and pipe count of each of the {} PIPES functions on {} runtimes, one request at a time)",
            ph[0].functions, ph[0].runtimes
        ),
        &|p| ms(p.refresh),
    );
    println!();

    println!("Each module's clock from the modules' boot, polled every 10 ms (the machine waits for: synced, |offset| ≤ 200 µs and no hard jump, for 200 ms):\n");
    println!("| module | first within 200 µs, ms | quiet from, ms (median) | hard jumps | polls out of bound after | worst offset after, µs |");
    println!("|---|---|---|---|---|---|");
    for (k, (name, _)) in ph[0].clocks.iter().enumerate() {
        let tr: Vec<&ClockTrace> = ph.iter().map(|p| &p.clocks[k].1).collect();
        let opt = |f: &dyn Fn(&ClockTrace) -> Option<Duration>| {
            let v: Vec<f64> = tr.iter().filter_map(|t| f(t)).map(ms).collect();
            if v.is_empty() {
                "never".to_string()
            } else {
                let (lo, med, hi) = stats(&v);
                format!("{med:.0} ({lo:.0}–{hi:.0})")
            }
        };
        println!(
            "| {name} | {} | {} | {} | {} | {:.0} |",
            opt(&|t| t.first_close),
            opt(&|t| t.settled_from),
            tr.iter()
                .map(|t| t.jumps.to_string())
                .collect::<Vec<_>>()
                .join(", "),
            tr.iter()
                .map(|t| t.out_after_close.to_string())
                .collect::<Vec<_>>()
                .join(", "),
            tr.iter()
                .map(|t| t.worst_after_close_us)
                .fold(0.0, f64::max),
        );
    }
    println!();
    for (k, (name, _)) in ph[0].clocks.iter().enumerate() {
        for (r, p) in ph.iter().enumerate() {
            let at: Vec<String> = p.clocks[k]
                .1
                .jump_times
                .iter()
                .map(|d| d.as_millis().to_string())
                .collect();
            println!(
                "- module {name}, run {}: new hard jumps seen at {} ms after boot",
                r + 1,
                at.join(", ")
            );
        }
    }
    println!();

    println!("| round trip to module a (host –USB– hub –UART– a), synchronized | median ms |");
    println!("|---|---|");
    let med = |f: &dyn Fn(&Phases) -> f64| stats(&each(f)).1;
    println!(
        "| PIPES function call (`get_position`) | {:.2} |",
        med(&|p| ms(p.rtt_call))
    );
    println!(
        "| PIPES control request (`set_output_mode`) | {:.2} |",
        med(&|p| ms(p.rtt_control))
    );
    println!(
        "| netresponder query (`clock_status`) | {:.2} |",
        med(&|p| ms(p.rtt_query))
    );
    println!(
        "\nthe simulated machine at rest with its graph running (timer, motion source, 1 kHz reports) takes {:.2} cores\n",
        med(&|p| p.idle_cores)
    );
}

/// The hatch as G-code: per row, pen up, travel to its start, pen down,
/// `CHORD` chords across; alternate rows run back.
fn hatch(rows: usize) -> String {
    let mut g = String::from("G21 G90\n");
    g.push_str(&format!("F{FEED_MM_MIN}\n"));
    let chords = (W / CHORD).round() as usize;
    for r in 0..rows {
        let y = Y0 + r as f64 * PITCH;
        let x_at = |k: usize| {
            let x = X0 + k as f64 * CHORD;
            if r % 2 == 0 {
                x
            } else {
                2.0 * X0 + W - x
            }
        };
        g.push_str("M5\n");
        g.push_str(&format!("G0 X{:.3} Y{y:.3}\n", x_at(0)));
        g.push_str("M3\n");
        for k in 1..=chords {
            g.push_str(&format!("G1 X{:.3}\n", x_at(k)));
        }
    }
    g.push_str(&format!("M5\nG0 X{X0} Y{Y0}\nM2\n"));
    g
}

/// A what-if change to the simulated machine, to measure what a part of
/// the simulation costs (the standard run is `osap run --sim --fast`).
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Variant {
    /// As `osap run --sim --fast`: homed, every report as the machine sets it.
    Standard,
    /// As `osap run --sim --fast --no-home`: `set_position` instead.
    NoHome,
    /// The motors' stepped-position reports every 20 ms instead of 1 ms
    /// (set after homing).
    SlowPositionReports,
    /// No homing switches in the machine file: the simulator publishes no
    /// steps to switch modules (`set_position` instead of homing).
    NoSwitches,
}

impl Variant {
    const ALL: [Variant; 4] = [
        Variant::Standard,
        Variant::NoHome,
        Variant::SlowPositionReports,
        Variant::NoSwitches,
    ];

    fn name(self) -> &'static str {
        match self {
            Variant::Standard => "as `osap run --sim --fast` (homed)",
            Variant::NoHome => "`--no-home` (set_position)",
            Variant::SlowPositionReports => {
                "homed, then stepped-position reports every 20 ms instead of 1 ms"
            }
            Variant::NoSwitches => "no homing switches in the machine file (set_position)",
        }
    }

    fn parse(s: &str) -> Option<Variant> {
        Some(match s {
            "standard" => Variant::Standard,
            "no-home" => Variant::NoHome,
            "slow-position-reports" => Variant::SlowPositionReports,
            "no-switches" => Variant::NoSwitches,
            _ => return None,
        })
    }
}

/// What one run of the job did.
struct JobRun {
    planned: f64,
    machine_s: Duration,
    sync_s: f64,
    motion_s: f64,
    started: Duration,
    homed: Option<(Duration, Duration)>,
    wall: Duration,
    cpu: Duration,
    take: Duration,
    planned_samples: usize,
    executed_samples: usize,
    edges: usize,
    following: Vec<(String, f64)>,
    faults: Vec<String>,
}

async fn run_job(cfg: &MachineFile, program: &Program, variant: Variant) -> JobRun {
    let mut cfg = cfg.clone();
    if variant == Variant::NoSwitches {
        for axis in cfg.axes.values_mut() {
            axis.homing = None;
        }
    }
    let cfg = &cfg;
    let w = Instant::now();
    let machine = Machine::simulate_with(cfg, SimOptions::VIRTUAL)
        .await
        .expect("the machine starts");
    let started = w.elapsed();
    let mut events = machine.events();
    let homed = match variant {
        Variant::Standard | Variant::SlowPositionReports => {
            let w = Instant::now();
            let v = tokio::time::Instant::now();
            machine.home().await.expect("homed");
            Some((w.elapsed(), v.elapsed()))
        }
        Variant::NoHome | Variant::NoSwitches => {
            machine
                .set_position(drive::start_position(cfg))
                .expect("set_position");
            None
        }
    };
    if variant == Variant::SlowPositionReports {
        let mut m = machine.manager().lock().await;
        for module in ["a", "b"] {
            m.set_input_mode(
                &FnRef::new(module, "get_position"),
                InputMode::OnTimer(20_000),
            )
            .await
            .expect("report period");
        }
    }

    let planned = program
        .planned_seconds(cfg, &machine.position())
        .expect("planned");
    machine.start_recording().await.expect("recording");
    let t0 = machine.now_us().await.expect("time");
    let w = Instant::now();
    let v = tokio::time::Instant::now();
    let cpu0 = cpu_time();
    let result = machine.run_program(program, |_| {}).await;
    let cpu = cpu_time() - cpu0;
    let (wall, machine_s) = (w.elapsed(), v.elapsed());
    let t1 = machine.now_us().await.expect("time");
    let w = Instant::now();
    let recording = machine.take_recording(t0).await.expect("recording");
    let take = w.elapsed();
    result.expect("the job runs");

    let mut faults = Vec::new();
    while let Ok(e) = events.try_recv() {
        match e {
            MachineEvent::Fault { module, reason, .. } => {
                faults.push(format!("{module}: {reason}"))
            }
            MachineEvent::LinkLost { module } => faults.push(format!("{module}: link lost")),
            MachineEvent::Refused { module, count, .. } => {
                faults.push(format!("{module}: {count} refused"))
            }
            _ => {}
        }
    }
    faults.dedup();
    let edges: usize = machine
        .with_sim(|sim| {
            ["a", "b"]
                .iter()
                .filter_map(|n| sim.module(n)?.module())
                .map(|m| m.lock(|m| m.board().motor().edges().len()))
                .sum()
        })
        .unwrap_or(0);
    machine.stop().await.expect("stop");
    JobRun {
        planned,
        machine_s,
        sync_s: (t1 - t0) as f64 * 1e-6,
        motion_s: recording.executed_duration(),
        started,
        homed,
        wall,
        cpu,
        take,
        planned_samples: recording.planned.len(),
        executed_samples: recording.executed.len(),
        edges,
        following: recording.following_error(),
        faults,
    }
}

fn print_job(program: &Program, r: &JobRun) {
    let ratio = r.machine_s.as_secs_f64() / r.wall.as_secs_f64();
    println!("| | |");
    println!("|---|---|");
    println!("| moves | {} |", program.moves.len());
    println!(
        "| planned duration (`Program::planned_seconds`) | {:.1} s |",
        r.planned
    );
    println!(
        "| machine time of `run_program` (tokio's clock) | {:.1} s (synchronized clock {:.1} s; recorded motion {:.1} s) |",
        r.machine_s.as_secs_f64(),
        r.sync_s,
        r.motion_s
    );
    println!("| wall: `simulate_with` | {:.0} ms |", ms(r.started));
    if let Some((wall, machine)) = r.homed {
        println!(
            "| wall: `home()` ({:.1} s of machine time) | {:.0} ms |",
            machine.as_secs_f64(),
            ms(wall)
        );
    }
    println!(
        "| **wall: `run_program`** | **{:.1} s** (process CPU {:.1} s) |",
        r.wall.as_secs_f64(),
        r.cpu.as_secs_f64()
    );
    println!("| wall: `take_recording` | {:.0} ms |", ms(r.take));
    println!("| **machine seconds per wall second** | **{ratio:.1}** |");
    println!(
        "| recording | {} planned samples, {} executed samples |",
        r.planned_samples, r.executed_samples
    );
    println!("| step edges (a + b, homing included) | {} |", r.edges);
    for (axis, e) in &r.following {
        println!("| largest following error {axis} | {e:.4} mm |");
    }
    println!(
        "| faults | {} |",
        if r.faults.is_empty() {
            "none".into()
        } else {
            r.faults.join("; ")
        }
    );
    let budget = 60.0 * (r.planned / 600.0).max(0.1);
    println!(
        "\ntarget: under {budget:.0} s of wall time for this job (60 s per 10 min): {}\n",
        if r.wall.as_secs_f64() < budget {
            "met"
        } else {
            "MISSED"
        }
    );
}

/// CPU time of the process (user + system), from /proc (Linux), else 0.
fn cpu_time() -> Duration {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else {
        return Duration::ZERO;
    };
    // Fields after the command's closing parenthesis; utime and stime are
    // the 14th and 15th fields of the whole line.
    let after = stat.rsplit_once(')').map_or("", |p| p.1);
    let f: Vec<&str> = after.split_whitespace().collect();
    let ticks = |i: usize| f.get(i).and_then(|v| v.parse::<u64>().ok()).unwrap_or(0);
    // USER_HZ is 100 on Linux.
    Duration::from_millis((ticks(11) + ticks(12)) * 10)
}

fn bench_job(cfg: &MachineFile, rows: usize, variants: &[Variant]) {
    let start = drive::start_position(cfg);
    let text = hatch(rows);
    let gcode = osap_machine::gcode::read(&text).expect("the hatch reads");
    let program = job::from_gcode(cfg, &gcode, &start).expect("the hatch fits");
    println!(
        "## A hatch job in virtual time (`osap run --sim --fast`): {rows} rows of {W} mm, {PITCH} mm apart, {CHORD} mm chords at {} mm/s, pen up between rows\n",
        FEED_MM_MIN / 60.0
    );
    let mut runs = Vec::new();
    for &v in variants {
        let r = virtual_runtime()
            .expect("a current-thread runtime")
            .block_on(run_job(cfg, &program, v));
        if runs.is_empty() {
            println!("{}:\n", v.name());
            print_job(&program, &r);
        }
        runs.push((v, r));
    }
    if runs.len() > 1 {
        println!("What parts of the simulation cost (the same job, one run each):\n");
        println!("| variant | wall `run_program` s | machine s per wall s | CPU s |");
        println!("|---|---|---|---|");
        for (v, r) in &runs {
            println!(
                "| {} | {:.1} | {:.1} | {:.1} |",
                v.name(),
                r.wall.as_secs_f64(),
                r.machine_s.as_secs_f64() / r.wall.as_secs_f64(),
                r.cpu.as_secs_f64()
            );
        }
        println!();
    }
}

fn main() {
    let a = args();
    let cfg = plotter();
    println!(
        "osap-machine machine bench: {} cores, load average {}\n",
        std::thread::available_parallelism().map_or(0, |n| n.get()),
        std::fs::read_to_string("/proc/loadavg")
            .map(|l| l.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
            .unwrap_or_else(|_| "?".into())
    );
    if a.first_motion {
        bench_first_motion(&cfg, a.reps);
    }
    if a.job {
        bench_job(&cfg, a.rows, &a.variants);
    }
}
