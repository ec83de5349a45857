//! The module firmware's hot start, simulated: every module runs
//! the firmware's policy (osap-module's) over a simulated rate sector. A first boot
//! (cold, erased flash) saves the rate its clock learned; a reboot from
//! that flash presets it, so it knows its rate strictly sooner than the
//! cold boot of the same seed learns it, and its phase is never later.
//!
//! The figures in docs/clock-sync.md ("Hot start") come from
//! `cargo test -p osap-sim --release --test firmware_hot_start -- --nocapture`.

use osap_module::hot_start::{Preset, SavePolicy};
use osap_sim::hot_start::{run_with_rate_flash, SimRateFlash};
use osap_sim::{Network, Scenario};

/// A topology shipped in `osap-sim/topologies/`.
fn shipped(file: &str) -> Network {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("topologies")
        .join(file);
    Network::load(path).expect("valid topology")
}

/// The firmware's poll period is its runtime loop's (tens of µs to a few
/// ms); 1 ms of simulated time is within that.
const POLL_US: u64 = 1_000;

/// How close to the rate its oscillator needs a clock's rate correction
/// must be for the clock to know its rate, ppm. A firmware hot start's
/// saved rate is off by what both crystals wandered between the save (60 s
/// after settling) and the reboot: at most 2 × (1.5 + 1.5) ppm for these
/// nodes (`ClockSpec` wander amplitudes), plus under 1 ppm of the learned
/// rate's own noise. A cold start begins at its crystal's whole offset,
/// tens of ppm.
const RATE_KNOWN_PPM: f64 = 10.0;

/// The start the rate is compared over, s: three times the second a cold
/// start takes to learn its rate (docs/clock-sync.md). Later, over USB,
/// cold and hot starts of one seed leave their rate alike (single-usb
/// seed 3: by 10 ppm from 7.9 s on); that is the controller's doing, not
/// the start's.
const START_S: f64 = 3.0;

/// Seconds until every node stays within 50 µs, and until every node's
/// rate stays known (within [`RATE_KNOWN_PPM`], through [`START_S`]): cold, firmware hot start
/// from the record a first boot saved, and the simulator's exact preset.
struct Starts {
    cold: f64,
    firmware: f64,
    exact: f64,
    cold_rate: f64,
    firmware_rate: f64,
}

