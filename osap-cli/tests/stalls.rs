//! `osap run --sim` on a mill whose motors have datasheet values: a job
//! accelerating the 20 kg y gantry past what its NEMA 23 can give stalls
//! the motor; the summary says so, `executed.csv`'s `stalled_y` column
//! marks when, and the run exits with the machine-fault code. Within the
//! motor's torque, nothing stalls.

use std::path::PathBuf;
use std::process::Command;

fn examples() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../examples")
}

/// The shipped mill (NEMA 23s: 1.26 N·m, 2.8 A, 0.9 Ω, 2.5 mH, 300 g·cm²
/// on 24 V, moving 12 / 20 / 4 kg) at `accel` mm/s² everywhere.
fn mill(accel: f64) -> String {
    let mut text = std::fs::read_to_string(examples().join("machines/mill.toml")).unwrap();
    assert_eq!(text.matches("supply_v = 24.0").count(), 3);
    assert!(text.contains("moving_mass_kg = 20.0"));
    for (axis, old) in [("x", 500.0), ("y", 500.0), ("z", 200.0)] {
        let at = text.find(&format!("[axes.{axis}]\n")).unwrap();
        let line = format!("acceleration = {old:.1}");
        let i = at + text[at..].find(&line).unwrap();
        text.replace_range(i..i + line.len(), &format!("acceleration = {accel:.1}"));
    }
    let at = text.find("[limits]\n").unwrap();
    let line = "acceleration = 500.0";
    let i = at + text[at..].find(line).unwrap();
    text.replace_range(i..i + line.len(), &format!("acceleration = {accel:.1}"));
    text
}

/// Runs the shuttle (y 40 mm out and back at 50 mm/s, five times) on the
/// mill at `accel`; returns the exit code, stdout and the `stalled_y`
/// column.
fn shuttle(accel: f64, dir: &std::path::Path) -> (Option<i32>, String, Vec<f64>) {
    std::fs::create_dir_all(dir).unwrap();
    std::fs::copy(
        examples().join("machines/mill-mesh.toml"),
        dir.join("mill-mesh.toml"),
    )
    .unwrap();
    std::fs::write(dir.join("mill.toml"), mill(accel)).unwrap();
    // Not homed: the machine takes itself to be at 0 (the simulated
    // carriages boot mid-travel), so y shuttles between 0 and 40.
    let mut job = String::from("G21 G90\n");
    for _ in 0..5 {
        job += "G1 Y40 F3000\nG1 Y0 F3000\n";
    }
    job += "M2\n";
    std::fs::write(dir.join("shuttle.ngc"), job).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_osap"))
        .args([
            "run",
            "mill.toml",
            "shuttle.ngc",
            "--sim",
            "--fast",
            "--no-home",
            "--out",
            "out",
        ])
        .current_dir(dir)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout).into_owned();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(dir.join("out/executed.csv").exists(), "{stdout}\n{stderr}");
    let csv = std::fs::read_to_string(dir.join("out/executed.csv")).unwrap();
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let k = header
        .iter()
        .position(|c| *c == "stalled_y")
        .unwrap_or_else(|| panic!("{header:?}"));
    let column = lines
        .map(|l| l.split(',').nth(k).unwrap().parse().unwrap())
        .collect();
    (o.status.code(), stdout, column)
}

#[test]
fn a_stall_is_reported_and_marked_in_executed_csv() {
    let dir = std::env::temp_dir().join(format!("osap-stalls-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let (code, calm, column) = shuttle(3000.0, &dir.join("calm"));
    assert_eq!(code, Some(0), "{calm}");
    assert!(
        calm.contains("stalls: 0") && calm.contains("faults: none"),
        "{calm}"
    );
    assert!(column.iter().all(|&v| v == 0.0));
    // A stall spoils the job: no "faults: none", and the run fails with
    // the machine-fault code (3), as a fault's stop would.
    let (code, hard, column) = shuttle(28_000.0, &dir.join("hard"));
    assert_eq!(code, Some(3), "{hard}");
    assert!(!hard.contains("faults: none"), "{hard}");
    assert!(hard.contains("stalls: 1"), "{hard}");
    assert!(hard.contains("error: motor y stalled 1 times"), "{hard}");
    // Stalled from the first acceleration at 50 mm/s until the job ends
    // (the shuttle never pauses 50 ms, so the motor never holds again).
    let stalled = column.iter().filter(|&&v| v == 1.0).count();
    assert!(
        stalled > 500 && stalled < column.len(),
        "{stalled} of {}",
        column.len()
    );
    let _ = std::fs::remove_dir_all(&dir);
}
