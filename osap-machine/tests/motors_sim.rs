//! Motors that stall, on the simulated mill with its motors' datasheet
//! values (NEMA 23, 1.26 N·m, 2.8 A, 0.9 Ω, 2.5 mH, 300 g·cm², on 24 V, 5 mm
//! screws) and a 20 kg gantry on y: a constant acceleration beyond what the
//! motor can give stalls it (steps lost, reported), one within it does
//! not, and planning from the motor model (`[limits] model = "motors"`,
//! margin 0.7) never stalls while using the torque the motor has at low
//! speed.
//!
//! Shuttling y 40 mm at 50 mm/s, a constant acceleration stalls the y
//! motor between 14 000 and 20 000 mm/s² (one stall, 14 391 full steps
//! lost at 20 000): what sets it is the torque at low speed (23 500 mm/s²
//! at rest, without margin). Near 50 mm/s the motor has a fifth of its
//! holding torque, but the ramp spends too little time there for the
//! rotor to fall two full steps behind.

use osap_machine::config::{MachineFile, MotorModelKeys, PlannerModel};
use osap_machine::gcode;
use osap_machine::job::{from_gcode, from_svg, gcode_options, Program};
use osap_machine::machine::drive::start_position;
use osap_machine::sim::SimOptions;
use osap_machine::svg::{self, SvgOptions};
use osap_machine::Machine;
use osap_sim::machine::virtual_runtime;

const NEMA23: MotorModelKeys = MotorModelKeys {
    holding_torque_nm: 1.26,
    rated_current_a: 2.8,
    resistance_ohm: 0.9,
    inductance_mh: 2.5,
    supply_v: 24.0,
    rotor_inertia_gcm2: 300.0,
    steps_per_rev: 200.0,
};

/// The mill with motor models and masses; every acceleration `accel`
/// (mm/s²), planned from the motors when `motors`.
fn mill(accel: f64, motors: bool) -> MachineFile {
    let mut cfg = MachineFile::load(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/machines/mill.toml"
    ))
    .unwrap();
    for m in cfg.motors.values_mut() {
        m.model = Some(NEMA23);
    }
    for (axis, kg) in [("x", 12.0), ("y", 20.0), ("z", 4.0)] {
        let a = cfg.axes.get_mut(axis).unwrap();
        a.acceleration = accel;
        a.moving_mass_kg = Some(kg);
    }
    cfg.limits.acceleration = accel;
    if motors {
        cfg.limits.model = Some(PlannerModel::Motors);
    }
    cfg.validate().unwrap();
    cfg
}

/// Back and forth along y, 40 mm at 50 mm/s (where the motor has a fifth
/// of its holding torque), ten times; returns (seconds, stalls, full
/// steps lost).
async fn shuttle(cfg: &MachineFile) -> (f64, usize, f64) {
    let m = Machine::simulate_with(cfg, SimOptions::VIRTUAL)
        .await
        .unwrap();
    m.set_position([150.0, 100.0, -10.0]).unwrap();
    let t0 = tokio::time::Instant::now();
    for k in 0..10 {
        let y = if k % 2 == 0 { 140.0 } else { 100.0 };
        m.goto_via_queue([150.0, y, -10.0], 50.0).await.unwrap();
    }
    m.idle().await.unwrap();
    let s = t0.elapsed().as_secs_f64();
    let stalls = m.sim_stalls();
    m.stop().await.unwrap();
    let y = stalls.iter().find(|s| s.motor == "y").unwrap();
    (s, y.stalls, y.lost_full_steps)
}

#[test]
fn constant_acceleration_past_the_torque_stalls_and_the_motor_model_does_not() {
    virtual_runtime().unwrap().block_on(async {
        let (t_slow, stalls, _) = shuttle(&mill(3000.0, false)).await;
        assert_eq!(stalls, 0, "3000 mm/s² stalled");
        let (_, stalls, _) = shuttle(&mill(14_000.0, false)).await;
        assert_eq!(stalls, 0, "14 000 mm/s² stalled");
        let (_, stalls, lost) = shuttle(&mill(20_000.0, false)).await;
        assert!(
            stalls > 0 && lost > 1000.0,
            "20 000 mm/s²: {stalls} stalls, {lost} steps lost"
        );
        // The model, with a 0.7 margin, plans up to 16 000 mm/s² at rest
        // and 3000 at 50 mm/s.
        let (t_model, stalls, _) = shuttle(&mill(30_000.0, true)).await;
        assert_eq!(stalls, 0, "the motor model stalled");
        eprintln!("shuttle: constant 3000 mm/s² {t_slow:.3} s, motor model {t_model:.3} s");
        assert!(t_model < t_slow, "{t_model} vs {t_slow}");
    });
}

