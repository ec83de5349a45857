//! `osap run` on a machine that faults mid-job reports which module and
//! why, and exits with the machine-fault code (3).

use std::path::PathBuf;
use std::process::Command;

#[test]
fn a_fault_mid_job_names_the_module_and_exits_3() {
    let dir = std::env::temp_dir().join(format!("osap-run-fault-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    // The plotter with 20 mm more x travel below 0 (its switch moves there
    // too) and the simulated carriage 5 mm from that switch. With
    // --no-home the machine takes itself to be at x = 0, so a move to
    // x = -10 drives the carriage 5 mm past the switch.
    let plotter = std::fs::read_to_string(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../examples/machines/plotter.toml"),
    )
    .unwrap();
    let machine = plotter
        .replacen("[axes.x]\nmin = 0.0", "[axes.x]\nmin = -20.0", 1)
        .replacen("[sim.axes.x]\n", "[sim.axes.x]\nstart = -15.0\n", 1);
    assert_ne!(machine, plotter);
    let machine_path = dir.join("plotter.toml");
    std::fs::write(&machine_path, machine).unwrap();
    let job = dir.join("job.gcode");
    std::fs::write(&job, "G21\nG90\nG1 X-10 Y0 F1200\nG1 X5 Y0 F1200\n").unwrap();
    let out = dir.join("out");
    let o = Command::new(env!("CARGO_BIN_EXE_osap"))
        .args(["run", "--sim", "--fast", "--no-home", "--out"])
        .arg(&out)
        .arg(&machine_path)
        .arg(&job)
        .current_dir(&dir)
        .output()
        .unwrap();
    let text = format!(
        "{}\n{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    assert_eq!(o.status.code(), Some(3), "{text}");
    assert!(
        text.contains("module a") && text.contains("limit switch"),
        "{text}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// A lead-screw axis (2 mm lead, 1.8° motor: 100 full steps/mm) at 32
/// microsteps, allowed 40 mm/s: 128 000 microsteps/s, past the module's
/// 100 000 step ticks/s, so a fast move sends steps late.
const FAST_AXIS: &str = r#"
name = "fast"
[modules]
x = { name = "x" }
[motors.x]
module = "x"
full_steps_per_unit = 100.0
microsteps = 32
[axes.x]
motor = "x"
min = 0.0
max = 9.0
velocity = 40.0
acceleration = 2000.0
jerk = 100000.0
[limits]
velocity = 40.0
acceleration = 2000.0
junction_deviation = 0.02
"#;

/// Runs an 8.5 mm move at 40 mm/s on the fast axis with `limits_extra`
/// added to its `[limits]`: the exit code and what was printed.
fn run_fast_move(name: &str, limits_extra: &str) -> (Option<i32>, String) {
    let dir = std::env::temp_dir().join(format!("osap-run-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let machine = FAST_AXIS.replace(
        "junction_deviation = 0.02",
        &format!("junction_deviation = 0.02\n{limits_extra}"),
    );
    let machine_path = dir.join("fast.toml");
    std::fs::write(&machine_path, machine).unwrap();
    let job = dir.join("job.gcode");
    std::fs::write(&job, "G21\nG90\nG1 X8.5 F2400\n").unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_osap"))
        .args(["run", "--sim", "--fast", "--no-home", "--out"])
        .arg(dir.join("out"))
        .arg(&machine_path)
        .arg(&job)
        .current_dir(&dir)
        .output()
        .unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    (
        o.status.code(),
        format!(
            "{}\n{}",
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr)
        ),
    )
}

#[test]
fn late_steps_are_a_fault_that_exits_3_never_a_warning() {
    let (code, text) = run_fast_move("late", "");
    assert_eq!(code, Some(3), "{text}");
    assert!(
        text.contains("error: fault: module x was asked to step faster than its step rate"),
        "{text}"
    );
    assert!(
        text.contains("error: machine faulted: module x was asked to step faster"),
        "{text}"
    );
    assert_eq!(
        text.matches("error: fault:").count(),
        1,
        "the first late steps, once: {text}"
    );
    assert!(!text.contains("went on"), "{text}");
    assert!(!text.contains("faults: none"), "{text}");
}

#[test]
fn late_steps_within_the_files_bound_are_noted_and_the_job_passes() {
    let (code, text) = run_fast_move("late-allowed", "max_late_steps = 1000000");
    assert_eq!(code, Some(0), "{text}");
    assert!(
        text.contains("note: module x was asked to step faster than its step rate")
            && text.contains("not a stop"),
        "{text}"
    );
    assert!(!text.contains("error:"), "{text}");
    assert_eq!(text.matches("note:").count(), 1, "{text}");
}
