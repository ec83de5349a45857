//! A first-order lag identified from a whole record: the measured output
//! (an extruder's outflow, read through its force) follows the measured
//! input (the flow the drive pushed, from the motor's stepped positions)
//! as `τ·y' = u − y`. Fitting `τ` over every sample, rather than over
//! idealized steps, takes the input's real ramps and the steps' real
//! times as they ran.

/// The lag of `input` (`(t s, u)`, time-ordered, linear between samples,
/// `u` held before the first) through `τ·y' = u − y`, starting settled on
/// the first sample, at each time of `at` (time-ordered).
pub fn lagged(input: &[(f64, f64)], tau_s: f64, at: &[f64]) -> Vec<f64> {
    let mut out = Vec::with_capacity(at.len());
    let Some(&(mut t, mut u)) = input.first() else {
        return vec![0.0; at.len()];
    };
    let mut y = u;
    let mut next = 1;
    // Advances the exact solution over a ramp from (t, u) to (t1, u1).
    let step = |y: f64, u0: f64, u1: f64, h: f64| -> f64 {
        if h <= 0.0 {
            return y;
        }
        let slope = (u1 - u0) / h;
        u1 - slope * tau_s + (y - u0 + slope * tau_s) * (-h / tau_s).exp()
    };
    for &a in at {
        while next < input.len() && input[next].0 <= a {
            let (t1, u1) = input[next];
            y = step(y, u, u1, t1 - t);
            (t, u) = (t1, u1);
            next += 1;
        }
        if a > t {
            // Part of the way along the current ramp (or past the end).
            let (ua, h) = match input.get(next) {
                Some(&(t1, u1)) => (u + (u1 - u) * (a - t) / (t1 - t), a - t),
                None => (u, a - t),
            };
            out.push(step(y, u, ua, h));
        } else {
            out.push(y);
        }
    }
    out
}

/// A fitted lag.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LagFit {
    /// The time constant, s.
    pub tau_s: f64,
    /// Its standard error, s.
    pub std_error: f64,
    /// The root-mean-square residual, in the output's unit.
    pub rms_residual: f64,
}

/// Fits `τ` within `range` (s) so that the lag of `input` matches
/// `measured` (`(t s, y)`) in least squares: a golden-section search on
/// `ln τ`, the standard error from the residual's curvature. `None` with
/// fewer than three measurements.
pub fn fit_lag(input: &[(f64, f64)], measured: &[(f64, f64)], range: (f64, f64)) -> Option<LagFit> {
    if measured.len() < 3 || input.len() < 2 || !(range.0 > 0.0 && range.1 > range.0) {
        return None;
    }
    let at: Vec<f64> = measured.iter().map(|m| m.0).collect();
    let ssr = |tau: f64| -> f64 {
        lagged(input, tau, &at)
            .iter()
            .zip(measured)
            .map(|(p, m)| (p - m.1).powi(2))
            .sum()
    };
    let (mut lo, mut hi) = (range.0.ln(), range.1.ln());
    let g = (5f64.sqrt() - 1.0) / 2.0;
    let (mut c, mut d) = (hi - g * (hi - lo), lo + g * (hi - lo));
    let (mut fc, mut fd) = (ssr(c.exp()), ssr(d.exp()));
    for _ in 0..80 {
        if fc < fd {
            hi = d;
            (d, fd) = (c, fc);
            c = hi - g * (hi - lo);
            fc = ssr(c.exp());
        } else {
            lo = c;
            (c, fc) = (d, fd);
            d = lo + g * (hi - lo);
            fd = ssr(d.exp());
        }
    }
    let tau = (0.5 * (lo + hi)).exp();
    let s = ssr(tau);
    let n = measured.len() as f64;
    let h = tau * 0.01;
    let curvature = (ssr(tau + h) - 2.0 * s + ssr(tau - h)) / (h * h);
    let variance = s / (n - 1.0);
    let std_error = if curvature > 0.0 {
        (2.0 * variance / curvature).sqrt()
    } else {
        f64::INFINITY
    };
    Some(LagFit {
        tau_s: tau,
        std_error,
        rms_residual: (s / n).sqrt(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_step_lags_exactly_and_a_ramp_trails_by_tau() {
        // A step at t = 1 (a 1 µs ramp).
        let input = [(0.0, 2.0), (1.0, 2.0), (1.000_001, 5.0), (10.0, 5.0)];
        let y = lagged(&input, 0.1, &[0.5, 1.1, 1.3, 3.0]);
        assert!((y[0] - 2.0).abs() < 1e-12);
        assert!(
            (y[1] - (5.0 - 3.0 * (-1.0f64).exp())).abs() < 1e-4,
            "{}",
            y[1]
        );
        assert!((y[2] - (5.0 - 3.0 * (-3.0f64).exp())).abs() < 1e-4);
        // A ramp of slope 2: settled, the lag trails by slope·τ.
        let ramp = [(0.0, 0.0), (5.0, 10.0)];
        let y = lagged(&ramp, 0.2, &[4.0]);
        assert!((y[0] - (8.0 - 0.4)).abs() < 1e-9, "{}", y[0]);
    }

    #[test]
    fn the_time_constant_is_found_through_noise() {
        // Flow steps with 5 ms acceleration ramps, measured at 80 a
        // second with noise.
        let mut input = vec![(0.0, 0.0)];
        for (k, q) in [2.0, 5.0, 8.0, 3.0].iter().enumerate() {
            let t = 1.0 + k as f64;
            let last = input.last().unwrap().1;
            input.push((t, last));
            input.push((t + 0.005, *q));
        }
        input.push((6.0, 3.0));
        let at: Vec<f64> = (0..480).map(|i| f64::from(i) / 80.0).collect();
        let truth = lagged(&input, 0.045, &at);
        let mut seed = 11u64;
        let measured: Vec<(f64, f64)> = at
            .iter()
            .zip(truth)
            .map(|(t, y)| {
                seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1);
                let u = (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
                (*t, y + 0.05 * u)
            })
            .collect();
        let f = fit_lag(&input, &measured, (0.001, 1.0)).unwrap();
        assert!((f.tau_s / 0.045 - 1.0).abs() < 0.05, "{f:?}");
        assert!(f.std_error < 0.005 && f.rms_residual < 0.03, "{f:?}");
        assert!(fit_lag(&input, &measured[..2], (0.001, 1.0)).is_none());
    }
}
