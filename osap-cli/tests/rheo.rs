//! `osap rheo --sim --fast` end to end: the simulated printer measures its
//! melt, prints the max flow per temperature within 5 % of the simulated
//! truth and its response time, writes its data and plots, and `--write`
//! puts `[axes.e.model]` into the machine file with its comments kept;
//! `osap run --temperature` then refuses what it cannot set before any
//! motion.

use std::path::PathBuf;
use std::process::Command;

/// The example printer without its hand-set flow cap and pressure advance
/// (the model replaces them), in `dir`.
fn printer(dir: &std::path::Path) -> PathBuf {
    let text = std::fs::read_to_string(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../examples/machines/printer.toml"),
    )
    .unwrap();
    let text: String = text
        .lines()
        .filter(|l| !l.starts_with("max_volumetric_speed") && !l.starts_with("pressure_advance"))
        .map(|l| format!("{l}\n"))
        .collect();
    let path = dir.join("printer.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// The truth of the example's `[sim.axes.e]`: flow at 32 N (80 % of the
/// 40 N grip), `(32 / (8 e^(−0.02 (T − 210))))^(1/0.6)`.
fn true_max_flow(t: f64) -> f64 {
    (32.0 / (8.0 * (-0.02 * (t - 210.0)).exp())).powf(1.0 / 0.6)
}

#[test]
fn rheo_measures_fits_writes_the_model_and_run_takes_it() {
    let dir = std::env::temp_dir().join(format!("osap-rheo-cli-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let machine = printer(&dir);
    let out_dir = dir.join("run");
    let out = Command::new(env!("CARGO_BIN_EXE_osap"))
        .args(["rheo"])
        .arg(&machine)
        .args([
            "--sim",
            "--fast",
            "--temps",
            "200,215,230",
            "--write",
            "--out",
        ])
        .arg(&out_dir)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stdout}\n{stderr}");
    println!("{stdout}");
    for t in [200.0, 215.0, 230.0] {
        let prefix = format!("max flow at {t} °C: ");
        let line = stdout
            .lines()
            .find(|l| l.starts_with(&prefix))
            .unwrap_or_else(|| panic!("no {prefix:?} in\n{stdout}"));
        let q: f64 = line[prefix.len()..]
            .split_whitespace()
            .next()
            .unwrap()
            .parse()
            .unwrap();
        let truth = true_max_flow(t);
        assert!((q / truth - 1.0).abs() < 0.05, "{line}: truth {truth:.2}");
    }
    // "response time: 50.0 ± 0.1 ms ...": the simulated melt's is 45 ms.
    let tau: f64 = stdout
        .lines()
        .find_map(|l| l.strip_prefix("response time: "))
        .and_then(|l| l.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no response time in\n{stdout}"));
    assert!((tau / 45.0 - 1.0).abs() < 0.15, "τ {tau} ms, truth 45");
    for f in [
        "force.csv",
        "inflow.csv",
        "steady.csv",
        "force_flow.svg",
        "step_response.svg",
    ] {
        let len = std::fs::metadata(out_dir.join(f)).map_or(0, |m| m.len());
        assert!(len > 200, "{f}: {len} bytes");
    }
    // The model is in the file, every comment kept, and it loads.
    let written = std::fs::read_to_string(&machine).unwrap();
    assert!(written.contains("[axes.e.model]"), "{written}");
    assert!(written.contains("# The simulated melt behind the extruder"));
    let cfg = osap_machine::config::MachineFile::load(&machine).unwrap();
    let model = cfg.extruder().unwrap().extruder.model.clone().unwrap();
    assert_eq!(model.temp_range, [200.0, 230.0]);
    // The model names the run record it was fitted from: that record
    // holds the file as it was before the model went in.
    let record_file = out_dir.join("run.json");
    assert_eq!(
        model.fitted_from.as_deref(),
        Some(record_file.display().to_string().as_str())
    );
    let record: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&record_file).unwrap()).unwrap();
    assert_eq!(record["command"], "rheo");
    assert_eq!(record["outcome"]["status"], "ok");
    assert!(!record["machine"]["text"]
        .as_str()
        .unwrap()
        .contains("[axes.e.model]"));
    // The printed response time (ms, one decimal) is the figure's.
    let recorded_ms = record["figures"]["response_time_s"].as_f64().unwrap() * 1e3;
    assert!(
        (recorded_ms - tau).abs() <= 0.05,
        "{recorded_ms} ms vs {tau} ms"
    );

    // osap run refuses a temperature the hotend cannot hold, and one for a
    // drawing, before anything moves.
    let examples = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../examples/jobs");
    for (job, temperature, says) in [
        ("cube-speed-layers.gcode", "400", "max_temp 290"),
        (
            "cube-speed-layers.gcode",
            "warm",
            "give auto or a temperature",
        ),
        ("drawing.svg", "auto", "a drawing heats nothing"),
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_osap"))
            .arg("run")
            .arg(&machine)
            .arg(examples.join(job))
            .args(["--sim", "--fast", "--temperature", temperature])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{job} {temperature}: {stderr}");
        assert!(stderr.contains(says), "{job} {temperature}: {stderr}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
