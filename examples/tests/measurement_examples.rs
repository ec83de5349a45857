//! The measurement examples, each run as its binary on a simulated machine
//! in virtual time: resonance (the plotter's y mode and its shaper),
//! capture (sensor streams beside a job) and level (the mill's bed, then a
//! levelled job).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn scratch(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("osap-example-{name}-{}", std::process::id()))
}

/// Runs `bin --out OUT`, prints and returns its stdout; panics on failure.
fn run(bin: &str, out: &Path) -> String {
    let o: Output = Command::new(bin)
        .arg("--out")
        .arg(out)
        .output()
        .expect("run the example");
    let (stdout, stderr) = (
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    );
    println!("{stdout}{stderr}");
    assert!(o.status.success(), "{bin}: {stdout}\n{stderr}");
    stdout
}

/// The first number after `prefix` on a line starting with it.
fn number_after(text: &str, prefix: &str) -> f64 {
    text.lines()
        .find_map(|l| l.strip_prefix(prefix))
        .and_then(|l| l.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no {prefix:?} line in:\n{text}"))
}

#[test]
fn resonance_finds_the_plotters_y_mode() {
    let out = scratch("resonance");
    let stdout = run(env!("CARGO_BIN_EXE_resonance"), &out);
    // "mode: natural frequency 37.98 Hz, damping ratio 0.100 ..."
    let hz = number_after(&stdout, "mode: natural frequency ");
    assert!((hz / 38.0 - 1.0).abs() < 0.02, "{hz} Hz");
    assert!(stdout.contains("recommended shaper: "), "{stdout}");
    for f in ["response.csv", "samples.csv", "bode.svg"] {
        assert!(out.join(f).exists(), "{f}");
    }
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn capture_records_the_accelerometers_beside_a_drawing() {
    let out = scratch("capture");
    let stdout = run(env!("CARGO_BIN_EXE_capture"), &out);
    // "job: N moves in S s; capture: R rows, 0 dropped, 0 stale"
    assert!(stdout.contains(" 0 dropped"), "{stdout}");
    for series in [
        "a.analog_read(0).value",
        "b.analog_read(0).value",
        "a.get_position.position",
    ] {
        let samples = number_after(&stdout, &format!("series {series}: "));
        assert!(samples > 1_000.0, "{series}: {samples} samples");
    }
    // Each accelerometer sees the carriage move within a few sample
    // periods of the plan's first move: one clock for both.
    for delay in stdout
        .lines()
        .filter_map(|l| l.trim().strip_prefix("first motion seen "))
    {
        let ms: f64 = delay.split_whitespace().next().unwrap().parse().unwrap();
        assert!((-1.0..=10.0).contains(&ms), "{delay}");
    }
    assert_eq!(stdout.matches("first motion seen").count(), 2, "{stdout}");
    let capture = osap_machine::capture::Capture::read(&out.join("capture.parquet")).unwrap();
    assert_eq!(capture.series.len(), 3);
    let svg = std::fs::read_to_string(out.join("timeline.svg")).unwrap();
    assert!(
        svg.contains("b.analog_read(0).value"),
        "the plot names its streams"
    );
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn level_keeps_the_tool_at_its_height_over_the_warped_bed() {
    let out = scratch("level");
    let stdout = run(env!("CARGO_BIN_EXE_level"), &out);
    assert_eq!(stdout.matches("probed (").count(), 20, "{stdout}");
    // Each probed height is the simulated bed's under the probe to within
    // a few z steps (3.1 µm each), and the fitted plane is its tilt.
    let worst = number_after(&stdout, "probe error against the simulated bed: worst ");
    assert!(worst < 0.02, "probe error {worst} mm");
    assert!(
        stdout.contains("tilt 0.00100 along x and -0.00150 along y"),
        "{stdout}"
    );
    // "tool height above the simulated bed: LO .. HI mm (target 0.5)"
    let line = stdout
        .lines()
        .find_map(|l| l.strip_prefix("tool height above the simulated bed: "))
        .unwrap_or_else(|| panic!("no height line in:\n{stdout}"));
    let v: Vec<f64> = line
        .split_whitespace()
        .filter_map(|w| w.parse().ok())
        .collect();
    let (lo, hi) = (v[0], v[1]);
    assert!(
        (lo - 0.5).abs() <= 0.05 && (hi - 0.5).abs() <= 0.05,
        "{lo}..{hi}"
    );
    let mesh = std::fs::read_to_string(out.join("mesh.toml")).unwrap();
    osap_machine::mesh::parse(&mesh).unwrap();
    assert!(out.join("mesh.svg").exists());
    let _ = std::fs::remove_dir_all(&out);
}
