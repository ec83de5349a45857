//! The planner's vector limits, centripetal junction limit and minimum
//! cruise ratio: planned speeds and accelerations within the limits on
//! chorded circles, spirals, zigzags, diagonals and long straight moves;
//! degenerate input.
//!
//! **Lateral acceleration at a junction**, as measured here: the planned
//! path is a polyline, and at the junction `p_j` between the chords
//! `p_{j−1} → p_j` and `p_j → p_{j+1}` the velocity turns from `v·u_prev`
//! to `v·u_next` at the planned junction speed `v`. Its lateral
//! acceleration is the centripetal acceleration of the path's real
//! curvature there: `a_lat = v² / R`, `R` the radius of the circle through
//! `p_{j−1}, p_j, p_{j+1}` (for chords of a circle, that circle), directed
//! along the velocity change `ŵ = (u_next − u_prev) / |u_next − u_prev|`
//! (towards that circle's centre for equal chords). With vector limits,
//! `a_lat ≤ max_accel`; with per-axis limits, `a_lat·|ŵ_i| ≤ max_acc[i]`
//! for each axis; both to a relative 1e-6. Collinear junctions have none.
//!
//! **Tangential**: every stamp's sampled speed and acceleration (along the
//! path) within `max_speed`, `max_accel` and, per axis, `max_vel[i]`,
//! `max_acc[i]`.
//!
//! Before the centripetal limit, chords of 0.1 mm on circles of radius
//! 1–5 mm reached 42 000 mm/s² laterally against 3000 mm/s² per axis
//! (feed 300–500 mm/s, δ = 0.02 mm); `worst_lateral_acceleration_report`
//! prints today's figure.

mod common;

use common::rng::XorShiftStar;
use maxl::blocks::planner::{
    square_corner_deviation, Arc, Limits, PlanError, Planner, PlannerBlock, VectorLimits,
    KLIPPER_MIN_CRUISE_RATIO,
};
use pipes_core::function::CallError;
use std::f64::consts::{PI, TAU};

const TOL: f64 = 1e-6;

// ---- paths ----

fn circle(r: f64, chord: f64, laps: f64) -> Vec<[f64; 3]> {
    let n = (TAU * r / chord).round().max(3.0);
    let steps = (n * laps).round() as usize;
    (0..=steps)
        .map(|k| {
            let a = TAU * k as f64 / n;
            [r * a.cos(), r * a.sin(), 0.0]
        })
        .collect()
}

fn spiral(r0: f64, r1: f64, pitch: f64, chord: f64) -> Vec<[f64; 3]> {
    let mut pts = Vec::new();
    let mut a = 0.0f64;
    let k = pitch / TAU * (r1 - r0).signum();
    loop {
        let r = r0 + k * a;
        if (r1 - r0) * (r - r1) > 0.0 || r <= 0.0 {
            break;
        }
        pts.push([r * a.cos(), r * a.sin(), 0.0]);
        a += chord / r.max(chord);
    }
    pts
}

fn zigzag(n: usize, leg: f64, angle: f64) -> Vec<[f64; 3]> {
    let mut p = [0.0; 3];
    let mut pts = vec![p];
    for i in 0..n {
        let a = if i % 2 == 0 { angle } else { -angle };
        p[0] += leg * a.cos();
        p[1] += leg * a.sin();
        pts.push(p);
    }
    pts
}

fn line(a: [f64; 3], b: [f64; 3], n: usize) -> Vec<[f64; 3]> {
    (0..=n)
        .map(|k| {
            let f = k as f64 / n as f64;
            std::array::from_fn(|i| a[i] + (b[i] - a[i]) * f)
        })
        .collect()
}

