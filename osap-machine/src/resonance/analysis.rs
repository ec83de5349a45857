//! The frequency response of an axis from a recording, its mode, and the
//! input shaper for it.
//!
//! - **Response.** `H(f) = A(f) / C(f)`, the measured acceleration's
//!   spectrum over the commanded acceleration's (both real FFTs with
//!   `realfft`, zero-padded 4×), estimated as `Σ A·C̄ / Σ |C|²` over a
//!   small band around each frequency (±0.2 % of it, at least one bin of
//!   the unpadded record): smoothing that keeps a lightly damped peak
//!   (whose half-power half-width is `ζ·f`, 2 % of `f` at ζ = 0.02) intact.
//! - **Peak.** The largest `|H|` within the chirp's range, refined by a
//!   parabola through the three points around it. A maximum in the outer
//!   3 % (in log frequency) of the range is a mode outside it: reported
//!   as below or above the range, never guessed.
//! - **Mode.** The base-excited mass-spring model the accelerometer
//!   sees, `H(s) = K (2ζωs + ω²) / (s² + 2ζωs + ω²)`, fitted to the complex
//!   response within ±25 % of the peak by linear least squares (Levy's
//!   method: the equation times the denominator is linear in `K·2ζω`,
//!   `K·ω²`, `2ζω` and `ω²`). Its natural frequency and damping are what a
//!   shaper is tuned to; for ζ = 0.2 the model's `|H|` peaks 3.5 % below
//!   its natural frequency, so both are reported.
//! - **Shaper.** Each of maxl's shapers, tuned to the mode, is scored by
//!   its worst residual vibration over ±15 % of the mode's frequency at
//!   the measured damping (a margin for the mode moving with the load and
//!   position); the shortest whose worst is at most 10 % is recommended,
//!   else the one with the smallest worst.

use std::f64::consts::PI;

use maxl::blocks::shaper::{residual_vibration, ShaperConfig, ShaperKind};
use realfft::num_complex::Complex64;
use realfft::RealFftPlanner;

/// Share of the range (in log frequency) at each end where a maximum
/// means the mode lies beyond it.
const EDGE: f64 = 0.03;
/// The fit's band around the peak, as a fraction of its frequency.
const FIT_BAND: f64 = 0.25;
/// Relative half-width of the smoothing band.
const SMOOTH: f64 = 0.002;
/// The shaper's robustness band, as a fraction of the mode's frequency.
const SHAPER_BAND: f64 = 0.15;
/// The residual vibration a recommended shaper keeps under, over that band.
const SHAPER_RESIDUAL: f64 = 0.10;

/// Why a recording could not be analysed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum AnalysisError {
    /// Too few samples, or the two series differ in length.
    #[error("{0}")]
    Samples(String),
    /// The commanded acceleration carries no energy in the range.
    #[error(
        "the commanded motion has no energy between {0:.1} and {1:.1} Hz: nothing was excited"
    )]
    NoExcitation(f64, f64),
}

/// One frequency of the response.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ResponsePoint {
    /// Hz.
    pub freq_hz: f64,
    /// The smoothed response (measured over commanded acceleration).
    pub h: Complex64,
}

impl ResponsePoint {
    /// `|H|`.
    pub fn magnitude(&self) -> f64 {
        self.h.norm()
    }

    /// `|H|` in dB.
    pub fn magnitude_db(&self) -> f64 {
        20.0 * self.h.norm().max(1e-12).log10()
    }

    /// The phase of `H`, degrees.
    pub fn phase_deg(&self) -> f64 {
        self.h.arg().to_degrees()
    }
}

/// Where the response peaks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Peak {
    /// Within the range, at this frequency (Hz), with this `|H|`.
    Found {
        /// Hz.
        freq_hz: f64,
        /// `|H|` there.
        magnitude: f64,
    },
    /// The response is largest at the range's low end: the mode (if any)
    /// is at or below `f0` Hz.
    BelowRange {
        /// The range's low end, Hz.
        f0: f64,
    },
    /// The response is largest at the range's high end: the mode (if any)
    /// is at or above `f1` Hz.
    AboveRange {
        /// The range's high end, Hz.
        f1: f64,
    },
}

/// A mode fitted to the response.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mode {
    /// Natural frequency, Hz.
    pub freq_hz: f64,
    /// Damping ratio.
    pub damping: f64,
    /// The fitted gain (1 when the accelerometer's scale is right).
    pub gain: f64,
}

