//! How long each phase of a machine's start took: what `osap run -v`
//! prints, and what a bench reads to see where a start-up goes.

use std::fmt;
use std::time::Duration;

use tokio::time::Instant;

/// The phases of one [`Machine`](super::Machine) start, in order, with
/// their durations (on tokio's clock: virtual time in a virtual-time
/// simulation).
#[derive(Debug, Clone)]
pub struct StartPhases {
    started: Instant,
    last: Instant,
    phases: Vec<(&'static str, Duration)>,
    /// When the clock-sync waits began and when the last clock was found
    /// synchronised, from the start.
    sync: Option<(Duration, Duration)>,
    total: Duration,
}

impl StartPhases {
    /// Phases from now.
    pub(super) fn new() -> Self {
        let now = Instant::now();
        StartPhases {
            started: now,
            last: now,
            phases: Vec::new(),
            sync: None,
            total: Duration::ZERO,
        }
    }

    /// Phase `name` ended now (it began where the last one ended).
    pub(super) fn mark(&mut self, name: &'static str) {
        let now = Instant::now();
        self.phases.push((name, now - self.last));
        self.last = now;
    }

    /// Phase `name` took `took`, measured by whoever ran it (it began
    /// where the last one ended).
    pub(super) fn add(&mut self, name: &'static str, took: Duration) {
        self.phases.push((name, took));
        self.last += took;
    }

    /// The clock-sync waits ran from `began` until `done`.
    pub(super) fn synced(&mut self, began: Instant, done: Instant) {
        self.sync = Some((began - self.started, done - self.started));
    }

    /// The start is over: logs the phases (info, `osap run -v`).
    pub(super) fn finish(&mut self) {
        self.total = self.started.elapsed();
        tracing::info!("machine start: {self}");
    }

    /// The phases, in order.
    pub fn phases(&self) -> &[(&'static str, Duration)] {
        &self.phases
    }

    /// From the start to the machine ready.
    pub fn total(&self) -> Duration {
        self.total
    }

    /// When the clock-sync waits began and when the last module's clock
    /// was found synchronised, from the start (`None`: nothing waited).
    pub fn sync_window(&self) -> Option<(Duration, Duration)> {
        self.sync
    }
}

impl fmt::Display for StartPhases {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let ms = |d: Duration| d.as_secs_f64() * 1e3;
        write!(f, "ready after {:.0} ms:", ms(self.total))?;
        for (name, took) in &self.phases {
            write!(f, " {name} {:.0} ms,", ms(*took))?;
        }
        if let Some((began, done)) = self.sync {
            write!(
                f,
                " clocks waited for from {:.0} ms, all synchronised at {:.0} ms",
                ms(began),
                ms(done)
            )?;
        }
        Ok(())
    }
}