fn families() -> Vec<(&'static str, Vec<Vec<[f64; 3]>>)> {
    let mut circles = Vec::new();
    for r in [1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0] {
        for chord in [0.1, 0.2, 0.3, 0.5, 0.7, 1.0] {
            circles.push(circle(r, chord, 1.5));
        }
    }
    vec![
        ("circles", circles),
        (
            "spirals",
            vec![
                spiral(0.5, 10.0, 1.0, 0.2),
                spiral(10.0, 0.5, 1.0, 0.5),
                spiral(0.3, 5.0, 0.4, 0.1),
            ],
        ),
        (
            "zigzags",
            vec![
                zigzag(40, 1.0, PI / 3.0),
                zigzag(40, 3.0, PI / 4.0),
                zigzag(60, 0.5, 1.4),
                zigzag(30, 10.0, 0.2),
            ],
        ),
        (
            "diagonals",
            vec![
                line([0.0; 3], [50.0, 50.0, 0.0], 1),
                line([0.0; 3], [30.0, 17.3, 5.0], 1),
                line([0.0; 3], [20.0, 20.0, 0.0], 200),
                vec![
                    [0.0; 3],
                    [20.0, 20.0, 0.0],
                    [40.0, 0.0, 0.0],
                    [20.0, -20.0, 0.0],
                    [0.0; 3],
                ],
            ],
        ),
        (
            "straight",
            vec![
                line([0.0; 3], [200.0, 0.0, 0.0], 1),
                line([0.0; 3], [0.0, 100.0, 0.0], 1000),
            ],
        ),
    ]
}

// ---- measurements ----

fn sub(a: &[f64; 3], b: &[f64; 3]) -> [f64; 3] {
    std::array::from_fn(|i| a[i] - b[i])
}

fn norm(a: &[f64; 3]) -> f64 {
    a.iter().map(|x| x * x).sum::<f64>().sqrt()
}

/// The radius of the circle through three points (infinite if collinear).
fn circumradius(a: &[f64; 3], b: &[f64; 3], c: &[f64; 3]) -> f64 {
    let (ab, bc, ca) = (sub(b, a), sub(c, b), sub(a, c));
    let (u, v) = (sub(b, a), sub(c, a));
    let cross = [
        u[1] * v[2] - u[2] * v[1],
        u[2] * v[0] - u[0] * v[2],
        u[0] * v[1] - u[1] * v[0],
    ];
    let area2 = norm(&cross);
    if area2 == 0.0 {
        return f64::INFINITY;
    }
    norm(&ab) * norm(&bc) * norm(&ca) / (2.0 * area2)
}

/// Per junction of the planned path: the lateral acceleration vector
/// (see the module docs).
fn lateral(plan: &maxl::blocks::planner::Plan<3>) -> Vec<[f64; 3]> {
    plan.segments
        .windows(2)
        .map(|w| {
            let (a, b) = (&w[0], &w[1]);
            assert!(
                (a.profile.exit - b.profile.entry).abs() <= 1e-9 * (1.0 + a.profile.exit),
                "speed continuous at the junction"
            );
            let v = b.profile.entry;
            let r = circumradius(&a.start, &b.start, &b.end);
            let dw = sub(&b.dir, &a.dir);
            let n = norm(&dw);
            if n == 0.0 || r.is_infinite() {
                return [0.0; 3];
            }
            std::array::from_fn(|i| v * v / r * dw[i] / n)
        })
        .collect()
}

/// Plans `pts` (queued whole) and checks every junction's lateral and
/// every segment's tangential limits; returns the largest lateral
/// acceleration magnitude and that relative to its limit.
fn check_plan(pts: &[[f64; 3]], limits: &Limits<3>, vector: VectorLimits, feed: f64) -> (f64, f64) {
    let mut p = Planner::with_vector_limits(limits.clone(), vector, pts.len()).unwrap();
    p.set_position(pts[0]).unwrap();
    for q in &pts[1..] {
        p.line(*q, feed).unwrap();
    }
    let plan = p.plan();
    let (mut worst, mut worst_rel) = (0.0f64, 0.0f64);
    for a in lateral(&plan) {
        let m = norm(&a);
        worst = worst.max(m);
        worst_rel = worst_rel.max(m / vector.max_accel);
        assert!(m <= vector.max_accel * (1.0 + TOL), "lateral {m} mm/s²");
        for (i, (ai, lim)) in a.iter().zip(&limits.max_acc).enumerate() {
            worst_rel = worst_rel.max(ai.abs() / lim);
            assert!(
                ai.abs() <= lim * (1.0 + TOL),
                "axis {i}: lateral {ai} mm/s²"
            );
        }
    }
    for s in &plan.segments {
        let pr = &s.profile;
        assert!(pr.cruise <= vector.max_speed * (1.0 + TOL) && pr.cruise <= feed * (1.0 + TOL));
        assert!(pr.accel <= vector.max_accel * (1.0 + TOL));
        for i in 0..3 {
            assert!(pr.cruise * s.dir[i].abs() <= limits.max_vel[i] * (1.0 + TOL));
            assert!(pr.accel * s.dir[i].abs() <= limits.max_acc[i] * (1.0 + TOL));
        }
    }
    (worst, worst_rel)
}

