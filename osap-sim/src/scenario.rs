//! One-call runs: a topology, a seed, a duration, and options.
//!
//! ```
//! use osap_sim::{run, Network};
//! let metrics = run(&Network::star8(), 1, 0.2).unwrap();
//! assert_eq!(metrics.node_count(), 10);
//! ```

use crate::busy::BusyModel;
use crate::error::SimError;
use crate::metrics::Metrics;
use crate::network::Network;
use crate::sim::{Sim, SimConfig};
use std::time::{Duration, Instant};

/// Runs `topology` with `seed` for `seconds` of simulated time and returns
/// the sampled metrics (every 10 ms).
pub fn run(topology: &Network, seed: u64, seconds: f64) -> Result<Metrics, SimError> {
    Ok(Scenario::new(topology.clone())
        .seed(seed)
        .seconds(seconds)
        .run()?
        .metrics)
}

/// A run to make: the network, its settings and how long.
#[derive(Debug, Clone)]
pub struct Scenario {
    /// The network.
    pub topology: Network,
    /// Simulation settings (seed, sampling).
    pub config: SimConfig,
    /// Simulated duration, s.
    pub seconds: f64,
    /// Preset every non-root clock's rate before starting.
    pub hot_start: bool,
}

/// What a run produced.
pub struct Outcome {
    /// The sampled errors.
    pub metrics: Metrics,
    /// The simulation as it ended (runtimes, counters, links).
    pub sim: Sim,
    /// Whether a requested hot start was applied.
    pub hot_start_applied: bool,
    /// Wall-clock time the run took.
    pub wall: Duration,
}

impl std::fmt::Debug for Outcome {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Its parts are tasks, locks and buffers: the name says enough.
        f.debug_struct("Outcome").finish_non_exhaustive()
    }
}

impl Outcome {
    /// Simulated seconds per wall-clock second.
    pub fn speed(&self) -> f64 {
        self.sim.now() as f64 * 1e-9 / self.wall.as_secs_f64().max(1e-9)
    }
}

impl Scenario {
    /// A scenario of `topology` with the default settings, 10 s long.
    pub fn new(topology: Network) -> Self {
        Scenario {
            topology,
            config: SimConfig::default(),
            seconds: 10.0,
            hot_start: false,
        }
    }

    /// Sets the seed.
    pub fn seed(mut self, seed: u64) -> Self {
        self.config.seed = seed;
        self
    }

    /// Sets the simulated duration, s.
    pub fn seconds(mut self, seconds: f64) -> Self {
        self.seconds = seconds;
        self
    }

    /// Sets the metrics sampling period, µs.
    pub fn sample_period_us(mut self, period: u64) -> Self {
        self.config.sample_period_us = period;
        self
    }

    /// Starts every non-root clock with its rate preset (hot start).
    pub fn hot_start(mut self, on: bool) -> Self {
        self.hot_start = on;
        self
    }

    /// Gives every microcontroller node the busy model.
    pub fn busy_modules(mut self, model: BusyModel) -> Self {
        self.topology = self.topology.with_busy_modules(model);
        self
    }

    /// Builds the simulation at time 0 (hot start applied if asked), for a
    /// caller that wants to attach ports or change configuration first.
    /// Returns it and whether the hot start was applied.
    pub fn build(&self) -> Result<(Sim, bool), SimError> {
        let mut sim = Sim::new(&self.topology, self.config)?;
        let applied = self.hot_start && sim.apply_hot_start();
        Ok((sim, applied))
    }

    /// Builds and runs the simulation.
    pub fn run(&self) -> Result<Outcome, SimError> {
        if !(self.seconds.is_finite() && self.seconds >= 0.0) {
            return Err(SimError::config(format!(
                "duration {} s must be finite and >= 0",
                self.seconds
            )));
        }
        let (mut sim, hot_start_applied) = self.build()?;
        let started = Instant::now();
        sim.run_secs(self.seconds);
        let wall = started.elapsed();
        Ok(Outcome {
            metrics: sim.metrics().clone(),
            sim,
            hot_start_applied,
            wall,
        })
    }
}
