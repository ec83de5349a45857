//! A uniform cubic B-spline reproduces every polynomial of degree ≤ 3 when
//! its control points are `P_i = f(T_i) − Δt²·f''(T_i)/6`: tracks fed such
//! points must give back the polynomial, its velocity, acceleration and jerk,
//! exactly (up to rounding) at any time, with every evaluator.

use maxl::*;
use osap_core::time::SystemInstant;

const LIM: BackstopLimits = BackstopLimits {
    max_acc: 1e9,
    max_jerk: 1e12,
};

/// `f(t) = c0 + c1 t + c2 t² + c3 t³`, t in seconds, in steps.
#[derive(Clone, Copy, Debug)]
struct Cubic([f64; 4]);

impl Cubic {
    fn at(&self, t: f64) -> [f64; 4] {
        let [c0, c1, c2, c3] = self.0;
        [
            c0 + t * (c1 + t * (c2 + t * c3)),
            c1 + t * (2.0 * c2 + t * 3.0 * c3),
            2.0 * c2 + 6.0 * c3 * t,
            6.0 * c3,
        ]
    }

    /// The control point stamped `t` for interval `dt` (s).
    fn point(&self, t: f64, dt: f64) -> f64 {
        let [p, _, a, _] = self.at(t);
        p - dt * dt * a / 6.0
    }
}

fn polynomials() -> Vec<Cubic> {
    vec![
        Cubic([1234.5, 0.0, 0.0, 0.0]),           // constant
        Cubic([-300.0, 2500.0, 0.0, 0.0]),        // constant velocity
        Cubic([10.0, -400.0, 9000.0, 0.0]),       // constant acceleration
        Cubic([-50.0, 800.0, -3000.0, 40_000.0]), // constant jerk
        Cubic([5.0, -1000.0, -20_000.0, -90_000.0]),
    ]
}

#[test]
fn every_evaluator_reproduces_cubics() {
    for us in [256u32, 1024, 4096, 16384] {
        let iv = Interval::from_micros(us).unwrap();
        let dt = f64::from(us) * 1e-6;
        for f in polynomials() {
            // Stamps from an arbitrary, large synchronized time, over up to
            // 0.3 s (the polynomials stay within Q16.16's ±32768 steps).
            let k0 = (1u64 << 40) / u64::from(us);
            let n = (0.3 / dt) as u64 + 4;
            let t0 = k0 * u64::from(us);
            let secs = |t: u64| (t - t0) as f64 * 1e-6;
            let mut tf: Track<f32, 128> = Track::new(iv, LIM);
            let mut tx: Track<Fx, 128> = Track::new(iv, LIM);
            let mut points = Vec::new();
            let n = n.min(120);
            for k in 0..n {
                let t = t0 + k * u64::from(us);
                let p = f.point(secs(t), dt);
                points.push(p);
                tf.push(SystemInstant::from_micros(t), p as f32).unwrap();
                tx.push(SystemInstant::from_micros(t), Fx::from_f64(p))
                    .unwrap();
            }
            let scale = f.0.iter().map(|c| c.abs()).fold(1.0, f64::max);
            let end = t0 + (n - 3) * u64::from(us);
            let step = u64::from(us) / 7 + 1;
            let mut t = t0 + u64::from(us);
            while t < end {
                let want = f.at(secs(t));
                // f64 reference on the unrounded points: exact to rounding.
                let i = ((t - t0) / u64::from(us)) as usize;
                let seg = [points[i - 1], points[i], points[i + 1], points[i + 2]];
                let du = ((t - t0) % u64::from(us)) as u32;
                let r = eval_f64(&seg, du, iv);
                let got = [r.pos, r.vel, r.acc, r.jerk];
                for (d, (g, w)) in got.iter().zip(want).enumerate() {
                    // Each derivative divides by Δt once more.
                    let tol = 1e-9 * scale * (1.0 / dt).powi(d as i32).max(1.0);
                    assert!(
                        (g - w).abs() <= tol,
                        "f64 d{d} at {t}: {g} vs {w} ({f:?}, {us} µs)"
                    );
                }
                // Fixed point: the points are rounded to 2^-16 step, so
                // position is within the proven bound (1.25 LSB) of f.
                let x = tx.sample(SystemInstant::from_micros(t)).unwrap();
                assert_eq!(x.status, TrackStatus::Tracking);
                let e = (x.kin.pos.to_f64() - want[0]).abs() * 65536.0;
                assert!(e <= 1.25, "fixed pos error {e} LSB at {t} ({f:?}, {us} µs)");
                // Velocity: points rounded by ≤ 0.5 LSB move it by ≤ 4.5 LSB/Δt.
                let ev = (x.kin.vel_f64() - want[1]).abs();
                assert!(
                    ev <= 6.0 / 65536.0 / dt + 1e-6 * want[1].abs(),
                    "fixed vel {ev}"
                );
                // f32: relative to the position's magnitude.
                let y = tf.sample(SystemInstant::from_micros(t)).unwrap();
                let ef = (f64::from(y.kin.pos) - want[0]).abs();
                assert!(ef <= 4e-7 * scale.max(want[0].abs()), "f32 pos error {ef}");
                t += step;
            }
        }
    }
}
