//! The resonance example, run as its binary on the simulated plotter in
//! virtual time: it finds y's 38 Hz mode and recommends a shaper.

use std::process::Command;

#[test]
fn resonance_finds_the_plotters_y_mode() {
    let out = std::env::temp_dir().join(format!("osap-resonance-example-{}", std::process::id()));
    let o = Command::new(env!("CARGO_BIN_EXE_resonance"))
        .arg("--out")
        .arg(&out)
        .output()
        .expect("run the example");
    let (stdout, stderr) = (
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr),
    );
    println!("{stdout}{stderr}");
    assert!(o.status.success(), "{stdout}\n{stderr}");
    // "mode: natural frequency 37.98 Hz, damping ratio 0.100 ..."
    let hz: f64 = stdout
        .lines()
        .find_map(|l| l.strip_prefix("mode: natural frequency "))
        .and_then(|l| l.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no mode line in:\n{stdout}"));
    assert!((hz / 38.0 - 1.0).abs() < 0.02, "{hz} Hz");
    assert!(stdout.contains("recommended shaper: "), "{stdout}");
    for f in ["response.csv", "samples.csv", "bode.svg"] {
        assert!(out.join(f).exists(), "{f}");
    }
    let _ = std::fs::remove_dir_all(&out);
}