/// The shipped machine `name`, with its motors' datasheet values and
/// moving masses as shipped, at one constant acceleration `Some(a)` on
/// every axis and the toolhead, or planned from its motors (`None`; each
/// axis's ceiling then out of the way).
fn shipped(name: &str, accel: Option<f64>) -> MachineFile {
    let mut cfg = MachineFile::load(format!(
        "{}/../examples/machines/{name}.toml",
        env!("CARGO_MANIFEST_DIR")
    ))
    .unwrap();
    let toolhead: Vec<String> = cfg.axis_names()[..cfg.toolhead_axes()]
        .iter()
        .map(|a| a.to_string())
        .collect();
    for axis in toolhead {
        cfg.axes.get_mut(&axis).unwrap().acceleration = accel.unwrap_or(1e7);
    }
    match accel {
        Some(a) => cfg.limits.acceleration = a,
        None => cfg.limits.model = Some(PlannerModel::Motors),
    }
    cfg.validate().unwrap();
    cfg
}

fn program(cfg: &MachineFile, job: &str) -> Program {
    let text = std::fs::read_to_string(format!(
        "{}/../examples/jobs/{job}",
        env!("CARGO_MANIFEST_DIR")
    ))
    .unwrap();
    if job.ends_with(".svg") {
        let drawing = svg::read(&text, &SvgOptions::default()).unwrap();
        from_svg(cfg, &drawing, cfg.limits.velocity / 2.0).unwrap()
    } else {
        let g = gcode::read_with(&text, &gcode_options(cfg, None)).unwrap();
        from_gcode(cfg, &g, &start_position(cfg)).unwrap()
    }
}

/// Runs `job` on the simulated machine from `at`: the seconds it took and
/// the stalls of all motors.
async fn run_job(cfg: &MachineFile, job: &str, at: &[f64]) -> (f64, usize) {
    let p = program(cfg, job);
    let m = Machine::simulate_with(cfg, SimOptions::VIRTUAL)
        .await
        .unwrap();
    m.set_position(at).unwrap();
    let t0 = tokio::time::Instant::now();
    m.run_program(&p, |_| {}).await.unwrap();
    m.idle().await.unwrap();
    let took = t0.elapsed().as_secs_f64();
    let stalls = m.sim_stalls().iter().map(|s| s.stalls).sum();
    m.stop().await.unwrap();
    (took, stalls)
}

