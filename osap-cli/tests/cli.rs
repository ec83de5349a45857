//! The `osap` command line, run as a user would run it.

use osap_host::map::NetworkMap;

mod common;
use std::path::PathBuf;
use std::process::Command;

/// The path of a topology shipped in `osap-sim/topologies/`.
fn shipped(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../osap-sim/topologies")
        .join(name)
}

fn osap() -> Command {
    Command::new(env!("CARGO_BIN_EXE_osap"))
}

#[test]
fn scan_of_a_simulated_machine_prints_a_tree_and_writes_the_map() {
    let out_path = std::env::temp_dir().join(format!("osap-cli-map-{}.json", std::process::id()));
    let out = osap()
        .args(["scan", "--sim"])
        .arg(shipped("small-machine.toml"))
        .arg("-o")
        .arg(&out_path)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for name in ["hub", "x", "y", "z", "tool"] {
        assert!(
            stdout.contains(&format!(": {name} (")),
            "{name} missing in\n{stdout}"
        );
    }
    assert!(stdout.contains("6 runtimes, 5 links"), "{stdout}");
    let map = NetworkMap::from_json(&std::fs::read_to_string(&out_path).unwrap()).unwrap();
    assert_eq!(map.find("tool").unwrap().route, vec![0, 4]);
    let _ = std::fs::remove_file(out_path);
}

#[test]
fn scan_writes_the_system_object_model_for_proxygen() {
    let path = std::env::temp_dir().join(format!("osap-cli-som-{}.json", std::process::id()));
    let out = osap()
        .args(["scan", "--sim"])
        .arg(shipped("small-machine.toml"))
        .arg("--som")
        .arg(&path)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // Four steppers with the module firmware's functions each; the hub
    // has none.
    let per_module = osap_module::functions::SIGNATURES.len();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.contains(&format!("({} functions)", 4 * per_module)),
        "{stdout}"
    );
    let som = osap_host::som::Som::from_json(&std::fs::read_to_string(&path).unwrap()).unwrap();
    let _ = std::fs::remove_file(path);
    for name in ["x", "y", "z", "tool"] {
        let r = som.runtimes.iter().find(|r| r.record.name == name).unwrap();
        let names: Vec<&str> = r.functions.iter().map(|f| f.name.as_str()).collect();
        assert_eq!(names.len(), per_module, "{name}: {names:?}");
        for f in ["add_point", "get_position", "read_limit", "analog_read"] {
            assert!(names.contains(&f), "{name} lacks {f}: {names:?}");
        }
    }
    let hub = som
        .runtimes
        .iter()
        .find(|r| r.record.name == "hub")
        .unwrap();
    assert!(hub.functions.is_empty(), "{:?}", hub.functions);
}

#[test]
fn ping_and_rename_by_name() {
    let file = shipped("single-usb.toml");
    let out = osap()
        .args(["ping", "-n", "20", "--sim"])
        .arg(&file)
        .arg("motor")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stdout}\n{stderr}");
    assert!(stdout.contains("20 round trips to [L0]"), "{stdout}");
    // Unknown names are named in the error, with what was found.
    let out = osap()
        .args(["rename", "--sim"])
        .arg(&file)
        .args(["nobody", "x"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("no runtime named nobody (found: host, motor)"),
        "{stderr}"
    );
    let out = osap()
        .args(["rename", "--sim"])
        .arg(&file)
        .args(["0", "axis"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("to axis"));
}

#[test]
fn time_lists_every_runtime() {
    let out = osap()
        .args(["time", "--sim"])
        .arg(shipped("loop.toml"))
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}");
    assert!(
        stdout
            .lines()
            .any(|l| l.starts_with("host") && l.contains("root")),
        "{stdout}"
    );
    for name in ["a", "b", "c", "m1"] {
        assert!(
            stdout.lines().any(|l| l.starts_with(name)),
            "{name} missing in\n{stdout}"
        );
    }
}

#[test]
fn nothing_to_talk_to_is_a_clear_error() {
    let out = osap()
        .args(["scan", "--port", "/dev/definitely-not-here"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("/dev/definitely-not-here"), "{stderr}");
}

#[test]
fn a_served_machine_is_scanned_from_another_process() {
    // Port 0: the server picks a free port and prints it.
    let (_server, addr) = common::serve(&shipped("small-machine.toml"));
    let out = osap().args(["scan", "--tcp", &addr]).output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("via tcp link 0: sim-host"), "{stdout}");
    assert!(stdout.contains(": tool ("), "{stdout}");
    assert!(stdout.contains("7 runtimes"), "{stdout}");
}

#[test]
fn bus_roles_are_refused_where_a_link_cannot_take_one_and_bad_roles_say_why() {
    let file = shipped("single-usb.toml");
    let run = |args: &[&str]| {
        let out = osap()
            .args(["bus", "--sim"])
            .arg(&file)
            .args(args)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr).to_string();
        (out.status.code(), stderr)
    };
    // A simulated module's USB link cannot switch to a bus.
    let (code, stderr) = run(&["motor", "drop:3", "--link", "0"]);
    assert_eq!(code, Some(1), "{stderr}");
    assert!(stderr.contains("cannot give link 0 a bus role"), "{stderr}");
    let (code, stderr) = run(&["motor", "head:8", "--link", "9"]);
    assert_eq!(code, Some(1), "{stderr}");
    assert!(stderr.contains("has no link 9"), "{stderr}");
    // Bad roles stop before anything is asked.
    for (role, says) in [
        ("drop:0", "from 1 to 254"),
        ("head:255", "from 1 to 254"),
        ("bus:1", "use off, head:N"),
    ] {
        let (code, stderr) = run(&["motor", role]);
        assert_eq!(code, Some(2), "{role}: {stderr}");
        assert!(stderr.contains(says), "{role}: {stderr}");
    }
}
