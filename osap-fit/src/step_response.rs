//! A first-order response to a step, seen through a sensor that is itself
//! a first-order lag of known time constant `sensor_tau_s`:
//!
//! ```text
//! y(t) = y0 + (y1 − y0)·(1 − (τ·e^(−t/τ) − τs·e^(−t/τs)) / (τ − τs))     t ≥ 0
//! ```
//!
//! (the plain `1 − e^(−t/τ)` when `τs` is 0). Fitting it to the samples
//! after each step identifies the process's time constant `τ`: an
//! extruder's pressure build-up, a heater block, a spindle.

use crate::least_squares::{fit, Fit, Model, Point};
use crate::FitError;

/// The response as a [`Model`]: `x = [t since the step, s]`, params `[y0,
/// y1, tau_s]`.
struct Response {
    sensor_tau_s: f64,
}

impl Response {
    /// The unit response at `t` for process time constant `tau`.
    fn unit(&self, tau: f64, t: f64) -> f64 {
        if t <= 0.0 {
            return 0.0;
        }
        let ts = self.sensor_tau_s;
        if ts <= 0.0 {
            return 1.0 - (-t / tau).exp();
        }
        if (tau - ts).abs() < 1e-9 * tau.max(ts) {
            // The limit of two equal lags.
            return 1.0 - (1.0 + t / tau) * (-t / tau).exp();
        }
        1.0 - (tau * (-t / tau).exp() - ts * (-t / ts).exp()) / (tau - ts)
    }
}

impl Model for Response {
    fn names(&self) -> &'static [&'static str] {
        &["y0", "y1", "tau_s"]
    }

    fn predict(&self, p: &[f64], x: &[f64]) -> f64 {
        p[0] + (p[1] - p[0]) * self.unit(p[2], x[0])
    }
}

/// A fitted step response.
#[derive(Debug, Clone, PartialEq)]
pub struct StepFit {
    /// Before the step.
    pub y0: f64,
    /// Where it settles.
    pub y1: f64,
    /// The process time constant, s.
    pub tau_s: f64,
    /// The fit behind it (params y0, y1, tau_s).
    pub fit: Fit,
}

impl StepFit {
    /// Fits the response to `(t since the step, y)` samples, the sensor's
    /// own lag `sensor_tau_s` known (0 for none). Samples before the step
    /// (t < 0) pin `y0`.
    pub fn fit(samples: &[(f64, f64)], sensor_tau_s: f64) -> Result<StepFit, FitError> {
        let points: Vec<Point> = samples
            .iter()
            .map(|&(t, y)| Point { x: vec![t], y })
            .collect();
        let before: Vec<f64> = samples.iter().filter(|s| s.0 <= 0.0).map(|s| s.1).collect();
        let span = samples.iter().map(|s| s.0).fold(0.0, f64::max);
        let last = samples.last().ok_or(FitError::TooFewPoints {
            points: 0,
            params: 3,
        })?;
        let y0 = if before.is_empty() {
            samples[0].1
        } else {
            before.iter().sum::<f64>() / before.len() as f64
        };
        // Start at a fifth of the window: a step is held for several τ.
        let start = [y0, last.1, (span / 5.0).max(1e-3)];
        let model = Response {
            sensor_tau_s: sensor_tau_s.max(0.0),
        };
        let fit = fit(&model, &points, &start)?;
        let tau_s = fit.params[2].abs();
        Ok(StepFit {
            y0: fit.params[0],
            y1: fit.params[1],
            tau_s,
            fit,
        })
    }
}

/// The time constants of several steps combined, each weighted by its
/// inverse variance: `(τ, its standard error)`.
pub fn combined_tau(fits: &[StepFit]) -> Option<(f64, f64)> {
    let (mut sum, mut weights) = (0.0, 0.0);
    for f in fits {
        let e = f.fit.std_errors[2];
        if e.is_finite() && e > 0.0 {
            let w = 1.0 / (e * e);
            sum += w * f.tau_s;
            weights += w;
        }
    }
    (weights > 0.0).then(|| (sum / weights, weights.sqrt().recip()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn samples(tau: f64, sensor: f64, noise: f64) -> Vec<(f64, f64)> {
        let model = Response {
            sensor_tau_s: sensor,
        };
        let mut seed = 7u64;
        (-20..300)
            .map(|i| {
                let t = f64::from(i) * 0.0125; // 80 samples a second
                seed = seed
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                let u = (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
                (t, model.predict(&[2.0, 14.0, tau], &[t]) + noise * u)
            })
            .collect()
    }

    #[test]
    fn the_time_constant_is_found_through_the_sensor_lag() {
        for (tau, sensor) in [(0.08, 0.0), (0.08, 0.02), (0.3, 0.02), (0.02, 0.02)] {
            let f = StepFit::fit(&samples(tau, sensor, 0.2), sensor).unwrap();
            assert!(
                (f.tau_s / tau - 1.0).abs() < 0.05,
                "{tau} through {sensor}: {}",
                f.tau_s
            );
            assert!((f.y1 - 14.0).abs() < 0.1 && (f.y0 - 2.0).abs() < 0.1);
        }
        // Ignoring a sensor lag as long as the process's reads it long.
        let f = StepFit::fit(&samples(0.05, 0.05, 0.0), 0.0).unwrap();
        assert!(f.tau_s > 0.06, "{}", f.tau_s);
    }

    #[test]
    fn steps_combine_by_their_errors() {
        let a = StepFit::fit(&samples(0.1, 0.02, 0.1), 0.02).unwrap();
        let b = StepFit::fit(&samples(0.1, 0.02, 1.0), 0.02).unwrap();
        let (tau, err) = combined_tau(&[a.clone(), b.clone()]).unwrap();
        assert!((tau - a.tau_s).abs() < (tau - b.tau_s).abs() + 1e-12);
        assert!(err <= a.fit.std_errors[2]);
    }
}
