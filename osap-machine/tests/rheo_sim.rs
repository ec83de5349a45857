//! `osap rheo`'s routine and fit on the simulated printer: the melt of
//! `[sim.axes.e]` (which the routine is never told) measured through the
//! module's load cell, and recovered: the max flow at each temperature
//! within 5 % of the truth, the response time within 15 %, and no slip.
//! Then the fitted model, written into a copy of the machine file, prints
//! a slicer job's fast layer: no slip and the force under the grip,
//! where a hand-set flow cap that is too high slips; and in the time the
//! true melt allows, within 10 %.

use osap_fit::MeltModel;
use osap_machine::config::{MachineFile, MeltModelKeys};
use osap_machine::job::{from_gcode, gcode_options, Program};
use osap_machine::rheo::{self, RheoFit, RheoOptions};
use osap_machine::sim::SimOptions;
use osap_machine::Machine;
use osap_sim::machine::virtual_runtime;

/// The speed cube's second layer (perimeters at 200 and infill at 250
/// mm/s) scaled 3× in x and y about the bed's centre: a 60 mm box with the
/// same beads (E per mm kept), its lines long enough to reach the
/// slicer's speeds. Heats to 210 °C, travels over the box's centre with
/// the filament retracted (as the first layer left it) and prints the
/// layer.
fn fast_layer() -> String {
    let cube = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/jobs/cube-speed-layers.gcode"
    ))
    .unwrap();
    let mut layers = cube.match_indices(";LAYER_CHANGE").map(|(i, _)| i);
    let (second, third) = (layers.nth(1).unwrap(), layers.next().unwrap());
    let mut job = String::from("M109 S210\nG90\nM83\nG1 X110 Y110 Z0.5 F9000\nG1 E-0.8 F2100\n");
    for line in cube[second..third].lines() {
        let code = line.split(';').next().unwrap_or("").trim();
        if !code.starts_with("G1 ") || !(code.contains('X') || code.contains('Y')) {
            job += line;
            job += "\n";
            continue;
        }
        let words: Vec<String> = code
            .split_whitespace()
            .map(|w| {
                let (letter, value) = w.split_at(1);
                match (letter, value.parse::<f64>()) {
                    ("X" | "Y", Ok(v)) => format!("{letter}{:.3}", 110.0 + 3.0 * (v - 110.0)),
                    ("E", Ok(v)) => format!("E{:.5}", 3.0 * v),
                    _ => w.to_string(),
                }
            })
            .collect();
        job += &words.join(" ");
        job += "\n";
    }
    job
}

/// The printer's machine file with its hand-set flow cap and pressure
/// advance taken out and `fit` written in as `osap rheo --write` does.
fn modelled(fit: &RheoFit) -> MachineFile {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/machines/printer.toml"
    ))
    .unwrap();
    let text: String = text
        .lines()
        .filter(|l| !l.starts_with("max_volumetric_speed") && !l.starts_with("pressure_advance"))
        .map(|l| format!("{l}\n"))
        .collect();
    let path = std::env::temp_dir().join(format!("rheo-sim-{}.toml", std::process::id()));
    std::fs::write(&path, text).unwrap();
    let notes = rheo::write_model(&path, fit, Some("rheo_sim")).unwrap();
    assert!(notes.is_empty(), "{notes:?}");
    let cfg = MachineFile::load(&path).unwrap();
    let _ = std::fs::remove_file(&path);
    cfg
}

/// Runs `program` on `m`: the seconds it printed (heater waits left out),
/// the slips it made, the melt's peak force so far, and the hotend's
/// coldest reading once it first held its target.
async fn print(m: &Machine, program: &Program) -> (f64, u64, f64, f64) {
    let before = m.sim_melt().unwrap().1.slips;
    let log = m.log_heaters(std::time::Duration::from_millis(50));
    let began = tokio::time::Instant::now();
    let stats = m.run_program(program, |_| {}).await.unwrap();
    let took = began.elapsed().as_secs_f64() - stats.heater_wait_s;
    let k = m
        .heaters()
        .iter()
        .position(|h| h.name() == "hotend")
        .unwrap();
    let hotend: Vec<_> = log.finish().await.iter().map(|r| r.readings[k]).collect();
    let held = hotend
        .iter()
        .position(|r| r.target > 0.0 && (r.celsius - r.target).abs() < 1.0)
        .unwrap_or(0);
    let coldest = hotend[held..]
        .iter()
        .map(|r| r.celsius)
        .fold(f64::INFINITY, f64::min);
    let (_, melt) = m.sim_melt().unwrap();
    (took, melt.slips - before, melt.peak_force_n, coldest)
}

