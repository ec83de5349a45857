//! Points really lost on the wire stop the machine: one stream's points
//! reach their module in order (docs/protocol.md §8), so a gap in them is a
//! loss, never a point overtaken on the way, and the machine stops on it.
//! In virtual time, on the simulated plotter.

use osap_machine::config::MachineFile;
use osap_machine::machine::events::FaultKind;
use osap_machine::sim::SimOptions;
use osap_machine::{Machine, MachineError, MachineEvent};
use osap_module::stepper::StepperError;
use osap_sim::machine::{virtual_runtime, Fault};
use std::time::Duration;

fn plotter() -> MachineFile {
    MachineFile::load(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/machines/plotter.toml"
    ))
    .unwrap()
}

/// Module `key`'s `get_counters`: (points, refused, last refusal code,
/// filled).
async fn counters(m: &Machine, key: &str) -> [u64; 4] {
    let out = m.call(key, "get_counters", &[]).await.unwrap();
    let n = |i: usize| out[i].as_f64().unwrap() as u64;
    [n(0), n(1), n(2), n(3)]
}

#[test]
fn points_lost_on_a_uart_stop_the_machine_with_a_gap() {
    virtual_runtime().unwrap().block_on(async {
        let m = Machine::simulate_with(&plotter(), SimOptions::VIRTUAL)
            .await
            .unwrap();
        let faults = m.with_sim(|s| s.injector()).unwrap();
        let mut events = m.events();
        m.set_position([20.0, 75.0]).unwrap();
        // 160 mm at 50 mm/s: 3.2 s of motion, a point every 2.048 ms.
        m.goto_via_queue([180.0, 75.0], 50.0).await.unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
        let before = counters(&m, "a").await;
        assert_eq!(before[1], 0, "a clean stream: {before:?}");

        // Every frame on motor a's UART broken for 10 ms: the points of
        // about five intervals are lost (and counted as frame errors where
        // they land).
        let corrupt = |per_byte| Fault::Corrupt {
            link: "hub-a".into(),
            per_byte,
        };
        faults.inject(&corrupt(1.0)).await.unwrap();
        tokio::time::sleep(Duration::from_millis(10)).await;
        faults.inject(&corrupt(0.0)).await.unwrap();
        let c = faults.corruption("hub-a").unwrap();
        let lost_intervals = 10_000 / 2048;
        assert!(
            c.rejected >= lost_intervals,
            "{c:?}: fewer frames lost than points sent"
        );

        // The first point after the hole is refused as a gap, and the
        // machine stops on it: the waiting call fails naming the module
        // and why, and so does every call after it.
        let e = m.idle().await.unwrap_err();
        let MachineError::Faulted(reason) = &e else {
            panic!("{e}")
        };
        assert!(
            reason.starts_with("module a refused a point:")
                && reason.contains("two or more points missing"),
            "{reason}"
        );
        let again = m.goto_via_queue([20.0, 75.0], 50.0).await.unwrap_err();
        assert!(
            matches!(&again, MachineError::Faulted(r) if r == reason),
            "{again}"
        );
        let gap = u32::from(StepperError::Gap.code());
        let mut heard = Vec::new();
        while let Ok(e) = events.try_recv() {
            heard.push(e);
        }
        assert!(
            heard.iter().any(|e| matches!(
                e,
                MachineEvent::Fault { module, kind: FaultKind::Refused, detail, .. }
                    if module == "a" && *detail == gap
            )),
            "{heard:?}"
        );
        let after = counters(&m, "a").await;
        assert!(after[1] > before[1], "{after:?}");
        // The carriage stopped short of the target.
        tokio::time::sleep(Duration::from_millis(500)).await;
        let x = m.sim_axis_position("x").unwrap();
        assert!(x < 179.0, "ran on to {x}");
        m.stop().await.unwrap();
    });
}
