//! The toolhead's simulated vibration.
//!
//! Each axis with a simulated resonance (`[sim.axes.NAME] resonance_hz`,
//! `damping_ratio`) carries the tool on the simulator's mass-spring mode
//! ([`osap_sim::machine::mode`]), driven by the positions the motors were
//! sent. Under a steady acceleration the spring holds the tool a fixed
//! distance behind the carriage; everything else the tool does is ringing.
//!
//! The vibration is that ringing's amplitude (the envelope of the free
//! oscillation, so its phase does not matter), measured wherever the
//! **planned** motion has held one acceleration (cruise, rest, or a steady
//! ramp) for at least the input shaper's window. There the shaped motion
//! holds that acceleration too, the spring's steady deflection is known
//! exactly, and what is left is the residual vibration of every velocity
//! and acceleration change before: what shows on a part after a corner.
//! While the shaper is still passing a change on (its window after it),
//! the tool rings partway by design and is not measured; without a
//! shaper the window is empty, so the full ring after each change counts.
//! Elsewhere the value is NaN.

use maxl::blocks::shaper::InputShaper;
use osap_sim::machine::mode::Mode;

use crate::config::MachineFile;
use crate::machine::drive::MAX_AXES;
use crate::record::{Recording, Sample};

/// How close two planned accelerations must be to count as one, as a share
/// of the axis's acceleration limit.
const STEADY_SHARE: f64 = 1e-3;

/// The vibration of each axis of `rec` that `cfg` gives a simulated
/// resonance (see the module docs), at every executed sample of `rec`
/// (machine units; NaN where it is not measured). Axes without a
/// resonance are left out; so is every axis when `rec` lacks planned,
/// unshaped or executed samples.
pub fn vibration(cfg: &MachineFile, rec: &Recording) -> Vec<(String, Vec<f64>)> {
    let Some(sim) = &cfg.sim else {
        return Vec::new();
    };
    let n = rec.axes.len();
    let usable = |s: &Sample| s.pos.len() == n && s.t.is_finite();
    if rec.planned.len() < 3
        || rec.executed.is_empty()
        || rec.unshaped.len() != rec.planned.len()
        || !rec.planned.iter().chain(&rec.unshaped).all(usable)
    {
        return Vec::new();
    }
    let window = match crate::machine::motion::shapers(cfg) {
        Ok(s) => InputShaper::<MAX_AXES>::new(s).window_s(),
        Err(_) => return Vec::new(),
    };
    let times: Vec<f64> = rec.planned.iter().map(|s| s.t).collect();
    rec.axes
        .iter()
        .enumerate()
        .filter_map(|(k, axis)| {
            let (hz, zeta) = sim.axes.get(axis.as_str())?.resonance()?;
            let mode = Mode::new(hz, zeta);
            let sent: Vec<(f64, f64)> = rec.planned.iter().map(|s| (s.t, s.pos[k])).collect();
            let plan: Vec<f64> = rec.unshaped.iter().map(|s| s.pos[k]).collect();
            let tolerance = STEADY_SHARE * cfg.axes.get(axis.as_str())?.acceleration;
            let steady = steady(&times, &plan, tolerance, window);
            let w2 = mode.omega() * mode.omega();
            let ringing: Vec<f64> = mode
                .deviation(&sent)
                .iter()
                .zip(&steady)
                .map(|(d, &steady)| {
                    if steady {
                        mode.free_amplitude(d.e + d.accel / w2, d.rate)
                    } else {
                        f64::NAN
                    }
                })
                .collect();
            let at_executed = rec
                .executed
                .iter()
                .map(|e| interpolate(&times, &ringing, e.t))
                .collect();
            Some((axis.clone(), at_executed))
        })
        .collect()
}

/// Whether, at each sample, the planned positions `x` (at `t`) have held
/// one acceleration (within `tolerance`) from `window` before it to one
/// sample after it, with a sample's margin either side (so the shaped
/// motion around the sample, and its second difference, are steady too).
fn steady(t: &[f64], x: &[f64], tolerance: f64, window: f64) -> Vec<bool> {
    let n = t.len();
    // The second difference at each inner sample.
    let accel: Vec<f64> = (0..n)
        .map(|i| {
            if i == 0 || i + 1 >= n {
                return f64::NAN;
            }
            let (h0, h1) = (t[i] - t[i - 1], t[i + 1] - t[i]);
            if h0 <= 0.0 || h1 <= 0.0 {
                return f64::NAN;
            }
            2.0 * ((x[i + 1] - x[i]) / h1 - (x[i] - x[i - 1]) / h0) / (h0 + h1)
        })
        .collect();
    // changes[i]: the samples up to i where the acceleration changed (or
    // is unknown), counted.
    let mut changes = Vec::with_capacity(n + 1);
    changes.push(0usize);
    for i in 0..n {
        let changed = match (i.checked_sub(1).map(|j| accel[j]), accel[i]) {
            (Some(a), b) => !(a.is_finite() && b.is_finite() && (a - b).abs() <= tolerance),
            (None, _) => true,
        };
        changes.push(changes[i] + usize::from(changed));
    }
    (0..n)
        .map(|i| {
            if i < 2 || i + 2 >= n {
                return false;
            }
            let margin = t[i] - t[i - 2];
            let from = t.partition_point(|&s| s < t[i] - window - margin);
            // No change at any sample in from+1..=i+2 (a change at `from`
            // is the step into the steady stretch, before the window).
            changes[i + 3] == changes[from + 1]
        })
        .collect()
}

/// `values` (at `times`, in order) at `t`, linearly between two samples
/// with values; NaN where either is NaN or `t` is outside.
fn interpolate(times: &[f64], values: &[f64], t: f64) -> f64 {
    let i = times.partition_point(|&s| s <= t);
    match (i.checked_sub(1), values.get(i)) {
        (Some(j), _) if times[j] == t => values[j],
        (Some(j), Some(&b)) if times[i] > times[j] => {
            let a = values[j];
            a + (b - a) * (t - times[j]) / (times[i] - times[j])
        }
        _ => f64::NAN,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steady_stretches_exclude_the_window_after_a_change() {
        let dt = 0.002;
        let t: Vec<f64> = (0..100).map(|k| k as f64 * dt).collect();
        // At rest until 0.05 s, then accelerating at 1000.
        let x: Vec<f64> = t
            .iter()
            .map(|&s| {
                if s <= 0.05 {
                    0.0
                } else {
                    500.0 * (s - 0.05).powi(2)
                }
            })
            .collect();
        let s = steady(&t, &x, 1.0, 0.0);
        // The change is seen at the sample at 0.05 s (index 25).
        assert!(s[20] && !s[24] && !s[25] && !s[27] && s[29], "{s:?}");
        let s = steady(&t, &x, 1.0, 0.02);
        assert!(!s[36] && s[39], "{s:?}");
        assert!(!s[0] && !s[1] && !s[98] && !s[99]);
    }

    #[test]
    fn interpolation_needs_both_neighbours() {
        let times = [0.0, 1.0, 2.0];
        let values = [0.0, 2.0, f64::NAN];
        assert_eq!(interpolate(&times, &values, 0.5), 1.0);
        assert!(interpolate(&times, &values, 1.5).is_nan());
        assert!(interpolate(&times, &values, -1.0).is_nan());
        assert_eq!(interpolate(&times, &values, 1.0), 2.0);
    }
}
