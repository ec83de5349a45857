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
/// 100 000 step ticks/s.
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

/// A machine whose speeds need steps faster than the step tick is refused
/// before anything moves, naming both fixes; late steps from what the
/// check cannot see (an arm near a singular pose, a script's own points)
/// are the module's fault to report, tested in osap-machine's
/// `machine_stops`.
#[test]
fn a_machine_that_would_step_late_is_refused_with_the_fix() {
    let dir = std::env::temp_dir().join(format!("osap-run-late-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let machine_path = dir.join("fast.toml");
    std::fs::write(&machine_path, FAST_AXIS).unwrap();
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
    let text = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{text}");
    assert!(
        text.contains("motors.x: axes.x.velocity 40.0 needs 128000 microsteps/s")
            && text
                .contains("lower axes.x.velocity to at most 31.2 or set motors.x.microsteps to 16"),
        "{text}"
    );
}
