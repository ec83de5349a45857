//! Every stop stops everything: an emergency stop, a halt, a fault and a
//! lost module halt every module of the machine at once and switch every
//! tool off, and say which modules confirmed; a module whose host goes
//! quiet puts its tools to their safe values by itself; every module is
//! watched, a tool's too; late steps past the machine file's bound stop
//! the machine. On the simulated plotter (and a fast lead-screw axis), in
//! virtual time, reading the simulated boards' outputs.

use std::time::Duration;

use osap_machine::config::MachineFile;
use osap_machine::machine::events::FaultKind;
use osap_machine::sim::SimOptions;
use osap_machine::{Machine, MachineError, MachineEvent, MachineState};
use osap_sim::machine::{virtual_runtime, Fault};
use tokio::sync::broadcast;

fn plotter_file() -> MachineFile {
    MachineFile::load(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/machines/plotter.toml"
    ))
    .unwrap()
}

async fn simulate(cfg: &MachineFile) -> Machine {
    Machine::simulate_with(cfg, SimOptions::VIRTUAL)
        .await
        .unwrap()
}

/// A PWM duty as the simulated board holds it (of 65 535).
fn duty(d: f64) -> u16 {
    (d as f32 * 65_535.0 + 0.5) as u16
}

/// Module `name`'s PWM output 0 on its simulated board, from a handle
/// that outlives the machine.
fn pwm0(module: &osap_sim::machine::SimModule) -> u16 {
    module.module().unwrap().lock(|m| m.board().pins().pwm()[0])
}

fn sim_module(m: &Machine, name: &str) -> osap_sim::machine::SimModule {
    m.with_sim(|s| s.module(name).cloned()).flatten().unwrap()
}

/// Module `name`'s latest fault record: (time, kind code, detail, count).
fn fault_record(m: &Machine, name: &str) -> (u64, u8, u32, u32) {
    sim_module(m, name)
        .module()
        .unwrap()
        .lock(|mm| mm.get_fault())
        .unwrap()
}

/// The next stop report on `events`.
async fn next_stop(events: &mut broadcast::Receiver<MachineEvent>) -> osap_machine::StopReport {
    loop {
        if let MachineEvent::Stop(report) = events.recv().await.unwrap() {
            return report;
        }
    }
}

fn unreached(report: &osap_machine::StopReport) -> Vec<&str> {
    report
        .unreachable
        .iter()
        .map(|u| u.module.as_str())
        .collect()
}

#[test]
fn an_emergency_stop_reaches_every_module_at_once_past_one_that_does_not_answer() {
    virtual_runtime().unwrap().block_on(async {
        let m = simulate(&plotter_file()).await;
        let z = sim_module(&m, "z");
        let mut events = m.events();
        m.set_position([20.0, 75.0]).unwrap();
        let pen = m.tool("pen").unwrap();
        pen.on().await.unwrap();
        assert_eq!(pwm0(&z), duty(0.075));
        m.goto_via_queue([180.0, 75.0], 50.0).await.unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
        // Module a's loop hangs: its halt goes unanswered.
        let faults = m.with_sim(|s| s.injector()).unwrap();
        faults.inject(&Fault::Freeze("a".into())).await.unwrap();
        let t0 = m.now_us().await.unwrap();
        let e = m.emergency_stop().await.unwrap_err();
        let took = m.now_us().await.unwrap() - t0;
        let MachineError::StopIncomplete(report) = &e else {
            panic!("{e}")
        };
        assert_eq!(report.confirmed, ["b", "z"], "{report}");
        assert_eq!(unreached(report), ["a"], "{report}");
        assert_eq!(&next_stop(&mut events).await, report);
        // The halt of a was asked three times (200 ms each) before the stop
        // gave it up; b and z were halted at once meanwhile, not after it.
        assert!(took >= 600_000, "{took} µs");
        for key in ["b", "z"] {
            let (time, code, ..) = fault_record(&m, key);
            assert_eq!(code, FaultKind::Halted.code(), "{key}");
            assert!(
                time >= t0 && time - t0 < 5_000,
                "module {key} halted {} µs after the stop began",
                time as i64 - t0 as i64
            );
        }
        // The pen is up: its off duty, not 0.
        assert_eq!(pwm0(&z), duty(0.05));
        assert_eq!(pen.level(), 0.0);
        assert_eq!(
            m.state(),
            MachineState::Faulted("emergency stop".into()),
            "the machine's own halts are no faults of their own"
        );
        // The machine's own halts come as the stop report, not as faults.
        while let Ok(e) = events.try_recv() {
            assert!(
                !matches!(
                    e,
                    MachineEvent::Fault {
                        kind: FaultKind::Halted,
                        ..
                    }
                ),
                "{e:?}"
            );
        }
        faults.inject(&Fault::Thaw("a".into())).await.unwrap();
        m.recover().await.unwrap();
        m.goto_now([60.0, 75.0], 50.0).await.unwrap();
        m.stop().await.unwrap();
    });
}

