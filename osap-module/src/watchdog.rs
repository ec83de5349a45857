//! The output watchdog: a module that hears nothing from upstream for a
//! while puts its outputs in their safe state by itself, so a dead host,
//! a pulled cable or a hung link cannot leave a spindle, a laser or a
//! heater on.
//!
//! `set_output_watchdog(timeout_ms)` arms it (0 turns it off; it is off at
//! boot, so a bare module a user pokes at by hand keeps its outputs). Every
//! PIPES call or pipe datagram that reaches one of the module's functions
//! from the network feeds it ([`crate::ModulePort`] does, for any of the
//! module's functions: `add_point` streams, `get_status` polls, ...). Runs
//! a module's own timer makes (a function set to run "on timer" as a pipe
//! source, such as `get_fault`) do not: they say nothing about upstream.
//!
//! When `timeout_ms` has passed since the last feed, the module applies
//! every safe output value ([`crate::io`]) and records a
//! [`FaultKind::OutputWatchdog`](crate::fault::FaultKind::OutputWatchdog)
//! fault, so a host that comes back hears why its tools went off. It then
//! stays fired (nothing is applied again) until the next call feeds it;
//! the outputs stay at their safe values until a caller writes them
//! again. The runtime's loop checks it through the pulse timer port, which
//! wakes for its deadline.

use osap_core::{Duration, Instant};

/// The output watchdog's state.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Watchdog {
    /// How long upstream may be quiet (`Duration::ZERO`: off).
    timeout: Duration,
    /// Local time of the latest feed.
    fed: Instant,
    /// Whether it fired since the latest feed.
    fired: bool,
    /// Times it fired since boot.
    fires: u32,
}

impl Watchdog {
    /// Off, as at boot.
    pub const fn new() -> Self {
        Watchdog {
            timeout: Duration::ZERO,
            fed: Instant::ZERO,
            fired: false,
            fires: 0,
        }
    }

    /// Arms it with `timeout_ms` (0: off), fed at local time `now`.
    pub fn set(&mut self, timeout_ms: u32, now: Instant) {
        self.timeout = Duration::from_millis(u64::from(timeout_ms));
        self.feed(now);
    }

    /// Upstream spoke at local time `now`: the timeout starts again, and a
    /// fired watchdog is ready to fire again.
    pub fn feed(&mut self, now: Instant) {
        self.fed = now;
        self.fired = false;
    }

    /// The timeout, ms (0: off).
    pub fn timeout_ms(&self) -> u32 {
        u32::try_from(self.timeout.as_micros() / 1_000).unwrap_or(u32::MAX)
    }

    /// When it fires if nothing feeds it first, local time; `None` when it
    /// is off or has fired.
    pub fn deadline(&self) -> Option<Instant> {
        (self.timeout > Duration::ZERO && !self.fired).then(|| self.fed + self.timeout)
    }

    /// Fires if its deadline has come at local time `now`: `Some(quiet)`,
    /// how long upstream has been quiet, the first time only (until the
    /// next feed).
    pub fn poll(&mut self, now: Instant) -> Option<Duration> {
        let deadline = self.deadline()?;
        if now < deadline {
            return None;
        }
        self.fired = true;
        self.fires = self.fires.wrapping_add(1);
        Some(now - self.fed)
    }

    /// Whether it fired since the latest feed.
    pub fn is_fired(&self) -> bool {
        self.fired
    }

    /// Times it fired since boot.
    pub fn fires(&self) -> u32 {
        self.fires
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(ms: u64) -> Instant {
        Instant::from_micros(ms * 1_000)
    }

    #[test]
    fn off_at_boot_and_at_zero() {
        let mut w = Watchdog::new();
        assert_eq!(w.deadline(), None);
        assert_eq!(w.poll(at(1_000_000)), None);
        w.set(500, at(0));
        w.set(0, at(10));
        assert_eq!(w.poll(at(1_000_000)), None);
        assert_eq!(w.fires(), 0);
    }

    #[test]
    fn fires_once_at_the_deadline_until_fed() {
        let mut w = Watchdog::new();
        w.set(500, at(100));
        assert_eq!(w.deadline(), Some(at(600)));
        assert_eq!(w.poll(Instant::from_micros(599_999)), None);
        assert_eq!(w.poll(at(600)), Some(Duration::from_millis(500)));
        assert!(w.is_fired());
        assert_eq!(w.deadline(), None);
        assert_eq!(w.poll(at(5_000)), None, "once");
        w.feed(at(5_000));
        assert!(!w.is_fired());
        assert_eq!(w.deadline(), Some(at(5_500)));
        assert_eq!(w.poll(at(5_700)), Some(Duration::from_millis(700)));
        assert_eq!(w.fires(), 2);
        assert_eq!(w.timeout_ms(), 500);
    }
}
