//! A machine axis's mass-spring mode: the tool hangs on the carriage the
//! motors move through a spring and a damper,
//!
//! ```text
//! y'' = ω² (x − y) + 2ζω (x' − y')      ω = 2π·resonance_hz, ζ = damping_ratio
//! ```
//!
//! with `x` the carriage and `y` the tool. The relative displacement
//! `e = y − x` obeys `e'' + 2ζω e' + ω² e = −x''`: between changes of the
//! carriage's velocity it rings freely, which [`Mode::ring`] integrates in
//! closed form (no integrator error at any spacing).
//!
//! # Deviation and ringing
//!
//! [`Mode::deviation`] follows `e` for a carriage moved along straight
//! lines between sampled positions (as the motors follow the points a
//! host sends): at every velocity change `e'` jumps by its opposite, and
//! between samples the mode rings freely. Under a steady acceleration `a`
//! the spring holds the tool `a/ω²` behind the carriage; whatever else the
//! tool does is ringing, whose amplitude [`Mode::free_amplitude`] gives
//! from the deviation `u = e + a/ω²` and its rate (the envelope of the
//! damped oscillation, exact at any phase).

use std::f64::consts::PI;

/// The mode's state at a sample: see [`Mode::deviation`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Deviation {
    /// The tool's displacement from the carriage, `e = y − x`.
    pub e: f64,
    /// Its rate, `e'`.
    pub rate: f64,
    /// The carriage's acceleration there (the mean of the intervals'
    /// either side).
    pub accel: f64,
}

/// A lightly damped (or any) second-order mode.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mode {
    omega: f64,
    zeta: f64,
}

impl Mode {
    /// A mode at `resonance_hz` with damping ratio `damping_ratio`.
    pub fn new(resonance_hz: f64, damping_ratio: f64) -> Mode {
        Mode {
            omega: 2.0 * PI * resonance_hz,
            zeta: damping_ratio,
        }
    }

    /// The natural angular frequency, rad/s.
    pub fn omega(&self) -> f64 {
        self.omega
    }

    /// Rings the free mode for `dt` seconds from relative displacement `e`
    /// and its rate `de`: the state `dt` later (exact for any damping).
    pub fn ring(&self, e: f64, de: f64, dt: f64) -> (f64, f64) {
        if dt <= 0.0 {
            return (e, de);
        }
        let (w, z) = (self.omega, self.zeta);
        let sigma = z * w;
        let decay = (-sigma * dt).exp();
        // c: cos-like term; s: sin(ω_d t)/ω_d-like term (also for ζ ≥ 1).
        let (c, s) = if z < 1.0 {
            let wd = w * (1.0 - z * z).sqrt();
            ((wd * dt).cos(), (wd * dt).sin() / wd)
        } else if z > 1.0 {
            let wd = w * (z * z - 1.0).sqrt();
            ((wd * dt).cosh(), (wd * dt).sinh() / wd)
        } else {
            (1.0, dt)
        };
        (
            decay * (e * c + (de + sigma * e) * s),
            decay * (de * c - (sigma * de + w * w * e) * s),
        )
    }

    /// The relative displacement `e`, its rate `e'` and the carriage's
    /// acceleration at each of `samples` (seconds, carriage position), in
    /// time order, for a carriage at rest at the first sample.
    ///
    /// The carriage is taken through the samples with the velocity of the
    /// central difference at each and a constant acceleration between two
    /// (exact for any steady acceleration; a velocity step between samples
    /// is spread over the two intervals around it, as a module's smooth
    /// track spreads it); over each interval the mode is integrated in
    /// closed form.
    pub fn deviation(&self, samples: &[(f64, f64)]) -> Vec<Deviation> {
        let n = samples.len();
        let velocity = |k: usize| -> f64 {
            if k == 0 || k + 1 >= n {
                return 0.0;
            }
            let (t0, x0) = samples[k - 1];
            let (t1, x1) = samples[k + 1];
            if t1 > t0 {
                (x1 - x0) / (t1 - t0)
            } else {
                0.0
            }
        };
        let w2 = self.omega * self.omega;
        let mut out = Vec::with_capacity(n);
        let (mut e, mut de) = (0.0, 0.0);
        let mut v = velocity(0);
        let mut before = 0.0;
        for k in 0..n {
            let v_next = velocity(k + 1);
            let h = samples.get(k + 1).map_or(0.0, |s| s.0 - samples[k].0);
            let after = if h > 0.0 { (v_next - v) / h } else { 0.0 };
            out.push(Deviation {
                e,
                rate: de,
                accel: 0.5 * (before + after),
            });
            if h > 0.0 {
                let (shifted, rate) = self.ring(e + after / w2, de, h);
                (e, de) = (shifted - after / w2, rate);
            }
            (v, before) = (v_next, after);
        }
        out
    }