#[test]
fn the_printer_measures_its_melt_fits_it_and_prints_from_it() {
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
    let rt = virtual_runtime().unwrap();
    let m_record_fit = rt.block_on(async {
        let m = Machine::simulate_with(&cfg, SimOptions::VIRTUAL)
            .await
            .unwrap();
        let record = rheo::measure(&m, &opts).await.unwrap();
        let fit = rheo::fit(&record, &opts).unwrap();
        (m, record, fit)
    });
    let (m, record, fit) = m_record_fit;
    let measured = m.sim_melt().unwrap().1;
    println!("the measurement: {measured:?}");
    assert_eq!(measured.slips, 0, "the routine slipped the filament");
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
    // The plots: a circle per settled point, a curve per temperature.
    let dir = std::env::temp_dir().join(format!("rheo-sim-plots-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let files = rheo::plot(&record, &fit, &dir).unwrap();
    let force_flow = std::fs::read_to_string(&files[0]).unwrap();
    assert_eq!(force_flow.matches("<circle").count(), fit.points.len());
    for t in &opts.temps {
        assert!(force_flow.contains(&format!("{t} °C, fitted")), "{t}");
    }
    assert!(std::fs::read_to_string(&files[1])
        .unwrap()
        .contains("fitted lag of the push"));
    let _ = std::fs::remove_dir_all(&dir);
    let lines = rheo::model_lines(&fit, None);
    assert!(lines[0] == "[axes.e.model]" && lines.iter().any(|l| l.starts_with("response_ms")));

    // Print from the model, as a user would: the machine restarted from the
    // file the model was written into (its pressure advance the model's),
    // the fitted model's flow limit first, then a hand-set cap too high
    // for this melt.
    let with_model = modelled(&fit);
    let e = &with_model.extruder().unwrap().extruder;
    assert!(e.pressure_advance.is_none() && e.max_volumetric_speed.is_none());
    assert!((e.pressure_advance_s() - fit.lag.tau_s).abs() < 1e-3);
    let text = fast_layer();
    let job = osap_machine::gcode::read_with(&text, &gcode_options(&with_model, None)).unwrap();
    let m = rt.block_on(async {
        m.heater("hotend").unwrap().set_target(0.0).await.unwrap();
        m.stop().await.unwrap();
        let m = Machine::simulate_with(&with_model, SimOptions::VIRTUAL)
            .await
            .unwrap();
        m.home().await.unwrap();
        m
    });
    let start = m.position();
    let program = |cfg: &MachineFile| from_gcode(cfg, &job, &start).unwrap();
    let mut hand = with_model.clone();
    let he = &mut hand.axes.get_mut("e").unwrap().extruder;
    he.model = None;
    he.max_volumetric_speed = Some(18.0);
    let mut true_melt = with_model.clone();
    let te = true_melt
        .axes
        .get_mut("e")
        .unwrap()
        .extruder
        .model
        .as_mut()
        .unwrap();
    *te = MeltModelKeys {
        flow_k: sim.flow_k,
        flow_n: sim.flow_n,
        temp_coeff: sim.temp_coeff,
        t_ref: sim.t_ref,
        response_ms: sim.response_ms,
        ..te.clone()
    };
    let (from_model, from_truth) = (program(&with_model), program(&true_melt));
    assert!(
        !from_model.slowed.is_empty(),
        "the fast layers ask more than the melt gives"
    );
    let planned = |p: &Program| p.planned_seconds(&with_model, &start).unwrap();
    let (truth_s, unlimited_s) = (
        planned(&from_truth),
        planned(&from_model.without_flow_limit()),
    );
    let model_planned_s = planned(&from_model);
    println!(
        "fast layer planned: {model_planned_s:.2} s from the model, {truth_s:.2} s from the true melt, {unlimited_s:.2} s unlimited"
    );
    // The limit binds, and what it costs from the fitted model is what it
    // costs from the true melt, within a fifth.
    assert!(
        truth_s - unlimited_s > 1.0,
        "{truth_s:.2} s against {unlimited_s:.2} s unlimited"
    );
    let cost = (model_planned_s - unlimited_s) / (truth_s - unlimited_s);
    assert!(
        (cost - 1.0).abs() < 0.2,
        "the model's limit costs {cost:.2}× the true melt's"
    );
    let (model_s, model_slips, model_peak, hand_slips, hand_peak) = rt.block_on(async {
        let (model_s, model_slips, model_peak, coldest) = print(&m, &from_model).await;
        println!("the model's print: the hotend at {coldest:.1} °C at its coldest");
        // From where the first print left the extruder (the job's E is
        // relative to it).
        let from_hand = from_gcode(&hand, &job, &m.position()).unwrap();
        let (_, hand_slips, hand_peak, _) = print(&m, &from_hand).await;
        m.heater("hotend").unwrap().set_target(0.0).await.unwrap();
        m.stop().await.unwrap();
        (model_s, model_slips, model_peak, hand_slips, hand_peak)
    });
    println!(
        "from the model: {model_s:.2} s printed, {model_slips} slips, peak {model_peak:.1} N; \
         hand-set 18 mm³/s: {hand_slips} slips, peak {hand_peak:.1} N"
    );
    assert_eq!(
        model_slips, 0,
        "the model's print slipped (peak {model_peak:.1} N)"
    );
    assert!(
        model_peak < grip,
        "peak {model_peak:.1} N against the {grip} N grip"
    );
    assert!(
        hand_slips > 0 && hand_peak >= grip,
        "the hand-set cap did not slip: {hand_peak:.1} N"
    );
    assert!(
        (model_s / truth_s - 1.0).abs() < 0.10,
        "printed in {model_s:.2} s; the true melt allows {truth_s:.2} s"
    );
}
