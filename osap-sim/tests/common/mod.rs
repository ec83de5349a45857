//! Helpers shared by the integration tests: small discrete-event topologies
//! and traces; for the real-time simulated machines a named host, the
//! shipped topology files, and a refresh that must read everything.
#![allow(dead_code)]

use osap_host::som::Manager;
use osap_host::{Host, HostConfig};
use osap_sim::clock::ClockSpec;
use osap_sim::medium::Side;
use osap_sim::sim::FrameRecord;
use osap_sim::{LinkModel, Network, NodeSpec, Sim, SimConfig};
use std::path::PathBuf;

/// Two nodes joined by one link: `host` (root, a perfect clock) on end A
/// and `m1` (booted 5 s earlier, 50 ppm fast) on end B.
pub(crate) fn pair(model: LinkModel) -> Network {
    Network::new("pair")
        .with_node(NodeSpec::host("host").with_clock(ClockSpec::fixed(0.0, 0.0)))
        .with_node(NodeSpec::mcu("m1").with_clock(ClockSpec::fixed(5_000_000.0, 50.0)))
        .with_link("host", "m1", model)
}

/// A simulation that records every frame.
pub(crate) fn traced(topology: &Network, seed: u64) -> Sim {
    let config = SimConfig {
        trace_frames: true,
        ..SimConfig::seeded(seed)
    };
    Sim::new(topology, config).expect("valid topology")
}

/// The delivered frames sent from end `side` of link 0, in send order.
pub(crate) fn frames_from(sim: &Sim, side: Side) -> Vec<FrameRecord> {
    let from = sim.links()[0].ends[side.index()].0;
    let mut v: Vec<FrameRecord> = sim
        .frames()
        .iter()
        .filter(|f| f.link == 0 && f.from == from && !f.transit.lost)
        .cloned()
        .collect();
    v.sort_by_key(|f| (f.transit.start_ns, f.transit.sent_ns));
    v
}

/// A host runtime named `name`, with the default configuration.
pub(crate) fn host(name: &str) -> Host {
    Host::start(HostConfig::named(name)).unwrap()
}

/// The path of a topology shipped in `osap-sim/topologies/`.
pub(crate) fn shipped(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("topologies")
        .join(name)
}

/// Refreshes the model and checks that every runtime and function was read.
pub(crate) async fn refresh(m: &mut Manager) {
    let report = m.refresh().await.unwrap();
    assert!(
        report.scan_failures.is_empty(),
        "{:?}",
        report.scan_failures
    );
    assert!(
        report.function_failures.is_empty(),
        "{:?}",
        report.function_failures
    );
}

/// Runs the test body `body` on the bus tests' runtime: virtual time by
/// default (every run the same, frames on tokio's 1 ms ticks), or with
/// `OSAP_BUS_REAL_TIME=1` in real time on 2 tokio workers, frames timed to
/// the µs on the wire thread (the figures docs/performance.md quotes).
pub(crate) fn on_bus_runtime<F: std::future::Future>(
    body: impl FnOnce(osap_sim::machine::TimeMode) -> F,
) -> F::Output {
    use osap_sim::machine::{virtual_runtime, TimeMode};
    if std::env::var_os("OSAP_BUS_REAL_TIME").is_some() {
        tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
            .unwrap()
            .block_on(body(TimeMode::RealTime))
    } else {
        virtual_runtime().unwrap().block_on(body(TimeMode::Virtual))
    }
}
