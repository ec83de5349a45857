//! The hot-start hook: the one place that presets a runtime's clock rate.
//!
//! A module that persisted its learned rate correction from an earlier run
//! (or was told it) starts with it instead of from zero; the clock-sync
//! benchmark compares such hot starts with cold ones. How a rate is handed
//! to the clock belongs to osap-core's clock controller, so the simulator
//! calls it only here: if that API changes, adapt this function alone.

use crate::node::SimRuntime;
use osap_core::Micros;

/// HOT-START HOOK: presets `runtime`'s rate correction to `ppb` parts per
/// billion at local time `local_now` (system time stays continuous there).
///
/// The sign convention is the clock's: system time advances by
/// `local · (1 + ppb·1e-9)`, so a node whose oscillator runs fast by `r`
/// relative to the root needs `ppb ≈ −r`. Returns whether the runtime
/// took it.
pub fn apply_hot_start(runtime: &mut SimRuntime, local_now: Micros, ppb: i32) -> bool {
    runtime.clock_mut().set_rate_ppb(local_now, ppb);
    true
}