#[test]
fn a_halt_stops_every_module_switches_the_pen_off_and_moves_resume() {
    virtual_runtime().unwrap().block_on(async {
        let m = simulate(&plotter_file()).await;
        let z = sim_module(&m, "z");
        let mut events = m.events();
        m.set_position([20.0, 75.0]).unwrap();
        // Where the machine believes it is, less where the carriage is.
        let off = [
            20.0 - m.sim_axis_position("x").unwrap(),
            75.0 - m.sim_axis_position("y").unwrap(),
        ];
        let pen = m.tool("pen").unwrap();
        pen.on().await.unwrap();
        m.goto_via_queue([180.0, 75.0], 100.0).await.unwrap();
        tokio::time::sleep(Duration::from_millis(400)).await;
        let report = m.halt().await.unwrap();
        assert_eq!(report.confirmed, ["a", "b", "z"], "{report}");
        assert!(report.is_complete());
        assert_eq!(pwm0(&z), duty(0.05));
        for key in ["a", "b", "z"] {
            assert_eq!(fault_record(&m, key).1, FaultKind::Halted.code(), "{key}");
        }
        // Stopped short, set up again where the motors' steps put them.
        let p = m.position();
        assert!(p[0] > 40.0 && p[0] < 170.0, "{p:?}");
        for (k, axis) in ["x", "y"].into_iter().enumerate() {
            let real = m.sim_axis_position(axis).unwrap() + off[k];
            assert!((p[k] - real).abs() < 0.02, "{axis}: {p:?} vs {real}");
        }
        assert_eq!(m.state(), MachineState::Idle);
        pen.on().await.unwrap();
        m.goto_now([100.0, 75.0], 100.0).await.unwrap();
        assert_eq!(pwm0(&z), duty(0.075));
        while let Ok(e) = events.try_recv() {
            assert!(!matches!(e, MachineEvent::Fault { .. }), "{e:?}");
        }
        let report = m.stop().await.unwrap();
        assert_eq!(report.confirmed, ["a", "b", "z"], "{report}");
        assert_eq!(pwm0(&z), duty(0.05));
    });
}

#[test]
fn a_fault_halts_every_module_and_switches_the_pen_off() {
    virtual_runtime().unwrap().block_on(async {
        let m = simulate(&plotter_file()).await;
        let z = sim_module(&m, "z");
        let mut events = m.events();
        m.set_position([20.0, 75.0]).unwrap();
        m.tool("pen").unwrap().on().await.unwrap();
        m.goto_via_queue([180.0, 75.0], 50.0).await.unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
        // Another client halts module a: a fault, which the machine stops
        // on (a controlled stop of the others, then every module halted).
        m.call("a", "halt", &[]).await.unwrap();
        let e = m.idle().await.unwrap_err();
        assert!(
            matches!(&e, MachineError::Faulted(r) if r.starts_with("module a was halted")),
            "{e}"
        );
        let report = next_stop(&mut events).await;
        assert!(report.reason.starts_with("module a was halted"), "{report}");
        assert_eq!(report.confirmed, ["a", "b", "z"], "{report}");
        assert_eq!(pwm0(&z), duty(0.05));
        for key in ["b", "z"] {
            assert_eq!(fault_record(&m, key).1, FaultKind::Halted.code(), "{key}");
        }
        m.recover().await.unwrap();
        m.goto_now([60.0, 75.0], 50.0).await.unwrap();
        m.stop().await.unwrap();
    });
}

