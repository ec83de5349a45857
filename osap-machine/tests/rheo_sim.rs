//! `osap rheo`'s routine and fit on the simulated printer: the melt of
//! `[sim.axes.e]` (which the routine is never told) measured through the
//! module's load cell, and recovered: the max flow at each temperature
//! within 5 % of the truth, the response time within 15 %, and no slip.

use osap_fit::MeltModel;
use osap_machine::config::MachineFile;
use osap_machine::rheo::{self, RheoOptions};
use osap_machine::sim::SimOptions;
use osap_machine::Machine;
use osap_sim::machine::{virtual_runtime, TimeMode};

#[test]
fn the_printer_measures_its_melt_and_fits_it() {
    let cfg = MachineFile::load(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/machines/printer.toml"
    ))
    .unwrap();
    let sim = cfg.sim.as_ref().unwrap().axes["e"].melt.unwrap();
    let truth = MeltModel {
        flow_k: sim.flow_k,
        flow_n: sim.flow_n,
        temp_coeff: sim.temp_coeff,
        t_ref: sim.t_ref,
    };
    let opts = RheoOptions {
        temps: vec![200.0, 215.0, 230.0],
        flows: vec![2.0, 4.0, 7.0, 11.0, 16.0, 22.0],
        hold_s: 1.5,
        settle_s: 0.8,
        soak_s: 2.0,
        ..RheoOptions::default()
    };
    let (record, fit) = virtual_runtime().unwrap().block_on(async {
        let m = Machine::simulate_with(
            &cfg,
            SimOptions {
                time: TimeMode::Virtual,
            },
        )
        .await
        .unwrap();
        let record = rheo::measure(&m, &opts).await.unwrap();
        m.heater("hotend").unwrap().set_target(0.0).await.unwrap();
        m.stop().await.unwrap();
        let fit = rheo::fit(&record, &opts).unwrap();
        (record, fit)
    });
    let grip = cfg.extruder().unwrap().extruder.max_force_n.unwrap();
    let peak = record.force.iter().map(|f| f.force_n).fold(0.0, f64::max);
    assert!(
        peak < grip,
        "the routine pushed {peak:.1} N against a {grip} N grip"
    );
    for &(t, q, err) in &fit.max_flows {
        let want = truth.flow_at(0.8 * grip, t);
        assert!(
            (q / want - 1.0).abs() < 0.05,
            "{t} °C: fitted {q:.2} ± {err:.2} mm³/s, truth {want:.2}"
        );
    }
    let tau_ms = fit.lag.tau_s * 1000.0;
    for &(t, q, err) in &fit.max_flows {
        println!(
            "max flow at {t} °C: {q:.2} ± {err:.2} mm³/s (truth {:.2})",
            truth.flow_at(0.8 * grip, t)
        );
    }
    println!(
        "response {tau_ms:.1} ± {:.1} ms (truth {})",
        fit.lag.std_error * 1000.0,
        sim.response_ms
    );
    assert!(
        (tau_ms / sim.response_ms - 1.0).abs() < 0.15,
        "τ {tau_ms:.1} ms, truth {}",
        sim.response_ms
    );
    let lines = rheo::model_lines(&fit, None);
    assert!(lines[0] == "[axes.e.model]" && lines.iter().any(|l| l.starts_with("response_ms")));
}
