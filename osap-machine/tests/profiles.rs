//! The time jerk limiting costs on the shipped jobs: each planned with
//! `[limits] profile = "trapezoid"` and `"scurve"` (the axes' own `jerk`).
//! `cargo test -p osap-machine --test profiles -- --nocapture` prints the
//! table docs/planner.md records.

use osap_machine::config::{MachineFile, ProfileKind};
use osap_machine::job::{self, Program};
use osap_machine::machine::drive::start_position;
use osap_machine::svg::{self, SvgOptions};

fn machine(name: &str) -> MachineFile {
    MachineFile::load(format!(
        "{}/../examples/machines/{name}.toml",
        env!("CARGO_MANIFEST_DIR")
    ))
    .unwrap()
}

fn job_text(name: &str) -> String {
    std::fs::read_to_string(format!(
        "{}/../examples/jobs/{name}",
        env!("CARGO_MANIFEST_DIR")
    ))
    .unwrap()
}

fn program(cfg: &MachineFile, name: &str, origin: Option<[f64; 3]>) -> Program {
    let text = job_text(name);
    if name.ends_with(".svg") {
        let drawing = svg::read(&text, &SvgOptions::default()).unwrap();
        job::from_svg(cfg, &drawing, cfg.limits.velocity / 2.0).unwrap()
    } else {
        let options = job::gcode_options(cfg, origin);
        let g = osap_machine::gcode::read_with(&text, &options).unwrap();
        job::from_gcode(cfg, &g, &start_position(cfg)).unwrap()
    }
}

#[test]
fn jerk_limiting_costs_little_on_the_shipped_jobs() {
    let jobs: [(&str, &str, Option<[f64; 3]>); 5] = [
        ("plotter", "drawing.svg", None),
        ("mill", "part.gcode", None),
        ("mill", "slot.ngc", Some([20.0, 20.0, -60.0])),
        ("printer", "cube-first-layers.gcode", None),
        ("printer", "cube-speed-layers.gcode", None),
    ];
    println!("| machine | job | trapezoid | S-curve | cost |");
    println!("|---|---|---|---|---|");
    for (m, j, origin) in jobs {
        let mut cfg = machine(m);
        let p = program(&cfg, j, origin);
        let start = start_position(&cfg);
        cfg.limits.profile = ProfileKind::Trapezoid;
        let trapezoid = p.planned_seconds(&cfg, &start).unwrap();
        cfg.limits.profile = ProfileKind::Scurve;
        let scurve = p.planned_seconds(&cfg, &start).unwrap();
        let cost = scurve / trapezoid - 1.0;
        println!(
            "| {m} | {j} | {trapezoid:.3} s | {scurve:.3} s | {:+.1} % |",
            100.0 * cost
        );
        // Jerk limiting only ever lengthens a ramp; the shipped jerks (at
        // least 20 × the acceleration per second) keep it modest.
        assert!(cost >= 0.0, "{m} {j}: {scurve} < {trapezoid}");
        assert!(cost < 0.25, "{m} {j}: {:.1} %", 100.0 * cost);
    }
}