#[test]
fn a_tool_module_that_vanishes_stops_the_machine_and_its_pen_goes_up_by_itself() {
    virtual_runtime().unwrap().block_on(async {
        let cfg = plotter_file();
        let watchdog = cfg.modules["z"].output_watchdog_ms();
        assert_eq!(watchdog, 500);
        let m = simulate(&cfg).await;
        let z = sim_module(&m, "z");
        let mut events = m.events();
        m.set_position([20.0, 75.0]).unwrap();
        m.tool("pen").unwrap().on().await.unwrap();
        m.goto_via_queue([180.0, 75.0], 50.0).await.unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
        let faults = m.with_sim(|s| s.injector()).unwrap();
        faults.inject(&Fault::Cut("hub-z".into())).await.unwrap();
        // Nothing reaches z now, so no stop can: until its watchdog fires
        // (500 ms after the host's last call, which came at most a quarter
        // of that before the cut), the pen stays down.
        tokio::time::sleep(Duration::from_millis(350)).await;
        assert_eq!(pwm0(&z), duty(0.075));
        tokio::time::sleep(Duration::from_millis(152)).await;
        assert_eq!(pwm0(&z), duty(0.05), "the pen is up by z's own watchdog");
        let (_, code, quiet, _) = fault_record(&m, "z");
        assert_eq!(code, FaultKind::OutputWatchdog.code());
        assert!((500_000..=502_048).contains(&quiet), "{quiet} µs");
        // The host finds z silent and stops the machine.
        let e = m.idle().await.unwrap_err();
        assert!(
            matches!(&e, MachineError::Faulted(r) if r == "module z stopped answering"),
            "{e}"
        );
        let mut lost = false;
        let report = loop {
            match events.recv().await.unwrap() {
                MachineEvent::LinkLost { module } => lost |= module == "z",
                MachineEvent::Stop(report) => break report,
                _ => {}
            }
        };
        assert!(lost);
        assert_eq!(report.confirmed, ["a", "b"], "{report}");
        assert_eq!(unreached(&report), ["z"], "{report}");
        // Back on the network, z is set up again and the pen goes down.
        faults
            .inject(&Fault::Restore("hub-z".into()))
            .await
            .unwrap();
        m.recover().await.unwrap();
        m.tool("pen").unwrap().on().await.unwrap();
        assert_eq!(pwm0(&z), duty(0.075));
        m.goto_now([60.0, 75.0], 50.0).await.unwrap();
        m.stop().await.unwrap();
    });
}

#[test]
fn a_machine_dropped_without_stopping_leaves_its_pen_up_within_the_watchdog() {
    virtual_runtime().unwrap().block_on(async {
        let m = simulate(&plotter_file()).await;
        let z = sim_module(&m, "z");
        // Keeps the simulated network running after the machine is gone.
        let _network = m.with_sim(|s| s.injector()).unwrap();
        m.set_position([20.0, 75.0]).unwrap();
        m.tool("pen").unwrap().on().await.unwrap();
        tokio::time::sleep(Duration::from_millis(1_000)).await;
        // Idle for a second, the pen stays down: the host kept z fed.
        assert_eq!(pwm0(&z), duty(0.075));
        assert_eq!(fault_record(&m, "z").1, FaultKind::None.code());
        // The script ends without stopping the machine (a crash, a ^C).
        drop(m);
        tokio::time::sleep(Duration::from_millis(350)).await;
        assert_eq!(pwm0(&z), duty(0.075));
        tokio::time::sleep(Duration::from_millis(152)).await;
        assert_eq!(pwm0(&z), duty(0.05), "the pen is up by z's own watchdog");
        let (_, code, quiet, _) = z.module().unwrap().lock(|mm| mm.get_fault()).unwrap();
        assert_eq!(code, FaultKind::OutputWatchdog.code());
        assert!((500_000..=502_048).contains(&quiet), "{quiet} µs");
    });
}

/// A SCARA arm on 100:1 harmonic drives (a 1.8° motor: 20 000 full steps
/// a turn, 3 183 per radian) at 64 microsteps: 203 718 microsteps per
/// radian. The machine file's step-rate check cannot bound an arm's joint
/// speeds (they grow without bound near a singular pose), so this arm may
/// be asked for more than the module's 100 000 microsteps/s: at 150 mm/s
/// across the front of its reach its shoulder turns about 1 rad/s. The
/// module's late-step fault is the backstop for such a stream.
const FAST_ARM: &str = r#"
name = "fast-arm"
[modules]
s = { name = "s" }
e = { name = "e" }
[motors.s]
module = "s"
full_steps_per_unit = 3183.1
microsteps = 64
[motors.e]
module = "e"
full_steps_per_unit = 3183.1
microsteps = 64
[kinematics]
type = "scara"
motors = ["s", "e"]
l1 = 100.0
l2 = 100.0
elbow = "left"
[axes.x]
min = 10.0
max = 150.0
velocity = 150.0
acceleration = 3000.0
jerk = 100000.0
[axes.y]
min = -150.0
max = 150.0
velocity = 150.0
acceleration = 3000.0
jerk = 100000.0
[limits]
velocity = 150.0
acceleration = 3000.0
junction_deviation = 0.02
"#;

const ARM_FROM: [f64; 2] = [120.0, -80.0];
const ARM_TO: [f64; 2] = [120.0, 80.0];