impl Mode {
    /// Where this mode's `|H|` peaks, Hz (below the natural frequency for
    /// a damped base-excited mode).
    pub fn peak_hz(&self) -> f64 {
        model_peak_hz(self.freq_hz, self.damping)
    }
}

/// Where `|H|` of the base-excited model `(2ζωs + ω²)/(s² + 2ζωs + ω²)`
/// peaks, Hz: `f_n · √(√(1 + 8ζ²) − 1) / (2ζ)` (`f_n` undamped).
pub fn model_peak_hz(freq_hz: f64, damping: f64) -> f64 {
    if damping <= 1e-9 {
        return freq_hz;
    }
    let z2 = damping * damping;
    freq_hz * ((1.0 + 8.0 * z2).sqrt() - 1.0).sqrt() / (2.0 * damping)
}

/// A shaper tuned to the mode and how well it does.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShaperScore {
    /// The shaper.
    pub shaper: ShaperConfig,
    /// Residual vibration at the mode itself (0: cancelled, 1: unshaped).
    pub residual: f64,
    /// The worst residual over ±15 % of the mode's frequency.
    pub worst: f64,
    /// Its duration, s (the smoothing it adds).
    pub duration_s: f64,
}

/// What a recording says about an axis.
#[derive(Debug, Clone, PartialEq)]
pub struct Analysis {
    /// The range the chirp excited, Hz.
    pub range: (f64, f64),
    /// The response over the range.
    pub response: Vec<ResponsePoint>,
    /// Where it peaks.
    pub peak: Peak,
    /// The mode fitted around the peak, if the peak is within range and
    /// the fit is a damped mode.
    pub mode: Option<Mode>,
    /// Every shaper tuned to the mode, in maxl's order.
    pub shapers: Vec<ShaperScore>,
    /// The recommended shaper (see the module docs).
    pub recommended: Option<ShaperConfig>,
}

/// Analyses `measured` and `commanded` acceleration, sampled together
/// every `dt` seconds, within `range` (Hz).
pub fn analyze(
    dt: f64,
    measured: &[f64],
    commanded: &[f64],
    range: (f64, f64),
) -> Result<Analysis, AnalysisError> {
    let response = frequency_response(dt, measured, commanded, range)?;
    let peak = find_peak(&response, range);
    let mode = match peak {
        Peak::Found { freq_hz, .. } => fit_mode(&response, freq_hz),
        _ => None,
    };
    let shapers = mode.map(score_shapers).unwrap_or_default();
    let recommended = recommend(&shapers);
    Ok(Analysis {
        range,
        response,
        peak,
        mode,
        shapers,
        recommended,
    })
}

/// The smoothed response `H(f)` within `range` (see the module docs).
pub fn frequency_response(
    dt: f64,
    measured: &[f64],
    commanded: &[f64],
    range: (f64, f64),
) -> Result<Vec<ResponsePoint>, AnalysisError> {
    if measured.len() != commanded.len() {
        return Err(AnalysisError::Samples(format!(
            "{} measured samples but {} commanded",
            measured.len(),
            commanded.len()
        )));
    }
    let n = measured.len();
    if n < 64 {
        return Err(AnalysisError::Samples(format!(
            "{n} samples: too few for a spectrum (record longer)"
        )));
    }
    if !(dt.is_finite() && dt > 0.0) {
        return Err(AnalysisError::Samples(format!("bad sample period {dt} s")));
    }
    if measured.iter().chain(commanded).any(|x| !x.is_finite()) {
        return Err(AnalysisError::Samples("a sample is not finite".into()));
    }
    let len = (4 * n).next_power_of_two();
    let mut planner = RealFftPlanner::<f64>::new();
    let fft = planner.plan_fft_forward(len);
    let spectrum = |x: &[f64]| -> Vec<Complex64> {
        let mean = x.iter().sum::<f64>() / x.len() as f64;
        let mut buf = fft.make_input_vec();
        for (b, v) in buf.iter_mut().zip(x) {
            *b = v - mean;
        }
        let mut out = fft.make_output_vec();
        // The lengths are the plan's own: it cannot fail.
        if fft.process(&mut buf, &mut out).is_err() {
            out.iter_mut().for_each(|c| *c = Complex64::new(0.0, 0.0));
        }
        out
    };
    let a = spectrum(measured);
    let c = spectrum(commanded);
    let df = 1.0 / (len as f64 * dt);
    let record_df = 1.0 / (n as f64 * dt);
    let nyquist = 0.5 / dt;
    let (lo, hi) = (range.0.max(df), range.1.min(nyquist * 0.98));
    // Prefix sums of A·C̄ and |C|² for O(1) band sums.
    let mut cross = vec![Complex64::new(0.0, 0.0); a.len() + 1];
    let mut power = vec![0.0; a.len() + 1];
    for k in 0..a.len() {
        cross[k + 1] = cross[k] + a[k] * c[k].conj();
        power[k + 1] = power[k] + c[k].norm_sqr();
    }
    let total: f64 = power[a.len()];
    let k0 = (lo / df).ceil() as usize;
    let k1 = ((hi / df).floor() as usize).min(a.len() - 1);
    let mut out = Vec::with_capacity(k1.saturating_sub(k0) + 1);
    let mut band_power = 0.0;
    for (k, ck) in c.iter().enumerate().take(k1 + 1).skip(k0) {
        let f = k as f64 * df;
        let half = ((SMOOTH * f).max(record_df) / df).round() as usize;
        let (i0, i1) = (k.saturating_sub(half), (k + half + 1).min(a.len()));
        let p = power[i1] - power[i0];
        band_power += ck.norm_sqr();
        let h = if p > 0.0 {
            (cross[i1] - cross[i0]) / p
        } else {
            Complex64::new(0.0, 0.0)
        };
        out.push(ResponsePoint { freq_hz: f, h });
    }
    if out.is_empty() || !(band_power > 1e-9 * total && total > 0.0) {
        return Err(AnalysisError::NoExcitation(range.0, range.1));
    }
    Ok(out)
}

