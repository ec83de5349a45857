//! `osap scan -f --sim FILE` lists, for every simulated stepper, exactly the
//! module firmware's functions (osap-module's set), in port order, each
//! with its summary line, and nothing for a hub.

use osap_module::functions::{ALL, SIGNATURES};
use pipes_core::signature::Arg;
use std::process::Command;

fn listed(args: &[Arg]) -> String {
    args.iter()
        .map(|a| format!("{}: {}", a.name, a.ty.name()))
        .collect::<Vec<_>>()
        .join(", ")
}

#[test]
fn scan_lists_the_firmware_functions_of_every_simulated_stepper() {
    let topology = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../osap-sim/topologies/small-machine.toml"
    );
    let out = Command::new(env!("CARGO_BIN_EXE_osap"))
        .args(["scan", "-f", "--sim", topology])
        .output()
        .expect("osap runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let want: Vec<String> = SIGNATURES
        .iter()
        .zip(ALL)
        .map(|(s, id)| {
            let mut line = format!("{}({})", s.name, listed(s.inputs));
            if !s.outputs.is_empty() {
                line.push_str(&format!(" -> ({})", listed(s.outputs)));
            }
            // The summary the function sent: its docs' first sentence,
            // on one line.
            let summary = pipes_core::docs::summary(id.docs()).replace('\n', " ");
            line.push_str(&format!("  # {summary}"));
            line
        })
        .collect();
    for module in ["x", "y", "z", "tool"] {
        let prefix = format!("{module}: ");
        let got: Vec<&str> = stdout
            .lines()
            .filter_map(|l| l.strip_prefix(&prefix))
            .collect();
        assert_eq!(got, want, "{module}:\n{stdout}");
    }
    assert!(!stdout.lines().any(|l| l.starts_with("hub: ")), "{stdout}");
}