fn per_axis(a: f64, jd: f64) -> Limits<3> {
    Limits::new([1000.0; 3], [a; 3], jd).unwrap()
}

#[test]
fn chorded_paths_stay_within_lateral_and_tangential_limits() {
    let jd_klipper = square_corner_deviation(5.0, 3000.0).unwrap();
    for (family, paths) in families() {
        for pts in &paths {
            for jd in [0.02, jd_klipper] {
                for feed in [100.0, 300.0, 500.0] {
                    // Per-axis limits only (the vector ones infinite).
                    check_plan(pts, &per_axis(3000.0, jd), VectorLimits::NONE, feed);
                    // Vector limits under generous per-axis ones, with and
                    // without Klipper's minimum cruise ratio.
                    for mcr in [0.0, KLIPPER_MIN_CRUISE_RATIO] {
                        let v = VectorLimits::new(400.0, 3000.0)
                            .unwrap()
                            .with_min_cruise_ratio(mcr)
                            .unwrap();
                        check_plan(pts, &per_axis(1e5, jd), v, feed);
                        // Both binding: per-axis 3000 and |a| 3000.
                        check_plan(pts, &per_axis(3000.0, jd), v, feed);
                    }
                }
            }
            let _ = family;
        }
    }
}

#[test]
fn worst_lateral_acceleration_report() {
    // `-- --nocapture` prints the largest lateral acceleration on the
    // chorded circles (radius 1–5 mm, chords 0.1–1 mm), feeds 100–500 mm/s.
    let jd_klipper = square_corner_deviation(5.0, 3000.0).unwrap();
    let circles = &families()[0].1;
    for (name, jd) in [("δ = 0.02 mm", 0.02), ("Klipper scv 5 mm/s", jd_klipper)] {
        let (mut axis, mut vec) = (0.0f64, 0.0f64);
        for pts in circles {
            for feed in [100.0, 200.0, 300.0, 500.0] {
                axis = axis.max(check_plan(pts, &per_axis(3000.0, jd), VectorLimits::NONE, feed).0);
                let v = VectorLimits::new(1000.0, 3000.0).unwrap();
                vec = vec.max(check_plan(pts, &per_axis(1e5, jd), v, feed).0);
            }
        }
        println!(
            "{name}: worst |a_lat| {axis:.0} mm/s² with 3000 mm/s² per axis (≤ 3000·√2 \
             in magnitude), {vec:.0} mm/s² with |a| ≤ 3000 mm/s²"
        );
        assert!(vec <= 3000.0 * (1.0 + TOL));
        assert!(axis <= 3000.0 * 2f64.sqrt() * (1.0 + TOL));
    }
}

#[test]
fn diagonal_runs_at_the_vector_limits() {
    // Per axis 300 mm/s and 3000 mm/s² alone let a 45° diagonal run at
    // 300·√2 and accelerate at 3000·√2; the vector limits hold it to 300
    // and 3000.
    let limits = Limits::new([300.0; 3], [3000.0; 3], 0.01).unwrap();
    let target = [200.0, 200.0, 0.0];
    let mut p = Planner::new(limits.clone()).unwrap();
    p.line(target, 1000.0).unwrap();
    let pr = p.plan().segments[0].profile;
    assert!((pr.cruise - 300.0 * 2f64.sqrt()).abs() < 1e-9);
    assert!((pr.accel - 3000.0 * 2f64.sqrt()).abs() < 1e-9);
    let v = VectorLimits::new(300.0, 3000.0).unwrap();
    let mut p = Planner::with_vector_limits(limits, v, 16).unwrap();
    p.line(target, 1000.0).unwrap();
    let plan = p.plan();
    let pr = plan.segments[0].profile;
    assert!((pr.cruise - 300.0).abs() < 1e-9 && (pr.accel - 3000.0).abs() < 1e-9);
    // Sampled at every 100 µs: |v| ≤ 300, |a| ≤ 3000.
    let mut t = 0;
    loop {
        let k = p.sample_kin(t).unwrap();
        assert!(norm(&k.vel) <= 300.0 * (1.0 + TOL));
        assert!(norm(&k.acc) <= 3000.0 * (1.0 + TOL));
        if p.is_idle() {
            break;
        }
        t += 100;
    }
    assert_eq!(p.sample(t).unwrap(), target);
}

