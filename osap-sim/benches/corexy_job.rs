//! A CoreXY motion job on simulated modules, shared by the virtual-time
//! test and benchmark: `Timer → Planner → CoreXY → add_point` pipes on the
//! shipped `corexy-plotter.toml`, squares drawn for a given time, and every
//! step edge the two belt motors took.

// Each includer uses part of it (and cargo also builds it as a bench of
// its own, where nothing does).
#![allow(dead_code)]

use maxl::blocks::kinematics::{CoreXy, CoreXyBlock};
use maxl::blocks::planner::PlannerBlock;
use maxl::blocks::timer::TimerBlock;
use osap_host::netrunner::{Netrunner, SyncGoal};
use osap_host::som::{FnRef, Manager, Value};
use osap_host::{Host, HostConfig};
use osap_sim::machine::board::StepEdge;
use osap_sim::machine::{SimMachine, TimeMode};
use osap_sim::topology::SimSpec;
use pipes_core::control::{InputMode, OutputMode};
use std::path::PathBuf;
use std::time::Duration;

/// Control-point interval, µs (the modules' default).
const IV: u32 = 2048;
/// How far the timer leads the clock: 32 intervals.
const LEAD: u32 = 32 * IV;

/// What a job did.
pub(crate) struct JobRun {
    /// Step edges of motors a and b, in order.
    pub edges: [Vec<StepEdge>; 2],
    /// Faults and refused points on a and b.
    pub faults: u32,
    /// Points refused by a and b.
    pub refused: u32,
    /// Simulated time the job took, from the first line to the last step, s.
    pub simulated_s: f64,
}

/// Runs squares for `seconds` of motion on the CoreXY plotter with link
/// latencies seeded by `seed`, in `mode`.
pub(crate) async fn run(seconds: f64, seed: u64, mode: TimeMode) -> JobRun {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("topologies/corexy-plotter.toml");
    let mut topology = SimSpec::load(path).expect("the shipped topology loads");
    topology.seed = seed;
    let host = Host::start(HostConfig::named("h")).expect("host");
    let sim = SimMachine::start_with(&host, &topology, mode)
        .await
        .expect("machine starts");
    let nr = Netrunner::new(&host).await.expect("netrunner");
    for name in ["a", "b"] {
        let route = sim.route_to(name).expect("route");
        nr.wait_synchronised(&route, SyncGoal::default())
            .await
            .expect("clocks sync");
    }
    let mut m = Manager::new(&host).await.expect("manager");
    m.refresh().await.expect("scan");
    let on_host = |member: &str| FnRef::new("h", member);

    let timer = m
        .define_class(TimerBlock::new(IV, LEAD).expect("timer"))
        .await
        .expect("timer class");
    let tick = on_host(timer.member("tick").expect("tick"));
    m.set_input_mode(&tick, InputMode::OnTimer(IV / 4))
        .await
        .expect("input mode");
    m.set_output_mode(&tick, OutputMode::OnChange)
        .await
        .expect("output mode");
    let planner = m
        .define_class(
            PlannerBlock::new(
                300.0,
                300.0,
                20.0,
                3000.0,
                3000.0,
                500.0,
                0.01,
                f64::INFINITY,
            )
            .expect("planner"),
        )
        .await
        .expect("planner class");
    let corexy = m
        .define_class(CoreXyBlock::new(CoreXy::new(1.0).expect("corexy")))
        .await
        .expect("corexy class");
    let sample = on_host(planner.member("sample").expect("sample"));
    let inverse = on_host(corexy.member("inverse").expect("inverse"));
    for axis in ["a", "b"] {
        m.function(&FnRef::new(axis, "set_enable"))
            .expect("set_enable")
            .call(&[Value::Bool(true)])
            .await
            .expect("enable");
    }
    let pipe = |from: &FnRef, to: FnRef, outputs: &'static [u8], inputs: &'static [u8]| {
        (from.clone(), to, outputs, inputs)
    };
    for (from, to, outputs, inputs) in [
        pipe(&tick, sample.clone(), &[0], &[0]),
        pipe(&sample, inverse.clone(), &[0, 1, 2, 3], &[0, 1, 2, 3]),
        pipe(&inverse, FnRef::new("a", "add_point"), &[0, 1], &[0, 1]),
        pipe(&inverse, FnRef::new("b", "add_point"), &[0, 2], &[0, 1]),
    ] {
        m.connect(&from, &to, outputs, inputs, Default::default())
            .await
            .expect("pipe");
    }
    // System time as µs: the job is paced in plain arithmetic.
    let start = host.system_time().await.expect("time").as_micros();
    let corners = [[20.0, 0.0], [20.0, 20.0], [0.0, 20.0], [0.0, 0.0]];
    let end = start + (seconds * 1e6) as u64;
    // One 20 mm side at 60 mm/s takes a third of a second; keep about a
    // second of lines queued ahead of the motion, as a job reader would.
    let side_us = 20.0 / 60.0 * 1e6;
    let mut k = 0u64;
    loop {
        let now = host.system_time().await.expect("time").as_micros();
        if now >= end {
            break;
        }
        let due = start + (k as f64 * side_us) as u64;
        if due > now + 1_000_000 {
            tokio::time::sleep(Duration::from_micros(due - now - 1_000_000)).await;
            continue;
        }
        let [x, y] = corners[k as usize % corners.len()];
        let queued = planner.state().lock().map(|mut p| p.line(x, y, 0.0, 60.0));
        match queued {
            Ok(Ok(_)) => k += 1,
            _ => tokio::time::sleep(Duration::from_millis(50)).await,
        }
    }
    while !planner
        .state()
        .lock()
        .map(|p| p.planner().is_idle())
        .unwrap_or(true)
    {
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let done =
        host.system_time().await.expect("time").as_micros() + u64::from(LEAD) + 4 * u64::from(IV);
    while host.system_time().await.expect("time").as_micros() < done {
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    let mut faults = 0;
    let mut refused = 0;
    let edges = ["a", "b"].map(|name| {
        let module = sim
            .module(name)
            .and_then(|s| s.module())
            .expect("a stepper");
        module.lock(|m| {
            let c = m.stepper.counters();
            faults += c.faults;
            refused += c.refused;
            m.board().motor().edges().to_vec()
        })
    });
    sim.stop().await.expect("stop");
    JobRun {
        edges,
        faults,
        refused,
        simulated_s: (done - start) as f64 * 1e-6,
    }
}
