//! Busy modules: spells during which a node's main loop does not run.
//!
//! A module that runs motor control in an interrupt, or a host that is
//! descheduled, stops polling its runtime for tens to hundreds of µs. Its
//! packets then wait, and if its receive stamps are taken in an interrupt
//! that the busy work pre-empts, those stamps come late by the rest of the
//! spell: exactly the bad samples a clock-sync filter has to reject (the
//! thesis's sync spikes).
//!
//! Spells start either with a probability at each event the node sees (a
//! poll, or the first byte of a frame arriving), or as a Poisson process in
//! time. Spells are kept as true-time intervals, so the question "was the
//! node busy at t?" has one answer however often it is asked.

use crate::error::SimError;
use crate::rng::{Dist, Rng};
use crate::Nanos;
use std::collections::VecDeque;

/// What starts a busy spell.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum BusyTrigger {
    /// Each event at the node (poll, frame arrival) starts a spell with
    /// this probability.
    PerEvent {
        /// Probability per event, [0, 1].
        probability: f64,
    },
    /// Spells start as a Poisson process with this mean interval, µs.
    Poisson {
        /// Mean time between spell starts, µs.
        mean_interval_us: f64,
    },
}

/// How and how long a node is busy.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BusyModel {
    /// What starts a spell.
    pub trigger: BusyTrigger,
    /// How long a spell lasts, µs.
    pub duration: Dist,
    /// Receive stamps are taken in an interrupt the busy work pre-empts, so
    /// a frame whose first byte arrives during a spell is stamped at its end.
    pub late_stamps: bool,
}

impl BusyModel {
    /// A module running motor control: 5 % of events start a spell of
    /// U[20, 200] µs, and receive stamps are pre-empted.
    pub const MOTOR: BusyModel = BusyModel {
        trigger: BusyTrigger::PerEvent { probability: 0.05 },
        duration: Dist::uniform(20.0, 200.0),
        late_stamps: true,
    };

    /// Checks the parameters; `node` names the node in the error.
    pub fn validate(&self, node: &str) -> Result<(), SimError> {
        match self.trigger {
            BusyTrigger::PerEvent { probability } if !(0.0..=1.0).contains(&probability) => {
                return Err(SimError::config(format!(
                    "node {node}: busy probability {probability} is not in [0, 1]"
                )));
            }
            BusyTrigger::Poisson { mean_interval_us }
                if !(mean_interval_us.is_finite() && mean_interval_us >= 1.0) =>
            {
                return Err(SimError::config(format!(
                    "node {node}: busy mean_interval_us {mean_interval_us} must be finite and >= 1"
                )));
            }
            _ => {}
        }
        self.duration
            .validate(&format!("node {node}: busy duration"))
    }
}

/// Spells are forgotten this long after they end (frames are never older).
const HISTORY_NS: Nanos = 1_000_000_000;

/// The busy spells of one node.
#[derive(Debug, Clone)]
pub struct BusyState {
    model: Option<BusyModel>,
    rng: Rng,
    /// Disjoint spells `[start, end)`, sorted by start.
    spells: VecDeque<(Nanos, Nanos)>,
    next_poisson: Option<Nanos>,
    started: u64,
}

impl BusyState {
    /// The state of a node with `model` (`None`: never busy).
    pub fn new(model: Option<BusyModel>, mut rng: Rng) -> Self {
        let next_poisson = match model.map(|m| m.trigger) {
            Some(BusyTrigger::Poisson { mean_interval_us }) => {
                Some(crate::rng::us_to_ns(rng.exponential(mean_interval_us)))
            }
            _ => None,
        };
        BusyState {
            model,
            rng,
            spells: VecDeque::new(),
            next_poisson,
            started: 0,
        }
    }

    /// The model, if the node is ever busy.
    pub fn model(&self) -> Option<&BusyModel> {
        self.model.as_ref()
    }

    /// Spells started so far.
    pub fn spells_started(&self) -> u64 {
        self.started
    }

    /// The node sees an event at `t`: it may start a spell there. Returns
    /// the end of the spell covering `t`, if the node is busy at `t`.
    pub fn event(&mut self, t: Nanos) -> Option<Nanos> {
        let model = self.model?;
        self.generate_until(t);
        if let BusyTrigger::PerEvent { probability } = model.trigger {
            if self.rng.chance(probability) {
                let d = model.duration.sample_ns(&mut self.rng);
                self.insert(t, t + d);
            }
        }
        self.prune(t.saturating_sub(HISTORY_NS));
        self.busy_until(t)
    }

    /// The end of the spell covering `t`, without starting one.
    pub fn busy_until(&mut self, t: Nanos) -> Option<Nanos> {
        self.generate_until(t);
        self.spells
            .iter()
            .find(|&&(s, e)| s <= t && t < e)
            .map(|&(_, e)| e)
    }

    fn generate_until(&mut self, t: Nanos) {
        let Some(BusyModel {
            trigger: BusyTrigger::Poisson { mean_interval_us },
            duration,
            ..
        }) = self.model
        else {
            return;
        };
        while let Some(start) = self.next_poisson.filter(|&s| s <= t) {
            let d = duration.sample_ns(&mut self.rng);
            self.insert(start, start + d);
            let gap = crate::rng::us_to_ns(self.rng.exponential(mean_interval_us)).max(1);
            self.next_poisson = Some(start + gap);
        }
    }

    /// Adds a spell, merging it with any it overlaps.
    fn insert(&mut self, start: Nanos, end: Nanos) {
        if end <= start {
            return;
        }
        self.started += 1;
        let (mut s, mut e) = (start, end);
        // Remove every spell that overlaps or touches [s, e) and absorb it.
        let mut i = 0;
        while i < self.spells.len() {
            let (a, b) = self.spells[i];
            if a <= e && s <= b {
                s = s.min(a);
                e = e.max(b);
                self.spells.remove(i);
            } else {
                i += 1;
            }
        }
        let at = self.spells.iter().position(|&(a, _)| a > s);
        match at {
            Some(i) => self.spells.insert(i, (s, e)),
            None => self.spells.push_back((s, e)),
        }
    }

    fn prune(&mut self, before: Nanos) {
        while self.spells.front().is_some_and(|&(_, e)| e < before) {
            self.spells.pop_front();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spells_merge_and_answer_consistently() {
        let model = BusyModel {
            trigger: BusyTrigger::PerEvent { probability: 1.0 },
            duration: Dist::Const(100.0),
            late_stamps: true,
        };
        let mut b = BusyState::new(Some(model), Rng::new(1));
        assert_eq!(b.event(1_000), Some(101_000));
        // Overlapping spell extends the first.
        assert_eq!(b.event(50_000), Some(150_000));
        assert_eq!(b.busy_until(120_000), Some(150_000));
        assert_eq!(b.busy_until(150_000), None);
        let mut idle = BusyState::new(None, Rng::new(1));
        assert_eq!(idle.event(5), None);
    }

    #[test]
    fn poisson_spells_have_their_rate() {
        let model = BusyModel {
            trigger: BusyTrigger::Poisson {
                mean_interval_us: 1_000.0,
            },
            duration: Dist::Const(10.0),
            late_stamps: false,
        };
        let mut b = BusyState::new(Some(model), Rng::new(3));
        let _ = b.busy_until(1_000_000_000);
        let n = b.spells_started();
        assert!((900..1100).contains(&n), "{n}");
    }
}
