//! The CNC router (examples/machines/router.toml) on simulated modules, in
//! virtual time: its spindle's module measures the speed from the
//! simulated spindle's tachometer pulses (osap-module's `tach_`
//! functions, the same logic as on a board), the machine waits for that
//! measured speed after `M3` (as long as the spindle's physics takes, no
//! settle constant), runs a CAM pocket job, and a stall under a load past
//! the drive's torque is reported and stops the job with the spindle off.

use std::time::Duration;

use osap_machine::config::MachineFile;
use osap_machine::gcode;
use osap_machine::job::{from_gcode, gcode_options, Program};
use osap_machine::sim::SimOptions;
use osap_machine::{Machine, MachineError, MachineEvent, MachineState};
use osap_sim::machine::virtual_runtime;

fn router() -> MachineFile {
    MachineFile::load(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/machines/router.toml"
    ))
    .unwrap()
}

/// Where the simulated router boots: the middle of its travel.
const MIDDLE: [f64; 3] = [300.0, 200.0, -50.0];

async fn start(cfg: &MachineFile) -> Machine {
    let m = Machine::simulate_with(cfg, SimOptions::VIRTUAL)
        .await
        .unwrap();
    m.set_position(MIDDLE).unwrap();
    m
}

fn pocket(cfg: &MachineFile) -> Program {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/jobs/pocket.ngc"
    ))
    .unwrap();
    let g = gcode::read_with(&text, &gcode_options(cfg, None)).unwrap();
    from_gcode(cfg, &g, &MIDDLE).unwrap()
}

/// The router's spindle spins up in `τ·ln(1/tolerance)` (its drive never
/// reaches its torque limit on the way to 18 000 rpm): 0.5 s · ln 50.
fn spin_up_s(cfg: &MachineFile) -> f64 {
    let sim = &cfg.sim.as_ref().unwrap().spindles["spindle"];
    let tach = cfg.tools["spindle"].tach.unwrap();
    let omega = 18_000.0 * std::f64::consts::TAU / 60.0;
    // Below the torque limit all the way (else the ramp would come first).
    assert!(sim.inertia_kgm2 * omega / sim.time_constant_s + sim.drag_nm < sim.max_torque_nm);
    sim.time_constant_s * (1.0 / tach.tolerance).ln()
}

#[test]
fn the_router_waits_for_its_spindles_measured_speed_and_cuts_a_pocket() {
    virtual_runtime().unwrap().block_on(async {
        let cfg = router();
        let m = start(&cfg).await;
        let mut events = m.events();
        let spindle = m.tool("spindle").unwrap();
        // At rest the tachometer measures nothing.
        assert_eq!(spindle.measured_rpm().await.unwrap().1, 0.0);

        spindle.set_rpm(18_000.0).await.unwrap();
        let reached = spindle.await_speed().await.unwrap();
        let expect = spin_up_s(&cfg);
        let waited = reached.waited.as_secs_f64();
        let real = m.sim_spindle_rpm("spindle").unwrap();
        eprintln!(
            "spin-up to 18 000 rpm: waited {waited:.3} s (the physics: {expect:.3} s); measured {:.0} rpm, the rotor at {real:.0} rpm",
            reached.rpm
        );
        // The wait ended once the measured speed was within 2 %: after the
        // rotor got there (the measurement spans a few pulses, 10 ms),
        // and within the module's and the host's polls (10 ms each) after.
        assert!((reached.rpm - 18_000.0).abs() <= 0.02 * 18_000.0, "{reached:?}");
        assert!(
            waited > expect - 0.005 && waited < expect + 0.035,
            "waited {waited} s for a {expect} s spin-up"
        );
        assert!((real - 18_000.0).abs() < 0.02 * 18_000.0, "{real}");

        // Stopping waits for the spindle to run down (to 2 % of 24 000).
        spindle.set_rpm(0.0).await.unwrap();
        let down = spindle.await_speed().await.unwrap();
        // The rotor gets there in τ·ln(18 000/480); measured over whole
        // pulse periods, which near 480 rpm at two pulses a turn are 62.5
        // ms long, plus the two polls.
        let down_expect = 0.5 * (18_000.0_f64 / 480.0).ln();
        let down_waited = down.waited.as_secs_f64();
        eprintln!("run-down to 480 rpm: waited {down_waited:.3} s (the physics: {down_expect:.3} s)");
        assert!(
            down_waited > down_expect - 0.005 && down_waited < down_expect + 0.0625 + 0.02,
            "{down:?} vs {down_expect}"
        );

        // The pocket: M3 S18000 waits for the speed, the cut runs, M5 waits
        // for the spindle to stop.
        let program = pocket(&cfg);
        let planned = program.planned_seconds(&cfg, &MIDDLE).unwrap();
        let t0 = tokio::time::Instant::now();
        m.run_program(&program, |_| {}).await.unwrap();
        let took = t0.elapsed().as_secs_f64();
        eprintln!("pocket.ngc: {took:.1} s (planned {planned:.1} s)");
        let p = m.position();
        assert!(p[0].abs() < 1e-9 && p[1].abs() < 1e-9, "{p:?}");
        assert!(m.sim_spindle_rpm("spindle").unwrap() < 0.02 * 24_000.0);
        assert_eq!(m.state(), MachineState::Idle);
        while let Ok(e) = events.try_recv() {
            assert!(
                !matches!(
                    e,
                    MachineEvent::Fault { .. } | MachineEvent::State(MachineState::Faulted(_))
                ),
                "{e:?}"
            );
        }
        m.stop().await.unwrap();
    });
}

