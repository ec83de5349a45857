//! `osap describe --sim FILE RUNTIME FUNCTION` on a simulated module: the
//! signature, the function's whole documentation (osap-module's table)
//! and every refusal code by name with its fix, as the module sent them.

use osap_module::functions::FnId;
use std::process::{Command, Output};

fn osap_describe(args: &[&str]) -> Output {
    let topology = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../osap-sim/topologies/single-usb.toml"
    );
    Command::new(env!("CARGO_BIN_EXE_osap"))
        .args(["describe", "--sim", topology])
        .args(args)
        .output()
        .expect("osap runs")
}

#[test]
fn describe_prints_the_signature_docs_and_refusal_codes() {
    let o = osap_describe(&["motor", "set_interval"]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stdout}\n{stderr}");
    let id = FnId::set_interval;
    let mut want = format!(
        "motor.set_interval(interval_us: u32)\n\n{}\n\nrefusal codes:\n",
        id.docs()
    );
    for f in id.failures() {
        want.push_str(&format!("  {f}\n"));
    }
    assert_eq!(stdout, want);
    // Named as `osap call` names a refusal.
    assert!(stdout.contains("\n  BadValue (code 10): "), "{stdout}");
}

#[test]
fn an_unknown_function_names_the_listing() {
    let o = osap_describe(&["motor", "set_intervals"]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("no function motor.set_intervals"),
        "{stderr}"
    );
    assert!(stderr.contains("osap scan -f"), "{stderr}");
}
