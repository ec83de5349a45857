//! The host's local clock: a monotonic clock since start, read as the
//! runtime's local [`osap_core::Instant`].
//!
//! The clock reads tokio's clock ([`tokio::time::Instant`]), which is the
//! system's monotonic clock unless tokio's time is paused: then the host,
//! and simulated modules on the same clock, run in virtual time.

use std::time::{Duration, Instant};

/// A monotonic microsecond counter shared by a host's runtime and its links,
/// so link receive stamps and the runtime's `now` are on the same clock.
#[derive(Debug, Clone, Copy)]
pub struct HostClock {
    epoch: Instant,
}

impl Default for HostClock {
    fn default() -> Self {
        HostClock::new()
    }
}

impl HostClock {
    /// A clock reading 0 now.
    pub fn new() -> Self {
        HostClock { epoch: now() }
    }

    /// The local time now (µs since the clock started).
    pub fn now(&self) -> osap_core::Instant {
        self.at(now())
    }

    /// The clock's reading at `t` ([`osap_core::Instant::ZERO`] before it
    /// started).
    pub fn at(&self, t: Instant) -> osap_core::Instant {
        let since = t.saturating_duration_since(self.epoch);
        osap_core::Instant::from_micros(u64::try_from(since.as_micros()).unwrap_or(u64::MAX))
    }

    /// The instant at which the clock reads `local`.
    pub fn instant_at(&self, local: osap_core::Instant) -> Instant {
        self.epoch + Duration::from_micros(local.as_micros())
    }
}

/// Now on tokio's clock (virtual when tokio's time is paused).
pub fn now() -> Instant {
    tokio::time::Instant::now().into_std()
}