#[test]
fn a_stalled_spindle_stops_the_job_and_is_reported() {
    virtual_runtime().unwrap().block_on(async {
        let cfg = router();
        let m = start(&cfg).await;
        let mut events = m.events();
        let program = pocket(&cfg);
        let job = {
            let m = m.clone();
            tokio::spawn(async move { m.run_program(&program, |_| {}).await })
        };
        // Into the cut: the spindle at speed, the cutter in the work at
        // the first pass's depth.
        tokio::time::sleep(Duration::from_secs(12)).await;
        let before = m.sim_spindle_rpm("spindle").unwrap();
        assert!((before - 18_000.0).abs() < 0.02 * 18_000.0, "{before}");
        assert_eq!(m.state(), MachineState::Moving);
        assert!((m.position()[2] + 61.5).abs() < 1e-9, "{:?}", m.position());
        // The cutter catches: 2 N·m against the drive's 1.3.
        assert!(m.sim_load_spindle("spindle", 2.0));
        let caught = tokio::time::Instant::now();
        let reason = loop {
            match events.recv().await.unwrap() {
                MachineEvent::State(MachineState::Faulted(r)) => break r,
                _ => continue,
            }
        };
        let after = caught.elapsed().as_secs_f64();
        // The rotor falls to 70 % of 18 000 rpm in (0.3 · 1885 rad/s) /
        // ((2 + 0.03 − 1.3) N·m / 1.5e-4 kg·m²) = 0.116 s; the module
        // measures it within its 10 ms and the host reads it every 25 ms.
        eprintln!("stall reported {after:.3} s after the load: {reason}");
        assert!(reason.contains("spindle spindle stalled"), "{reason}");
        assert!(after > 0.116 && after < 0.116 + 0.06, "{after}");
        let e = job.await.unwrap().unwrap_err();
        assert!(
            matches!(&e, MachineError::Faulted(r) if r.contains("stalled")),
            "{e}"
        );
        // Safe: motion stopped (after the controlled stop's ramp down), the
        // spindle's drive commanded off.
        tokio::time::sleep(Duration::from_millis(500)).await;
        let here = m.position();
        tokio::time::sleep(Duration::from_millis(500)).await;
        assert_eq!(m.position(), here);
        let duty = m
            .with_sim(|s| {
                s.module("router-spindle")
                    .and_then(|sm| sm.module())
                    .map(|sm| sm.lock(|mm| mm.board().pins().pwm()[0]))
            })
            .flatten()
            .unwrap();
        assert_eq!(duty, 0);
        assert!(matches!(m.state(), MachineState::Faulted(_)));
        m.stop().await.unwrap();
    });
}

#[test]
fn a_spindle_that_never_reaches_its_speed_faults_after_its_timeout() {
    virtual_runtime().unwrap().block_on(async {
        let cfg = router();
        let m = start(&cfg).await;
        // Jammed before it starts: 2 N·m against the drive's 1.3.
        assert!(m.sim_load_spindle("spindle", 2.0));
        let spindle = m.tool("spindle").unwrap();
        spindle.set_rpm(18_000.0).await.unwrap();
        let t0 = tokio::time::Instant::now();
        let e = spindle.await_speed().await.unwrap_err();
        let waited = t0.elapsed().as_secs_f64();
        eprintln!("after {waited:.3} s: {e}");
        assert!(
            matches!(&e, MachineError::Tool { reason, .. }
                if reason.contains("did not reach 18000 rpm within 10 s") && reason.contains("measures 0 rpm")),
            "{e}"
        );
        // The tachometer's timeout, to the host's 10 ms poll.
        assert!((10.0..10.03).contains(&waited), "{waited}");
        assert!(matches!(m.state(), MachineState::Faulted(r) if r.contains("did not reach")));
        // The stop switched the drive off.
        tokio::time::sleep(Duration::from_millis(100)).await;
        let duty = m
            .with_sim(|s| {
                s.module("router-spindle")
                    .and_then(|sm| sm.module())
                    .map(|sm| sm.lock(|mm| mm.board().pins().pwm()[0]))
            })
            .flatten()
            .unwrap();
        assert_eq!(duty, 0);
        m.stop().await.unwrap();
    });
}