#[test]
fn centripetal_limit_on_a_chorded_circle() {
    // Equal chords d on radius r: the junction speed is √(a·½·d·tan(θ/2))
    // = √(a·r·cos(φ/2)), φ the angle a chord spans, below the feed.
    let (r, chord, a) = (2.0, 0.1, 3000.0);
    let pts = circle(r, chord, 1.0);
    let v = VectorLimits::new(1000.0, a).unwrap();
    let mut p = Planner::with_vector_limits(per_axis(1e5, 0.05), v, pts.len()).unwrap();
    p.set_position(pts[0]).unwrap();
    for q in &pts[1..] {
        p.line(*q, 1000.0).unwrap();
    }
    let plan = p.plan();
    let d = norm(&sub(&pts[1], &pts[0]));
    let phi = 2.0 * (d / (2.0 * r)).asin();
    let want = (a * r * (phi / 2.0).cos()).sqrt();
    let mid = &plan.segments[plan.segments.len() / 2];
    assert!(
        (mid.junction_max - want).abs() < 1e-6 * want,
        "{} vs {want}",
        mid.junction_max
    );
    assert!((mid.profile.entry - want).abs() < 1e-6 * want);
}

#[test]
fn minimum_cruise_ratio_cruises_short_moves() {
    // One 10 mm move from rest to rest at a = 1000: without the ratio a
    // triangle peaking at √(a·L) = 100 mm/s; with ratio 0.5 the peak is
    // √(a·(1 − 0.5)·L) ≈ 70.7 mm/s and it cruises over half the length.
    let limits = Limits::new([1e4; 3], [1e6; 3], 0.01).unwrap();
    for (ratio, peak, cruise_len) in [(0.0, 100.0, 0.0), (0.5, 50f64.sqrt() * 10.0, 5.0)] {
        let v = VectorLimits::new(1000.0, 1000.0)
            .unwrap()
            .with_min_cruise_ratio(ratio)
            .unwrap();
        let mut p = Planner::with_vector_limits(limits.clone(), v, 4).unwrap();
        p.line([10.0, 0.0, 0.0], 500.0).unwrap();
        let pr = p.plan().segments[0].profile;
        assert!((pr.cruise - peak).abs() < 1e-9, "{ratio}: {pr:?}");
        assert!(
            (pr.t_cruise * pr.cruise - cruise_len).abs() < 1e-9,
            "{ratio}: {pr:?}"
        );
    }
}

/// Every planned profile covers its segment: the distance its ramps and
/// cruise cover at their speeds is the segment's length, and the exit of
/// each is the entry of the next.
fn check_profiles(plan: &maxl::blocks::planner::Plan<3>) {
    for s in &plan.segments {
        let p = &s.profile;
        let d = 0.5 * (p.entry + p.cruise) * p.t_acc
            + p.cruise * p.t_cruise
            + 0.5 * (p.cruise + p.exit) * p.t_dec;
        assert!(
            (d - p.length).abs() <= 1e-9 * (1.0 + p.length),
            "profile covers {d} of {}: {p:?}",
            p.length
        );
        assert!(
            p.entry <= p.cruise * (1.0 + 1e-12) + 1e-12 || p.t_acc > 0.0,
            "{p:?}"
        );
    }
    for w in plan.segments.windows(2) {
        assert!(
            (w[0].profile.exit - w[1].profile.entry).abs() <= 1e-9 * (1.0 + w[0].profile.exit),
            "{:?} then {:?}",
            w[0].profile,
            w[1].profile
        );
    }
}

