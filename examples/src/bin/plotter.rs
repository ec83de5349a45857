//! A machine script for a CoreXY plotter, run on simulated modules.
//!
//! It starts `osap-sim/topologies/corexy-plotter.toml` (a hub on USB, belt
//! motors `a` and `b` on UARTs, each a stepper module running the module
//! firmware's logic on a simulated board with its own drifting clock), waits
//! for their clocks to follow the host's, powers the motors, wires
//! `Timer → Planner → CoreXY → add_point` with pipes, draws a square with one
//! rounded corner, and compares what the motors did (every step edge, at the
//! true time of its step tick) with the stream they were sent. The calls
//! it makes are the ones module firmware serves (osap-module is shared by
//! firmware and simulator), so on hardware only the start would differ
//! (and the comparison, which reads the simulated motors' step edges);
//! it has not been run on a real board.
//!
//! ```text
//! cargo run -p osap-examples --release --bin plotter -- --out docs/img/plotter.svg
//! ```

use std::error::Error;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use clap::Parser;
use maxl::blocks::interp::InterpolatorBlock;
use maxl::blocks::kinematics::{CoreXy, CoreXyBlock};
use maxl::blocks::planner::PlannerBlock;
use maxl::blocks::timer::TimerBlock;
use osap_host::netrunner::{Netrunner, SyncGoal};
use osap_host::som::{FnRef, Manager, PipeOptions, Value};
use osap_host::{Host, HostConfig};
use osap_sim::machine::SimMachine;
use osap_sim::topology::SimSpec;
use pipes_core::control::{InputMode, OutputMode};
use plotters::prelude::*;

#[derive(Parser, Debug)]
#[command(about = "Draw a shape on a simulated CoreXY plotter and compare executed with sent")]
struct Args {
    /// The SVG of the executed path to write.
    #[arg(long, default_value = "examples-out/plotter.svg")]
    out: PathBuf,
    /// Side of the square (mm).
    #[arg(long, default_value_t = 30.0)]
    side: f64,
    /// Radius of the rounded corner (mm).
    #[arg(long, default_value_t = 8.0)]
    radius: f64,
    /// Feed rate (mm/s).
    #[arg(long, default_value_t = 80.0)]
    feed: f64,
}

/// The axes' control-point interval: the modules' default, µs.
const IV: u32 = 2048;
const HOST: &str = "script";
/// How far the timer leads real time: 16 intervals (33 ms), room for the
/// host to be held up (a simulated machine shares the host's cores).
const LEAD: u32 = 16 * IV;

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> std::process::ExitCode {
    osap_examples::init_logging();
    osap_examples::exit_code(run().await)
}

