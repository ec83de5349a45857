//! The host's local clock: microseconds on a monotonic clock since start.
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

    /// Microseconds since the clock started.
    pub fn now_us(&self) -> u64 {
        now().saturating_duration_since(self.epoch).as_micros() as u64
    }

    /// The clock's reading at `t` (0 before it started).
    pub fn us_at(&self, t: Instant) -> u64 {
        t.saturating_duration_since(self.epoch).as_micros() as u64
    }

    /// The instant at which the clock reads `us`.
    pub fn instant_at(&self, us: u64) -> Instant {
        self.epoch + Duration::from_micros(us)
    }
}

/// Now on tokio's clock (virtual when tokio's time is paused).
pub fn now() -> Instant {
    tokio::time::Instant::now().into_std()
}