/// Streams `pts` into a planner that keeps `depth` segments queued,
/// sampling every `step` µs, and checks every stamp: speed and
/// acceleration within the limits, speed changes within the acceleration
/// between stamps, positions moving as fast as the speeds say. Returns the
/// time to rest (µs).
fn stream(pts: &[[f64; 3]], p: &mut Planner<3>, depth: usize, feed: f64, step: u64) -> u64 {
    let (vmax, amax) = (p.vector_limits().max_speed, p.vector_limits().max_accel);
    let mut next = pts.iter().skip(1);
    let mut t = 0;
    let mut last: Option<maxl::blocks::planner::Kin<3>> = None;
    let dt = step as f64 * 1e-6;
    loop {
        while p.stats().pending < depth {
            match next.next() {
                Some(q) => {
                    p.line(*q, feed).unwrap();
                }
                None => break,
            }
        }
        let k = p.sample_kin(t).unwrap();
        check_profiles(&p.plan());
        let (v, a) = (norm(&k.vel), norm(&k.acc));
        assert!(
            v <= vmax * (1.0 + TOL) && v <= feed * (1.0 + TOL),
            "t {t}: |v| {v}"
        );
        assert!(a <= amax * (1.0 + TOL), "t {t}: |a| {a}");
        if let Some(l) = last {
            let dv = (v - norm(&l.vel)).abs();
            assert!(
                dv <= amax * dt * (1.0 + 1e-6) + 1e-9,
                "t {t}: speed jumps by {dv}"
            );
            let ds = norm(&sub(&k.pos, &l.pos));
            assert!(
                ds <= vmax.min(feed) * dt * (1.0 + 1e-6) + 1e-9,
                "t {t}: moved {ds}"
            );
        }
        last = Some(k);
        if p.is_idle() && next.len() == 0 {
            break;
        }
        t += step;
        assert!(t < 3_600_000_000, "runs to rest");
    }
    assert_eq!(p.tail(), *pts.last().unwrap());
    assert_eq!(last.unwrap().pos, *pts.last().unwrap());
    t
}

#[test]
fn streaming_keeps_the_limits_with_the_minimum_cruise_ratio() {
    // Segments start running while the queue is short, so the caps often
    // lower a started segment's exit below the lookahead's entry: the
    // rest of the queue is replanned from it.
    let mut rng = XorShiftStar(0x5EED_0FC0_FFEE);
    let mut pts = vec![[0.0; 3]];
    let mut heading = 0.0f64;
    for _ in 0..600 {
        heading += (rng.next() - 0.5) * 2.5;
        let len = 0.05 + 2.0 * rng.next() * rng.next();
        let q = *pts.last().unwrap();
        pts.push([q[0] + len * heading.cos(), q[1] + len * heading.sin(), 0.0]);
    }
    let e = pts[600];
    pts.extend(
        circle(3.0, 0.2, 1.0)[1..]
            .iter()
            .map(|q| [e[0] + q[0] - 3.0, e[1] + q[1], 0.0]),
    );
    let jd = square_corner_deviation(5.0, 2000.0).unwrap();
    for mcr in [0.0, 0.5, 0.9] {
        for depth in [2, 5, 30] {
            let v = VectorLimits::new(250.0, 2000.0)
                .unwrap()
                .with_min_cruise_ratio(mcr)
                .unwrap();
            let mut p = Planner::with_vector_limits(per_axis(1e5, jd), v, 64).unwrap();
            stream(&pts, &mut p, depth, 200.0, 500);
        }
    }
}