#[test]
fn late_steps_past_the_bound_stop_the_machine() {
    virtual_runtime().unwrap().block_on(async {
        let cfg = MachineFile::parse(FAST_ARM).unwrap();
        assert_eq!(cfg.limits.max_late_steps, 0);
        let m = simulate(&cfg).await;
        let mut events = m.events();
        m.set_position(ARM_FROM).unwrap();
        m.goto_via_queue(ARM_TO, 150.0).await.unwrap();
        let e = m.idle().await.unwrap_err();
        assert!(
            // Both joints are asked past the step rate in this sweep (the
            // shoulder at about 1.25 rad/s mid-way, the elbow at up to 1.2
            // rad/s near the ends, against 0.49 rad/s): whichever reports
            // first stops the machine.
            matches!(&e, MachineError::Faulted(r)
            if ["module s", "module e"].iter().any(|m| r.starts_with(&format!(
                "{m} was asked to step faster than its step rate"
            )))),
            "{e}"
        );
        let mut late = None;
        while let Ok(e) = events.try_recv() {
            if let MachineEvent::Fault {
                kind: FaultKind::StepOverrun,
                detail,
                ..
            } = e
            {
                late.get_or_insert(detail);
            }
        }
        assert!(late.is_some_and(|n| n > 0), "{late:?}");
        m.stop().await.unwrap();

        // A bound above what the move sends late: reported, not a stop.
        let loose = FAST_ARM.replace(
            "junction_deviation = 0.02",
            "junction_deviation = 0.02\nmax_late_steps = 1000000",
        );
        let cfg = MachineFile::parse(&loose).unwrap();
        let m = simulate(&cfg).await;
        let mut events = m.events();
        m.set_position(ARM_FROM).unwrap();
        m.goto_via_queue(ARM_TO, 150.0).await.unwrap();
        m.idle().await.unwrap();
        let mut late = Vec::new();
        while let Ok(e) = events.try_recv() {
            if let MachineEvent::Fault {
                kind: FaultKind::StepOverrun,
                detail,
                ..
            } = e
            {
                late.push(detail);
            }
        }
        assert!(
            !late.is_empty() && late.iter().all(|n| *n <= 1_000_000),
            "{late:?}"
        );
        eprintln!(
            "late-step reports in a 160 mm sweep at 150 mm/s: {}, the count reaching {}",
            late.len(),
            late.iter().max().unwrap()
        );
        m.stop().await.unwrap();
    });
}

/// Module `name`'s link counts, all links: (packets in, bytes in,
/// packets out, bytes out).
async fn link_counts(module: &osap_sim::machine::SimModule) -> [u64; 4] {
    module
        .with_runtime(|rt, _| {
            let mut sum = [0u64; 4];
            for c in (0..8).filter_map(|i| rt.link_counters(i)) {
                for (s, v) in sum
                    .iter_mut()
                    .zip([c.received, c.rx_bytes, c.sent, c.tx_bytes])
                {
                    *s += u64::from(v);
                }
            }
            sum
        })
        .await
        .unwrap()
}

/// Module `module`'s traffic per second over `window` seconds from now.
async fn traffic(module: &osap_sim::machine::SimModule, window: f64) -> [f64; 4] {
    let before = link_counts(module).await;
    tokio::time::sleep(Duration::from_secs_f64(window)).await;
    let after = link_counts(module).await;
    [0, 1, 2, 3].map(|i| (after[i] - before[i]) as f64 / window)
}

#[test]
fn an_idle_machine_feeds_its_tool_module_at_a_small_cost() {
    virtual_runtime().unwrap().block_on(async {
        // The same network without a machine: clock sync alone.
        let cfg = plotter_file();
        let host = osap_host::Host::start(osap_host::HostConfig::named("bare")).unwrap();
        let topology = osap_machine::sim::spec(&cfg).unwrap();
        let sim = osap_sim::machine::SimMachine::start(&host, &topology)
            .await
            .unwrap();
        tokio::time::sleep(Duration::from_millis(500)).await;
        let bare = traffic(sim.module("z").unwrap(), 10.0).await;
        sim.stop().await.unwrap();
        // The machine at rest: z is watched (status every 50 ms) and fed
        // (get_status called every 125 ms).
        let m = simulate(&cfg).await;
        m.set_position([20.0, 75.0]).unwrap();
        tokio::time::sleep(Duration::from_millis(500)).await;
        let fed = traffic(&sim_module(&m, "z"), 10.0).await;
        let added: Vec<f64> = (0..4).map(|i| fed[i] - bare[i]).collect();
        eprintln!(
            "module z at rest, per second: clock sync alone {:.1} packets ({:.0} B) in, {:.1} ({:.0} B) out; a machine adds {:.1} ({:.0} B) in, {:.1} ({:.0} B) out",
            bare[0], bare[1], bare[2], bare[3], added[0], added[1], added[2], added[3]
        );
        // In: at least the feeding calls, 8 a second.
        assert!(added[0] >= 8.0, "{added:?}");
        // All the machine's traffic to a module at rest (the feeding, the
        // status reports, the pipes' acknowledgements) stays under 2 % of
        // the 2 Mbaud UART (200 000 B/s).
        assert!(added[1] + added[3] < 0.02 * 200_000.0, "{added:?}");
        m.stop().await.unwrap();
    });
}
