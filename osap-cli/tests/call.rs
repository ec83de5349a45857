//! `osap call --sim FILE RUNTIME FUNCTION ARGS..` on a simulated module:
//! outputs print one a line; a refusal prints the failure code's name and
//! its fix (osap-module's table), and exits with 3.

use osap_module::failure::failure;
use osap_module::stepper::StepperError;
use std::process::{Command, Output};

fn osap_call(args: &[&str]) -> Output {
    let topology = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../osap-sim/topologies/single-usb.toml"
    );
    Command::new(env!("CARGO_BIN_EXE_osap"))
        .args(["call", "--sim", topology])
        .args(args)
        .output()
        .expect("osap runs")
}

fn text(o: &Output) -> (String, String) {
    (
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

#[test]
fn a_refusal_prints_its_name_and_fix() {
    // 1000 µs is not a power of two: BadValue.
    let o = osap_call(&["motor", "set_interval", "1000"]);
    let (stdout, stderr) = text(&o);
    assert_eq!(o.status.code(), Some(3), "{stdout}\n{stderr}");
    let want = failure("set_interval", StepperError::BadValue.code()).unwrap();
    assert_eq!(want.name, "BadValue");
    assert!(
        stderr.contains(&format!("motor.set_interval refused: {want}")),
        "{stderr}"
    );
    assert!(stderr.contains("BadValue (code 10): "), "{stderr}");
    assert!(!stderr.contains("Remote {"), "Debug leaked: {stderr}");
}

#[test]
fn a_call_prints_its_outputs_and_bad_arguments_name_the_inputs() {
    let o = osap_call(&["motor", "get_status"]);
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "{stdout}\n{stderr}");
    for line in ["mode = 0", "queued = 0", "enabled = false", "faults = 0"] {
        assert!(stdout.lines().any(|l| l == line), "{line}:\n{stdout}");
    }

    let o = osap_call(&["motor", "add_point", "1000"]);
    let (stdout, stderr) = text(&o);
    assert_eq!(o.status.code(), Some(1), "{stdout}\n{stderr}");
    assert!(
        stderr.contains("takes 2 input(s) (time: u64, position: f32), 1 given"),
        "{stderr}"
    );

    let o = osap_call(&["motor", "add_pointz", "1", "2"]);
    let (_, stderr) = text(&o);
    assert_eq!(o.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("osap scan -f"), "{stderr}");
}
