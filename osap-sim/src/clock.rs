//! Simulated oscillators: each node's free-running local µs counter as a
//! function of true time.
//!
//! ```text
//! local_ns(t) = offset + t + t·rate + wander(t)
//! wander(t)   = ∫₀ᵗ A·sin(ωs + φ) ds = A/ω · (cos φ − cos(ωt + φ))
//! local_us(t) = ⌊local_ns(t) / 1000⌋
//! ```
//!
//! `t` is true time in ns, `rate` the crystal's fixed rate error (±100 ppm
//! is typical), and the wander a slow sinusoidal rate variation of amplitude
//! `A` (about 1 ppm over minutes: temperature). The model is a pure function
//! of `t`, so any instant can be asked about in any order, and it is
//! monotonic, so it can be inverted: [`ClockModel::true_time_at`] gives the
//! true time at which the counter reaches a value, which the simulator needs
//! to turn a runtime's `wake_at` (local µs) into an event time.

use crate::error::SimError;
use crate::rng::Rng;
use crate::Nanos;
use osap_core::Instant;

/// A scalar parameter that is either fixed or drawn from a seeded uniform
/// distribution when the simulation is built.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Param {
    /// This value.
    Fixed(f64),
    /// Uniform in `[lo, hi]`.
    Uniform(f64, f64),
}

impl Param {
    /// Draws the value.
    pub fn draw(&self, rng: &mut Rng) -> f64 {
        match *self {
            Param::Fixed(v) => v,
            Param::Uniform(lo, hi) => rng.uniform(lo, hi),
        }
    }

    fn bounds(&self) -> (f64, f64) {
        match *self {
            Param::Fixed(v) => (v, v),
            Param::Uniform(lo, hi) => (lo, hi),
        }
    }

    fn validate(&self, what: &str, min: f64, max: f64) -> Result<(), SimError> {
        let (lo, hi) = self.bounds();
        if lo.is_finite() && hi.is_finite() && lo <= hi && lo >= min && hi <= max {
            Ok(())
        } else {
            Err(SimError::config(format!(
                "{what}: {self:?} must lie within [{min}, {max}] (and lo <= hi)"
            )))
        }
    }
}

/// How a node's oscillator is drawn when the simulation is built.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClockSpec {
    /// The counter's value at true time 0, µs (when the module booted,
    /// relative to the others). Must be ≥ 0.
    pub offset_us: Param,
    /// Fixed rate error, ppm (positive: the counter runs fast).
    pub rate_ppm: Param,
    /// Amplitude of the slow sinusoidal rate wander, ppm.
    pub wander_ppm: Param,
    /// Period of the wander, s.
    pub wander_period_s: Param,
}

impl ClockSpec {
    /// A microcontroller crystal: booted within the first 10 s, ±100 ppm,
    /// wandering by about 1 ppm over 2–10 minutes.
    pub const MCU: ClockSpec = ClockSpec {
        offset_us: Param::Uniform(0.0, 10_000_000.0),
        rate_ppm: Param::Uniform(-100.0, 100.0),
        wander_ppm: Param::Uniform(0.5, 1.5),
        wander_period_s: Param::Uniform(120.0, 600.0),
    };

    /// A PC's clock: ±50 ppm, the same wander.
    pub const HOST: ClockSpec = ClockSpec {
        offset_us: Param::Uniform(0.0, 10_000_000.0),
        rate_ppm: Param::Uniform(-50.0, 50.0),
        wander_ppm: Param::Uniform(0.5, 1.5),
        wander_period_s: Param::Uniform(120.0, 600.0),
    };

    /// A perfect clock that reads true time (for tests).
    pub const IDEAL: ClockSpec = ClockSpec {
        offset_us: Param::Fixed(0.0),
        rate_ppm: Param::Fixed(0.0),
        wander_ppm: Param::Fixed(0.0),
        wander_period_s: Param::Fixed(300.0),
    };

