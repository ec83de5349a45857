//! Limiter: random streams never exceed the limits after limiting (finite
//! differences and the evaluated curve), streams within the limits pass bit
//! for bit, counters and errors.

use maxl::eval::{eval_f64, Fx};
use maxl::limit::{AxisLimits, LimitError, Limiter, RawLimits};
use maxl::Interval;
use proptest::prelude::*;

const LIM: AxisLimits = AxisLimits {
    max_vel: 5_000.0,
    max_acc: 100_000.0,
    max_jerk: 10_000_000.0,
};

fn iv() -> Interval {
    Interval::from_micros(1024).unwrap()
}

/// Max |first, second, third difference| of a stream that starts at rest.
fn diffs<T: Copy>(pts: &[T], f: impl Fn(T) -> f64) -> (f64, f64, f64) {
    let (mut d1p, mut d2p) = (0.0, 0.0);
    let (mut m1, mut m2, mut m3) = (0.0f64, 0.0f64, 0.0f64);
    for w in pts.windows(2) {
        let d1 = f(w[1]) - f(w[0]);
        let d2 = d1 - d1p;
        let d3 = d2 - d2p;
        m1 = m1.max(d1.abs());
        m2 = m2.max(d2.abs());
        m3 = m3.max(d3.abs());
        (d1p, d2p) = (d1, d2);
    }
    (m1, m2, m3)
}

fn limit_fx(input: &[Fx]) -> (Vec<Fx>, Limiter<Fx>) {
    let mut l = Limiter::<Fx>::new(LIM, iv()).unwrap();
    let out = input.iter().map(|p| l.push(*p).point).collect();
    (out, l)
}

/// Exact check of the curve: |v|, |a|, |j| of the spline through `pts`.
fn curve_within(pts: &[f64], lim: AxisLimits, tol: f64) {
    let i = iv();
    for k in 1..pts.len().saturating_sub(2) {
        let seg = [pts[k - 1], pts[k], pts[k + 1], pts[k + 2]];
        for du in (0..=1024).step_by(64) {
            let q = eval_f64(&seg, du, i);
            assert!(
                q.vel.abs() <= lim.max_vel as f64 * (1.0 + tol),
                "v {}",
                q.vel
            );
            assert!(
                q.acc.abs() <= lim.max_acc as f64 * (1.0 + tol),
                "a {}",
                q.acc
            );
            assert!(
                q.jerk.abs() <= lim.max_jerk as f64 * (1.0 + tol),
                "j {}",
                q.jerk
            );
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(128))]

    #[test]
    fn fixed_point_streams_end_within_limits(
        raw in proptest::collection::vec(-(1i32 << 26)..(1 << 26), 2..400),
        hold in 0usize..4,
    ) {
        // Some streams jump around, some hold each value a few points.
        let input: Vec<Fx> = raw.iter().flat_map(|r| std::iter::repeat_n(Fx(*r), hold + 1)).collect();
        let (out, l) = limit_fx(&input);
        let rl = l.raw_limits();
        let (m1, m2, m3) = diffs(&out, |p| p.0 as f64);
        prop_assert!(m1 <= rl.vel as f64 && m2 <= rl.acc as f64 && m3 <= rl.jerk as f64,
            "{m1} {m2} {m3} vs {rl:?}");
        // Within the physical limits too (raw limits are rounded down).
        let dt = 1024e-6;
        prop_assert!(m1 / 65536.0 / dt <= LIM.max_vel as f64);
        prop_assert!(m2 / 65536.0 / (dt * dt) <= LIM.max_acc as f64);
        prop_assert!(m3 / 65536.0 / (dt * dt * dt) <= LIM.max_jerk as f64 * (1.0 + 1e-6));
        curve_within(&out.iter().map(|p| p.to_f64()).collect::<Vec<_>>(), LIM, 1e-6);
        // The output is a stream within the limits: it passes again unchanged.
        let (again, l2) = limit_fx(&out);
        prop_assert_eq!(&again, &out);
        prop_assert_eq!(l2.stats().clamped, 0);
        prop_assert_eq!(l.stats().points, input.len() as u64);
    }

    #[test]
    fn f32_streams_end_within_limits(
        raw in proptest::collection::vec(-2000.0f32..2000.0, 2..400),
    ) {
        let mut l = Limiter::<f32>::new(LIM, iv()).unwrap();
        let out: Vec<f32> = raw.iter().map(|p| l.push(*p).point).collect();
        let (m1, m2, m3) = diffs(&out, |p| p as f64);
        let dt = 1024e-6f64;
        // f32 positions round to 2^-13 step below 2^11 steps: allow a few
        // of those in each difference.
        let eps = 4.0 * 2f64.powi(-13);
        prop_assert!(m1 <= LIM.max_vel as f64 * dt * (1.0 + 1e-5) + eps, "{m1}");
        prop_assert!(m2 <= LIM.max_acc as f64 * dt * dt * (1.0 + 1e-5) + 2.0 * eps, "{m2}");
        prop_assert!(m3 <= LIM.max_jerk as f64 * dt * dt * dt * (1.0 + 1e-5) + 4.0 * eps, "{m3}");
    }
}

