//! The hot-start hooks: the places that preset a runtime's clock rate.
//!
//! A module that persisted its learned rate correction from an earlier run
//! (or was told it) starts with it instead of from zero; the clock-sync
//! benchmark compares such hot starts with cold ones. How a rate is handed
//! to the clock belongs to osap-core's clock controller, so the simulator
//! calls it only here: if that API changes, adapt this file alone.
//!
//! Two kinds of hot start:
//! - [`apply_hot_start`] presets the rate the root needs at boot, exactly
//!   (the simulator knows every oscillator): the best a hot start can do;
//! - [`run_with_rate_flash`] runs the module firmware's own policy
//!   (osap-module's [`RateKeeper`], which the firmware runs) on every non-root node over a
//!   simulated rate sector that outlives the run: a first boot saves the
//!   rate it learned, a second run from the same flash is the firmware's
//!   hot start, preset from the saved record once the clock follows the
//!   source it was learned against.

use crate::error::SimError;
use crate::metrics::Metrics;
use crate::node::SimRuntime;
use crate::scenario::Scenario;
use osap_core::Instant;
use osap_module::hot_start::{Preset, RateKeeper, SavePolicy};
use osap_module::rate_store::{RamRateFlash, RateRecord};

/// HOT-START HOOK: presets `runtime`'s rate correction to `ppb` parts per
/// billion at local time `local_now` (system time stays continuous there).
///
/// The sign convention is the clock's: system time advances by
/// `local · (1 + ppb·1e-9)`, so a node whose oscillator runs fast by `r`
/// relative to the root needs `ppb ≈ −r`. Returns whether the runtime
/// took it.
pub fn apply_hot_start(runtime: &mut SimRuntime, local_now: Instant, ppb: i32) -> bool {
    runtime.clock_mut().set_rate_ppb(local_now, ppb);
    true
}

/// A simulated module's rate sector: 4 KiB, as on the RP2040.
pub type SimRateFlash = RamRateFlash<4096>;

/// What a run with the firmware's hot start policy produced.
#[derive(Debug)]
pub struct FlashRun {
    /// The sampled errors.
    pub metrics: Metrics,
    /// What became of each node's saved rate (the root's: `Nothing` or
    /// `Declined`).
    pub presets: Vec<Preset>,
    /// Each node's newest record at the end of the run.
    pub records: Vec<Option<RateRecord>>,
    /// Records written during the run, over all nodes.
    pub saves: u32,
}

/// Runs `scenario` (its own hot start is ignored) with every node running
/// the firmware's hot start policy `policy` over its sector in `flash`
/// (index = node index), polled every `poll_us` of simulated time, as the
/// firmware polls it after each runtime poll.
///
/// # Errors
/// If the scenario does not build, or `flash` has fewer sectors than the
/// topology has nodes.
pub fn run_with_rate_flash(
    scenario: &Scenario,
    flash: &mut [SimRateFlash],
    policy: SavePolicy,
    poll_us: u64,
) -> Result<FlashRun, SimError> {
    let (mut sim, _) = Scenario {
        hot_start: false,
        ..scenario.clone()
    }
    .build()?;
    let nodes = sim.nodes().len();
    if flash.len() < nodes || poll_us == 0 {
        return Err(SimError::config(format!(
            "{} rate sectors for {nodes} nodes, polled every {poll_us} µs",
            flash.len()
        )));
    }
    let writes_before: u32 = flash.iter().map(|f| f.writes).sum();
    let mut keepers: Vec<_> = flash
        .iter_mut()
        .take(nodes)
        .map(|f| RateKeeper::open(f, policy))
        .collect();
    let end = (scenario.seconds * 1e9) as u64;
    let step = poll_us * 1_000;
    let mut t = 0;
    while t < end {
        t = (t + step).min(end);
        sim.run_until(t);
        for (i, keeper) in keepers.iter_mut().enumerate() {
            let local = sim.node(i).local_us(t);
            let clock = sim.node_mut(i).runtime_mut().clock_mut();
            // A failed save is the simulated flash's doing (a test that
            // sets `fail`); the policy retries after its interval.
            let _ = keeper.poll(local, clock);
        }
    }
    let presets = keepers.iter().map(|k| k.preset()).collect();
    let records = keepers.iter().map(|k| k.store().newest()).collect();
    drop(keepers);
    let saves = flash.iter().map(|f| f.writes).sum::<u32>() - writes_before;
    Ok(FlashRun {
        metrics: sim.into_metrics(),
        presets,
        records,
        saves,
    })
}
