//! Stepped experiments: hold a condition (a temperature), step a setpoint
//! (a flow) through values, record a response (a force) on one clock,
//! then reduce the record to one steady value per step and to the
//! transient after each step.
//!
//! A runner (a machine routine, a simulator) walks the [`Plan`], marks
//! each step's start and end on the clock it records with, and hands the
//! record to [`steady_states`] and [`transients`].

use serde::{Deserialize, Serialize};

/// What one step holds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct StepSpec {
    /// The condition held (°C, say).
    pub condition: f64,
    /// The setpoint (mm³/s, say).
    pub setpoint: f64,
    /// How long it is held, s.
    pub hold_s: f64,
}

/// A step as it ran: its spec and its span on the record's clock.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RanStep {
    /// What it held.
    pub spec: StepSpec,
    /// When it started, s.
    pub start_s: f64,
    /// When it ended, s.
    pub end_s: f64,
}

/// The steps of an experiment, in the order they run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Plan {
    /// The steps.
    pub steps: Vec<StepSpec>,
}

impl Plan {
    /// Every setpoint at every condition, conditions in the order given,
    /// setpoints rising within each, each held `hold_s`.
    pub fn grid(conditions: &[f64], setpoints: &[f64], hold_s: f64) -> Plan {
        let steps = conditions
            .iter()
            .flat_map(|&condition| {
                setpoints.iter().map(move |&setpoint| StepSpec {
                    condition,
                    setpoint,
                    hold_s,
                })
            })
            .collect();
        Plan { steps }
    }

    /// The time the steps hold, s (without what it takes to change the
    /// condition between them).
    pub fn hold_time_s(&self) -> f64 {
        self.steps.iter().map(|s| s.hold_s).sum()
    }
}

/// Walks a [`Plan`] without passing a limit. Within each condition the
/// setpoints rise; before running the next one the routine predicts its
/// steady value from the last two it measured (a power law through them,
/// the shape most process laws have locally) and skips the condition's
/// remaining setpoints if the prediction, or a value measured, passes
/// `limit`. An experiment that must not damage what it measures (a
/// filament drive that would slip, a cutter that would break) stays below
/// the limit this way without knowing the process beforehand.
#[derive(Debug, Clone)]
pub struct Routine {
    plan: Plan,
    limit: f64,
    next: usize,
    /// (setpoint, steady value) measured at the current condition.
    seen: Vec<(f64, f64)>,
}

impl Routine {
    /// A routine over `plan` that keeps each condition below `limit`.
    pub fn new(plan: Plan, limit: f64) -> Routine {
        Routine {
            plan,
            limit,
            next: 0,
            seen: Vec::new(),
        }
    }

    /// The steady value predicted at `setpoint` from the last two
    /// measured at this condition.
    fn predict(&self, setpoint: f64) -> Option<f64> {
        let [.., (s1, v1), (s2, v2)] = self.seen[..] else {
            return None;
        };
        if !(s1 > 0.0 && s2 > s1 && v1 > 0.0 && v2 > 0.0) {
            return None;
        }
        // The local exponent, no less than linear's half and at most
        // quadratic: a noisy pair must not promise a flat curve.
        let slope = ((v2 / v1).ln() / (s2 / s1).ln()).clamp(0.5, 2.0);
        Some(v2 * (setpoint / s2).powf(slope))
    }

    /// The next step to run, given the steady value the previous step
    /// reached (`None` for the first step, or when it had none).
    pub fn next_step(&mut self, previous: Option<f64>) -> Option<StepSpec> {
        if let Some(last) = self.next.checked_sub(1).map(|i| self.plan.steps[i]) {
            if let Some(value) = previous {
                self.seen.push((last.setpoint, value));
            }
            let over = |r: &Routine, s: &StepSpec| {
                previous.is_some_and(|v| v > r.limit)
                    || r.predict(s.setpoint).is_some_and(|p| p > r.limit)
            };
            while let Some(s) = self.plan.steps.get(self.next).copied() {
                if s.condition != last.condition || !over(self, &s) {
                    break;
                }
                self.next += 1;
            }
            if self
                .plan
                .steps
                .get(self.next)
                .is_none_or(|s| s.condition != last.condition)
            {
                self.seen.clear();
            }
        }
        let step = self.plan.steps.get(self.next).copied();
        self.next += 1;
        step
    }
}

