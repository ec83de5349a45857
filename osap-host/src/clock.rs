//! The host's local clock: a monotonic clock since start, read as the
//! runtime's local [`osap_core::Instant`].
//!
//! The clock reads tokio's clock ([`tokio::time::Instant`]), which is the
//! system's monotonic clock unless tokio's time is paused: then the host,
//! and simulated modules on the same clock, run in virtual time.
//!
//! A host normally runs in real time. Against an emulated module that
//! cannot keep up with real time, the host's clock can be slowed to the
//! emulator's steady [`Pace`], so both sides agree on how long a second is
//! and clock sync has a rate it can follow.

use std::num::NonZeroU32;
use std::time::{Duration, Instant};

/// How fast a host's clock runs against the system's monotonic clock:
/// `local` µs of host time pass in every `wall` µs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Pace {
    local: NonZeroU32,
    wall: NonZeroU32,
}

impl Pace {
    /// The clock runs in real time (the default).
    pub const REAL_TIME: Pace = Pace {
        local: NonZeroU32::MIN,
        wall: NonZeroU32::MIN,
    };

    /// `local` µs of host time per `wall` µs of real time (`None` if either
    /// is 0).
    pub fn new(local: u32, wall: u32) -> Option<Pace> {
        Some(Pace {
            local: NonZeroU32::new(local)?,
            wall: NonZeroU32::new(wall)?,
        })
    }

    /// Host time per unit of real time.
    pub fn ratio(&self) -> f64 {
        f64::from(self.local.get()) / f64::from(self.wall.get())
    }

    fn is_real_time(&self) -> bool {
        self.local == self.wall
    }
}

impl Default for Pace {
    fn default() -> Self {
        Pace::REAL_TIME
    }
}

/// A monotonic microsecond counter shared by a host's runtime and its links,
/// so link receive stamps and the runtime's `now` are on the same clock.
#[derive(Debug, Clone, Copy)]
pub struct HostClock {
    epoch: Instant,
    pace: Pace,
}

impl Default for HostClock {
    fn default() -> Self {
        HostClock::new()
    }
}

impl HostClock {
    /// A real-time clock reading 0 now.
    pub fn new() -> Self {
        HostClock::paced(Pace::REAL_TIME)
    }

    /// A clock reading 0 now and running at `pace`.
    pub fn paced(pace: Pace) -> Self {
        HostClock { epoch: now(), pace }
    }

    /// The pace the clock runs at.
    pub fn pace(&self) -> Pace {
        self.pace
    }

    /// The local time now (µs since the clock started).
    pub fn now(&self) -> osap_core::Instant {
        self.at(now())
    }

    /// The clock's reading at `t` ([`osap_core::Instant::ZERO`] before it
    /// started).
    pub fn at(&self, t: Instant) -> osap_core::Instant {
        let since = t.saturating_duration_since(self.epoch).as_micros();
        let local = if self.pace.is_real_time() {
            since
        } else {
            since * u128::from(self.pace.local.get()) / u128::from(self.pace.wall.get())
        };
        osap_core::Instant::from_micros(u64::try_from(local).unwrap_or(u64::MAX))
    }

    /// The instant at which the clock reads `local`.
    pub fn instant_at(&self, local: osap_core::Instant) -> Instant {
        let local = u128::from(local.as_micros());
        let wall = if self.pace.is_real_time() {
            local
        } else {
            // Rounded up: at that instant the clock has reached `local`.
            (local * u128::from(self.pace.wall.get())).div_ceil(u128::from(self.pace.local.get()))
        };
        self.epoch + Duration::from_micros(u64::try_from(wall).unwrap_or(u64::MAX))
    }
}

/// Now on tokio's clock (virtual when tokio's time is paused).
pub fn now() -> Instant {
    tokio::time::Instant::now().into_std()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_paced_clock_runs_at_its_pace_both_ways() {
        let half = HostClock::paced(Pace::new(1, 2).unwrap());
        let t = half.epoch + Duration::from_micros(3_000_001);
        assert_eq!(half.at(t), osap_core::Instant::from_micros(1_500_000));
        let local = osap_core::Instant::from_micros(1_500_000);
        assert_eq!(
            half.instant_at(local),
            half.epoch + Duration::from_micros(3_000_000)
        );
        // Whatever instant_at gives, the clock reads at least that there.
        for us in [0, 1, 7, 999_999, 123_456_789] {
            let local = osap_core::Instant::from_micros(us);
            assert!(half.at(half.instant_at(local)) >= local);
            assert!(half.at(half.instant_at(local) - Duration::from_micros(1)) < local || us == 0);
        }
        let real = HostClock::new();
        let t = real.epoch + Duration::from_micros(42);
        assert_eq!(real.at(t), osap_core::Instant::from_micros(42));
        assert_eq!(real.instant_at(osap_core::Instant::from_micros(42)), t);
    }

    #[test]
    fn a_pace_needs_both_parts() {
        assert_eq!(Pace::new(0, 1), None);
        assert_eq!(Pace::new(1, 0), None);
        assert_eq!(Pace::default(), Pace::REAL_TIME);
        assert_eq!(Pace::new(3, 4).unwrap().ratio(), 0.75);
    }
}
