//! `osap resonance` on the simulated plotter in virtual time: it prints the
//! mode and the shaper, writes its files, and `--write` puts the shaper
//! into (a copy of) the machine file; an axis without an accelerometer is
//! refused with exit code 2.

use std::path::PathBuf;
use std::process::Command;

fn plotter() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../examples/machines/plotter.toml")
}

/// The number after `label` in `text` (up to the next space or comma).
fn number_after(text: &str, label: &str) -> f64 {
    let at = text
        .find(label)
        .unwrap_or_else(|| panic!("no {label:?} in:\n{text}"))
        + label.len();
    let digits: String = text[at..]
        .chars()
        .take_while(|c| c.is_ascii_digit() || *c == '.')
        .collect();
    digits
        .parse()
        .unwrap_or_else(|_| panic!("no number after {label:?} in:\n{text}"))
}

/// The raw response peak within 2 % of where the model's `|H|` peaks
/// (`model_peak_hz`: 37.6 Hz for 38 Hz at damping 0.1, 1 % below the
/// natural frequency), the bound docs/resonance.md gives the raw peak. A 4 s
/// chirp resolves 1 / 4 s = 0.25 Hz (0.7 % of 38 Hz).
const WITHIN: f64 = 0.02;

/// The fitted natural frequency, and the shaper tuned to it, within 0.5 %
/// of the model's (it comes out within 0.1 %).
const FIT_WITHIN: f64 = 0.005;

/// `[sim.axes.y] resonance_hz` of the shipped plotter.
fn osap_machine_model_hz() -> f64 {
    sim_axis_y("resonance_hz = ")
}

/// `[sim.axes.y] damping_ratio` of the shipped plotter.
fn model_damping() -> f64 {
    sim_axis_y("damping_ratio = ")
}

fn sim_axis_y(key: &str) -> f64 {
    let text = std::fs::read_to_string(plotter()).unwrap();
    let section = &text[text.find("[sim.axes.y]").expect("a [sim.axes.y] section")..];
    number_after(section, key)
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
    // The simulated y axis rings at the file's [sim.axes.y] resonance_hz.
    let model = osap_machine_model_hz();
    assert_eq!(model, 38.0);
    let model_peak = osap_machine::resonance::analysis::model_peak_hz(model, model_damping());
    for (label, expected, within) in [
        ("peak: ", model_peak, WITHIN),
        ("mode: natural frequency ", model, FIT_WITHIN),
    ] {
        let found = number_after(&stdout, label);
        eprintln!("{label}{found} Hz, model {expected:.2} Hz");
        assert!(
            (found - expected).abs() <= within * expected,
            "{label}{found} Hz against the model's {expected:.2} Hz:\n{stdout}"
        );
    }
    assert!(stdout.contains("recommended shaper: "), "{stdout}");
    for f in ["response.csv", "samples.csv", "bode.svg"] {
        assert!(out.join(f).exists(), "{f}");
    }
    let text = std::fs::read_to_string(&machine).unwrap();
    let line = text
        .lines()
        .find(|l| l.starts_with("shaper = "))
        .unwrap_or_else(|| panic!("no shaper line:\n{text}"));
    let written = number_after(line, "freq_hz = ");
    assert!(
        (written - model).abs() <= FIT_WITHIN * model,
        "{line} against the model's {model} Hz"
    );
    // The shaper names the run it was fitted from, and that run's record
    // holds the file as it was before the shaper went in, and the data.
    let record_file = out.join("run.json");
    assert!(
        line.contains(&format!(
            "fitted_from = {:?}",
            record_file.display().to_string()
        )),
        "{line}"
    );
    let record: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&record_file).unwrap()).unwrap();
    assert_eq!(record["command"], "resonance");
    assert_eq!(record["outcome"]["status"], "ok");
    assert_eq!(record["options"]["axis"], "y");
    assert!(!record["machine"]["text"]
        .as_str()
        .unwrap()
        .contains("shaper = "));
    let fitted = record["figures"]["shaper_freq_hz"].as_f64().unwrap();
    assert!((fitted - written).abs() < 0.01, "{fitted} vs {written}");
    let files: Vec<&str> = record["files"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["path"].as_str().unwrap())
        .collect();
    for f in ["response.csv", "samples.csv", "bode.svg"] {
        assert!(files.contains(&f), "{f} in {files:?}");
    }
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

/// Runs `osap` with `args` and returns stdout, failing on a non-zero exit.
fn osap(args: &[&std::ffi::OsStr]) -> String {
    let o = Command::new(env!("CARGO_BIN_EXE_osap"))
        .args(args)
        .output()
        .unwrap();
    let (stdout, stderr) = (
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr),
    );
    assert!(o.status.success(), "{args:?}:\n{stdout}\n{stderr}");
    stdout.into_owned()
}

/// The user's flow: measure x and y with `--write`, then run the shipped
/// drawing on the file as shipped and on the written one. The shapers
/// `osap resonance` recommends cut the largest residual vibration of each
/// axis at least 5× (docs/resonance.md records the figures), and
/// `executed.csv` carries the vibration columns.
#[test]
fn the_recommended_shapers_cut_the_drawings_vibration_5x() {
    let dir = std::env::temp_dir().join(format!("osap-shaped-run-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let machine = dir.join("plotter.toml");
    std::fs::copy(plotter(), &machine).unwrap();
    for axis in ["x", "y"] {
        let out = dir.join(format!("resonance-{axis}"));
        let stdout = osap(&[
            "resonance".as_ref(),
            "--sim".as_ref(),
            "--fast".as_ref(),
            "--axis".as_ref(),
            axis.as_ref(),
            "--write".as_ref(),
            machine.as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
        ]);
        assert!(stdout.contains("recommended shaper: "), "{stdout}");
    }
    let text = std::fs::read_to_string(&machine).unwrap();
    assert_eq!(text.matches("\nshaper = ").count(), 2, "{text}");
    let drawing = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../examples/jobs/drawing.svg");
    let run = |file: &std::path::Path, out: &str| -> (String, PathBuf) {
        let out = dir.join(out);
        let stdout = osap(&[
            "run".as_ref(),
            file.as_os_str(),
            drawing.as_os_str(),
            "--sim".as_ref(),
            "--fast".as_ref(),
            "--out".as_ref(),
            out.as_os_str(),
        ]);
        (stdout, out)
    };
    let (plain, _) = run(&plotter(), "plain");
    let (shaped, shaped_out) = run(&machine, "shaped");
    for axis in ["x", "y"] {
        let label = format!("largest vibration {axis}: ");
        let (before, after) = (number_after(&plain, &label), number_after(&shaped, &label));
        eprintln!("vibration {axis}: {before} mm unshaped, {after} mm shaped");
        // The unshaped ring is the size of an acceleration step's
        // deflection (2500 mm/s² over (2π·40 Hz)²: 0.04 mm).
        assert!(before > 0.02, "{plain}");
        assert!(
            after * 5.0 <= before,
            "{axis}: {after} vs {before}\n{shaped}"
        );
    }
    let executed = std::fs::read_to_string(shaped_out.join("executed.csv")).unwrap();
    let header = executed.lines().next().unwrap();
    assert_eq!(
        header,
        "t,x,y,vibration_x,vibration_y,stalled_a,stalled_b,tool_pen"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
