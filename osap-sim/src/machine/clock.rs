//! A simulated module's drifting local clock, in real time.

use crate::clock::ClockModel;
use osap_core::Instant as LocalInstant;
use std::time::{Duration, Instant};

/// A module's free-running µs counter, running at its own rate against the
/// host's monotonic clock:
///
/// ```text
/// local_us(t) = offset + (t − boot) × (1 + rate_ppm·1e-6) + wander(t − boot)
/// ```
///
/// with `t` an [`Instant`], `boot` when the module (re)started, and the
/// oscillator an [`crate::clock::ClockModel`] (so the same model as the
/// discrete-event simulator, only driven by real time). The mapping is
/// monotonic and can be inverted, which is how a runtime's `wake_at` (local
/// µs) becomes a timer deadline.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriftClock {
    boot: Instant,
    model: ClockModel,
}

impl DriftClock {
    /// A clock that booted at `boot` with oscillator `model`.
    pub fn new(boot: Instant, model: ClockModel) -> Self {
        DriftClock { boot, model }
    }

    /// When the module booted.
    pub fn boot(&self) -> Instant {
        self.boot
    }

    /// The oscillator.
    pub fn model(&self) -> &ClockModel {
        &self.model
    }

    /// The fixed rate error, ppm.
    pub fn rate_ppm(&self) -> f64 {
        self.model.rate_ppm()
    }

    /// The local counter at instant `t` (its boot value before boot).
    pub fn local_at(&self, t: Instant) -> LocalInstant {
        let ns = t.saturating_duration_since(self.boot).as_nanos();
        self.model.local_us(ns.min(u128::from(u64::MAX)) as u64)
    }

    /// The local counter now.
    pub fn now(&self) -> LocalInstant {
        self.local_at(osap_host::clock::now())
    }

    /// The first instant at which the local counter reads at least `local`.
    pub fn instant_at(&self, local: LocalInstant) -> Instant {
        let ns = self.model.true_time_at(local);
        self.boot
            .checked_add(Duration::from_nanos(ns))
            .unwrap_or_else(|| self.boot + Duration::from_secs(86_400 * 365))
    }
}