/// One shipped job against acceleration: the highest constant
/// acceleration that never stalls (found to within 10 %), the job's time
/// there, at the file's own acceleration and planned from the motors, and
/// the planned time with no acceleration limit at all: what no planner of
/// acceleration can beat.
async fn standing(name: &str, job: &str, at: &[f64]) {
    let file_accel = shipped(name, None).limits.acceleration;
    let (t_file, stalls) = run_job(&shipped(name, Some(file_accel)), job, at).await;
    assert_eq!(stalls, 0, "{name}: the file's {file_accel} mm/s² stalled");
    let (mut lo, mut t_lo) = (file_accel, t_file);
    let mut hi = lo;
    loop {
        hi *= 2.0;
        assert!(hi < 1e7, "{name}: no stall below {hi} mm/s²");
        let (t, stalls) = run_job(&shipped(name, Some(hi)), job, at).await;
        if stalls > 0 {
            break;
        }
        (lo, t_lo) = (hi, t);
    }
    while hi / lo > 1.1 {
        let mid = (lo * hi).sqrt();
        let (t, stalls) = run_job(&shipped(name, Some(mid)), job, at).await;
        if stalls > 0 {
            hi = mid;
        } else {
            (lo, t_lo) = (mid, t);
        }
    }
    let (_, above) = run_job(&shipped(name, Some(1.2 * lo)), job, at).await;
    let (t_model, model_stalls) = run_job(&shipped(name, None), job, at).await;
    let unlimited = shipped(name, Some(1e7));
    let start = start_position(&unlimited);
    let t_floor = program(&unlimited, job)
        .planned_seconds(&unlimited, &start)
        .unwrap();
    let best = shipped(name, Some(lo));
    let t_best_planned = program(&best, job).planned_seconds(&best, &start).unwrap();
    println!(
        "| {name} | {job} | {t_file:.3} s ({file_accel}) | {t_lo:.3} s ({lo:.0}) | {above} | {t_model:.3} s | {model_stalls} | {:.1} % |",
        100.0 * (1.0 - t_floor / t_best_planned)
    );
    assert_eq!(model_stalls, 0, "{name}: the motor model stalled");
    assert!(above > 0, "{name}: 1.2 × {lo:.0} mm/s² did not stall");
    // The model uses the torque the motors have (less its margin): it
    // beats the file's acceleration, and comes within 1 % of the best
    // constant one, which has no margin at all.
    assert!(t_model < t_file, "{name}: {t_model} vs {t_file}");
    assert!(t_model < 1.01 * t_lo, "{name}: {t_model} vs {t_lo}");
    // Why it cannot be 10 % faster: even unlimited acceleration would
    // save less than that on these jobs (their time is in cruising,
    // cornering and the tool's waits, not in ramps).
    assert!(
        t_floor > 0.9 * t_best_planned,
        "{name}: {t_floor} vs {t_best_planned}"
    );
}

#[test]
fn the_plotter_drawing_against_its_motors() {
    virtual_runtime().unwrap().block_on(async {
        let cfg = shipped("plotter", None);
        standing("plotter", "drawing.svg", &start_position(&cfg)).await;
    });
}

#[test]
fn the_mill_part_against_its_motors() {
    virtual_runtime()
        .unwrap()
        .block_on(standing("mill", "part.gcode", &[150.0, 100.0, -40.0]));
}

/// A job's `M203` changes only the speed (the motors' model stays), and
/// an `M204` caps the model's acceleration (said once in the warnings).
#[test]
fn a_jobs_m203_leaves_the_model_and_m204_caps_it() {
    let cfg = shipped("printer", None);
    let start = start_position(&cfg);
    let moves: String = (0..20)
        .map(|k| format!("G1 X{} Y{} F18000\n", 20 + 8 * (k % 2), 20 + 3 * k))
        .collect();
    let plan = |head: &str| {
        let text = format!("G21 G90\n{head}{moves}");
        let g = gcode::read_with(&text, &gcode_options(&cfg, None)).unwrap();
        let p = from_gcode(&cfg, &g, &start).unwrap();
        (p.planned_seconds(&cfg, &start).unwrap(), p.warnings)
    };
    let (model, warnings) = plan("");
    assert!(warnings.is_empty(), "{warnings:?}");
    let (same, warnings) = plan("M203 X300 Y300\n");
    assert!((same - model).abs() < 1e-9, "{same} vs {model}");
    assert!(warnings.is_empty(), "{warnings:?}");
    let (capped, warnings) = plan("M204 P1000\nM203 X300 Y300\n");
    assert!(capped > 1.5 * model, "{capped} vs {model}");
    assert_eq!(warnings.len(), 1, "{warnings:?}");
    assert!(warnings[0].contains("M204") && warnings[0].contains("caps"));
    // The same job at a constant 1000 mm/s²: the M204 (and the M203 after
    // it, which keeps it) plans exactly that.
    let constant = shipped("printer", Some(1000.0));
    let text = format!("G21 G90\n{moves}");
    let g = gcode::read_with(&text, &gcode_options(&constant, None)).unwrap();
    let at_1000 = from_gcode(&constant, &g, &start)
        .unwrap()
        .planned_seconds(&constant, &start)
        .unwrap();
    assert!(
        (capped - at_1000).abs() < 1e-6 * at_1000,
        "{capped} vs {at_1000}"
    );
}
