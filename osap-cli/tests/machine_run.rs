//! `osap run|home|jog|move` on machines simulated from their machine files,
//! in virtual time, as a user runs them: exit codes, summaries, the files
//! `--out` receives, and refusals before any motion.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

mod common;

fn example(path: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../examples")
        .join(path)
}

/// One machine at a time: the simulated machines of these tests share two
/// cores, and one of them runs in real time, where a starved simulation
/// would miss its deadlines.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn serial() -> std::sync::MutexGuard<'static, ()> {
    ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

fn osap(args: &[&str], cwd: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_osap"))
        .args(args)
        .current_dir(cwd)
        .output()
        .unwrap()
}

fn text(o: &Output) -> String {
    format!(
        "{}\n{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("osap-run-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn plotter_draws_the_example_drawing() {
    let _one = serial();
    let dir = scratch("plotter");
    let machine = example("machines/plotter.toml");
    let job = example("jobs/drawing.svg");
    let o = osap(
        &[
            "run",
            s(&machine),
            s(&job),
            "--sim",
            "--fast",
            "--out",
            "out",
        ],
        &dir,
    );
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    for want in [
        "planned duration",
        "executed duration",
        "largest following error x",
        "largest following error y",
        "largest vibration x",
        "largest vibration y",
        "faults: none",
        "wrote 5 files to out",
    ] {
        assert!(t.contains(want), "{want:?} missing in\n{t}");
    }
    for f in [
        "planned.csv",
        "executed.csv",
        "path.svg",
        "speed.svg",
        "error.svg",
    ] {
        let p = dir.join("out").join(f);
        assert!(p.metadata().map(|m| m.len() > 100).unwrap_or(false), "{f}");
    }
    // Header, seconds, machine axes by name, the simulated vibration of
    // the axes with a [sim.axes] resonance, the stalls of the motors
    // with datasheet values and the duty the pen's module applied (the
    // pen is streamed with the motion); executed at ≥ 1 kHz.
    let executed = std::fs::read_to_string(dir.join("out/executed.csv")).unwrap();
    let mut lines = executed.lines();
    assert_eq!(
        lines.next(),
        Some("t,x,y,vibration_x,vibration_y,stalled_a,stalled_b,tool_pen")
    );
    let rows: Vec<Vec<f64>> = lines
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    let times: Vec<f64> = rows.iter().map(|r| r[0]).collect();
    // The pen (0.05 up, 0.075 down) is up at both ends and goes down
    // for each of the drawing's 4 strokes.
    let pen: Vec<f64> = rows.iter().map(|r| r[7]).collect();
    for end in [pen[0], pen[pen.len() - 1]] {
        assert!((end - 0.05).abs() < 1e-4, "{end}");
    }
    let downs = pen
        .windows(2)
        .filter(|w| w[0] < 0.0625 && w[1] >= 0.0625)
        .count();
    assert_eq!(downs, 4, "pen-down steps");
    let span = times.last().unwrap() - times.first().unwrap();
    assert!(span > 5.0, "{span}");
    assert!(
        times.len() as f64 >= 1000.0 * span * 0.99,
        "{} samples over {span} s",
        times.len()
    );
    // Following error within a few steps (12.5 µm each).
    for axis in ["x", "y"] {
        let line = t
            .lines()
            .find(|l| l.starts_with(&format!("largest following error {axis}:")))
            .unwrap();
        let mm: f64 = line.split_whitespace().nth(4).unwrap().parse().unwrap();
        assert!(mm < 0.1, "{line}");
    }
}

#[test]
fn mill_cuts_the_example_part() {
    let _one = serial();
    let dir = scratch("mill");
    let o = osap(
        &[
            "run",
            s(&example("machines/mill.toml")),
            s(&example("jobs/part.gcode")),
            "--sim",
            "--fast",
            "--out",
            "out",
        ],
        &dir,
    );
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(t.contains("largest following error z"), "{t}");
    let planned = std::fs::read_to_string(dir.join("out/planned.csv")).unwrap();
    assert!(
        planned.starts_with("t,x,y,z\n"),
        "{}",
        &planned[..40.min(planned.len())]
    );
}

#[test]
fn a_cam_file_runs_once_placed_with_origin() {
    let _one = serial();
    let dir = scratch("origin");
    let mill = example("machines/mill.toml");
    let job = example("jobs/slot.ngc");
    // Its z = +1 in clearance is above the mill's travel (z up to 0).
    let o = osap(&["run", s(&mill), s(&job), "--sim", "--fast"], &dir);
    let t = text(&o);
    assert_eq!(o.status.code(), Some(2), "{t}");
    assert!(
        t.contains("line 12: axis z would go to 25.400") && t.contains("nothing moved"),
        "{t}"
    );
    // --offset is for drawings.
    let o = osap(
        &[
            "run",
            s(&mill),
            s(&job),
            "--sim",
            "--fast",
            "--offset",
            "20,20",
        ],
        &dir,
    );
    assert_eq!(o.status.code(), Some(2));
    assert!(text(&o).contains("--origin X,Y,Z"), "{}", text(&o));
    // The work's top at z = -60, its corner at (20, 20).
    let o = osap(
        &[
            "run",
            s(&mill),
            s(&job),
            "--sim",
            "--fast",
            "--origin",
            "20,20,-60",
            "--out",
            "out",
        ],
        &dir,
    );
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(
        t.contains("G-code dialect     rs274ngc (the default for kind = \"mill\")"),
        "{t}"
    );
    assert!(t.contains("faults: none"), "{t}");
    assert!(!t.contains("warning:"), "{t}");
    // The cut reaches 0.05 in below the work's top, and no deeper.
    let planned = std::fs::read_to_string(dir.join("out/planned.csv")).unwrap();
    let lowest = planned
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(3).unwrap().parse::<f64>().unwrap())
        .fold(f64::INFINITY, f64::min);
    assert!((lowest - (-61.27)).abs() < 1e-3, "{lowest}");
}

#[test]
fn jobs_that_leave_the_travel_are_refused_before_motion() {
    let _one = serial();
    let dir = scratch("refuse");
    std::fs::write(dir.join("far.gcode"), "G21 G90\nG0 X10 Y10\nG1 X250 F600\n").unwrap();
    let o = osap(
        &[
            "run",
            s(&example("machines/plotter.toml")),
            "far.gcode",
            "--sim",
            "--fast",
        ],
        &dir,
    );
    let t = text(&o);
    assert_eq!(o.status.code(), Some(2), "{t}");
    assert!(
        t.contains("line 3") && t.contains("axis x") && t.contains("nothing moved"),
        "{t}"
    );
    // Nothing started, so no output folder either.
    let made: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().starts_with("osap-run-"))
        .collect();
    assert!(made.is_empty());
}

