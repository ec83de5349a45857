//! The Machine API on simulated modules (the firmware's logic), in virtual
//! time: homing finds the switches, queued moves run, tools switch, and
//! what the motors stepped matches what was planned.

use osap_machine::config::MachineFile;
use osap_machine::sim::SimOptions;
use osap_machine::{Machine, MachineError, MachineEvent};
use osap_sim::machine::virtual_runtime;

fn load(name: &str) -> MachineFile {
    MachineFile::load(format!(
        "{}/../examples/machines/{name}.toml",
        env!("CARGO_MANIFEST_DIR")
    ))
    .unwrap()
}

async fn start(name: &str) -> Machine {
    Machine::simulate_with(&load(name), SimOptions::VIRTUAL)
        .await
        .unwrap()
}

#[test]
fn plotter_homes_and_draws_a_square() {
    virtual_runtime().unwrap().block_on(async {
        let m = start("plotter").await;
        let mut events = m.events();
        // Not homed: moves are refused.
        let e = m.goto_via_queue([10.0, 10.0], 50.0).await.unwrap_err();
        assert!(matches!(e, MachineError::NotHomed(_)), "{e}");
        m.home().await.unwrap();
        let p = m.position();
        // Homing backs off 2 mm from each min switch, which sits 1 mm
        // beyond the travel (the default endstop, -1). How close that is
        // to where the carriage really is: tests/switch_edges.rs.
        assert!(
            (p[0] - 1.0).abs() < 1e-9 && (p[1] - 1.0).abs() < 1e-9,
            "{p:?}"
        );
        m.start_recording().await.unwrap();
        let t0 = m.now_us().await.unwrap();
        let pen = m.tool("pen").unwrap();
        m.goto_now([20.0, 20.0], 100.0).await.unwrap();
        pen.on().await.unwrap();
        pen.await_ready().await.unwrap();
        for p in [[60.0, 20.0], [60.0, 60.0], [20.0, 60.0], [20.0, 20.0]] {
            m.goto_via_queue(p, 80.0).await.unwrap();
        }
        m.idle().await.unwrap();
        pen.off().await.unwrap();
        let rec = m.take_recording(t0).await.unwrap();
        let p = m.position();
        assert!(
            (p[0] - 20.0).abs() < 1e-9 && (p[1] - 20.0).abs() < 1e-9,
            "{p:?}"
        );
        assert!(!rec.executed.is_empty() && !rec.planned.is_empty());
        for (axis, err) in rec.following_error() {
            // Step quantization (12.5 µm at 80 steps/mm, one microstep)
            // plus the spline's rounding of corners.
            assert!(err < 0.5, "{axis}: {err}");
        }
        let last = rec.executed.last().unwrap();
        assert!(
            (last.pos[0] - 20.0).abs() < 0.02 && (last.pos[1] - 20.0).abs() < 0.02,
            "{last:?}"
        );
        while let Ok(e) = events.try_recv() {
            assert!(
                !matches!(
                    e,
                    MachineEvent::Fault { .. } | MachineEvent::LinkLost { .. }
                ),
                "{e:?}"
            );
        }
        m.stop().await.unwrap();
    });
}

#[test]
fn halt_stops_within_limits_and_moves_resume() {
    virtual_runtime().unwrap().block_on(async {
        let m = start("plotter").await;
        let mut events = m.events();
        // The simulated carriage starts mid-travel: say so instead of homing.
        m.set_position([100.0, 75.0]).unwrap();
        m.goto_via_queue([190.0, 75.0], 100.0).await.unwrap();
        tokio::time::sleep(std::time::Duration::from_millis(400)).await;
        m.halt().await.unwrap();
        let p = m.position();
        assert!(p[0] > 110.0 && p[0] < 180.0, "{p:?}");
        assert_eq!(m.state(), osap_machine::MachineState::Idle);
        m.goto_now([100.0, 75.0], 100.0).await.unwrap();
        assert_eq!(m.position(), vec![100.0, 75.0]);
        while let Ok(e) = events.try_recv() {
            assert!(!matches!(e, MachineEvent::Fault { .. }), "{e:?}");
        }
        m.stop().await.unwrap();
    });
}

#[test]
fn a_script_waits_until_only_a_few_moves_are_queued() {
    virtual_runtime().unwrap().block_on(async {
        let m = start("plotter").await;
        m.set_position([20.0, 20.0]).unwrap();
        // 40 moves of 20 mm at 50 mm/s: about 16 s of motion queued at once.
        for k in 0..40 {
            let x = if k % 2 == 0 { 40.0 } else { 20.0 };
            m.goto_via_queue([x, 20.0], 50.0).await.unwrap();
        }
        assert!(m.queued_moves() >= 30, "{}", m.queued_moves());
        let t = tokio::time::Instant::now();
        m.wait_queued_at_most(4).await.unwrap();
        let waited = t.elapsed().as_secs_f64();
        // It returned as the 36th move finished, not at once and not at
        // the end: the last few are still queued.
        assert!(m.queued_moves() <= 4, "{}", m.queued_moves());
        assert!(m.queued_moves() >= 1, "{}", m.queued_moves());
        assert!((12.0..16.0).contains(&waited), "waited {waited:.2} s");
        m.idle().await.unwrap();
        assert_eq!(m.queued_moves(), 0);
        m.stop().await.unwrap();
    });
}