async fn run() -> Result<(), Box<dyn Error>> {
    let args = Args::parse();
    let (side, r) = (args.side, args.radius);
    if !(side > 0.0 && r >= 0.0 && r < side && args.feed > 0.0) {
        return Err("need side > 0, 0 <= radius < side and feed > 0".into());
    }
    let host = Host::start(HostConfig::named(HOST))?;
    let topology = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../osap-sim/topologies/corexy-plotter.toml"
    );
    let machine = SimMachine::start(&host, &SimSpec::load(topology)?).await?;
    let mut m = Manager::new(&host).await?;
    m.refresh().await?;

    // Motion is keyed by synchronized time: wait until the motors' clocks
    // have settled on the host's (no more steps while settling).
    let nr = Netrunner::new(&host).await?;
    let started = Instant::now();
    for name in ["a", "b"] {
        let route = machine.route_to(name).ok_or("no route")?;
        nr.wait_synchronised(&route, SyncGoal::default()).await?;
    }
    println!(
        "clocks settled {:.2} s after the scan",
        started.elapsed().as_secs_f64()
    );

    // The graph: a timer leading real time by `LEAD`, the planner,
    // CoreXY, both motors, and a reference interpolator of what was sent.
    let timer = m.define_class(TimerBlock::new(IV, LEAD)?).await?;
    let planner = m
        .define_class(PlannerBlock::new(
            300.0,
            300.0,
            20.0,
            3000.0,
            3000.0,
            500.0,
            0.01,
            f64::INFINITY,
        )?)
        .await?;
    let corexy = m.define_class(CoreXyBlock::new(CoreXy::new(1.0)?)).await?;
    let sent = m.define_class(InterpolatorBlock::new(IV, 1 << 15)?).await?;
    let host_fn = |member: Option<&str>| FnRef::new(HOST, member.unwrap_or_default());
    let tick = host_fn(timer.member("tick"));
    let sample = host_fn(planner.member("sample"));
    let inverse = host_fn(corexy.member("inverse"));
    m.set_input_mode(&tick, InputMode::OnTimer(IV / 4)).await?;
    m.set_output_mode(&tick, OutputMode::OnChange).await?;
    // Power the motors (a and b keep the firmware's default scale, 80 full
    // steps per mm, the belts' in the topology).
    for motor in ["a", "b"] {
        m.function(&FnRef::new(motor, "set_enable"))?
            .call(&[Value::Bool(true)])
            .await?;
    }
    let o = PipeOptions::default();
    m.connect(&tick, &sample, &[0], &[0], o).await?;
    m.connect(&sample, &inverse, &[0, 1, 2, 3], &[0, 1, 2, 3], o)
        .await?;
    m.connect(
        &sample,
        &host_fn(sent.member("push")),
        &[0, 1, 2, 3],
        &[0, 1, 2, 3],
        o,
    )
    .await?;
    m.connect(&inverse, &FnRef::new("a", "add_point"), &[0, 1], &[0, 1], o)
        .await?;
    m.connect(&inverse, &FnRef::new("b", "add_point"), &[0, 2], &[0, 1], o)
        .await?;

    // The shape: a square whose last corner is rounded.
    let begin = host.system_time().await?.as_micros();
    {
        let mut p = planner
            .state()
            .lock()
            .map_err(|_| "planner lock poisoned")?;
        p.line(side, 0.0, 0.0, args.feed)?;
        p.line(side, side, 0.0, args.feed)?;
        p.line(0.0, side, 0.0, args.feed)?;
        p.line(0.0, r, 0.0, args.feed)?;
        p.arc(r, 0.0, 0.0, r, r, false, args.feed)?;
    }
    loop {
        tokio::time::sleep(Duration::from_millis(20)).await;
        if planner
            .state()
            .lock()
            .map_err(|_| "planner lock poisoned")?
            .planner()
            .is_idle()
        {
            break;
        }
    }
    let end = host.system_time().await?.as_micros() + u64::from(LEAD);
    while host.system_time().await?.as_micros() < end + u64::from(4 * IV) {
        tokio::time::sleep(Duration::from_millis(10)).await;
    }

    // What ran: each motor's steps, as (true time of the step tick, carriage
    // position after it), from where it booted (0).
    let path = |name: &str| -> Result<Vec<(f64, f64)>, Box<dyn Error>> {
        let sim = machine.module(name).ok_or("no module")?;
        let module = sim.module().ok_or("not a stepper")?;
        let (edges, step) = module.lock(|m| {
            let per_unit = m.board().motor().spec().full_steps_per_unit
                * f64::from(m.board().driver().microsteps());
            (m.board().motor().edges().to_vec(), 1.0 / per_unit)
        });
        let mut p = 0.0;
        Ok(edges
            .iter()
            .map(|e| {
                p += if e.up { step } else { -step };
                (sim.host_time_at(e.local).as_micros() as f64, p)
            })
            .collect())
    };
    let (a, b) = (path("a")?, path("b")?);
    let in_run = |t: f64| t >= begin as f64 && t <= end as f64;
    let reference = sent
        .state()
        .lock()
        .map_err(|_| "interpolator lock poisoned")?
        .clone();
    // Each motor against the stream it was sent (a = x + y, b = x − y), right
    // after each of its steps: half a step (6.25 µm) plus timing.
    let mut worst = 0.0f64;
    for (motor, sign) in [(&a, 1.0), (&b, -1.0)] {
        for &(t, p) in motor.iter().filter(|s| in_run(s.0)) {
            if let Some(k) = reference.0.eval(t as u64) {
                worst = worst.max((p - (k.pos[0] + sign * k.pos[1])).abs());
            }
        }
    }
    // The pen after every step of either motor: each motor stands where its
    // last step left it.
    let at = |path: &[(f64, f64)], t: f64| {
        let i = path.partition_point(|s| s.0 <= t);
        i.checked_sub(1).map_or(0.0, |i| path[i].1)
    };
    let mut times: Vec<f64> = a.iter().chain(&b).map(|s| s.0).collect();
    times.sort_by(f64::total_cmp);
    times.dedup();
    let pen: Vec<(f64, f64)> = std::iter::once(0.0)
        .chain(times)
        .map(|t| {
            let (pa, pb) = (at(&a, t), at(&b, t));
            ((pa + pb) / 2.0, (pa - pb) / 2.0)
        })
        .collect();
    println!(
        "{} pen positions ({} + {} steps) over {:.2} s; worst motor distance from its sent stream at true time: {:.1} µm",
        pen.len(),
        a.len(),
        b.len(),
        (end - begin) as f64 * 1e-6,
        worst * 1e3
    );
    let mut faulted = Vec::new();
    for name in ["a", "b"] {
        let module = machine
            .module(name)
            .and_then(|m| m.module())
            .ok_or("not a stepper")?;
        let (mode, c, steps) = module.lock(|m| {
            (
                m.stepper.mode(),
                m.stepper.counters(),
                m.stepper.step_counts(),
            )
        });
        println!("motor {name}: {mode:?}, {c:?}, steps (net, up, down, late) {steps:?}");
        if c.faults > 0 {
            faulted.push(name);
        }
    }

    let root = SVGBackend::new(&args.out, (640, 640)).into_drawing_area();
    root.fill(&WHITE)?;
    let pad = 0.1 * side;
    let mut chart = ChartBuilder::on(&root)
        .caption("executed path (simulated CoreXY)", ("sans-serif", 20))
        .margin(10)
        .x_label_area_size(30)
        .y_label_area_size(40)
        .build_cartesian_2d(-pad..side + pad, -pad..side + pad)?;
    chart
        .configure_mesh()
        .x_desc("x (mm)")
        .y_desc("y (mm)")
        .draw()?;
    // A point every 0.05 mm of pen travel (under a pixel) keeps the SVG small.
    let mut drawn: Vec<(f64, f64)> = Vec::new();
    for p in pen {
        if drawn
            .last()
            .is_none_or(|q| (p.0 - q.0).hypot(p.1 - q.1) >= 0.05)
        {
            drawn.push(p);
        }
    }
    chart.draw_series(LineSeries::new(drawn, &BLUE))?;
    root.present()?;
    println!("wrote {}", args.out.display());
    machine.stop().await?;
    if !faulted.is_empty() {
        return Err(format!(
            "motor(s) {faulted:?} stopped on their safety backstop: their stream ran dry, \
             so the host fell behind by more than the timer's lead ({} ms); \
             give the machine more CPU or a longer lead, and disable and \
             enable the motor (set_enable) to clear the fault",
            LEAD / 1000
        )
        .into());
    }
    Ok(())
}
