//! `osap scan -v` reads every link's counters through the netresponders and
//! prints one line per link: packets in and out, the runtime's drops, and
//! the link gateway's own frame counts.

mod common;

use common::number_after;
use std::process::Command;

#[test]
fn scan_v_prints_every_links_counters() {
    let topology = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../osap-sim/topologies/small-machine.toml"
    );
    let out = Command::new(env!("CARGO_BIN_EXE_osap"))
        .args(["scan", "-v", "--sim", topology])
        .output()
        .expect("osap runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("\nlink counters:\n"), "{stdout}");
    // The hub's link to each stepper and the stepper's end of it carried
    // the scan: packets both ways, frames counted by the link, none lost.
    for (runtime, link) in [
        ("hub", 1),
        ("hub", 2),
        ("x", 1),
        ("y", 1),
        ("z", 1),
        ("tool", 1),
    ] {
        let prefix = format!("  {runtime} link {link} (uart): ");
        let line = stdout
            .lines()
            .find(|l| l.starts_with(&prefix))
            .unwrap_or_else(|| panic!("no line {prefix:?}:\n{stdout}"));
        let got = |w: &str| number_after(line, w).unwrap_or_else(|| panic!("{w}: {line}"));
        assert!(got("in ") > 0 && got("out ") > 0, "{line}");
        // Frames the link took and the runtime has yet to (a clock-sync
        // exchange in flight) may be a few more.
        let (frames, packets) = (got("wire: "), got("in "));
        assert!(frames >= packets && frames <= packets + 4, "{line}");
        assert!(line.contains("(0 dropped)"), "{line}");
        assert!(line.contains(", 0 bad,"), "{line}");
    }
}