#[test]
fn streaming_sweep_keeps_every_profile_feasible() {
    // A deterministic sweep of short queues (1–6 segments ahead), random
    // stamps, random chords and turns and ratios 0.3–0.95: after every
    // sample, every planned profile (the running one too) covers exactly
    // its segment and joins the next at the same speed. (Without the
    // replanning from a started segment's capped exit, some of these cases
    // plan an exit the segment cannot reach.)
    let mut rng = XorShiftStar(12345);
    for case in 0..2000 {
        let mcr = [0.3, 0.5, 0.8, 0.95][case % 4];
        let v = VectorLimits::new(50.0 + 400.0 * rng.next(), 500.0 + 5000.0 * rng.next())
            .unwrap()
            .with_min_cruise_ratio(mcr)
            .unwrap();
        let limits = Limits::new([1e5; 3], [1e7; 3], 0.01 * rng.next()).unwrap();
        let mut p = Planner::with_vector_limits(limits, v, 64).unwrap();
        let depth = 1 + (rng.next() * 6.0) as usize;
        let step = 100 + (rng.next() * 3000.0) as u64;
        let (mut q, mut h, mut t) = ([0.0; 3], 0.0f64, 0);
        for _ in 0..150 {
            while p.stats().pending < depth {
                h += (rng.next() - 0.5) * 3.0 * rng.next();
                let l = 0.02 + 5.0 * rng.next().powi(3);
                q = [q[0] + l * h.cos(), q[1] + l * h.sin(), 0.0];
                p.line(q, 20.0 + 500.0 * rng.next()).unwrap();
            }
            p.sample(t).unwrap();
            t += step;
            check_profiles(&p.plan());
        }
    }
}

#[test]
fn vector_limits_change_while_running() {
    let pts = circle(5.0, 0.5, 3.0);
    let v = VectorLimits::new(300.0, 5000.0).unwrap();
    let mut p = Planner::with_vector_limits(per_axis(1e5, 0.01), v, pts.len()).unwrap();
    p.set_position(pts[0]).unwrap();
    for q in &pts[1..] {
        p.line(*q, 300.0).unwrap();
    }
    let mut t = 0;
    let mut last_v = 0.0;
    let mut changed = false;
    while !p.is_idle() {
        let k = p.sample_kin(t).unwrap();
        let v = norm(&k.vel);
        assert!((v - last_v).abs() <= 5000.0 * 500e-6 * (1.0 + 1e-6) + 1e-9);
        assert!(norm(&k.acc) <= 5000.0 * (1.0 + TOL));
        last_v = v;
        if !changed && t >= 60_000 {
            // Lower the speed (the path is faster there) and turn on the
            // minimum cruise ratio; acceleration unchanged.
            let lower = VectorLimits::new(100.0, 5000.0)
                .unwrap()
                .with_min_cruise_ratio(0.5)
                .unwrap();
            p.set_vector_limits(lower).unwrap();
            changed = true;
        }
        t += 500;
    }
    assert_eq!(p.sample(t).unwrap(), *pts.last().unwrap());
    // Settled under the new speed after braking.
    let plan_end = p.plan();
    assert!(plan_end.segments.is_empty());
}

// ---- degenerate input ----

#[test]
fn bad_vector_limits_are_refused() {
    for (s, a, r) in [
        (0.0, 1.0, 0.0),
        (-1.0, 1.0, 0.0),
        (f64::NAN, 1.0, 0.0),
        (1.0, 0.0, 0.0),
        (1.0, -5.0, 0.0),
        (1.0, f64::NAN, 0.0),
        (1.0, 1.0, -0.1),
        (1.0, 1.0, 1.0),
        (1.0, 1.0, f64::NAN),
        (1.0, 1.0, f64::INFINITY),
    ] {
        let v = VectorLimits {
            max_speed: s,
            max_accel: a,
            min_cruise_ratio: r,
            path_axes: 0,
            ..VectorLimits::NONE
        };
        assert!(
            matches!(v.validate(), Err(PlanError::InvalidLimit { .. })),
            "{v:?}"
        );
        assert!(VectorLimits::new(s, a)
            .and_then(|v| v.with_min_cruise_ratio(r))
            .is_err());
        let l = per_axis(100.0, 0.01);
        assert!(matches!(
            Planner::with_vector_limits(l.clone(), v, 8),
            Err(PlanError::InvalidLimit { .. })
        ));
        // Refused while running: nothing changes.
        let mut p = Planner::new(l).unwrap();
        p.line([1.0, 0.0, 0.0], 10.0).unwrap();
        let before = p.plan();
        assert!(matches!(
            p.set_vector_limits(v),
            Err(PlanError::InvalidLimit { .. })
        ));
        assert_eq!(p.plan(), before);
        assert_eq!(*p.vector_limits(), VectorLimits::NONE);
    }
    // Infinite speed and acceleration are "none"; ratio 0 is off.
    assert!(VectorLimits::new(f64::INFINITY, f64::INFINITY).is_ok());
    assert_eq!(VectorLimits::default(), VectorLimits::NONE);
    // Square-corner velocity: ≥ 0 and finite, at an acceleration > 0.
    let jd = square_corner_deviation(5.0, 3000.0).unwrap();
    assert!((jd - 25.0 * (2f64.sqrt() - 1.0) / 3000.0).abs() < 1e-15);
    assert_eq!(square_corner_deviation(0.0, 3000.0), Ok(0.0));
    for (scv, a) in [
        (-1.0, 1.0),
        (f64::NAN, 1.0),
        (f64::INFINITY, 1.0),
        (1.0, 0.0),
        (1.0, -1.0),
        (1.0, f64::INFINITY),
    ] {
        assert!(matches!(
            square_corner_deviation(scv, a),
            Err(PlanError::InvalidLimit { .. })
        ));
        assert!(per_axis(1.0, 0.1)
            .with_square_corner_velocity(scv, a)
            .is_err());
    }
    let l = per_axis(3000.0, 0.1)
        .with_square_corner_velocity(5.0, 3000.0)
        .unwrap();
    assert_eq!(l.junction_deviation, jd);
}

