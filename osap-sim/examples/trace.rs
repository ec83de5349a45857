//! Prints one node's error against the root (and, optionally, against a
//! parent node) with its clock status, every `STEP` seconds (default 0.25).
//!
//! `cargo run --release -p osap-sim --example trace -- TOPOLOGY NODE [SECONDS] [PARENT]`
//! e.g. `-- star8 m1 12 hub`.
use osap_sim::network::Network;
use osap_sim::sim::{Sim, SimConfig};
use std::process::ExitCode;

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().collect();
    let usage = "usage: trace TOPOLOGY NODE [SECONDS] [PARENT]";
    let (Some(topo), Some(who)) = (args.get(1), args.get(2)) else {
        eprintln!("{usage}");
        return ExitCode::FAILURE;
    };
    let topology = match Network::named(topo) {
        Ok(t) => t,
        Err(e) => {
            eprintln!("{e}");
            return ExitCode::FAILURE;
        }
    };
    let Ok(secs) = args.get(3).map_or(Ok(30.0), |s| s.parse::<f64>()) else {
        eprintln!("SECONDS must be a number; {usage}");
        return ExitCode::FAILURE;
    };
    let step: f64 = std::env::var("STEP")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0.25);
    let mut sim = match Sim::new(&topology, SimConfig::seeded(1)) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("{e}");
            return ExitCode::FAILURE;
        }
    };
    let (Some(node), Some(root)) = (sim.node_index(who), sim.node_index("host")) else {
        eprintln!("no node {who} (or no host) in {topo}");
        return ExitCode::FAILURE;
    };
    let parent = args.get(4).and_then(|p| sim.node_index(p));
    let system = |sim: &Sim, n: usize| {
        let now = sim.now();
        sim.node(n)
            .runtime()
            .system_time(sim.node(n).local_us(now))
            .as_micros() as i64
    };
    let mut t = 0.0;
    while t < secs {
        t += step;
        sim.run_secs(step);
        let e = system(&sim, node) - system(&sim, root);
        let st = sim.node(node).runtime().clock().status();
        let hop = parent.map(|p| e - (system(&sim, p) - system(&sim, root)));
        println!(
            "{t:6.2}s err {e:6} hop {hop:?} tier {:3} {:?} off {:7.1}us rate {:7}ppb rtt {}/{} acc {} rej {}/{} jumps {}",
            st.tier,
            st.state,
            st.offset_ns as f64 / 1000.0,
            st.rate_ppb,
            st.last_rtt_us,
            st.min_rtt_us,
            st.stats.accepted,
            st.stats.rejected_rtt,
            st.stats.rejected_residual,
            st.stats.jumps
        );
    }
    ExitCode::SUCCESS
}
