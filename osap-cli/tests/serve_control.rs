//! `osap serve --control`: faults injected into a served machine from its
//! standard input, and what `osap scan` then says (and exits with).

mod common;

use common::{number_after, Controlled};
use std::path::PathBuf;
use std::process::{Command, Output};

fn plotter() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../examples/machines/plotter.toml")
}

fn scan(addr: &str) -> Output {
    Command::new(env!("CARGO_BIN_EXE_osap"))
        .args(["scan", "--tcp", addr])
        .output()
        .unwrap()
}

#[test]
fn faults_injected_through_serve_show_in_scans_and_lift() {
    let mut served = Controlled::start(&plotter());
    assert_eq!(
        served.command("links"),
        "ok links: 0: host-hub, 1: hub-a, 2: hub-b, 3: hub-z"
    );
    let bad = served.command("explode b");
    assert!(
        bad.starts_with("error: unknown fault command \"explode\""),
        "{bad}"
    );
    let bad = served.command("freeze nobody");
    assert!(bad.contains("no module \"nobody\""), "{bad}");

    // A frozen module answers nothing: the scan is partial, says where,
    // and exits with 2. (Heard first: a module frozen before it ever
    // spoke is, to a scan, an open link with no neighbour.)
    assert_eq!(scan(&served.addr).status.code(), Some(0));
    assert_eq!(served.command("freeze b"), "ok freeze b");
    let out = scan(&served.addr);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("the runtime behind hub's link 2 (route 0,0,2)"),
        "{stderr}"
    );

    // Thawed, it answers again.
    assert_eq!(served.command("thaw b"), "ok thaw b");
    let out = scan(&served.addr);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(
        out.status.code(),
        Some(0),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("via uart link 2: b "), "{stdout}");

    // Corruption is counted where the frames arrive.
    assert_eq!(
        served.command("corrupt hub-a 0.003"),
        "ok corrupt hub-a 0.003"
    );
    scan(&served.addr);
    assert_eq!(served.command("corrupt hub-a 0"), "ok corrupt hub-a 0");
    let stats = served.command("stats hub-a");
    assert!(stats.starts_with("ok stats hub-a: corrupted "), "{stats}");
    let count = |key: &str| number_after(&stats, key).unwrap();
    assert!(count("corrupted ") > 0, "{stats}");
    assert!(
        count("frame errors counted ") >= count("rejected "),
        "{stats}"
    );

    // A cut link: the hub sees it closed, so the scan maps around it.
    assert_eq!(served.command("cut hub-b"), "ok cut hub-b");
    let out = scan(&served.addr);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(!stdout.contains("via uart link 2: b "), "{stdout}");
    assert_eq!(served.command("restore hub-b"), "ok restore hub-b");
}

fn call(addr: &str, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_osap"))
        .args(["call", "--tcp", addr])
        .args(args)
        .output()
        .unwrap()
}

fn called(addr: &str, args: &[&str]) {
    let out = call(addr, args);
    assert!(
        out.status.success(),
        "osap call {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn outputs_show_what_a_module_drives_and_that_a_halt_made_it_safe() {
    let mut served = Controlled::start(&plotter());
    // At boot every output is off.
    assert_eq!(
        served.command("outputs z"),
        "ok pwm0=0.000 pwm1=0.000 d0=0 d1=0 d2=0 d3=0"
    );
    // The plotter's pen servo (module z, PWM 0) down, a relay on pin 1 on.
    called(&served.addr, &["z", "pwm_write", "0", "0.1"]);
    called(&served.addr, &["z", "digital_write", "1", "true"]);
    assert_eq!(
        served.command("outputs z"),
        "ok pwm0=0.100 pwm1=0.000 d0=0 d1=1 d2=0 d3=0"
    );
    // Safe values change nothing until a stop; a halt applies them all.
    called(&served.addr, &["z", "set_safe_pwm", "0", "0.05"]);
    assert!(served.command("outputs z").starts_with("ok pwm0=0.100 "));
    called(&served.addr, &["z", "halt"]);
    assert_eq!(
        served.command("outputs z"),
        "ok pwm0=0.050 pwm1=0.000 d0=0 d1=0 d2=0 d3=0"
    );
    // Other modules are untouched; a hub has no outputs.
    assert_eq!(
        served.command("outputs a"),
        "ok pwm0=0.000 pwm1=0.000 d0=0 d1=0 d2=0 d3=0"
    );
    let hub = served.command("outputs hub");
    assert!(
        hub.starts_with("error: module \"hub\" has no outputs"),
        "{hub}"
    );
    let nobody = served.command("outputs nobody");
    assert!(nobody.contains("no module \"nobody\""), "{nobody}");
}