#[test]
fn bad_arguments_and_files_get_clear_messages() {
    let _one = serial();
    let dir = scratch("bad");
    let plotter = example("machines/plotter.toml");
    // An unknown job type.
    std::fs::write(dir.join("job.txt"), "hello").unwrap();
    let o = osap(&["run", s(&plotter), "job.txt", "--sim", "--fast"], &dir);
    assert_eq!(o.status.code(), Some(2));
    assert!(text(&o).contains("unknown job type"), "{}", text(&o));
    // A machine file with a non-positive step count names the key.
    let bad = std::fs::read_to_string(&plotter).unwrap().replacen(
        "full_steps_per_unit = 5.0",
        "full_steps_per_unit = 0.0",
        1,
    );
    std::fs::write(dir.join("bad.toml"), bad).unwrap();
    let o = osap(&["home", "bad.toml", "--sim", "--fast"], &dir);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        text(&o).contains("motors.a.full_steps_per_unit"),
        "{}",
        text(&o)
    );
    // --fast needs --sim.
    let o = osap(&["home", s(&plotter), "--fast"], &dir);
    assert_eq!(o.status.code(), Some(2));
    assert!(text(&o).contains("--sim"), "{}", text(&o));
    // A missing machine file.
    let o = osap(&["home", "nope.toml", "--sim"], &dir);
    assert_eq!(o.status.code(), Some(2));
    assert!(text(&o).contains("nope.toml"), "{}", text(&o));
}

#[test]
fn one_off_commands_home_jog_and_move() {
    let _one = serial();
    let dir = scratch("oneoff");
    let plotter = example("machines/plotter.toml");
    let o = osap(&["home", s(&plotter), "--sim", "--fast"], &dir);
    assert!(o.status.success(), "{}", text(&o));
    // The switches sit 1 mm beyond the travel; homing backs off 2 mm.
    assert!(text(&o).contains("x=1.000 y=1.000"), "{}", text(&o));
    let o = osap(
        &[
            "move",
            s(&plotter),
            "--sim",
            "--fast",
            "--to",
            "x=50",
            "--to",
            "y=40",
        ],
        &dir,
    );
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("x=50.000 y=40.000"), "{}", text(&o));
    let o = osap(
        &["move", s(&plotter), "--sim", "--fast", "--to", "x=500"],
        &dir,
    );
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("outside its travel"), "{}", text(&o));
    let o = osap(
        &[
            "jog",
            s(&plotter),
            "--sim",
            "--fast",
            "--axis",
            "y",
            "--distance",
            "-5",
        ],
        &dir,
    );
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("y=-5.000"), "{}", text(&o));
}

#[test]
fn a_job_runs_over_tcp_on_a_machine_served_from_its_machine_file() {
    let _one = serial();
    let dir = scratch("tcp");
    let mill = example("machines/mill.toml");
    let (_server, addr) = common::serve(&mill);
    // Real time, so a short job; the simulated carriage stands mid-travel,
    // where --no-home takes the machine to be at its start (0, 0, 0).
    std::fs::write(
        dir.join("short.gcode"),
        "G21 G90\nG1 X5 Y5 F1200\nG1 Z-2 F300\nG1 X10\nG0 Z0\n",
    )
    .unwrap();
    let o = osap(
        &[
            "run",
            s(&mill),
            "short.gcode",
            "--tcp",
            &addr,
            "--no-home",
            "--out",
            "out",
        ],
        &dir,
    );
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("(3 modules, connected)"), "{}", text(&o));
    assert!(dir.join("out/executed.csv").exists());
}
