//! `osap graph save|apply` against a served simulated network (`osap serve
//! --sim small-machine.toml`, reached with `--tcp`): a graph written from
//! the network's own signatures is applied (dry first), applied again to
//! no effect, saved back identical; a graph that does not match is refused,
//! naming the mismatch.

mod common;

use std::path::PathBuf;
use std::process::{Command, Output};

use serde_json::{json, Value};

fn topology() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../osap-sim/topologies/small-machine.toml")
}

fn osap(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_osap"))
        .args(args)
        .output()
        .expect("osap runs")
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// A function of the scanned model, as a graph lists it.
fn function(som: &Value, runtime: &str, name: &str, input_mode: Value, output_mode: &str) -> Value {
    let rt = som["runtimes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|r| r["name"] == runtime)
        .unwrap();
    let f = rt["functions"]
        .as_array()
        .unwrap()
        .iter()
        .find(|f| f["name"] == name)
        .unwrap();
    json!({
        "runtime": runtime,
        "function": name,
        "inputs": f["inputs"],
        "outputs": f["outputs"],
        "input_mode": input_mode,
        "output_mode": output_mode,
    })
}

#[test]
fn a_graph_file_applies_once_and_saves_back_the_same() {
    let (_server, addr) = common::serve(&topology());
    let dir = std::env::temp_dir().join(format!("osap-graph-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = |f: &str| dir.join(f).to_string_lossy().into_owned();

    let o = osap(&["scan", "--tcp", &addr, "--som", &path("som.json")]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let som: Value =
        serde_json::from_str(&std::fs::read_to_string(path("som.json")).unwrap()).unwrap();
    let graph = json!({
        "format": "osap-graph",
        "version": 1,
        "functions": [
            function(&som, "x", "get_position", json!({"mode": "on_timer", "interval_us": 50000}), "on_change"),
            function(&som, "y", "set_scale", json!({"mode": "on_all_fresh"}), "always"),
        ],
        "pipes": [{
            "source": {"runtime": "x", "function": "get_position"},
            "slot": 0,
            "destination": {"runtime": "y", "function": "set_scale"},
            "argmap": [{"output": 1, "input": 0}],
            "ttl_us": 20000,
            "delivery": "acked",
        }],
    });
    std::fs::write(
        path("graph.json"),
        serde_json::to_string_pretty(&graph).unwrap(),
    )
    .unwrap();

    let o = osap(&[
        "graph",
        "apply",
        &path("graph.json"),
        "--dry-run",
        "--tcp",
        &addr,
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(stdout(&o).contains("would change 4"), "{}", stdout(&o));
    let o = osap(&["graph", "apply", &path("graph.json"), "--tcp", &addr]);
    assert!(stdout(&o).contains("changed 4"), "{}", stdout(&o));
    assert!(
        stdout(&o).contains("pipe x.get_position slot 0 -> y.set_scale (1->0)"),
        "{}",
        stdout(&o)
    );
    let o = osap(&["graph", "apply", &path("graph.json"), "--tcp", &addr]);
    assert!(stdout(&o).contains("nothing to change"), "{}", stdout(&o));

    let o = osap(&["graph", "save", &path("saved.json"), "--tcp", &addr]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let saved: Value =
        serde_json::from_str(&std::fs::read_to_string(path("saved.json")).unwrap()).unwrap();
    // Version 1 (before blocks) is read; this build writes version 2.
    let mut expected = graph.clone();
    expected["version"] = 2.into();
    assert_eq!(saved, expected);

    // A runtime the network lacks, and a signature that differs.
    let mut wrong = graph.clone();
    wrong["functions"][1]["runtime"] = "lathe".into();
    wrong["functions"][0]["outputs"][1]["type"] = "f64".into();
    std::fs::write(path("wrong.json"), wrong.to_string()).unwrap();
    let o = osap(&["graph", "apply", &path("wrong.json"), "--tcp", &addr]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("no runtime lathe") && err.contains("x.get_position: signature"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
