//! `osap resonance` on the simulated plotter in virtual time: it prints the
//! mode and the shaper, writes its files, and `--write` puts the shaper
//! into (a copy of) the machine file; an axis without an accelerometer is
//! refused with exit code 2.

use std::path::PathBuf;
use std::process::Command;

fn plotter() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../examples/machines/plotter.toml")
}

#[test]
fn resonance_measures_the_plotters_y_and_writes_its_shaper() {
    let dir = std::env::temp_dir().join(format!("osap-resonance-cli-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let machine = dir.join("plotter.toml");
    std::fs::copy(plotter(), &machine).unwrap();
    let out = dir.join("out");
    let o = Command::new(env!("CARGO_BIN_EXE_osap"))
        .args([
            "resonance",
            "--sim",
            "--fast",
            "--axis",
            "y",
            "--seconds",
            "4",
            "--write",
        ])
        .arg(&machine)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let (stdout, stderr) = (
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr),
    );
    assert!(o.status.success(), "{stdout}\n{stderr}");
    assert!(stdout.contains("mode: natural frequency 3"), "{stdout}");
    assert!(stdout.contains("recommended shaper: "), "{stdout}");
    for f in ["response.csv", "samples.csv", "bode.svg"] {
        assert!(out.join(f).exists(), "{f}");
    }
    let text = std::fs::read_to_string(&machine).unwrap();
    let line = text
        .lines()
        .find(|l| l.starts_with("shaper = "))
        .unwrap_or_else(|| panic!("no shaper line:\n{text}"));
    assert!(line.contains("freq_hz = 3"), "{line}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn an_axis_without_an_accelerometer_is_refused_with_2() {
    let mill = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../examples/machines/mill.toml");
    let o = Command::new(env!("CARGO_BIN_EXE_osap"))
        .args(["resonance", "--sim", "--fast", "--axis", "x"])
        .arg(&mill)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("accelerometer = {"), "{stderr}");
    let o = Command::new(env!("CARGO_BIN_EXE_osap"))
        .args(["resonance", "--sim", "--fast", "--axis", "q"])
        .arg(plotter())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("no axis \"q\""), "{stderr}");
}
