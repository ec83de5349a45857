//! Prints one node's error against the root and its clock status over time.
//! `cargo run --release -p osap-sim --example trace -- chain4 hub1 30`
use osap_sim::sim::{Sim, SimConfig};
use osap_sim::topology::Topology;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let topo = Topology::named(args.get(1).map_or("chain4", |s| s)).expect("topology");
    let who = args.get(2).map_or("hub1", |s| s.as_str()).to_string();
    let secs: f64 = args.get(3).map_or(30.0, |s| s.parse().unwrap());
    let mut sim = Sim::new(&topo, SimConfig::seeded(1)).expect("sim");
    let node = sim.node_index(&who).expect("node");
    let root = sim.node_index("host").expect("root");
    let parent = args.get(4).and_then(|p| sim.node_index(p));
    let step: f64 = std::env::var("STEP")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0.25);
    let mut t = 0.0;
    while t < secs {
        t += step;
        sim.run_secs(step);
        let now = sim.now();
        let e = sim
            .node(node)
            .runtime()
            .system_time(sim.node(node).local_us(now)) as i64
            - sim
                .node(root)
                .runtime()
                .system_time(sim.node(root).local_us(now)) as i64;
        let st = sim.node(node).runtime().clock().status();
        let pe = parent.map(|p| {
            sim.node(p).runtime().system_time(sim.node(p).local_us(now)) as i64
                - sim
                    .node(root)
                    .runtime()
                    .system_time(sim.node(root).local_us(now)) as i64
        });
        print!("parent {:?} hop {:?} ", pe, pe.map(|p| e - p));
        println!(
            "{t:6.2}s err {e:8} tier {:3} state {:?} off {:8.1}us rate {:8}ppb rtt {}/{} acc {} rrtt {} rres {} jumps {}",
            st.tier, st.state, st.offset_ns as f64 / 1000.0, st.rate_ppb, st.last_rtt_us, st.min_rtt_us,
            st.stats.accepted, st.stats.rejected_rtt, st.stats.rejected_residual, st.stats.jumps
        );
    }
}
