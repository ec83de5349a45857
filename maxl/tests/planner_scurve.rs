//! Jerk-limited (S-curve) profiles: with infinite jerk the plan is the
//! trapezoid's exactly; with finite jerk every sampled acceleration moves
//! at most at the jerk limit (per axis and along the path), the
//! acceleration is zero where segments meet, every profile covers its
//! segment and joins the next at the same speed, and every move ends where
//! it was sent.

mod common;

use common::rng::XorShiftStar;
use maxl::blocks::planner::{Limits, Planner, Profile, VectorLimits};

fn norm(a: &[f64; 3]) -> f64 {
    (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt()
}

/// A random polyline in the xy plane: `n` chords of 0.05 to 20 mm, with
/// turns up to `turn` radians, from the origin.
fn polyline(rng: &mut XorShiftStar, n: usize, turn: f64) -> Vec<([f64; 3], f64)> {
    let (mut q, mut h) = ([0.0; 3], 0.0f64);
    (0..n)
        .map(|_| {
            h += (rng.next() - 0.5) * 2.0 * turn;
            let l = 0.05 + 20.0 * rng.next().powi(2);
            q = [q[0] + l * h.cos(), q[1] + l * h.sin(), 0.0];
            (q, 20.0 + 300.0 * rng.next())
        })
        .collect()
}

fn planner(jerk: f64, jd: f64, mcr: f64) -> Planner<3> {
    let limits = Limits::new([300.0, 300.0, 50.0], [3000.0, 3000.0, 500.0], jd)
        .unwrap()
        .with_max_jerk([jerk; 3])
        .unwrap();
    let vector = VectorLimits::new(250.0, 2500.0)
        .unwrap()
        .with_min_cruise_ratio(mcr)
        .unwrap()
        .with_max_jerk(jerk)
        .unwrap();
    Planner::with_vector_limits(limits, vector, 4096).unwrap()
}

#[test]
fn infinite_jerk_plans_the_trapezoid_exactly() {
    let mut rng = XorShiftStar(0xC0FFEE);
    for mcr in [0.0, 0.5] {
        let path = polyline(&mut rng, 300, 1.5);
        let mut a = planner(f64::INFINITY, 0.02, mcr);
        let limits = Limits::new([300.0, 300.0, 50.0], [3000.0, 3000.0, 500.0], 0.02).unwrap();
        let vector = VectorLimits::new(250.0, 2500.0)
            .unwrap()
            .with_min_cruise_ratio(mcr)
            .unwrap();
        let mut b = Planner::with_vector_limits(limits, vector, 4096).unwrap();
        for (q, f) in &path {
            a.line(*q, *f).unwrap();
            b.line(*q, *f).unwrap();
        }
        assert_eq!(a.plan(), b.plan());
        for t in (0..40_000_000u64).step_by(2048) {
            assert_eq!(a.sample_kin(t).unwrap(), b.sample_kin(t).unwrap());
        }
    }
    // And a single profile, bit for bit.
    let p = Profile::plan(10.0, 5.0, 20.0, 100.0, 3000.0);
    assert_eq!(
        Profile::plan_jerk(10.0, 5.0, 20.0, 100.0, 3000.0, f64::INFINITY),
        p
    );
}

/// Samples the whole plan every `dt` µs, checking each stamp against the
/// limits; returns the samples.
fn sample_all(p: &mut Planner<3>, dt: u64) -> Vec<maxl::blocks::planner::Kin<3>> {
    let mut out = Vec::new();
    let mut t = 0;
    loop {
        out.push(p.sample_kin(t).unwrap());
        if p.is_idle() {
            return out;
        }
        t += dt;
        assert!(t < 3_600_000_000);
    }
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(48))]

    /// Jerk is bounded on sampled output: between any two stamps each
    /// axis's acceleration changes by at most its jerk limit times the
    /// interval (the path's by the vector limit), on random polylines,
    /// limits and minimum cruise ratios; the speed and acceleration stay
    /// within theirs, and every profile is feasible.
    #[test]
    fn jerk_is_bounded_on_sampled_output(
        seed in 1u64..u64::MAX,
        jerk in 2.0e4f64..2.0e6,
        jd in 0.0f64..0.1,
        mcr in proptest::sample::select(vec![0.0, 0.5]),
        turn in proptest::sample::select(vec![0.0, 0.3, 1.5]),
    ) {
        let mut rng = XorShiftStar(seed);
        let path = polyline(&mut rng, 60, turn);
        let mut p = planner(jerk, jd, mcr);
        for (q, f) in &path {
            p.line(*q, *f).unwrap();
        }
        let plan = p.plan();
        for s in &plan.segments {
            let pr = &s.profile;
            let d = 0.5 * (pr.entry + pr.cruise) * pr.t_acc
                + pr.cruise * pr.t_cruise
                + 0.5 * (pr.cruise + pr.exit) * pr.t_dec;
            proptest::prop_assert!((d - pr.length).abs() <= 1e-9 * (1.0 + pr.length), "{pr:?}");
            // Zero acceleration where it meets its neighbours.
            proptest::prop_assert!(pr.at(0.0).2.abs() < 1e-6 * pr.accel, "{pr:?}");
            proptest::prop_assert!(pr.at(pr.duration()).2.abs() < 1e-6 * pr.accel, "{pr:?}");
        }
        for w in plan.segments.windows(2) {
            proptest::prop_assert!((w[0].profile.exit - w[1].profile.entry).abs() <= 1e-9 * (1.0 + w[0].profile.exit));
        }
        let dt_us = 250;
        let dt = dt_us as f64 * 1e-6;
        let k = sample_all(&mut p, dt_us);
        proptest::prop_assert!(k.len() > 100, "{} samples", k.len());
        for w in k.windows(2) {
            let da: [f64; 3] = std::array::from_fn(|i| w[1].acc[i] - w[0].acc[i]);
            for (i, d) in da.iter().enumerate() {
                proptest::prop_assert!(d.abs() <= jerk * dt * (1.0 + 1e-6) + 1e-6, "axis {i}: Δa {d}");
            }
            proptest::prop_assert!(norm(&da) <= jerk * dt * (1.0 + 1e-6) + 1e-6);
            proptest::prop_assert!(norm(&w[1].acc) <= 2500.0 * (1.0 + 1e-9));
            proptest::prop_assert!(norm(&w[1].vel) <= 250.0 * (1.0 + 1e-9));
        }
        proptest::prop_assert_eq!(k.last().unwrap().pos, path.last().unwrap().0);
    }

    /// On a straight line split into pieces at random feeds the sampled
    /// positions alone show the bound: their third differences, the jerk
    /// averaged over three intervals, stay within the limit.
    #[test]
    fn third_differences_of_a_straight_line_stay_within_the_jerk(
        seed in 1u64..u64::MAX,
        jerk in 2.0e4f64..1.0e6,
    ) {
        let mut rng = XorShiftStar(seed);
        let mut p = planner(jerk, 0.02, 0.0);
        let mut x = 0.0;
        let dir = [0.6, 0.8, 0.0];
        for _ in 0..20 {
            x += 0.5 + 30.0 * rng.next();
            p.line([dir[0] * x, dir[1] * x, 0.0], 20.0 + 230.0 * rng.next()).unwrap();
        }
        let dt_us = 1000;
        let dt = dt_us as f64 * 1e-6;
        let k = sample_all(&mut p, dt_us);
        proptest::prop_assert!(k.len() > 100, "{} samples", k.len());
        let s: Vec<f64> = k.iter().map(|k| k.pos[0] / dir[0]).collect();
        for w in s.windows(4) {
            let j = (w[3] - 3.0 * w[2] + 3.0 * w[1] - w[0]) / (dt * dt * dt);
            proptest::prop_assert!(j.abs() <= jerk * (1.0 + 1e-6) + 1.0, "jerk {j} over {jerk}");
        }
    }
}

#[test]
fn jerk_limiting_costs_time_and_never_saves_it() {
    let mut rng = XorShiftStar(99);
    let path = polyline(&mut rng, 400, 1.0);
    let duration = |jerk: f64| {
        let mut p = planner(jerk, 0.02, 0.0);
        for (q, f) in &path {
            p.line(*q, *f).unwrap();
        }
        p.plan().duration_us()
    };
    let trapezoid = duration(f64::INFINITY);
    let mut last = trapezoid;
    for jerk in [1e6, 1e5, 3e4] {
        let d = duration(jerk);
        assert!(d >= last * (1.0 - 1e-9), "{jerk}: {d} < {last}");
        last = d;
    }
    // Lower jerk costs more: 30 000 mm/s³ ramps to 2500 mm/s² in 83 ms.
    assert!(last > 1.1 * trapezoid, "{last} vs {trapezoid}");
}