/// Where `response` peaks within `range` (see the module docs).
pub fn find_peak(response: &[ResponsePoint], range: (f64, f64)) -> Peak {
    let Some((i, best)) = response
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.magnitude().total_cmp(&b.1.magnitude()))
    else {
        return Peak::BelowRange { f0: range.0 };
    };
    let span = (range.1 / range.0).ln();
    let at = (best.freq_hz / range.0).ln() / span;
    if at < EDGE {
        return Peak::BelowRange { f0: range.0 };
    }
    if at > 1.0 - EDGE {
        return Peak::AboveRange { f1: range.1 };
    }
    let mut freq_hz = best.freq_hz;
    if i > 0 && i + 1 < response.len() {
        let m = |j: usize| response[j].magnitude().max(1e-300).ln();
        let (y0, y1, y2) = (m(i - 1), m(i), m(i + 1));
        let den = y0 - 2.0 * y1 + y2;
        if den < 0.0 {
            let shift = (0.5 * (y0 - y2) / den).clamp(-0.5, 0.5);
            freq_hz += shift * (response[i + 1].freq_hz - response[i].freq_hz);
        }
    }
    Peak::Found {
        freq_hz,
        magnitude: best.magnitude(),
    }
}

/// The base-excited mode fitted around `peak_hz` (see the module docs);
/// `None` when the fit is not a damped mode within the response.
pub fn fit_mode(response: &[ResponsePoint], peak_hz: f64) -> Option<Mode> {
    // Unknowns x = [p, q, a, b]: p = K·2ζω, q = K·ω², a = 2ζω, b = ω².
    // H (s² + a s + b) = p s + q, divided by s²:
    // p/s + q/s² − a·H/s − b·H/s² = H.
    let mut ata = [[0.0f64; 4]; 4];
    let mut atb = [0.0f64; 4];
    let (lo, hi) = (peak_hz * (1.0 - FIT_BAND), peak_hz * (1.0 + FIT_BAND));
    let mut used = 0;
    for p in response.iter().filter(|p| (lo..=hi).contains(&p.freq_hz)) {
        let s = Complex64::new(0.0, 2.0 * PI * p.freq_hz);
        let (is, is2) = (s.inv(), (s * s).inv());
        let row = [is, is2, -p.h * is, -p.h * is2];
        for part in 0..2 {
            let pick = |c: Complex64| if part == 0 { c.re } else { c.im };
            let r: [f64; 4] = row.map(pick);
            let y = pick(p.h);
            for i in 0..4 {
                atb[i] += r[i] * y;
                for j in 0..4 {
                    ata[i][j] += r[i] * r[j];
                }
            }
        }
        used += 1;
    }
    if used < 8 {
        return None;
    }
    let x = solve4(ata, atb)?;
    let (a, b) = (x[2], x[3]);
    if !(a > 0.0 && b > 0.0) {
        return None;
    }
    let omega = b.sqrt();
    let damping = a / (2.0 * omega);
    let freq_hz = omega / (2.0 * PI);
    let gain = x[1] / b;
    let ok = damping < 1.0
        && freq_hz.is_finite()
        && (response.first()?.freq_hz..=response.last()?.freq_hz).contains(&freq_hz);
    ok.then_some(Mode {
        freq_hz,
        damping,
        gain,
    })
}

