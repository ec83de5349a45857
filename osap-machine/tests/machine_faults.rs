//! Faults reach the script: a module's `get_fault` source pushes each fault
//! to the host, the machine stops, the events stream names the module, the
//! kind, the detail and the time, and every waiting call fails naming the
//! module and the reason. In virtual time, on the simulated plotter.

use osap_host::som::Value;
use osap_machine::config::{MachineFile, MotorLimits};
use osap_machine::machine::events::FaultKind;
use osap_machine::sim::SimOptions;
use osap_machine::{Machine, MachineError, MachineEvent};
use osap_module::stepper::StepperError;
use osap_sim::machine::virtual_runtime;
use std::time::Duration;
use tokio::sync::broadcast;

fn plotter_file() -> MachineFile {
    MachineFile::load(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/machines/plotter.toml"
    ))
    .unwrap()
}

/// The simulated plotter of `cfg`, in virtual time.
async fn plotter_with(cfg: &MachineFile) -> Machine {
    Machine::simulate_with(cfg, SimOptions::VIRTUAL)
        .await
        .unwrap()
}

async fn plotter() -> Machine {
    plotter_with(&plotter_file()).await
}

/// The fault events heard so far: (module, kind, detail, time).
fn faults(events: &mut broadcast::Receiver<MachineEvent>) -> Vec<(String, FaultKind, u32, u64)> {
    let mut out = Vec::new();
    while let Ok(e) = events.try_recv() {
        if let MachineEvent::Fault {
            module,
            kind,
            detail,
            time,
            ..
        } = e
        {
            out.push((module, kind, detail, time));
        }
    }
    out
}

#[test]
fn a_refused_point_stops_the_machine_and_names_the_module_and_why() {
    virtual_runtime().unwrap().block_on(async {
        let m = plotter().await;
        let mut events = m.events();
        m.set_position([20.0, 75.0]).unwrap();
        m.goto_via_queue([180.0, 75.0], 50.0).await.unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
        assert!(faults(&mut events).is_empty(), "a clean move has no fault");
        // A point whose time has passed, mid-stream: module b refuses it
        // and the script hears so, with the refusal code and the module's
        // time stamp.
        let now = m.now_us().await.unwrap();
        let late = now / 2048 * 2048 - 10 * 2048;
        let e = m
            .call("b", "add_point", &[Value::U64(late), Value::F32(0.0)])
            .await
            .unwrap_err();
        assert!(
            matches!(&e, MachineError::ModuleRefused { module, .. } if module == "b"),
            "{e}"
        );
        let stale = u32::from(StepperError::Stale.code());
        let mut heard = Vec::new();
        for _ in 0..100 {
            if heard.iter().any(|(_, _, detail, _)| *detail == stale) {
                break;
            }
            tokio::time::sleep(Duration::from_millis(5)).await;
            heard.extend(faults(&mut events));
        }
        assert!(
            heard
                .iter()
                .any(|(module, kind, detail, time)| module == "b"
                    && *kind == FaultKind::Refused
                    && *detail == stale
                    && time.abs_diff(now) < 100_000),
            "{heard:?}"
        );
        // It stops the machine, as every refusal does: one stream's points
        // reach the module in the order they were sent (docs/protocol.md
        // §8), so a late one was not overtaken on the way, it is wrong.
        let e = m.idle().await.unwrap_err();
        let MachineError::Faulted(reason) = &e else {
            panic!("{e}")
        };
        assert!(
            reason.starts_with("module b refused a point:") && reason.contains("arrived late"),
            "{reason}"
        );
        // Once the axes stand (what the stop itself reports is not this
        // test's), recovered, on towards the far end again.
        tokio::time::sleep(Duration::from_millis(500)).await;
        assert!(m.position()[0] < 179.0, "{:?}", m.position());
        m.recover().await.unwrap();
        faults(&mut events);
        heard.clear();
        m.goto_via_queue([180.0, 75.0], 50.0).await.unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
        // A point the module cannot follow (beyond 2^46 microsteps: an axis
        // has no end, but a position must convert exactly).
        let t0 = m.now_us().await.unwrap();
        let next = t0 / 2048 * 2048 + 200 * 2048;
        let e = m
            .call("b", "add_point", &[Value::U64(next), Value::F32(1.0e13)])
            .await
            .unwrap_err();
        assert!(
            matches!(&e, MachineError::ModuleRefused { module, .. } if module == "b"),
            "{e}"
        );
        // The waiting call fails, naming the module and the reason, within
        // the fault source's 5 ms period and the links' latency.
        let e = m.idle().await.unwrap_err();
        let heard_after = m.now_us().await.unwrap() - t0;
        eprintln!(
            "fault to failed call: {:.1} ms (virtual time)",
            heard_after as f64 / 1e3
        );
        assert!(heard_after < 30_000, "{heard_after} µs");
        let MachineError::Faulted(reason) = &e else {
            panic!("{e}")
        };
        assert!(
            reason.starts_with("module b refused a point:") && reason.contains("2^46 microsteps"),
            "{reason}"
        );
        // So does every call after it, until recovered.
        let e = m.goto_via_queue([20.0, 75.0], 50.0).await.unwrap_err();
        assert!(matches!(&e, MachineError::Faulted(r) if r == reason), "{e}");
        heard.extend(faults(&mut events));
        let out_of_range = u32::from(StepperError::OutOfRange.code());
        assert!(
            heard.iter().any(|(module, kind, detail, _)| module == "b"
                && *kind == FaultKind::Refused
                && *detail == out_of_range),
            "{heard:?}"
        );
        assert!(
            heard.iter().all(|f| f.0 == "b"),
            "only b faulted: {heard:?}"
        );
        // The axes stopped: the planner halted, short of the target.
        tokio::time::sleep(Duration::from_millis(500)).await;
        let p = m.position();
        assert!(p[0] < 179.0, "{p:?}");
        // Recovered, the machine moves again and hears no new fault.
        m.recover().await.unwrap();
        m.goto_now([100.0, 75.0], 50.0).await.unwrap();
        assert!(faults(&mut events).is_empty());
        m.stop().await.unwrap();
    });
}

