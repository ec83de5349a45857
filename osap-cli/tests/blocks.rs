//! `osap block types|new|delete` against a served simulated network, and
//! blocks in graph files: a graph with blocks and a pipe between them is
//! saved, applied to a fresh network (which makes the blocks), and saved
//! back identical; deleting a block takes the pipes into it first.

mod common;

use std::path::PathBuf;
use std::process::{Command, Output};

use serde_json::Value;

fn topology() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../osap-sim/topologies/small-machine.toml")
}

fn osap(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_osap"))
        .args(args)
        .output()
        .expect("osap runs")
}

fn ok(o: &Output) -> String {
    assert!(
        o.status.success(),
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn err(o: &Output) -> String {
    assert_eq!(
        o.status.code(),
        Some(1),
        "{}",
        String::from_utf8_lossy(&o.stdout)
    );
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[test]
fn blocks_are_made_used_and_deleted_from_the_command_line() {
    let (_server, addr) = common::serve(&topology());
    let a = addr.as_str();

    let types = ok(&osap(&["block", "types", "x", "--tcp", a]));
    assert!(
        types.contains(
            "comparator(threshold: f32, hysteresis: f32, halt: bool): block (time: u64, value: f32) -> (time: u64, above: bool, crossings: u32), 0 of 2 in use"
        ),
        "{types}"
    );
    for class in ["scale(", "lowpass(", "limiter(", "trigger("] {
        assert!(types.contains(class), "{class} missing:\n{types}");
    }

    let made = ok(&osap(&[
        "block", "new", "x", "scale", "half", "0.5", "-1", "--tcp", a,
    ]));
    assert!(made.contains("x.half made: a scale in slot 2"), "{made}");
    // A function like any other: listed, and called.
    let scan = ok(&osap(&["scan", "-f", "--tcp", a]));
    assert!(scan.contains("half"), "{scan}");
    let out = ok(&osap(&["call", "x", "half", "1000", "3", "--tcp", a]));
    assert_eq!(out, "time = 1000\nvalue = 0.5\n");
    // It explains itself, as its class.
    let d = ok(&osap(&["describe", "x", "half", "--tcp", a]));
    assert!(
        d.contains("half(time: u64, value: f32)") && d.contains("A scale block"),
        "{d}"
    );

    // Refusals say what is wrong.
    let e = err(&osap(&[
        "block", "new", "x", "scale", "half", "1", "0", "--tcp", a,
    ]));
    assert!(e.contains("a block of this name exists"), "{e}");
    let e = err(&osap(&[
        "block",
        "new",
        "x",
        "scale",
        "get_status",
        "1",
        "0",
        "--tcp",
        a,
    ]));
    assert!(e.contains("a block of this name exists"), "{e}");
    let e = err(&osap(&[
        "block", "new", "x", "scale", "twice", "1", "--tcp", a,
    ]));
    assert!(e.contains("takes 2 input(s)"), "{e}");
    let e = err(&osap(&[
        "block", "new", "x", "lowpass", "lp", "-3", "--tcp", a,
    ]));
    assert!(e.contains("out of its range"), "{e}");
    let e = err(&osap(&["block", "new", "x", "gearbox", "g", "--tcp", a]));
    assert!(
        e.contains("no block class \"gearbox\"") && e.contains("comparator"),
        "{e}"
    );
    ok(&osap(&[
        "block", "new", "x", "scale", "double", "2", "0", "--tcp", a,
    ]));
    let e = err(&osap(&[
        "block", "new", "x", "scale", "triple", "3", "0", "--tcp", a,
    ]));
    assert!(e.contains("every block of class"), "{e}");

    let gone = ok(&osap(&["block", "delete", "x", "half", "--tcp", a]));
    assert!(gone.contains("x.half deleted (slot 2 is free)"), "{gone}");
    let e = err(&osap(&["call", "x", "half", "1000", "3", "--tcp", a]));
    assert!(e.contains("no such function"), "{e}");
    let e = err(&osap(&["block", "delete", "x", "half", "--tcp", a]));
    assert!(e.contains("no block of this name"), "{e}");
    // Its slot takes a new one.
    ok(&osap(&[
        "block", "new", "x", "scale", "triple", "3", "0", "--tcp", a,
    ]));
}

/// A graph of two blocks piped one into the other, as a file.
fn graph_with_blocks() -> Value {
    let sample =
        serde_json::json!([{"name": "time", "type": "u64"}, {"name": "value", "type": "f32"}]);
    serde_json::json!({
        "format": "osap-graph",
        "version": 2,
        "functions": [
            {"runtime": "y", "function": "probe",
             "inputs": sample,
             "outputs": [{"name": "time", "type": "u64"}, {"name": "above", "type": "bool"},
                         {"name": "crossings", "type": "u32"}],
             "input_mode": {"mode": "on_any_fresh"}, "output_mode": "on_change"},
            {"runtime": "y", "function": "smooth",
             "inputs": sample, "outputs": sample,
             "input_mode": {"mode": "on_any_fresh"}, "output_mode": "always"},
        ],
        "pipes": [{
            "source": {"runtime": "y", "function": "smooth"}, "slot": 0,
            "destination": {"runtime": "y", "function": "probe"},
            "argmap": [{"output": 0, "input": 0}, {"output": 1, "input": 1}],
            "ttl_us": 20000, "delivery": "best_effort",
        }],
        "blocks": [
            {"runtime": "y", "name": "probe", "class": "comparator", "arguments": [
                {"name": "threshold", "type": "f32", "value": "0.5"},
                {"name": "hysteresis", "type": "f32", "value": "0.1"},
                {"name": "halt", "type": "bool", "value": "true"}]},
            {"runtime": "y", "name": "smooth", "class": "lowpass", "arguments": [
                {"name": "cutoff_hz", "type": "f32", "value": "20"}]},
        ],
    })
}

#[test]
fn a_graph_with_blocks_is_made_again_on_a_fresh_network() {
    let dir = std::env::temp_dir().join(format!("osap-blocks-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = |f: &str| dir.join(f).to_string_lossy().into_owned();
    let graph = graph_with_blocks();
    std::fs::write(path("graph.json"), graph.to_string()).unwrap();

    let (first, addr) = common::serve(&topology());
    let dry = ok(&osap(&[
        "graph",
        "apply",
        &path("graph.json"),
        "--dry-run",
        "--tcp",
        &addr,
    ]));
    assert!(
        dry.contains("y.probe: make a comparator(threshold = 0.5, hysteresis = 0.1, halt = true)"),
        "{dry}"
    );
    let applied = ok(&osap(&[
        "graph",
        "apply",
        &path("graph.json"),
        "--tcp",
        &addr,
    ]));
    assert!(
        applied.contains("pipe y.smooth slot 0 -> y.probe (0->0, 1->1)"),
        "{applied}"
    );
    let again = ok(&osap(&[
        "graph",
        "apply",
        &path("graph.json"),
        "--tcp",
        &addr,
    ]));
    assert!(again.contains("nothing to change"), "{again}");
    ok(&osap(&[
        "graph",
        "save",
        &path("saved.json"),
        "--tcp",
        &addr,
    ]));
    let saved: Value =
        serde_json::from_str(&std::fs::read_to_string(path("saved.json")).unwrap()).unwrap();
    assert_eq!(saved, graph);

    // Deleting the comparator wipes the pipe into it first.
    ok(&osap(&["block", "delete", "y", "probe", "--tcp", &addr]));
    ok(&osap(&[
        "graph",
        "save",
        &path("after.json"),
        "--tcp",
        &addr,
    ]));
    let after: Value =
        serde_json::from_str(&std::fs::read_to_string(path("after.json")).unwrap()).unwrap();
    assert_eq!(after["pipes"], serde_json::json!([]), "{after}");
    assert_eq!(after["blocks"].as_array().unwrap().len(), 1, "{after}");
    drop(first);

    // A fresh network: the file makes the same graph.
    let (_second, addr) = common::serve(&topology());
    ok(&osap(&[
        "graph",
        "apply",
        &path("saved.json"),
        "--tcp",
        &addr,
    ]));
    ok(&osap(&[
        "graph",
        "save",
        &path("fresh.json"),
        "--tcp",
        &addr,
    ]));
    let fresh: Value =
        serde_json::from_str(&std::fs::read_to_string(path("fresh.json")).unwrap()).unwrap();
    assert_eq!(fresh, graph);

    // A block of the same name made otherwise is a mismatch, named.
    let mut other = graph.clone();
    other["blocks"][1]["arguments"][0]["value"] = "40".into();
    std::fs::write(path("other.json"), other.to_string()).unwrap();
    let e = err(&osap(&[
        "graph",
        "apply",
        &path("other.json"),
        "--tcp",
        &addr,
    ]));
    assert!(
        e.contains("y.smooth: a lowpass made with (cutoff_hz = 20) on the network, a lowpass made with (cutoff_hz = 40) in the graph"),
        "{e}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
