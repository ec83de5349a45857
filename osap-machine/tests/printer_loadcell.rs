//! The printer's load cell on simulated modules: set up from
//! `[axes.e.loadcell]` at start, tared hot at rest, and read while the
//! extruder pushes filament into the simulated melt of `[sim.axes.e]`:
//! the force is the melt law's at that flow and temperature.

use osap_machine::config::MachineFile;
use osap_machine::sim::SimOptions;
use osap_machine::{Machine, MachineError};
use osap_sim::machine::virtual_runtime;
use std::time::Duration;

fn printer() -> MachineFile {
    MachineFile::load(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/machines/printer.toml"
    ))
    .unwrap()
}

#[test]
fn the_load_cell_weighs_the_melt_while_the_extruder_pushes() {
    let cfg = printer();
    let melt = cfg.sim.as_ref().unwrap().axes["e"].melt.unwrap();
    virtual_runtime().unwrap().block_on(async {
        let m = Machine::simulate_with(&cfg, SimOptions::VIRTUAL)
            .await
            .unwrap();
        let hotend = m.heater("hotend").unwrap();
        hotend.set_target(210.0).await.unwrap();
        hotend.wait_for_target().await.unwrap();
        tokio::time::sleep(Duration::from_secs(10)).await;
        let cell = m.loadcell().unwrap();
        cell.tare(40).await.unwrap();
        let rest = cell.read().await.unwrap();
        assert!(rest.force_n.abs() < 0.3, "{rest:?}");
        // 8 mm of filament at 2 mm/s: 4.81 mm³/s for 4 s.
        let mut to = m.position();
        let e = m.axes().iter().position(|a| a == "e").unwrap();
        to[e] += 8.0;
        m.line(&to, 2.0).await.unwrap();
        let start = m.now_us().await.unwrap();
        let mut forces = Vec::new();
        let mut last = 0;
        while m.now_us().await.unwrap() < start + 4_000_000 {
            let r = cell.read().await.unwrap();
            let t = r.time_us.saturating_sub(start);
            if r.time_us != last && (1_500_000..3_800_000).contains(&t) {
                forces.push(r.force_n);
            }
            last = r.time_us;
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        m.idle().await.unwrap();
        let q = 2.0 * std::f64::consts::PI * 0.875f64.powi(2);
        let law = melt.flow_k * q.powf(melt.flow_n);
        let mean = forces.iter().sum::<f64>() / forces.len() as f64;
        assert!(forces.len() > 100, "{} samples", forces.len());
        assert!(
            (mean / law - 1.0).abs() < 0.03,
            "{mean:.2} N read, the melt law gives {law:.2} N at 210 °C"
        );
        m.stop().await.unwrap();
    });
}

#[test]
fn a_machine_without_a_load_cell_says_so() {
    let cfg = MachineFile::load(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/machines/mill.toml"
    ))
    .unwrap();
    assert!(cfg.extruder().is_none());
    virtual_runtime().unwrap().block_on(async {
        let m = Machine::simulate_with(&cfg, SimOptions::VIRTUAL)
            .await
            .unwrap();
        assert!(matches!(m.loadcell(), Err(MachineError::NoLoadCell)));
        m.stop().await.unwrap();
    });
}