#[test]
fn a_stream_within_limits_passes_bit_for_bit() {
    // 100 steps · (1 − cos 2t), from rest: v ≤ 200, a ≤ 400, j ≤ 800, far
    // inside LIM (a sine starting at full speed would not be: infinite
    // acceleration from rest).
    let dt = 1024e-6;
    let f: Vec<f32> = (0..5000)
        .map(|k| (100.0 * (1.0 - (2.0 * k as f64 * dt).cos())) as f32)
        .collect();
    let mut lf = Limiter::<f32>::new(LIM, iv()).unwrap();
    for p in &f {
        let r = lf.push(*p);
        assert_eq!(r.point.to_bits(), p.to_bits());
        assert!(!r.clamped.any());
    }
    assert_eq!(lf.stats().clamped, 0);
    let x: Vec<Fx> = f.iter().map(|p| Fx::from_f64(*p as f64)).collect();
    let (out, l) = limit_fx(&x);
    assert_eq!(out, x);
    assert_eq!(l.stats().clamped, 0);
    assert_eq!(l.stats().points, 5000);
}

#[test]
fn clamps_are_reported_and_counted() {
    let mut l = Limiter::<Fx>::new(LIM, iv()).unwrap();
    assert!(!l.push(Fx(0)).clamped.any());
    // A 1000-step jump breaks all three.
    let r = l.push(Fx(1000 << 16));
    assert!(r.clamped.jerk && r.clamped.acc);
    assert!(r.point.0 > 0 && r.point.0 <= l.raw_limits().jerk as i32);
    // Chasing a far target: the velocity limit ends up binding.
    let mut vel_seen = false;
    for _ in 0..2000 {
        vel_seen |= l.push(Fx(20_000 << 16)).clamped.vel;
    }
    assert!(vel_seen);
    let s = l.stats();
    assert_eq!(s.points, 2002);
    assert!(s.clamped >= s.jerk.max(s.acc).max(s.vel) && s.vel > 0 && s.jerk > 0);
    // Reset: the next point is a rest position again.
    l.reset();
    let r = l.push(Fx(-5 << 16));
    assert_eq!(r.point, Fx(-5 << 16));
    assert!(!r.clamped.any());
}

#[test]
fn saturates_at_the_fx_range() {
    let lim = AxisLimits {
        max_vel: 1e9,
        max_acc: 1e12,
        max_jerk: 1e15,
    };
    let mut l = Limiter::<Fx>::new(lim, iv()).unwrap();
    l.push(Fx(i32::MAX - 10));
    for _ in 0..50 {
        let r = l.push(Fx(i32::MAX));
        assert!(r.point.0 >= i32::MAX - 10);
    }
    let mut l = Limiter::<Fx>::new(lim, iv()).unwrap();
    l.push(Fx(i32::MIN));
    let r = l.push(Fx(i32::MAX));
    assert!(r.point.0 > i32::MIN);
}

#[test]
fn bad_limits_are_errors() {
    for bad in [0.0, -1.0, f32::NAN, f32::INFINITY] {
        let l = AxisLimits {
            max_vel: 1.0,
            max_acc: bad,
            max_jerk: 1.0,
        };
        assert_eq!(Limiter::<Fx>::new(l, iv()).err(), Some(LimitError::Invalid));
        assert_eq!(
            Limiter::<f32>::new(l, iv()).err(),
            Some(LimitError::Invalid)
        );
    }
    let tiny = AxisLimits {
        max_vel: 1000.0,
        max_acc: 1000.0,
        max_jerk: 1.0,
    };
    let i256 = Interval::from_micros(256).unwrap();
    assert_eq!(
        Limiter::<Fx>::new(tiny, i256).err(),
        Some(LimitError::TooSmall)
    );
    assert_eq!(
        Limiter::<Fx>::from_raw(RawLimits {
            vel: 1,
            acc: 0,
            jerk: 1
        })
        .err(),
        Some(LimitError::TooSmall)
    );
    assert!(Limiter::<f32>::new(tiny, i256).is_ok());
    assert!(!LimitError::TooSmall.to_string().is_empty());
}

#[test]
fn a_copy_checks_a_point_without_taking_it() {
    // osap-module refuses a point past a limit instead of clamping it:
    // it pushes into a copy and keeps the copy only for an accepted point.
    let mut l = Limiter::<Fx>::new(LIM, iv()).unwrap();
    for k in 0..4 {
        assert!(!l.push(Fx(k)).clamped.any());
    }
    let before = l;
    let mut probe = l;
    assert!(probe.push(Fx(1000 << 16)).clamped.any());
    // The original still continues the stream where it was.
    let mut again = before;
    assert_eq!(l.push(Fx(4)), again.push(Fx(4)));
    assert!(!l.push(Fx(5)).clamped.any());
    // A clamped push does move the limiter on (to the clamped point).
    let mut moved = before;
    let r = moved.push(Fx(1000 << 16));
    assert_ne!(r.point, Fx(1000 << 16));
    let mut fresh = before;
    assert_ne!(moved.push(Fx(4)), fresh.push(Fx(4)));
}
