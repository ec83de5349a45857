//! Clock-sync targets, asserted on short simulated runs so a regression in
//! the controller fails CI. The full ten-minute measurements are made by the
//! `clock_sync_report` binary (see docs/performance.md); these thresholds
//! are what every run of it meets, with a margin for the shorter runs.

use osap_sim::busy::BusyModel;
use osap_sim::{Network, Scenario};

/// A topology shipped in `osap-sim/topologies/`, for the discrete-event
/// simulator.
fn shipped(file: &str) -> Network {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("topologies")
        .join(file);
    Network::load(path).expect("valid topology")
}

/// Host (root) and two modules in a chain over 2 Mbaud UARTs.
fn uart_chain() -> Network {
    shipped("uart-chain.toml")
}

/// chain4 with the USB hub module as the root; the host follows over USB.
fn chain4_hub_root() -> Network {
    shipped("chain4-hub-root.toml")
}

#[test]
fn uart_hops_converge_in_seconds_and_hold_microseconds() {
    for seed in [1, 2] {
        let m = Scenario::new(uart_chain())
            .seed(seed)
            .seconds(30.0)
            .run()
            .unwrap()
            .metrics;
        let cold = m.summary();
        let to_50 = cold.converged_50us_s.expect("converged");
        assert!(to_50 < 2.0, "seed {seed}: within 50 µs after {to_50} s");
        let to_10 = cold.converged_10us_s.expect("converged to 10 µs");
        assert!(to_10 < 2.0, "seed {seed}: within 10 µs after {to_10} s");
        // Steady state: from 5 s on. Errors are read in whole µs (as the
        // modules read their time), so 1 µs is the least a nonzero error
        // reads; before the responder's midpoint was taken below the µs and
        // the phase averaged over the stamps' noise, both were 2 µs.
        let p99 = m.pooled_stats(5.0).p99;
        assert!(p99 <= 1.0, "seed {seed}: p99 {p99}");
        let hops = m.hop_stats("uart", 5.0).unwrap().p99;
        assert!(hops <= 1.0, "seed {seed}: UART hop p99 {hops}");

        let hot = Scenario::new(uart_chain())
            .seed(seed)
            .seconds(10.0)
            .hot_start(true)
            .run()
            .unwrap()
            .metrics
            .summary();
        let to_50 = hot.converged_50us_s.expect("converged");
        assert!(
            to_50 < 0.5,
            "seed {seed}: hot start within 50 µs after {to_50} s"
        );
    }
}

#[test]
fn usb_topologies_hold_the_usb_target() {
    for topology in [Network::chain4(), Network::star8(), Network::loop3()] {
        let name = topology.name.clone();
        let m = Scenario::new(topology)
            .seed(1)
            .seconds(60.0)
            .run()
            .unwrap()
            .metrics;
        let s = m.summary();
        let to_50 = s.converged_50us_s.expect("converged to 50 µs");
        assert!(to_50 < 30.0, "{name}: within 50 µs only after {to_50} s");
        // Steady state: from 20 s on.
        let usb = m.hop_stats("usb_cdc", 20.0).expect("a USB hop").p99;
        let uart = m.hop_stats("uart", 20.0).expect("a UART hop").p99;
        let err = m.pooled_stats(20.0).p99;
        println!("{name}: USB hop p99 {usb}, UART hop p99 {uart}, error p99 {err}");
        assert!(usb < 50.0, "{name}: USB hop p99 {usb}");
        assert!(err < 50.0, "{name}: error p99 {err}");
        // Behind a hub that follows USB the hop is limited by the hub's
        // own time moving (it slews away the USB link's noise), not by
        // the UART: see docs/clock-sync.md.
        assert!(uart <= 2.0, "{name}: UART hop p99 {uart}");
    }
}

/// How a run starts.
#[derive(Clone, Copy)]
enum Start {
    Cold,
    Hot,
    Busy,
}

/// Seconds until every node stays within 50 µs, for chain4, star8 and
/// loop with seeds 1-4, each run `seconds` long; every run must get there
/// within `worst` s.
fn usb_starts(start: Start, seconds: f64, worst: f64) -> Vec<f64> {
    let mut times = Vec::new();
    for seed in 1..=4 {
        for topology in [Network::chain4(), Network::star8(), Network::loop3()] {
            let name = topology.name.clone();
            let mut scenario = Scenario::new(topology).seed(seed).seconds(seconds);
            match start {
                Start::Cold => {}
                Start::Hot => scenario = scenario.hot_start(true),
                Start::Busy => scenario = scenario.busy_modules(BusyModel::MOTOR),
            }
            let s = scenario.run().unwrap().metrics.summary();
            let to_50 = s.converged_50us_s.expect("converged to 50 µs");
            assert!(
                to_50 < worst,
                "{name} seed {seed}: within 50 µs after {to_50} s"
            );
            times.push(to_50);
        }
    }
    times
}

#[test]
fn usb_hot_starts_converge_within_half_a_second() {
    // A hot start knows its rate; across USB the phase comes from the
    // prompt one-way envelope within the first quarter second. Measured
    // over seeds 1-20 (scripts/clock-sync-seeds.sh): 59 of 60 under 0.5 s,
    // worst 2.1 s; seeds 1-4 here: worst 0.33 s.
    let times = usb_starts(Start::Hot, 10.0, 0.5);
    eprintln!("USB hot starts, s: {times:?}");
}