    /// The amplitude of the free oscillation whose deviation from
    /// equilibrium is `u` with rate `du` (the envelope of the damped
    /// oscillation at this instant; for `ζ ≥ 1`, `|u|`).
    pub fn free_amplitude(&self, u: f64, du: f64) -> f64 {
        let z = self.zeta;
        if z >= 1.0 {
            return u.abs();
        }
        let wd = self.omega * (1.0 - z * z).sqrt();
        u.hypot((du + z * self.omega * u) / wd)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Position of a move of `d` at cruise `v` and acceleration `a` at time
    /// `t` (trapezoid, starting at 0).
    fn trapezoid(d: f64, v: f64, a: f64, t: f64) -> f64 {
        let ta = v / a;
        let da = 0.5 * a * ta * ta;
        let tc = (d - 2.0 * da) / v;
        let total = 2.0 * ta + tc;
        if t <= 0.0 {
            0.0
        } else if t < ta {
            0.5 * a * t * t
        } else if t < ta + tc {
            da + v * (t - ta)
        } else if t < total {
            let r = total - t;
            d - 0.5 * a * r * r
        } else {
            d
        }
    }

    fn sampled(dt: f64, until: f64, x: impl Fn(f64) -> f64) -> Vec<(f64, f64)> {
        let n = (until / dt) as usize;
        (0..=n).map(|k| (k as f64 * dt, x(k as f64 * dt))).collect()
    }

    /// The ringing amplitude at each sample of `x`, with the deflection
    /// of the acceleration `a(t)` taken out.
    fn ringing(m: &Mode, s: &[(f64, f64)], a: impl Fn(f64) -> f64) -> Vec<f64> {
        let w2 = m.omega() * m.omega();
        m.deviation(s)
            .iter()
            .zip(s)
            .map(|(d, &(t, _))| m.free_amplitude(d.e + a(t) / w2, d.rate))
            .collect()
    }

    /// Steady acceleration deflects the spring by a/ω² but does not ring
    /// it: once the start has died out, no ringing, at any spacing.
    #[test]
    fn steady_acceleration_deflects_without_ringing() {
        let m = Mode::new(40.0, 0.5);
        let w2 = m.omega() * m.omega();
        for dt in [0.000_5, 0.002, 0.004] {
            let s = sampled(dt, 0.5, |t| 0.5 * 2000.0 * t * t);
            let d = m.deviation(&s);
            let late = (0.2 / dt) as usize;
            assert!((d[late].e + 2000.0 / w2).abs() < 1e-6 * 2000.0 / w2);
            assert!((d[late].accel - 2000.0).abs() < 1e-6);
            let r = ringing(&m, &s, |_| 2000.0);
            // (The last sample has no successor to difference with.)
            let worst = r[late..r.len() - 1].iter().fold(0.0f64, |a, b| a.max(*b));
            assert!(worst < 1e-6, "dt {dt}: {worst}");
        }
    }

    /// A step of acceleration `Δa` into an undamped mode rings it at
    /// amplitude `Δa/ω²`, seen at every sample whatever its phase; with
    /// two half steps half a period apart (the ZV shaper) nothing rings
    /// after the second, and half as much between them.
    #[test]
    fn an_acceleration_step_rings_at_delta_a_over_omega_squared() {
        let f = 40.0;
        let m = Mode::new(f, 0.0);
        let a = 3000.0;
        let dt = 0.002;
        let want = a / (m.omega() * m.omega());
        let plain = |t: f64| trapezoid(200.0, 150.0, a, t);
        let s = sampled(dt, 0.3, plain);
        let accel = |t: f64| if t < 0.05 { a } else { 0.0 };
        let r = ringing(&m, &s, accel);
        // While it accelerates (to 0.05 s).
        for (k, amp) in r.iter().enumerate().take(24).skip(2) {
            let t = k as f64 * dt;
            assert!((amp / want - 1.0).abs() < 0.01, "{t}: {amp} vs {want}");
        }
        let half = 0.5 / f;
        let zv = |t: f64| 0.5 * (plain(t) + plain(t - half));
        let zv_accel = |t: f64| 0.5 * (accel(t) + if t >= half { accel(t - half) } else { 0.0 });
        let r = ringing(&m, &sampled(dt, 0.3, zv), zv_accel);
        let worst = |from: f64, to: f64| {
            r[(from / dt) as usize..(to / dt) as usize]
                .iter()
                .fold(0.0f64, |x, y| x.max(*y))
        };
        // The second half step falls between two samples (at 12.5 ms),
        // where the reconstruction spreads it over two intervals and the
        // halves no longer cancel exactly: 3 % of the ring is left, the
        // floor of what 2 ms samples resolve at 40 Hz (unshaped: 100 %).
        assert!(worst(0.016, 0.048) < 0.04 * want, "{}", worst(0.016, 0.048));
        assert!(worst(0.066, 0.3) < 0.04 * want, "{}", worst(0.066, 0.3));
        let between = worst(0.002, 0.010) / (0.5 * want);
        assert!((between - 1.0).abs() < 0.01, "{between}");
    }

    #[test]
    fn ring_decays_as_a_damped_oscillator() {
        let m = Mode::new(10.0, 0.1);
        let (e, _) = m.ring(1.0, 0.0, 1.0 / (10.0 * (1.0 - 0.01f64).sqrt()));
        // One damped period: back to exp(−ζω·T_d) of the start.
        let want = (-0.1 * 2.0 * PI / 0.99f64.sqrt()).exp();
        assert!((e - want).abs() < 1e-12, "{e} {want}");
    }
}