/// Solves `m x = v` (4×4) by Gaussian elimination with partial pivoting;
/// `None` when singular.
fn solve4(mut m: [[f64; 4]; 4], mut v: [f64; 4]) -> Option<[f64; 4]> {
    // Scale columns so the unknowns' very different sizes do not matter.
    let mut scale = [1.0f64; 4];
    for (j, s) in scale.iter_mut().enumerate() {
        let d = m[j][j].abs().sqrt();
        if d > 0.0 {
            *s = 1.0 / d;
        }
    }
    for i in 0..4 {
        for j in 0..4 {
            m[i][j] *= scale[i] * scale[j];
        }
        v[i] *= scale[i];
    }
    for col in 0..4 {
        let piv = (col..4).max_by(|&a, &b| m[a][col].abs().total_cmp(&m[b][col].abs()))?;
        if m[piv][col].abs() < 1e-14 {
            return None;
        }
        m.swap(col, piv);
        v.swap(col, piv);
        for r in col + 1..4 {
            let f = m[r][col] / m[col][col];
            let pivot_row = m[col];
            for (x, p) in m[r].iter_mut().zip(pivot_row).skip(col) {
                *x -= f * p;
            }
            v[r] -= f * v[col];
        }
    }
    let mut x = [0.0; 4];
    for i in (0..4).rev() {
        let s: f64 = (i + 1..4).map(|k| m[i][k] * x[k]).sum();
        x[i] = (v[i] - s) / m[i][i];
    }
    for (xi, s) in x.iter_mut().zip(scale) {
        *xi *= s;
    }
    x.iter().all(|x| x.is_finite()).then_some(x)
}

/// Every shaper kind tuned to `mode`, scored (see the module docs). Kinds
/// that cannot take the mode's damping are left out.
pub fn score_shapers(mode: Mode) -> Vec<ShaperScore> {
    ShaperKind::ALL
        .into_iter()
        .filter_map(|kind| {
            let shaper = ShaperConfig::new(kind, mode.freq_hz, mode.damping).ok()?;
            let imp = shaper.impulses();
            let residual = residual_vibration(&imp, mode.freq_hz, mode.damping);
            let worst = (0..=30)
                .map(|i| {
                    let f =
                        mode.freq_hz * (1.0 - SHAPER_BAND + 2.0 * SHAPER_BAND * i as f64 / 30.0);
                    residual_vibration(&imp, f, mode.damping)
                })
                .fold(0.0, f64::max);
            Some(ShaperScore {
                shaper,
                residual,
                worst,
                duration_s: shaper.duration_s(),
            })
        })
        .collect()
}

