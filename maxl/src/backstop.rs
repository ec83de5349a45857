//! Jerk-limited stop used when the point stream runs dry.
//!
//! From the state `(v0, a0)` at the end of the last fully known segment, the
//! profile is a sequence of at most four constant-jerk phases that brings the
//! axis to `v = 0, a = 0` with `|j| <= max_jerk` and, when the starting state
//! is within the limits, `|a| <= max_acc`. Computed once (in `f32`) when the
//! backstop latches, then evaluated in closed form at any time offset.

/// Limits for the backstop, in steps/s² and steps/s³ (both must be `> 0`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BackstopLimits {
    /// Largest deceleration, steps/s².
    pub max_acc: f32,
    /// Largest jerk, steps/s³.
    pub max_jerk: f32,
}

/// A piecewise-constant-jerk stop profile relative to its start.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StopProfile {
    v0: f32,
    a0: f32,
    /// (duration s, jerk steps/s³)
    phases: [(f32, f32); 4],
    n: usize,
}

/// Square root by Newton's method (core has no `sqrt` without std).
fn sqrt(x: f32) -> f32 {
    if x <= 0.0 {
        return 0.0;
    }
    let mut r = if x > 1.0 { x } else { 1.0 };
    for _ in 0..64 {
        let next = 0.5 * (r + x / r);
        if next >= r {
            break;
        }
        r = next;
    }
    r
}

impl StopProfile {
    /// Plan a stop from velocity `v0` and acceleration `a0`.
    pub fn plan(v0: f32, a0: f32, lim: BackstopLimits) -> Self {
        let jm = lim.max_jerk;
        let am = lim.max_acc;
        let mut phases = [(0.0f32, 0.0f32); 4];
        let mut n = 0;
        let (mut v, mut a) = (v0, a0);
        for _ in 0..2 {
            // Work with the velocity non-negative (d = direction of motion).
            let d = if v > 0.0 || (v == 0.0 && a >= 0.0) {
                1.0
            } else {
                -1.0
            };
            let (vc, ac) = (v * d, a * d);
            if vc == 0.0 && ac == 0.0 {
                break;
            }
            if ac < 0.0 && vc < ac * ac / (2.0 * jm) {
                // Already braking so hard that even releasing the brake at max
                // jerk crosses zero velocity: release, then stop the reverse motion.
                let t = -ac / jm;
                phases[n] = (t, d * jm);
                n += 1;
                v = d * (vc - ac * ac / (2.0 * jm));
                a = 0.0;
                continue;
            }
            let free = sqrt(jm * vc + 0.5 * ac * ac);
            let ap = free.min(am).max(-ac);
            let t1 = (ac + ap) / jm;
            let t2 = if ap > 0.0 {
                ((vc + ac * ac / (2.0 * jm) - ap * ap / jm) / ap).max(0.0)
            } else {
                0.0
            };
            let t3 = ap / jm;
            phases[n] = (t1, -d * jm);
            phases[n + 1] = (t2, 0.0);
            phases[n + 2] = (t3, d * jm);
            n += 3;
            break;
        }
        StopProfile { v0, a0, phases, n }
    }

    /// Total duration in seconds.
    pub fn duration(&self) -> f32 {
        self.phases[..self.n].iter().map(|p| p.0).sum()
    }

    /// `(dp, v, a, j)` at `tau` seconds after the start; at rest after the end.
    pub fn at(&self, tau: f32) -> (f32, f32, f32, f32) {
        let (mut p, mut v, mut a) = (0.0f32, self.v0, self.a0);
        let mut left = if tau > 0.0 { tau } else { 0.0 };
        for &(dur, j) in &self.phases[..self.n] {
            let dt = if left < dur { left } else { dur };
            p += v * dt + a * dt * dt / 2.0 + j * dt * dt * dt / 6.0;
            v += a * dt + j * dt * dt / 2.0;
            a += j * dt;
            if left < dur {
                return (p, v, a, j);
            }
            left -= dur;
        }
        (p, 0.0, 0.0, 0.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const LIM: BackstopLimits = BackstopLimits {
        max_acc: 2000.0,
        max_jerk: 100_000.0,
    };

    fn check(v0: f32, a0: f32) {
        let s = StopProfile::plan(v0, a0, LIM);
        let d = s.duration();
        let n = 2000;
        let mut prev_a = a0;
        for k in 0..=n {
            let t = d * k as f32 / n as f32;
            let (_, _, a, j) = s.at(t);
            assert!(j.abs() <= LIM.max_jerk * 1.0001, "jerk {j}");
            if a0.abs() <= LIM.max_acc {
                assert!(a.abs() <= LIM.max_acc * 1.001, "acc {a} v0={v0} a0={a0}");
            }
            let da = (a - prev_a).abs();
            assert!(
                da <= LIM.max_jerk * d / n as f32 * 1.01 + 1e-2,
                "acc step {da}"
            );
            prev_a = a;
        }
        let (_, v_end, a_end, _) = s.at(d * (1.0 - 1e-6));
        assert!(v_end.abs() < 1e-2 * (1.0 + v0.abs()), "v_end {v_end}");
        assert!(a_end.abs() < 1.0, "a_end {a_end}");
        assert_eq!(s.at(d + 1.0).1, 0.0);
    }

    #[test]
    fn stops_within_limits_from_many_states() {
        for &v0 in &[0.0, 1.0, 50.0, 500.0, 5000.0, -5000.0, -3.0] {
            for &a0 in &[0.0, 1500.0, -1500.0, 2000.0, -2000.0, 10.0] {
                check(v0, a0);
            }
        }
    }

    #[test]
    fn sqrt_is_accurate() {
        for &x in &[1e-6f32, 0.25, 2.0, 1e6, 3.3e9] {
            let r = sqrt(x);
            assert!((r * r - x).abs() <= x * 1e-5, "{x} {r}");
        }
    }
}