/// One step reduced to its steady value.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SteadyState {
    /// The step.
    pub spec: StepSpec,
    /// The mean response over the step's settled part.
    pub mean: f64,
    /// The standard deviation of the samples it averages.
    pub std_dev: f64,
    /// How many samples.
    pub samples: usize,
}

/// Each step's steady value: the mean of its samples from `settle_s`
/// after its start to its end. A step with fewer than `min_samples`
/// settled samples is left out (and counted in the second value).
pub fn steady_states(
    steps: &[RanStep],
    record: &[(f64, f64)],
    settle_s: f64,
    min_samples: usize,
) -> (Vec<SteadyState>, usize) {
    let mut out = Vec::new();
    let mut skipped = 0;
    for s in steps {
        let from = s.start_s + settle_s;
        let ys: Vec<f64> = record
            .iter()
            .filter(|(t, y)| *t >= from && *t < s.end_s && y.is_finite())
            .map(|(_, y)| *y)
            .collect();
        if ys.len() < min_samples.max(1) {
            skipped += 1;
            continue;
        }
        let n = ys.len() as f64;
        let mean = ys.iter().sum::<f64>() / n;
        let var = ys.iter().map(|y| (y - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
        out.push(SteadyState {
            spec: s.spec,
            mean,
            std_dev: var.sqrt(),
            samples: ys.len(),
        });
    }
    (out, skipped)
}

/// The samples around each step change, as `(t since the step, y)`: from
/// `before_s` before its start to its end.
pub fn transients(steps: &[RanStep], record: &[(f64, f64)], before_s: f64) -> Vec<Vec<(f64, f64)>> {
    steps
        .iter()
        .map(|s| {
            record
                .iter()
                .filter(|(t, _)| *t >= s.start_s - before_s && *t < s.end_s)
                .map(|(t, y)| (t - s.start_s, *y))
                .collect()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_routine_skips_a_conditions_higher_setpoints_past_the_limit() {
        let mut r = Routine::new(Plan::grid(&[1.0, 2.0], &[1.0, 2.0, 3.0], 1.0), 3.5);
        // The response is setpoint × condition.
        let mut seen = Vec::new();
        let mut previous = None;
        while let Some(s) = r.next_step(previous) {
            seen.push((s.condition, s.setpoint));
            previous = Some(s.condition * s.setpoint);
        }
        assert_eq!(
            seen,
            [(1.0, 1.0), (1.0, 2.0), (1.0, 3.0), (2.0, 1.0), (2.0, 2.0)]
        );
    }

    #[test]
    fn a_grid_runs_each_setpoint_at_each_condition_and_reduces_to_means() {
        let plan = Plan::grid(&[200.0, 220.0], &[2.0, 4.0, 8.0], 1.0);
        assert_eq!(plan.steps.len(), 6);
        assert_eq!(plan.steps[3].condition, 220.0);
        assert_eq!(plan.hold_time_s(), 6.0);
        let ran: Vec<RanStep> = plan
            .steps
            .iter()
            .enumerate()
            .map(|(i, &spec)| RanStep {
                spec,
                start_s: i as f64,
                end_s: i as f64 + 1.0,
            })
            .collect();
        // The response settles to setpoint·condition/100 within 0.25 s.
        let record: Vec<(f64, f64)> = (0..600)
            .map(|k| {
                let t = f64::from(k) * 0.01;
                let s = &ran[(t as usize).min(5)];
                let settled = s.spec.setpoint * s.spec.condition / 100.0;
                let y = if t - s.start_s < 0.25 { 0.0 } else { settled };
                (t, y)
            })
            .collect();
        let (means, skipped) = steady_states(&ran, &record, 0.3, 10);
        assert_eq!(skipped, 0);
        for m in &means {
            assert!((m.mean - m.spec.setpoint * m.spec.condition / 100.0).abs() < 1e-12);
            assert!((69..=71).contains(&m.samples), "{}", m.samples);
        }
        let (_, skipped) = steady_states(&ran, &record, 0.95, 10);
        assert_eq!(skipped, 6);
        let tr = transients(&ran, &record, 0.1);
        assert_eq!(tr[1].first().unwrap().0.round(), 0.0);
        assert!(tr[1].first().unwrap().0 < 0.0);
    }
}
