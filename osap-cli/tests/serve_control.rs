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
