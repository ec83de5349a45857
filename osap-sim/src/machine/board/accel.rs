//! A simulated accelerometer on a module's analog input, seeing the
//! module's own carriage through a mass-spring mode.
//!
//! The tool (mass) hangs on the carriage through a spring and a damper:
//!
//! ```text
//! y'' = ω² (x − y) + 2ζω (x' − y')      ω = 2π·resonance_hz, ζ = damping_ratio
//! ```
//!
//! where `x` is the carriage (moved by the motor's steps) and `y` the tool.
//! The carriage moves in steps, so between two steps `x` is constant and the
//! relative displacement `e = y − x` rings freely; the model integrates that
//! in closed form (no integrator error, whatever the spacing of steps and
//! readings). A step of `Δ` moves `x` at once: `e` drops by `Δ`, and the
//! damper's impulse adds `2ζωΔ` to the tool's velocity.
//!
//! A reading is the tool's mean acceleration since the previous reading,
//! `(y'(now) − y'(before)) / (now − before)`, as an accelerometer with a
//! boxcar (averaging) filter reports it: no step's impulse is missed, and
//! the converter does not alias the steps' fine structure. It is mapped to
//! a fraction of full scale as `0.5 + a / (2·range)` and clamped, so the
//! module's own `analog_read` reads it through the 12-bit converter.

use crate::machine::mode::Mode;
use crate::topology::AccelSpec;
use osap_core::Instant;
use std::collections::VecDeque;

/// The running model.
#[derive(Debug, Clone)]
pub struct Accel {
    spec: AccelSpec,
    mode: Mode,
    /// Relative displacement `e = y − x`, axis units.
    e: f64,
    /// The tool's velocity, axis units/s (equal to `e'` between steps).
    v: f64,
    /// Local time the state is at, µs.
    at: Instant,
    /// Steps clocked out but not yet due: (local µs, axis units moved).
    pending: VecDeque<(Instant, f64)>,
    /// The tool's velocity and the time at the previous reading.
    last_read: Option<(Instant, f64)>,
}

impl Accel {
    /// An accelerometer at rest at local time 0.
    pub fn new(spec: AccelSpec) -> Self {
        let mode = Mode::new(spec.resonance_hz, spec.damping_ratio);
        Accel {
            spec,
            mode,
            e: 0.0,
            v: 0.0,
            at: Instant::ZERO,
            pending: VecDeque::new(),
            last_read: None,
        }
    }

    /// What it is.
    pub fn spec(&self) -> &AccelSpec {
        &self.spec
    }

    /// The carriage moved by `delta` carriage units at local `local` (the
    /// step generator clocks steps out ahead of time; they act when due).
    pub(crate) fn step(&mut self, local: Instant, delta: f64) {
        self.pending.push_back((local, delta * self.spec.coef));
    }

    /// Rings the free mode for `dt` seconds (exact for any damping);
    /// between steps the carriage stands, so the tool's velocity is `e'`.
    fn ring(&mut self, dt: f64) {
        (self.e, self.v) = self.mode.ring(self.e, self.v, dt);
    }

    /// Advances the model to local `now`, applying the steps due.
    fn advance(&mut self, now: Instant) {
        while let Some(&(t, d)) = self.pending.front() {
            if t > now {
                break;
            }
            self.pending.pop_front();
            let t = t.max(self.at);
            self.ring((t - self.at).as_secs_f64());
            self.at = t;
            self.e -= d;
            self.v += 2.0 * self.spec.damping_ratio * self.mode.omega() * d;
        }
        if now > self.at {
            self.ring((now - self.at).as_secs_f64());
            self.at = now;
        }
    }

    /// The mean acceleration since the previous reading at local `now`,
    /// axis units/s² (0 for the first reading).
    pub fn acceleration(&mut self, now: Instant) -> f64 {
        self.advance(now);
        let a = match self.last_read {
            Some((t, v)) if now > t => (self.v - v) / (now - t).as_secs_f64(),
            _ => 0.0,
        };
        if self.last_read.is_none_or(|(t, _)| now > t) {
            self.last_read = Some((now, self.v));
        }
        a
    }

    /// A reading at local `now` as a fraction of full scale (`0..=1`).
    pub fn read(&mut self, now: Instant) -> f64 {
        let a = self.acceleration(now);
        (0.5 + a / (2.0 * self.spec.range)).clamp(0.0, 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    fn spec(f: f64, z: f64) -> AccelSpec {
        AccelSpec {
            channel: 0,
            resonance_hz: f,
            damping_ratio: z,
            range: 1e6,
            coef: 1.0,
        }
    }

    /// A carriage stepped along a sine: the steady-state amplitude ratio of
    /// the tool's acceleration to the carriage's is the base-excitation
    /// transmissibility `|(1 + 2jζr)/(1 − r² + 2jζr)|`.
    #[test]
    fn transmissibility_of_a_stepped_sine() {
        for &(f, z, r) in &[(40.0, 0.05, 1.0), (40.0, 0.1, 0.5), (40.0, 0.2, 1.5)] {
            let mut a = Accel::new(spec(f, z));
            let fin = f * r;
            let w = 2.0 * PI * fin;
            let amp = 1.0;
            let q = 1e-4; // step size: its impulses are noise
            let mut pos = 0.0_f64;
            let mut peak: f64 = 0.0;
            let total_us = 4_000_000u64;
            let mut t = 0;
            while t < total_us {
                let want = amp * (w * t as f64 * 1e-6).sin();
                while (want - pos).abs() >= q {
                    let d = q * (want - pos).signum();
                    pos += d;
                    a.step(Instant::from_micros(t), d);
                }
                if t % 100 == 0 {
                    let acc = a.acceleration(Instant::from_micros(t));
                    if t > total_us / 2 {
                        peak = peak.max(acc.abs());
                    }
                }
                t += 1;
            }
            let num = (1.0f64).hypot(2.0 * z * r);
            let den = (1.0 - r * r).hypot(2.0 * z * r);
            let want = amp * w * w * num / den;
            // The 100 µs boxcar lowers a sine's peak by sinc(f·100 µs).
            let x = PI * fin * 1e-4;
            let want = want * x.sin() / x;
            assert!(
                (peak / want - 1.0).abs() < 0.01,
                "f {f} z {z} r {r}: peak {peak} want {want}"
            );
        }
    }

    #[test]
    fn bad_specs_are_named() {
        let mut s = spec(40.0, 0.1);
        s.channel = 3;
        assert!(s.check().unwrap_err().to_string().contains("channel"));
        let mut s = spec(40.0, 0.1);
        s.range = 0.0;
        assert!(s.check().unwrap_err().to_string().contains("range"));
        assert!(spec(0.0, 0.1)
            .check()
            .unwrap_err()
            .to_string()
            .contains("resonance_hz"));
    }
}
