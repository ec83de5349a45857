//! Logging: quiet by default, raised by -v, and RUST_LOG works.

use std::path::PathBuf;
use std::process::Command;

mod common;

fn scan(addr: &str, verbose: &[&str], rust_log: Option<&str>) -> String {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_osap"));
    cmd.args(verbose).args(["scan", "--tcp", addr]);
    cmd.env_remove("RUST_LOG");
    if let Some(filter) = rust_log {
        cmd.env("RUST_LOG", filter);
    }
    let o = cmd.output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "{stderr}");
    stderr
}

#[test]
fn v_and_rust_log_raise_the_log_level() {
    let topology =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../osap-sim/topologies/small-machine.toml");
    let (_server, addr) = common::serve(&topology);
    // The TCP link logs "connected" at info.
    let quiet = scan(&addr, &[], None);
    assert!(!quiet.contains("connected"), "{quiet}");
    let v = scan(&addr, &["-v"], None);
    assert!(v.contains("INFO") && v.contains("connected"), "{v}");
    let env = scan(&addr, &[], Some("osap_host=info"));
    assert!(env.contains("connected"), "{env}");
}
