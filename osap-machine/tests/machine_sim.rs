//! The Machine API on simulated modules (the firmware's logic), in virtual
//! time: homing finds the switches, queued moves run, tools switch, and
//! what the motors stepped matches what was planned.

use osap_machine::config::MachineFile;
use osap_machine::machine::SimOptions;
use osap_machine::{Machine, MachineError, MachineEvent};
use osap_sim::machine::{virtual_runtime, TimeMode};

fn load(name: &str) -> MachineFile {
    MachineFile::load(format!(
        "{}/../examples/machines/{name}.toml",
        env!("CARGO_MANIFEST_DIR")
    ))
    .unwrap()
}

async fn start(name: &str) -> Machine {
    Machine::simulate_with(
        &load(name),
        SimOptions {
            time: TimeMode::Virtual,
        },
    )
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
        // Homing backs off 2 mm from each min switch.
        assert!(
            (p[0] - 2.0).abs() < 1e-9 && (p[1] - 2.0).abs() < 1e-9,
            "{p:?}"
        );
        // Where the simulated carriage really is, from the motors' steps:
        // homing found the switches within a step or two (12.5 µm).
        let cfg = load("plotter");
        for (k, axis) in ["x", "y"].iter().enumerate() {
            let form = osap_machine::sim::axis_form(&cfg, axis).unwrap();
            let real = m
                .with_sim(|s| {
                    form.value(|module| {
                        s.module(module)
                            .and_then(|sm| sm.module())
                            .map_or(f64::NAN, |sm| sm.lock(|mm| mm.board().motor().position()))
                    })
                })
                .unwrap();
            assert!(
                (real - p[k]).abs() < 0.03,
                "{axis}: machine {} real {real}",
                p[k]
            );
        }
        m.start_recording();
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
        let rec = m.take_recording(t0);
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
