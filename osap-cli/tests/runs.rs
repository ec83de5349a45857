//! Run records: `osap run` leaves `run.json` beside its data, however it
//! ends; `osap runs list|show` read them back and `osap runs replay`
//! re-runs the recorded job from the record's own copies, reproducing the
//! summary in virtual time.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use serde_json::Value;

fn example(path: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../examples")
        .join(path)
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
    let d = std::env::temp_dir().join(format!("osap-runs-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn record(dir: &Path) -> Value {
    let text = std::fs::read_to_string(dir.join("run.json")).unwrap();
    serde_json::from_str(&text).unwrap()
}

fn sha256(path: &Path) -> String {
    osap_machine::runs::sha256_hex(&std::fs::read(path).unwrap())
}

/// The summary lines that do not read the wall clock.
fn steady(r: &Value) -> Vec<String> {
    r["summary"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|l| !l["wall_clock"].as_bool().unwrap_or(false))
        .map(|l| l["text"].as_str().unwrap().to_string())
        .collect()
}

/// The mill's G-code part, recorded, listed, shown and replayed in
/// virtual time: the replay's summary is the record's, line for line.
#[test]
fn a_run_is_recorded_listed_shown_and_replayed_to_the_same_summary() {
    let dir = scratch("replay");
    let machine = example("machines/mill.toml");
    let job = example("jobs/part.gcode");
    let o = osap(
        &[
            "run",
            s(&machine),
            s(&job),
            "--sim",
            "--fast",
            "--out",
            "first",
        ],
        &dir,
    );
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    let first = dir.join("first");
    let r = record(&first);

    // What ran, on what, with which firmware.
    assert_eq!(r["format"], "osap-run");
    assert_eq!(r["command"], "run");
    assert_eq!(r["machine_name"], "mill");
    assert_eq!(r["machine"]["sha256"], sha256(&machine));
    assert_eq!(
        r["machine"]["text"],
        std::fs::read_to_string(&machine).unwrap()
    );
    assert_eq!(
        r["machine_inputs"]["bed_mesh"]["sha256"],
        sha256(&example("machines/mill-mesh.toml"))
    );
    assert_eq!(r["job"]["sha256"], sha256(&job));
    assert_eq!(r["target"]["sim"], true);
    assert_eq!(r["target"]["fast"], true);
    assert_eq!(r["host"]["program"], "osap");
    assert_eq!(r["host"]["version"], env!("CARGO_PKG_VERSION"));
    let id = format!(
        "{:#010x}",
        osap_module::functions::function_set_id(&osap_module::functions::SIGNATURES)
    );
    let modules = r["modules"].as_object().unwrap();
    assert_eq!(modules.len(), 3, "{modules:?}");
    for (key, m) in modules {
        assert_eq!(m["function_set_id"], id.as_str(), "module {key}");
        assert_eq!(m["build"], "simulated", "module {key}");
    }

    // How it went, on both clocks.
    assert_eq!(r["outcome"]["status"], "ok");
    assert_eq!(r["outcome"]["exit_code"], 0);
    assert!(r["faults"].as_array().unwrap().is_empty(), "{r:#}");
    let t0 = r["started"]["sync_us"].as_u64().unwrap();
    let t1 = r["ended"]["sync_us"].as_u64().unwrap();
    let executed = r["figures"]["executed_s"].as_f64().unwrap();
    assert!(
        (t1 - t0) as f64 * 1e-6 > executed,
        "the machine's clock spans the job: {t0}..{t1}, {executed} s"
    );
    let lines = steady(&r);
    assert!(
        lines.iter().any(|l| l.starts_with("planned duration")),
        "{lines:?}"
    );
    assert!(lines.iter().any(|l| l == "faults: none"), "{lines:?}");
    // Every data file, hashed as it lies on disk.
    let files = r["files"].as_array().unwrap();
    assert!(files.len() >= 5, "{files:?}");
    for f in files {
        let path = first.join(f["path"].as_str().unwrap());
        assert_eq!(f["sha256"], sha256(&path), "{}", path.display());
        assert_eq!(
            f["bytes"].as_u64().unwrap(),
            std::fs::metadata(&path).unwrap().len()
        );
    }

    // Listed and shown.
    let o = osap(&["runs", "list"], &dir);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    let row = t
        .lines()
        .find(|l| l.ends_with(" first"))
        .unwrap_or_else(|| panic!("{t}"));
    for want in ["mill", "run part.gcode", "ok"] {
        assert!(row.contains(want), "{want:?} in {row:?}");
    }
    let o = osap(&["runs", "show", "first"], &dir);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    for want in [
        "outcome    ok (exit code 0)",
        "job        ",
        "part.gcode",
        &format!("function set {id}"),
        "file       planned.csv",
    ] {
        assert!(t.contains(want), "{want:?} in\n{t}");
    }

    // Replayed from the record's copies, into a new folder named by time:
    // the same summary, line for line, wall-clock lines aside.
    let o = osap(&["runs", "replay", "first"], &dir);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(t.contains("the summaries agree"), "{t}");
    let second = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| {
            p.file_name()
                .unwrap()
                .to_string_lossy()
                .starts_with("osap-run-mill-")
        })
        .unwrap_or_else(|| panic!("no osap-run-mill-YYYYMMDD-HHMMSS folder:\n{t}"));
    let name = second.file_name().unwrap().to_string_lossy().into_owned();
    let stamp = name.trim_start_matches("osap-run-mill-");
    assert!(
        stamp.len() == 15 && stamp.as_bytes()[8] == b'-',
        "YYYYMMDD-HHMMSS: {name}"
    );
    let again = record(&second);
    assert_eq!(steady(&again), lines);
    assert_eq!(again["figures"], r["figures"]);
    assert_eq!(again["machine"]["sha256"], r["machine"]["sha256"]);
    assert_eq!(again["job"]["sha256"], r["job"]["sha256"]);
    assert!(
        again["replay_of"].as_str().unwrap().ends_with("run.json"),
        "{again:#}"
    );
    // The same CSVs, byte for byte, in virtual time.
    for f in ["planned.csv", "executed.csv"] {
        assert_eq!(
            sha256(&first.join(f)),
            sha256(&second.join(f)),
            "{f} differs between the run and its replay"
        );
    }
}

/// A run that never reached its machine still leaves its record, saying
/// why; and a record of another command is not replayed as a job.
#[test]
fn a_failed_run_is_recorded_and_a_capture_is_not_replayed_as_a_job() {
    let dir = scratch("failed");
    let machine = example("machines/plotter.toml");
    let job = example("jobs/drawing.svg");
    // Nothing listens on port 9 of the loopback: the connection fails.
    let o = osap(
        &[
            "run",
            s(&machine),
            s(&job),
            "--tcp",
            "127.0.0.1:9",
            "--out",
            "nowhere",
        ],
        &dir,
    );
    let t = text(&o);
    assert!(!o.status.success(), "{t}");
    let r = record(&dir.join("nowhere"));
    assert_ne!(r["outcome"]["status"], "ok", "{r:#}");
    assert_eq!(
        r["outcome"]["exit_code"].as_u64().unwrap(),
        u64::from(o.status.code().unwrap() as u8)
    );
    let reason = r["outcome"]["reason"].as_str().unwrap();
    assert!(
        t.contains(reason),
        "the reason printed is the reason recorded: {reason:?}\n{t}"
    );
    assert_eq!(r["target"]["tcp"][0], "127.0.0.1:9");

    let mut capture = r.clone();
    capture["command"] = "capture".into();
    std::fs::write(
        dir.join("cap.csv.run.json"),
        serde_json::to_string(&capture).unwrap(),
    )
    .unwrap();
    let o = osap(&["runs", "replay", "cap.csv.run.json"], &dir);
    let t = text(&o);
    assert_eq!(o.status.code(), Some(2), "{t}");
    assert!(t.contains("a record of `osap capture`"), "{t}");
    // Both are listed, the failed run as what it was.
    let o = osap(&["runs", "list"], &dir);
    let t = text(&o);
    assert!(t.contains("cap.csv.run.json"), "{t}");
    let row = t
        .lines()
        .find(|l| l.ends_with(" nowhere"))
        .unwrap_or_else(|| panic!("{t}"));
    assert!(
        row.contains(r["outcome"]["status"].as_str().unwrap()),
        "{row}"
    );
}