#[test]
fn degenerate_moves() {
    let v = VectorLimits::new(100.0, 1000.0)
        .unwrap()
        .with_min_cruise_ratio(0.5)
        .unwrap();
    let mut p = Planner::with_vector_limits(per_axis(1000.0, 0.02), v, 64).unwrap();
    // Zero-length (and sub-nanometre) moves queue nothing.
    assert_eq!(p.line([0.0; 3], 10.0), Ok(0));
    assert_eq!(p.line([1e-10, 0.0, 0.0], 10.0), Ok(0));
    assert!(p.is_idle());
    // Non-finite coordinates and overflowing lengths are refused.
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        for axis in 0..3 {
            let mut q = [1.0; 3];
            q[axis] = bad;
            assert_eq!(
                p.line(q, 10.0),
                Err(PlanError::NonFiniteCoordinate { axis })
            );
        }
    }
    assert_eq!(p.line([1e200, 0.0, 0.0], 10.0), Err(PlanError::MoveTooLong));
    assert_eq!(PlanError::MoveTooLong.code(), 10);
    p.set_position([-1.7e308, 0.0, 0.0]).unwrap();
    assert_eq!(
        p.line([1.7e308, 0.0, 0.0], 10.0),
        Err(PlanError::MoveTooLong)
    );
    let arc = Arc {
        end: [-1.7e308, 0.0, 0.0],
        plane: (0, 1),
        center: [0.0, 0.0],
        clockwise: false,
        chord_tolerance: 1e300,
    };
    assert!(p.arc(&arc, 10.0).is_err());
    assert!(p.is_idle() && p.stats().queued_total == 0);
    p.set_position([0.0; 3]).unwrap();
    // A 180° reversal: a full stop at the turn.
    p.line([10.0, 0.0, 0.0], 50.0).unwrap();
    p.line([0.0, 0.0, 0.0], 50.0).unwrap();
    let plan = p.plan();
    assert_eq!(plan.segments[0].junction_max, 0.0);
    assert_eq!(plan.segments[1].junction_max, 0.0);
    assert_eq!(plan.segments[0].profile.exit, 0.0);
    assert_eq!(plan.segments[1].profile.entry, 0.0);
    // A reversal of a diagonal, in 3D, on the same line.
    p.line([3.0, 4.0, 12.0], 50.0).unwrap();
    p.line([-3.0, -4.0, -12.0], 50.0).unwrap();
    assert_eq!(p.plan().segments[3].junction_max, 0.0);
    // Sampled to rest: the velocity passes through 0 at each reversal.
    let mut t = 0;
    while !p.is_idle() {
        p.sample_kin(t).unwrap();
        t += 1000;
    }
    assert_eq!(p.sample(t).unwrap(), [-3.0, -4.0, -12.0]);
}