fn starts(topology: Network, seed: u64) -> Starts {
    let name = topology.name.clone();
    let nodes = topology.nodes.len();
    let mut flash = vec![SimRateFlash::erased(); nodes];
    let policy = SavePolicy::default();

    // First boot: settles, then saves after the hold (60 s).
    let first = Scenario::new(topology.clone()).seed(seed).seconds(75.0);
    let boot = run_with_rate_flash(&first, &mut flash, policy, POLL_US).unwrap();
    let root = boot.metrics.root;
    for (i, record) in boot.records.iter().enumerate() {
        assert_eq!(record.is_some(), i != root, "{name} seed {seed} node {i}");
    }
    assert_eq!(boot.saves as usize, nodes - 1, "{name}: one save each");

    // Reboot from the saved flash.
    let again = Scenario::new(topology.clone()).seed(seed).seconds(10.0);
    let hot = run_with_rate_flash(&again, &mut flash, policy, POLL_US).unwrap();
    for (i, preset) in hot.presets.iter().enumerate() {
        let want = if i == root {
            Preset::Nothing
        } else {
            Preset::Applied
        };
        assert_eq!(*preset, want, "{name} seed {seed} node {i}");
    }
    // The same rate again: nothing written in the first 10 minutes.
    assert_eq!(hot.saves, 0);

    let cold = Scenario::new(topology.clone()).seed(seed).seconds(10.0);
    let exact = cold.clone().hot_start(true);
    let cold = cold.run().unwrap().metrics;
    // A cold start has a rate to learn: every follower's crystal is
    // further off than a known rate may be.
    for i in cold.followers() {
        let first = cold.rate_error_ppm[i][0];
        assert!(
            first.abs() > RATE_KNOWN_PPM,
            "{name} seed {seed} node {i}: a cold start within {first} ppm has nothing to learn"
        );
    }
    let to_50 = |m: &osap_sim::metrics::Metrics| {
        m.summary()
            .converged_50us_s
            .unwrap_or_else(|| panic!("{name} seed {seed}: did not converge"))
    };
    let known = |m: &osap_sim::metrics::Metrics| {
        m.rate_known_time(RATE_KNOWN_PPM, START_S)
            .unwrap_or_else(|| {
                panic!(
                    "{name} seed {seed}: a rate was not within {RATE_KNOWN_PPM} ppm by {START_S} s"
                )
            })
    };
    Starts {
        cold: to_50(&cold),
        firmware: to_50(&hot.metrics),
        exact: to_50(&exact.run().unwrap().metrics),
        cold_rate: known(&cold),
        firmware_rate: known(&hot.metrics),
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

#[test]
fn a_reboot_presets_the_saved_rate_and_knows_it_sooner_than_a_cold_boot() {
    let mut rows = Vec::new();
    for seed in 1..=4 {
        // (In chain4 and star8 the modules behind the USB hub do not
        // report settled within a minute in this tree, so their first boot
        // saves nothing to restore.)
        for topology in [shipped("uart-chain.toml"), shipped("single-usb.toml")] {
            let name = topology.name.clone();
            let s = starts(topology, seed);
            eprintln!(
                "{name:>12} seed {seed}: within 50 µs after cold {:.2} s, firmware hot start {:.2} s, exact preset {:.2} s; \
                 rate within {RATE_KNOWN_PPM} ppm after cold {:.2} s, firmware hot start {:.2} s",
                s.cold, s.firmware, s.exact, s.cold_rate, s.firmware_rate
            );
            rows.push((name, s));
        }
    }
    let (cold, firmware): (Vec<f64>, Vec<f64>) =
        rows.iter().map(|(_, s)| (s.cold, s.firmware)).unzip();
    let exact: Vec<f64> = rows.iter().map(|(_, s)| s.exact).collect();
    let sooner: Vec<f64> = rows.iter().map(|(_, s)| s.cold - s.firmware).collect();
    eprintln!(
        "median over {} runs: cold {:.2} s, firmware hot start {:.2} s, exact preset {:.2} s; \
         sooner by median {:.2} s, least {:.2} s; worst firmware hot start {:.2} s",
        rows.len(),
        median(cold.clone()),
        median(firmware.clone()),
        median(exact),
        median(sooner.clone()),
        sooner.iter().copied().fold(f64::INFINITY, f64::min),
        firmware.iter().copied().fold(0.0, f64::max),
    );
    for ((name, s), d) in rows.iter().zip(&sooner) {
        // The rate is known strictly sooner than a cold start learns it:
        // the preset is what a hot start is for.
        assert!(
            s.firmware_rate < s.cold_rate,
            "{name}: rate known after {} s hot against {} s cold",
            s.firmware_rate,
            s.cold_rate
        );
        // And the phase is never later (most runs are within 50 µs at the
        // first exchange either way, so there equal, to the 10 ms sample).
        assert!(
            *d >= 0.0,
            "{name}: hot {} s against cold {} s",
            s.firmware,
            s.cold
        );
        // The saved rate is as good as the exact one: a wrong preset would
        // leave the clock to learn its rate again, as a cold start does.
        assert!(
            (s.firmware - s.exact).abs() <= 0.05,
            "{name}: firmware hot start {} s against an exact preset's {} s",
            s.firmware,
            s.exact
        );
    }
    // A cold start that had to learn its rate (single-usb seed 3 takes
    // about a second) is what a hot start is for: it settles at once.
    let slow: Vec<&(String, Starts)> = rows.iter().filter(|(_, s)| s.cold > 0.5).collect();
    assert!(!slow.is_empty(), "no slow cold start left to compare");
    for (name, s) in slow {
        assert!(
            s.firmware < 0.25,
            "{name}: hot {} s against cold {} s",
            s.firmware,
            s.cold
        );
    }
}