#[test]
fn usb_cold_starts_converge_within_two_seconds() {
    // A cold start learns its rate from the one-way envelopes within about
    // a second, and follows the prompt one meanwhile. Measured over seeds
    // 1-20 (scripts/clock-sync-seeds.sh): 60 of 60 under 2 s, worst 1.5 s;
    // seeds 1-4 here: worst 1.06 s.
    let times = usb_starts(Start::Cold, 20.0, 2.0);
    eprintln!("USB cold starts, s: {times:?}");
}

#[test]
fn usb_busy_starts_converge_within_two_seconds_mostly() {
    // Busy modules stamp late and trail a hub whose rate still moves.
    // Measured over seeds 1-20: 57 of 60 under 2 s, worst 2.6 s; seeds 1-4
    // here: 11 of 12, worst 2.3 s.
    let times = usb_starts(Start::Busy, 20.0, 5.0);
    eprintln!("USB busy starts, s: {times:?}");
    let quick = times.iter().filter(|t| **t < 2.0).count();
    assert!(
        quick >= 10,
        "only {quick} of 12 busy starts within 2 s: {times:?}"
    );
}

#[test]
fn a_module_root_keeps_every_uart_hop_within_microseconds() {
    let m = Scenario::new(chain4_hub_root())
        .seed(1)
        .seconds(60.0)
        .run()
        .unwrap()
        .metrics;
    let uart = m.hop_stats("uart", 10.0).unwrap().p99;
    assert!(uart <= 1.0, "UART hop p99 {uart}");
    let usb = m.hop_stats("usb_cdc", 10.0).unwrap().p99;
    assert!(usb < 50.0, "USB hop p99 {usb}");
}

#[test]
fn busy_modules_cause_no_spike_beyond_100_us() {
    for topology in [uart_chain(), Network::star8()] {
        let name = topology.name.clone();
        let m = Scenario::new(topology)
            .seed(5)
            .seconds(60.0)
            .busy_modules(BusyModel::MOTOR)
            .run()
            .unwrap()
            .metrics;
        let s = m.summary();
        let from = s.converged_50us_s.expect("converged");
        assert!(from < 30.0, "{name}: converged after {from} s");
        let worst = m.worst_abs()[m.index_at(from)..]
            .iter()
            .copied()
            .fold(0.0, f64::max);
        assert!(worst <= 100.0, "{name}: spike of {worst} µs");
        if name == "uartchain" {
            // Late stamps are white noise to the phase filter: with a root
            // behind a clean UART the hops stay within a µs.
            let hops = m.hop_stats("uart", from + 5.0).unwrap().p99;
            assert!(hops <= 1.0, "{name}: busy UART hop p99 {hops}");
        }
    }
}

/// System time of `node` minus that of `other`, at the current instant, µs.
fn gap(sim: &osap_sim::Sim, node: usize, other: usize) -> i64 {
    let now = sim.now();
    let t = |n: usize| {
        let local = sim.node(n).local_us(now);
        sim.node(n).runtime().system_time(local).as_micros() as i64
    };
    t(node) - t(other)
}

#[test]
fn root_loss_holds_over_without_runaway_and_a_new_root_takes_over() {
    use osap_core::clock::{SyncState, TimeConfig, TIER_UNSYNCED};
    let (mut sim, _) = Scenario::new(uart_chain()).seed(3).build().unwrap();
    let (hub, m1) = (
        sim.node_index("hub").unwrap(),
        sim.node_index("m1").unwrap(),
    );
    sim.run_secs(10.0);
    assert_eq!(sim.node(m1).runtime().clock().tier(), 2);
    let rate_before = sim.node(hub).runtime().clock().rate_ppb();

    // The root's link goes away (link 0 joins host and hub).
    sim.set_link_open(0, false);
    sim.run_secs(10.0);
    for n in [hub, m1] {
        let clock = sim.node(n).runtime().clock();
        assert_eq!(clock.tier(), TIER_UNSYNCED, "tiers age out");
        assert_eq!(clock.state(), SyncState::Holdover);
    }
    // Holdover: the learned rate is kept, not chased anywhere ...
    let drift = (sim.node(hub).runtime().clock().rate_ppb() - rate_before).abs();
    assert!(drift < 2_000, "hub rate moved {drift} ppb in holdover");
    // ... and the two modules stay together.
    let apart = gap(&sim, m1, hub).abs();
    assert!(
        apart < 50,
        "modules {apart} µs apart after 10 s of holdover"
    );

    // The hub is made root over configuration: the network follows it.
    let root = TimeConfig {
        root: true,
        ..TimeConfig::default()
    };
    sim.node_mut(hub)
        .runtime_mut()
        .clock_mut()
        .set_config(root)
        .unwrap();
    sim.run_secs(3.0);
    assert_eq!(sim.node(hub).runtime().clock().tier(), 0);
    assert_eq!(sim.node(m1).runtime().clock().tier(), 1);
    assert_eq!(sim.node(m1).runtime().clock().state(), SyncState::Synced);
    let apart = gap(&sim, m1, hub).abs();
    assert!(apart <= 5, "m1 {apart} µs from the new root");
}
