//! `osap capture` on the simulated plotter (virtual time): a capture's
//! summary, file and plot; bad sources refused before the machine starts;
//! a full disk exits 1 naming the file; Ctrl-C leaves a readable file.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

use osap_machine::capture::Capture;

mod common;
use common::Killed;

fn plotter() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../examples/machines/plotter.toml")
}

fn scratch(test: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("osap-capture-cli-{test}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn capture(args: &[&str], out: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_osap"))
        .arg("capture")
        .arg(plotter())
        .args(["--sim", "--fast"])
        .args(args)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap()
}

fn text(o: &Output) -> (String, String) {
    (
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

#[test]
fn one_second_of_two_sources_into_parquet_with_a_plot() {
    let dir = scratch("ok");
    let out = dir.join("run.parquet");
    let plot = dir.join("run.svg");
    let o = capture(
        &[
            "--source",
            "a.analog_read(0)",
            "--source",
            "b.get_position",
            "--seconds",
            "1",
            "--period-us",
            "2000",
            "--plot",
            plot.to_str().unwrap(),
        ],
        &out,
    );
    let (stdout, stderr) = text(&o);
    println!("{stdout}");
    assert!(o.status.success(), "{stdout}\n{stderr}");
    assert!(stdout.contains("a.analog_read(0).value"), "{stdout}");
    assert!(stdout.contains("b.get_position.position"), "{stdout}");
    assert!(!stdout.contains("lost"), "{stdout}");
    // Every 2 ms for a second (and the few ms the recorder takes to
    // finish): one sample per period over the span recorded, to within
    // five (1 %).
    let capture = Capture::read(&out).unwrap();
    assert_eq!(capture.series.len(), 2);
    for s in &capture.series {
        let span_s = (s.time_us.last().unwrap() - s.time_us[0]) as f64 * 1e-6;
        assert!((1.0..1.05).contains(&span_s), "{}: {span_s} s", s.name);
        let expected = span_s / 0.002 + 1.0;
        assert!(
            (s.value.len() as f64 - expected).abs() <= 5.0,
            "{}: {} samples over {span_s} s",
            s.name,
            s.value.len()
        );
        assert!(s.time_us.windows(2).all(|w| w[0] < w[1]), "{}", s.name);
    }
    // The accelerometer of a machine at rest reads half scale.
    let accel = capture.get("a.analog_read(0).value").unwrap();
    assert!(
        accel.value.iter().all(|v| (v - 0.5).abs() < 1e-3),
        "{:?}",
        &accel.value[..8]
    );
    let svg = std::fs::read_to_string(&plot).unwrap();
    assert!(
        svg.contains("a.analog_read(0).value"),
        "the plot names its series"
    );
    // The record beside the file: what was captured, and both files.
    let record: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("run.parquet.run.json")).unwrap())
            .unwrap();
    assert_eq!(record["command"], "capture");
    assert_eq!(record["outcome"]["status"], "ok");
    assert_eq!(record["options"]["sources"][1], "b.get_position");
    assert_eq!(record["figures"]["lost_at_source"], 0.0);
    let files: Vec<&str> = record["files"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["path"].as_str().unwrap())
        .collect();
    assert_eq!(files, ["run.parquet", "run.svg"]);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Module b's `get_position` also feeds the machine at 1 kHz. Its samples
/// come in blocks from b's `sample_block`, numbered, so every sample b took
/// is written or counted lost, never silently missing (before blocks,
/// about 17 % of them found the function's pipe queue full).
#[test]
fn samples_a_module_could_not_send_are_counted() {
    let dir = scratch("lost");
    let out = dir.join("fast.csv");
    let o = capture(&["--source", "b.get_position", "--seconds", "1"], &out);
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "{stdout}\n{stderr}");
    let rows = Capture::read(&out).unwrap().rows() as f64;
    let lost: f64 = stdout
        .lines()
        .find_map(|l| l.trim().split_once(" samples lost at the modules"))
        .map_or(0.0, |(n, _)| n.parse().unwrap());
    assert!(
        (rows + lost - 1_000.0).abs() <= 20.0,
        "{rows} written + {lost} lost: {stdout}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_sources_and_formats_are_refused_before_the_machine_starts() {
    let dir = scratch("bad");
    let cases: [(&[&str], &str, &str); 4] = [
        (
            &["--source", "q.analog_read(0)", "--seconds", "1"],
            "run.parquet",
            "q",
        ),
        (
            &["--source", "a.no_such_function", "--seconds", "1"],
            "run.parquet",
            "no_such_function",
        ),
        (
            &["--source", "a.get_position.nothing", "--seconds", "1"],
            "run.parquet",
            "nothing",
        ),
        (
            &["--source", "a.get_position", "--seconds", "1"],
            "run.xlsx",
            ".parquet",
        ),
    ];
    for (args, file, named) in cases {
        let out = dir.join(file);
        let o = capture(args, &out);
        let (stdout, stderr) = text(&o);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {stdout}\n{stderr}");
        assert!(stderr.contains(named), "{args:?}: {stderr}");
        assert!(!out.exists(), "{args:?} left {}", out.display());
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_full_disk_exits_1_naming_the_file() {
    let dir = scratch("full");
    // A file on a full disk: writes fail with "No space left on device".
    let out = dir.join("full.csv");
    std::os::unix::fs::symlink("/dev/full", &out).unwrap();
    let o = capture(&["--source", "a.get_position", "--seconds", "2"], &out);
    let (stdout, stderr) = text(&o);
    assert_eq!(o.status.code(), Some(1), "{stdout}\n{stderr}");
    assert!(stderr.contains("full.csv"), "{stderr}");
    assert!(stderr.contains("free space"), "{stderr}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn ctrl_c_leaves_a_closed_readable_file() {
    let dir = scratch("int");
    let out = dir.join("long.parquet");
    let child = Command::new(env!("CARGO_BIN_EXE_osap"))
        .arg("capture")
        .arg(plotter())
        .args(["--sim", "--source", "a.get_position", "--seconds", "600"])
        .arg("--out")
        .arg(&out)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut child = Killed(child);
    let mut lines = BufReader::new(child.0.stdout.take().unwrap()).lines();
    let first = lines.next().unwrap().unwrap();
    assert!(first.starts_with("recording 1 series"), "{first}");
    // Interrupt as soon as it records: whatever came so far (maybe
    // nothing) must be in a properly closed file.
    let pid = child.0.id().to_string();
    assert!(Command::new("kill")
        .args(["-INT", &pid])
        .status()
        .unwrap()
        .success());
    let rest: Vec<String> = lines.map_while(Result::ok).collect();
    let status = child.0.wait().unwrap();
    let stderr = std::io::read_to_string(child.0.stderr.take().unwrap()).unwrap_or_default();
    assert!(status.success(), "{rest:?}\n{stderr}");
    assert!(
        rest.iter().any(|l| l.starts_with("interrupted")),
        "{rest:?}"
    );
    // "N rows in FILE": the file holds exactly what the summary says.
    let rows: usize = rest
        .iter()
        .find_map(|l| l.split_once(" rows in ").map(|(n, _)| n.trim()))
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no summary in {rest:?}"));
    let capture = Capture::read(&out).unwrap();
    assert_eq!(capture.rows(), rows);
    let _ = std::fs::remove_dir_all(&dir);
}