#[test]
fn wire_set_vector_limits() {
    let mut b = PlannerBlock::new(
        300.0,
        300.0,
        20.0,
        3000.0,
        3000.0,
        200.0,
        0.02,
        f64::INFINITY,
    )
    .unwrap();
    assert_eq!(*b.planner().vector_limits(), VectorLimits::NONE);
    b.set_vector_limits(250.0, 2500.0, 0.5).unwrap();
    assert_eq!(
        *b.planner().vector_limits(),
        VectorLimits {
            max_speed: 250.0,
            max_accel: 2500.0,
            min_cruise_ratio: 0.5,
            path_axes: 0,
            ..VectorLimits::NONE
        }
    );
    b.set_vector_limits(f64::INFINITY, f64::INFINITY, 0.0)
        .unwrap();
    assert_eq!(*b.planner().vector_limits(), VectorLimits::NONE);
    let code = |e: PlanError| CallError::from(e);
    for bad in [
        (0.0, 1.0, 0.0),
        (1.0, -1.0, 0.0),
        (1.0, 1.0, 1.0),
        (f64::NAN, 1.0, 0.0),
    ] {
        assert_eq!(
            b.set_vector_limits(bad.0, bad.1, bad.2).map_err(code),
            Err(CallError::Failed(pipes_core::FailureCode::Other(1)))
        );
    }
    assert_eq!(*b.planner().vector_limits(), VectorLimits::NONE);
    // The diagonal through the wire: |v| ≤ 100 after setting it.
    b.set_vector_limits(100.0, 1000.0, 0.0).unwrap();
    b.line(100.0, 100.0, 0.0, 500.0).unwrap();
    assert!((b.planner().plan().segments[0].profile.cruise - 100.0).abs() < 1e-9);
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(200))]

    /// Random sequences of calls, degenerate ones among them: nothing
    /// panics, every refusal is a typed error, the plan stays continuous
    /// and within the limits, and sampling reaches rest at the tail.
    #[test]
    fn random_calls_never_panic(
        ops in proptest::collection::vec((0u8..8, proptest::array::uniform3(
            proptest::prop_oneof![
                6 => -20.0f64..20.0,
                1 => proptest::strategy::Just(0.0),
                1 => proptest::strategy::Just(f64::NAN),
                1 => proptest::strategy::Just(f64::INFINITY),
                1 => proptest::strategy::Just(1e300),
            ]), -1.0f64..600.0, -0.5f64..1.2), 1..80),
        accel in 10.0f64..50_000.0,
        axis_accel in 10.0f64..50_000.0,
    ) {
        let limits = Limits::new([200.0, 150.0, 30.0], [axis_accel; 3], 0.02).unwrap();
        let v = VectorLimits::new(250.0, accel).unwrap().with_min_cruise_ratio(0.3).unwrap();
        let mut p = Planner::with_vector_limits(limits, v, 40).unwrap();
        let mut t = 0u64;
        for (op, q, x, y) in ops {
            let r = match op {
                0..=2 => p.line(q, x).map(|_| ()),
                3 => p.arc(&Arc {
                    end: q,
                    plane: (0, 1),
                    center: [0.0, 0.0],
                    clockwise: x > 300.0,
                    chord_tolerance: 0.01,
                }, x).map(|_| ()),
                4 => p.set_vector_limits(VectorLimits {
                    max_speed: x,
                    max_accel: accel * y.abs().max(1e-3),
                    min_cruise_ratio: y,
                    path_axes: 0,
                    ..VectorLimits::NONE
                }),
                5 => p.set_feed_scale(y * 2.0).map(|_| ()),
                6 => p.halt().map(|_| ()),
                _ => {
                    t += (x.abs() * 100.0) as u64;
                    p.sample_kin(t).map(|k| {
                        assert!(k.pos.iter().all(|c| c.is_finite()));
                    })
                }
            };
            if let Err(e) = r {
                assert!((1..=10).contains(&e.code()), "{e}");
            }
            let plan = p.plan();
            check_profiles(&plan);
            for s in &plan.segments {
                proptest::prop_assert!(s.duration_us.is_finite() && s.duration_us >= 0.0);
            }
        }
        let mut n = 0;
        while !p.is_idle() {
            t += 2000;
            p.sample(t).unwrap();
            n += 1;
            proptest::prop_assert!(n < 10_000_000);
        }
        proptest::prop_assert_eq!(p.sample(t).unwrap(), p.tail());
    }
}