    /// A clock with a fixed offset and rate error and no wander.
    pub const fn fixed(offset_us: f64, rate_ppm: f64) -> ClockSpec {
        ClockSpec {
            offset_us: Param::Fixed(offset_us),
            rate_ppm: Param::Fixed(rate_ppm),
            wander_ppm: Param::Fixed(0.0),
            wander_period_s: Param::Fixed(300.0),
        }
    }

    /// Checks the ranges: offsets non-negative, rate errors within ±10 000
    /// ppm (beyond that no crystal is meant), wander periods positive.
    pub fn validate(&self, node: &str) -> Result<(), SimError> {
        let at = |field: &str| format!("node {node}: clock {field}");
        self.offset_us.validate(&at("offset_us"), 0.0, 1e15)?;
        self.rate_ppm
            .validate(&at("rate_ppm"), -10_000.0, 10_000.0)?;
        self.wander_ppm.validate(&at("wander_ppm"), 0.0, 10_000.0)?;
        self.wander_period_s
            .validate(&at("wander_period_s"), 1e-3, 1e9)?;
        Ok(())
    }

    /// Draws an oscillator. Always draws all four parameters and a phase, so
    /// the number of random numbers used does not depend on the values.
    pub fn draw(&self, rng: &mut Rng) -> ClockModel {
        let offset = self.offset_us.draw(rng);
        let rate = self.rate_ppm.draw(rng);
        let wander = self.wander_ppm.draw(rng);
        let period = self.wander_period_s.draw(rng);
        let phase = rng.uniform(0.0, core::f64::consts::TAU);
        ClockModel::new(offset, rate).with_wander(wander, period, phase)
    }
}

/// One node's oscillator: local time as a function of true time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClockModel {
    offset_ns: i128,
    /// Fixed rate error, ppm (kept in ppm so that whole ppm times whole ns
    /// divide exactly).
    rate_ppm: f64,
    /// Wander amplitude as a fraction.
    wander_amp: f64,
    /// Wander angular frequency, rad/ns.
    wander_omega: f64,
    wander_phase: f64,
}

impl ClockModel {
    /// A clock reading `offset_us` at true time 0 and running `rate_ppm` fast.
    pub fn new(offset_us: f64, rate_ppm: f64) -> Self {
        ClockModel {
            offset_ns: (offset_us.max(0.0) * 1000.0).round() as i128,
            rate_ppm,
            wander_amp: 0.0,
            wander_omega: 0.0,
            wander_phase: 0.0,
        }
    }

    /// The same clock with a sinusoidal rate wander of `amplitude_ppm`,
    /// period `period_s` and starting phase `phase` (radians).
    pub fn with_wander(mut self, amplitude_ppm: f64, period_s: f64, phase: f64) -> Self {
        if amplitude_ppm > 0.0 && period_s > 0.0 {
            self.wander_amp = amplitude_ppm * 1e-6;
            self.wander_omega = core::f64::consts::TAU / (period_s * 1e9);
            self.wander_phase = phase;
        }
        self
    }

    /// The fixed rate error, ppm.
    pub fn rate_ppm(&self) -> f64 {
        self.rate_ppm
    }

    /// The instantaneous rate error at true time `t`, ppm (fixed + wander).
    pub fn rate_ppm_at(&self, t: Nanos) -> f64 {
        self.rate_ppm + self.wander_rate(t) * 1e6
    }

    fn wander_rate(&self, t: Nanos) -> f64 {
        if self.wander_amp == 0.0 {
            return 0.0;
        }
        self.wander_amp * (self.wander_omega * t as f64 + self.wander_phase).sin()
    }

    /// The accumulated effect of rate error and wander at `t`, ns.
    fn skew_ns(&self, t: Nanos) -> f64 {
        let tf = t as f64;
        let mut skew = tf * self.rate_ppm / 1e6;
        if self.wander_amp != 0.0 {
            let w = self.wander_omega;
            let p = self.wander_phase;
            skew += self.wander_amp / w * (p.cos() - (w * tf + p).cos());
        }
        skew
    }

    /// The local counter at true time `t`, in ns (the integer part of `t`
    /// is kept exact; only the small skew goes through floating point).
    pub fn local_ns(&self, t: Nanos) -> i128 {
        self.offset_ns + i128::from(t) + self.skew_ns(t).floor() as i128
    }

