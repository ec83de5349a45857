//! `osap level` on the simulated mill (virtual time): the levelling example
//! run in CI. It probes the bed of mill.toml's `[sim.bed]`, writes the mesh
//! and its plot where `--mesh` says (never over the example's own mesh),
//! and a machine file without `[probe]` is refused with the fix.

use std::path::PathBuf;
use std::process::Command;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

#[test]
fn level_the_simulated_mill() {
    let dir = std::env::temp_dir().join(format!("osap-level-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mesh = dir.join("mill-mesh.toml");
    let out = Command::new(env!("CARGO_BIN_EXE_osap"))
        .arg("level")
        .arg(root().join("examples/machines/mill.toml"))
        .args(["--sim", "--fast", "--mesh"])
        .arg(&mesh)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stdout}\n{stderr}");
    // The summary, for docs/machine.md's figures (with --nocapture).
    println!("{stdout}");
    assert!(stdout.contains("point 20/20"), "{stdout}");
    assert!(
        stdout.contains("tilt +0.00100 along x, -0.00150 along y"),
        "{stdout}"
    );
    // The mesh reads back, and the plot is beside it.
    let text = std::fs::read_to_string(&mesh).unwrap();
    let m = osap_machine::mesh::parse(&text).unwrap();
    assert_eq!((m.grid().nx, m.grid().ny), (5, 4));
    let svg = std::fs::read_to_string(mesh.with_extension("svg")).unwrap();
    assert!(svg.contains("<svg"));
    // The mesh names its run; the record beside it holds the probing.
    let record_file = dir.join("mill-mesh.toml.run.json");
    assert!(
        text.contains(&format!(
            "fitted_from = {:?}",
            record_file.display().to_string()
        )),
        "{text}"
    );
    let record: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&record_file).unwrap()).unwrap();
    assert_eq!(record["command"], "level");
    assert_eq!(record["outcome"]["status"], "ok");
    assert_eq!(record["modules"].as_object().unwrap().len(), 3);
    assert!(record["figures"]["rms"].as_f64().unwrap() > 0.0);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_machine_without_a_probe_is_refused() {
    let out = Command::new(env!("CARGO_BIN_EXE_osap"))
        .arg("level")
        .arg(root().join("examples/machines/plotter.toml"))
        .args(["--sim", "--fast"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("no [probe] section"), "{stderr}");
}