/// The shortest shaper whose worst residual is within the goal, else the
/// most robust.
pub fn recommend(scores: &[ShaperScore]) -> Option<ShaperConfig> {
    scores
        .iter()
        .filter(|s| s.worst <= SHAPER_RESIDUAL)
        // Shortest first; of equal lengths (EI and ZVD), the more robust.
        .min_by(|a, b| {
            (1e6 * a.duration_s)
                .round()
                .total_cmp(&(1e6 * b.duration_s).round())
                .then(a.worst.total_cmp(&b.worst))
        })
        .or_else(|| scores.iter().min_by(|a, b| a.worst.total_cmp(&b.worst)))
        .map(|s| s.shaper)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The model driven by the continuous commanded acceleration `cmd(t)`,
    /// integrated by RK4 at a fine step; returns, per sample window of
    /// `dt`, the tool's and the carriage's mean acceleration (as the
    /// accelerometer and the commanded spline are compared).
    fn simulate(
        f: f64,
        z: f64,
        dt: f64,
        n: usize,
        cmd: impl Fn(f64) -> f64,
    ) -> (Vec<f64>, Vec<f64>) {
        // State: carriage velocity xv, e = y − x, ev = e'; x'' = cmd,
        // e'' = −ω² e − 2ζω e' − x''.
        let w = 2.0 * PI * f;
        let sub = 16;
        let h = dt / sub as f64;
        let d = |t: f64, s: [f64; 3]| {
            let a = cmd(t);
            [a, s[2], -w * w * s[1] - 2.0 * z * w * s[2] - a]
        };
        let mut s = [0.0f64; 3];
        let (mut meas, mut com) = (Vec::with_capacity(n), Vec::with_capacity(n));
        for k in 0..n {
            let before = s;
            for j in 0..sub {
                let t = k as f64 * dt + j as f64 * h;
                let add = |s: [f64; 3], k: [f64; 3], c: f64| {
                    [s[0] + c * k[0], s[1] + c * k[1], s[2] + c * k[2]]
                };
                let k1 = d(t, s);
                let k2 = d(t + 0.5 * h, add(s, k1, 0.5 * h));
                let k3 = d(t + 0.5 * h, add(s, k2, 0.5 * h));
                let k4 = d(t + h, add(s, k3, h));
                for i in 0..3 {
                    s[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
                }
            }
            com.push((s[0] - before[0]) / dt);
            meas.push((s[0] + s[2] - before[0] - before[2]) / dt);
        }
        (meas, com)
    }

    /// A constant-amplitude exponential chirp of acceleration, faded.
    fn chirp(f0: f64, f1: f64, secs: f64) -> impl Fn(f64) -> f64 {
        let k = (f1 / f0).ln();
        move |t| {
            if !(0.0..secs).contains(&t) {
                return 0.0;
            }
            let fade = 0.2;
            let edge = t.min(secs - t);
            let w = if edge >= fade {
                1.0
            } else {
                0.5 * (1.0 - (PI * edge / fade).cos())
            };
            let phase = 2.0 * PI * f0 * secs * ((k * t / secs).exp() - 1.0) / k;
            1000.0 * w * phase.sin()
        }
    }

    #[test]
    fn modes_are_found_within_a_percent_over_a_spread() {
        let dt = 1e-3;
        for f in [15.0, 20.0, 33.0, 45.0, 80.0, 120.0, 150.0] {
            for z in [0.02, 0.05, 0.1, 0.2] {
                let (meas, cmd) = simulate(f, z, dt, 12_000, chirp(5.0, 200.0, 8.0));
                let a = analyze(dt, &meas, &cmd, (5.0, 200.0)).unwrap();
                let mode = a.mode.unwrap_or_else(|| panic!("{f} Hz ζ {z}: no mode"));
                assert!(
                    (mode.freq_hz / f - 1.0).abs() < 0.01,
                    "{f} Hz ζ {z}: fitted {mode:?}"
                );
                assert!(
                    (mode.damping / z - 1.0).abs() < 0.1,
                    "{f} Hz ζ {z}: {mode:?}"
                );
                let Peak::Found { freq_hz, .. } = a.peak else {
                    panic!("{f} Hz ζ {z}: {:?}", a.peak)
                };
                let want = model_peak_hz(f, z);
                assert!(
                    (freq_hz / want - 1.0).abs() < 0.01,
                    "{f} Hz ζ {z}: peak {freq_hz} want {want}"
                );
                assert!(a.recommended.is_some());
            }
        }
    }

    #[test]
    fn a_mode_outside_the_range_is_reported_as_such() {
        let dt = 1e-3;
        let (meas, cmd) = simulate(150.0, 0.05, dt, 8000, chirp(20.0, 100.0, 6.0));
        let a = analyze(dt, &meas, &cmd, (20.0, 100.0)).unwrap();
        assert_eq!(a.peak, Peak::AboveRange { f1: 100.0 });
        assert!(a.mode.is_none() && a.recommended.is_none());
        let (meas, cmd) = simulate(10.0, 0.05, dt, 8000, chirp(20.0, 100.0, 6.0));
        let a = analyze(dt, &meas, &cmd, (20.0, 100.0)).unwrap();
        assert_eq!(a.peak, Peak::BelowRange { f0: 20.0 });
    }

    #[test]
    fn bad_input_is_an_error() {
        assert!(analyze(1e-3, &[0.0; 10], &[0.0; 10], (5.0, 100.0)).is_err());
        assert!(analyze(1e-3, &[0.0; 100], &[0.0; 99], (5.0, 100.0)).is_err());
        assert!(matches!(
            analyze(1e-3, &[0.0; 1000], &[0.0; 1000], (5.0, 100.0)),
            Err(AnalysisError::NoExcitation(..))
        ));
        let mut x = vec![1.0; 1000];
        x[3] = f64::NAN;
        assert!(analyze(1e-3, &x, &x, (5.0, 100.0)).is_err());
    }

    #[test]
    fn light_damping_gets_a_short_shaper_and_heavy_a_robust_one() {
        let s = score_shapers(Mode {
            freq_hz: 40.0,
            damping: 0.1,
            gain: 1.0,
        });
        assert_eq!(s.len(), 6);
        let r = recommend(&s).unwrap();
        assert!(s
            .iter()
            .any(|x| x.shaper == r && x.worst <= SHAPER_RESIDUAL));
    }
}