    /// The local µs counter the runtime sees at true time `t` (floor).
    pub fn local_us(&self, t: Nanos) -> Instant {
        let us = self
            .local_ns(t)
            .div_euclid(1000)
            .clamp(0, i128::from(u64::MAX));
        Instant::from_micros(us as u64)
    }

    /// The first true time at which the local µs counter reads at least
    /// `local`; 0 if it already did at true time 0.
    pub fn true_time_at(&self, local: Instant) -> Nanos {
        let target = i128::from(local.as_micros()) * 1000;
        if self.local_ns(0) >= target {
            return 0;
        }
        // Newton steps from the fixed-rate estimate land within a few ns;
        // the rate is within 1 ± 1 % of unity, so they cannot overshoot far.
        // Without wander the estimate itself is within a few ns: no steps.
        let rate = self.rate_ppm * 1e-6;
        let mut t = ((target - self.offset_ns) as f64 / (1.0 + rate)).max(0.0);
        if self.wander_amp != 0.0 {
            for _ in 0..3 {
                let err = (self.local_ns(t as Nanos) - target) as f64;
                let slope = 1.0 + rate + self.wander_rate(t as Nanos);
                t = (t - err / slope).max(0.0);
            }
        }
        let guess = t as Nanos;
        // The answer is almost always within a few ns of the guess: walk to
        // it (a simulated machine converts clocks on every poll and step
        // word, so this is hot); the bracket and bisection below are the
        // fallback, and give the same instant.
        if guess > 0 {
            let mut t = guess;
            for _ in 0..8 {
                let here = self.local_ns(t) >= target;
                let before = self.local_ns(t - 1) >= target;
                match (before, here) {
                    (false, true) => return t,
                    (true, _) if t > 1 => t -= 1,
                    (false, false) => t += 1,
                    _ => break,
                }
            }
        }
        // Bracket, widening if the guess was off, then bisect: the first t
        // with local_ns(t) >= target.
        let mut step: Nanos = 16;
        let mut lo = guess.saturating_sub(step);
        while lo > 0 && self.local_ns(lo) >= target {
            step = step.saturating_mul(2);
            lo = lo.saturating_sub(step);
        }
        let mut hi = guess.saturating_add(16);
        let mut step: Nanos = 16;
        while self.local_ns(hi) < target {
            step = step.saturating_mul(2);
            hi = hi.saturating_add(step);
        }
        if self.local_ns(lo) >= target {
            return lo; // only when lo == 0
        }
        // Invariant: local_ns(lo) < target <= local_ns(hi).
        while hi - lo > 1 {
            let mid = lo + (hi - lo) / 2;
            if self.local_ns(mid) >= target {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        hi
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inverse_is_the_first_instant() {
        let c = ClockModel::new(1234.5, -87.0).with_wander(1.0, 200.0, 1.0);
        for local in [1235u64, 2_000, 1_000_000, 600_000_000, 600_000_001] {
            let t = c.true_time_at(Instant::from_micros(local));
            assert!(c.local_us(t) >= Instant::from_micros(local));
            assert!(
                t == 0 || c.local_us(t - 1) < Instant::from_micros(local),
                "{local}"
            );
        }
        assert_eq!(c.true_time_at(Instant::from_micros(5)), 0);
    }

    #[test]
    fn the_inverse_is_exact_with_and_without_wander() {
        let clocks = [
            ClockModel::new(0.0, 0.0),
            ClockModel::new(17.3, 40.0),
            ClockModel::new(900.0, -120.0),
            ClockModel::new(3.0, 25.0).with_wander(2.0, 300.0, 0.4),
        ];
        for c in clocks {
            // About a second apart over 20 minutes, at odd µs.
            for k in 1..1_200u64 {
                let local = Instant::from_micros(k * 997_003 + k % 7);
                let t = c.true_time_at(local);
                assert!(c.local_us(t) >= local, "{c:?} {k}");
                assert!(t == 0 || c.local_us(t - 1) < local, "{c:?} {k}");
            }
        }
    }
}