#[test]
fn feed_override_scales_moves_not_yet_started() {
    virtual_runtime().unwrap().block_on(async {
        let m = start("plotter").await;
        m.set_position([20.0, 75.0]).unwrap();
        let mut took = Vec::new();
        for (k, to) in [(1.0, 120.0), (0.5, 20.0)] {
            m.set_feed_override(k).unwrap();
            let t = tokio::time::Instant::now();
            m.goto_via_queue([to, 75.0], 50.0).await.unwrap();
            m.idle().await.unwrap();
            took.push(t.elapsed().as_secs_f64());
        }
        // 100 mm at 50 then 25 mm/s (plus the same start-up lead each time).
        let ratio = (took[1] - 0.09) / (took[0] - 0.09);
        assert!((ratio - 2.0).abs() < 0.1, "{took:?}");
        assert!(m.set_feed_override(0.0).is_err());
        m.stop().await.unwrap();
    });
}

#[test]
fn a_lost_module_faults_the_machine_and_the_script_hears_why() {
    virtual_runtime().unwrap().block_on(async {
        let m = start("plotter").await;
        let mut events = m.events();
        m.set_position([20.0, 75.0]).unwrap();
        m.goto_via_queue([180.0, 75.0], 50.0).await.unwrap();
        tokio::time::sleep(std::time::Duration::from_millis(300)).await;
        let b = m.with_sim(|s| s.module("b").cloned()).flatten().unwrap();
        b.kill().await.unwrap();
        let e = m.idle().await.unwrap_err();
        assert!(
            matches!(&e, MachineError::Faulted(r) if r.contains("module b")),
            "{e}"
        );
        // Moves are refused until recovered.
        let e = m.goto_via_queue([20.0, 75.0], 50.0).await.unwrap_err();
        assert!(matches!(e, MachineError::Faulted(_)), "{e}");
        // The fault's stop halts every module and switches the pen off; its
        // report names the module it could not reach.
        let mut lost = false;
        let report = loop {
            match events.recv().await.unwrap() {
                MachineEvent::LinkLost { module } => lost |= module == "b",
                MachineEvent::Stop(report) => break report,
                _ => {}
            }
        };
        assert!(lost);
        assert!(report.reason.contains("module b"), "{report}");
        assert_eq!(report.confirmed, ["a", "z"], "{report}");
        let unreached: Vec<&str> = report
            .unreachable
            .iter()
            .map(|u| u.module.as_str())
            .collect();
        assert_eq!(unreached, ["b"], "{report}");
        // So does stopping the machine, as an error.
        let e = m.stop().await.unwrap_err();
        let MachineError::StopIncomplete(report) = &e else {
            panic!("{e}")
        };
        assert_eq!(report.confirmed, ["a", "z"], "{report}");
        assert_eq!(report.unreachable[0].module, "b", "{report}");
        assert!(e.to_string().contains("NOT reached: b"), "{e}");
    });
}

#[test]
fn a_limit_hit_outside_homing_halts_the_machine() {
    virtual_runtime().unwrap().block_on(async {
        let m = start("plotter").await;
        let mut events = m.events();
        // Wrong: the carriage is really at (100, 75), mid-travel, so going
        // to x = 10 drives it 40 mm past the x switch at -1 (its endstop).
        m.set_position([150.0, 75.0]).unwrap();
        m.goto_via_queue([10.0, 75.0], 50.0).await.unwrap();
        let e = m.idle().await.unwrap_err();
        assert!(matches!(&e, MachineError::Faulted(r) if r.contains("limit switch")), "{e}");
        // Every module halted at once, the pen's too, and every one said so.
        let mut hit = false;
        let report = loop {
            match events.recv().await.unwrap() {
                MachineEvent::Stop(report) => break report,
                e => {
                    hit |= matches!(&e, MachineEvent::Limit { module, pressed: true, expected: false, .. } if module == "a")
                }
            }
        };
        assert!(hit);
        assert!(report.reason.contains("limit switch on module a"), "{report}");
        assert_eq!(report.confirmed, ["a", "b", "z"], "{report}");
        assert!(report.is_complete(), "{report}");
        // Recovery: the machine is where its motors stopped, at once, at the
        // switch (101 mm travelled, not 140), and must home before moving.
        m.recover().await.unwrap();
        let p = m.position();
        assert!(p[0] > 48.0 && p[0] <= 49.0, "{p:?}");
        let e = m.goto_now([120.0, 75.0], 50.0).await.unwrap_err();
        assert!(matches!(e, MachineError::NotHomed(_)), "{e}");
        m.home().await.unwrap();
        m.goto_now([120.0, 75.0], 50.0).await.unwrap();
        m.stop().await.unwrap();
    });
}