#[test]
fn a_module_halted_mid_move_faults_the_machine_with_its_first_reason() {
    virtual_runtime().unwrap().block_on(async {
        let m = plotter().await;
        let mut events = m.events();
        m.set_position([20.0, 75.0]).unwrap();
        m.goto_via_queue([180.0, 75.0], 50.0).await.unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
        // Another client halts module a behind the script's back.
        m.call("a", "halt", &[]).await.unwrap();
        let e = m.idle().await.unwrap_err();
        assert!(
            matches!(&e, MachineError::Faulted(r) if r.starts_with("module a was halted")),
            "{e}"
        );
        // The refusals of the stream behind the halt keep the halt as their
        // cause: the reason stays the first fault's.
        tokio::time::sleep(Duration::from_millis(200)).await;
        let e = m.idle().await.unwrap_err();
        assert!(
            matches!(&e, MachineError::Faulted(r) if r.starts_with("module a was halted")),
            "{e}"
        );
        let heard = faults(&mut events);
        assert!(
            heard
                .iter()
                .any(|(module, kind, ..)| module == "a" && *kind == FaultKind::Halted),
            "{heard:?}"
        );
        m.recover().await.unwrap();
        m.goto_now([60.0, 75.0], 50.0).await.unwrap();
        m.stop().await.unwrap();
    });
}

#[test]
fn a_motor_limit_below_the_plan_is_held_by_the_module_and_reported() {
    virtual_runtime().unwrap().block_on(async {
        // Every other test here runs its moves under the limits derived
        // from the machine file. Here motor b's own limits sit below what
        // a 50 mm/s move asks of it: the module refuses the stream.
        let mut cfg = plotter_file();
        cfg.motors.get_mut("b").unwrap().limits = Some(MotorLimits {
            velocity: 10.0,
            acceleration: 1.0e5,
            jerk: 0.0,
        });
        let m = plotter_with(&cfg).await;
        let mut events = m.events();
        m.set_position([20.0, 75.0]).unwrap();
        m.goto_via_queue([180.0, 75.0], 50.0).await.unwrap();
        let e = m.idle().await.unwrap_err();
        let MachineError::Faulted(reason) = &e else {
            panic!("{e}")
        };
        assert!(
            reason.starts_with("module b refused a point past its velocity limit")
                && reason.contains("module_margin"),
            "{reason}"
        );
        let p = m.position();
        assert!(p[0] < 179.0, "the axes stopped short: {p:?}");
        let heard = faults(&mut events);
        assert!(
            heard.iter().any(|(module, kind, detail, _)| module == "b"
                && *kind == FaultKind::OverLimit
                && detail & osap_module::fault::OVER_VELOCITY != 0),
            "{heard:?}"
        );
        // Module a's limits (derived from the file) let the move through.
        assert!(heard.iter().all(|f| f.0 == "b"), "{heard:?}");
        m.stop().await.unwrap();
    });
}
