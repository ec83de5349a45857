//! Bed levelling on the simulated mill, in virtual time: a probe that
//! never touches the bed stops at its search limit and says so. The
//! levelling itself (probe accuracy, the fitted tilt, a levelled job
//! within 0.05 mm of its height above the tilted, warped bed) is tested by
//! running the `level` example: `examples/tests/measurement_examples.rs`.

use osap_machine::config::MachineFile;
use osap_machine::level;
use osap_machine::sim::SimOptions;
use osap_machine::{Machine, MachineError};
use osap_sim::machine::virtual_runtime;

fn mill() -> MachineFile {
    let mut cfg = MachineFile::load(format!(
        "{}/../examples/machines/mill.toml",
        env!("CARGO_MANIFEST_DIR")
    ))
    .unwrap();
    // Start flat: the example's mesh is for another bed.
    cfg.bed_mesh = None;
    cfg
}

async fn start(cfg: &MachineFile) -> Machine {
    Machine::simulate_with(cfg, SimOptions::VIRTUAL)
        .await
        .unwrap()
}

#[test]
fn a_probe_that_never_triggers_stops_at_its_search_limit() {
    virtual_runtime().unwrap().block_on(async {
        let mut cfg = mill();
        // The bed sits below the search: start_z - search_depth = -74.
        cfg.sim.as_mut().unwrap().bed.as_mut().unwrap().z = -78.0;
        let m = start(&cfg).await;
        m.home().await.unwrap();
        let e = level::level(&m, |_, _| {}).await.unwrap_err();
        let text = e.to_string();
        assert!(matches!(e, MachineError::Probe { .. }), "{text}");
        assert!(text.contains("point (0, 0)"), "{text}");
        assert!(text.contains("never triggered"), "{text}");
        assert!(text.contains("-74"), "{text}");
        // The axis stopped at the search's end, not past it.
        let z = m.position()[2];
        assert!((z - -74.0).abs() < 1e-6, "z {z}");
        assert!(m.bed_mesh().is_none());
    });
}
