//! Parity with Klipper's lookahead planner.
//!
//! `klipper` below is an independent reference model of Klipper's
//! `klippy/toolhead.py` (`Move.calc_junction`, `LookAheadQueue.flush`,
//! `Move.set_junction`), written from its documented formulas, in its own
//! terms (squared speeds, one forward chain at queueing, one backward and
//! one forward pass at the flush, the whole path flushed at once):
//!
//! - a move's speed limit is `min(feed, max_velocity)`, its acceleration
//!   `max_accel`, `delta_v2 = 2·L·accel`;
//! - junction deviation `δ = scv²·(√2 − 1)/max_accel`; with
//!   `cos θ = −u_prev·u_next`, `R = sin(θ/2)/(1 − sin(θ/2))`, the junction
//!   limit is `R·δ·accel` (v²), and the centripetal limit
//!   `½·L·accel·tan(θ/2)` for both the previous and the next move;
//! - `max_start_v2` also within the previous move's `max_start_v2 +
//!   delta_v2` and both moves' cruise limits;
//! - minimum cruise ratio: a second ("smoothed") lookahead at
//!   `max_accel·(1 − ratio)` (Klipper's `mcr_pseudo_accel`, formerly
//!   `max_accel_to_decel`); a move whose smoothed profile rises at its start
//!   cruises at most at the peak of its smoothed hill, one whose smoothed
//!   profile falls at most at the cruise of the move before;
//! - trapezoids from `(start, cruise, end)` with times `distance / mean
//!   speed`.
//!
//! Every generated path (circles of radius 1–5 mm in 0.1–1 mm chords,
//! spirals, zigzags, diagonals, long straight moves) is planned by both, at
//! several speeds, accelerations, square-corner velocities and minimum
//! cruise ratios, and maxl's total planned duration must match the model's
//! within 0.5 % (it matches to about 1e-13). The worst mismatch per family
//! is printed
//! (`cargo test -p maxl --features std --test planner_klipper -- --nocapture`).
//!
//! Checked once against Klipper's own `klippy/toolhead.py` too (its
//! `Move` and `LookAheadQueue`, run unmodified with stub modules, at
//! Klipper commit 84104bbbd): 168 plans of circles, a spiral, zigzags and
//! random polylines with z steps, at 3 velocity/acceleration pairs, square
//! corner velocities 1 and 5, ratios 0 and 0.5 and feeds 100 and 1000;
//! worst mismatch 9.7e-14 (docs/planner.md).

use maxl::blocks::planner::{
    square_corner_deviation, Limits, Planner, VectorLimits, KLIPPER_MIN_CRUISE_RATIO,
};

use std::f64::consts::{PI, TAU};

/// A Klipper `[printer]` configuration and the feed of every move.
#[derive(Clone, Copy, Debug)]
struct Config {
    max_velocity: f64,
    max_accel: f64,
    square_corner_velocity: f64,
    min_cruise_ratio: f64,
    feed: f64,
}

/// One move of the reference model (Klipper's `Move`).
struct KMove {
    d: f64,
    r: [f64; 3],
    accel: f64,
    max_cruise_v2: f64,
    delta_v2: f64,
    mcr_delta_v2: f64,
    max_start_v2: f64,
    max_mcr_start_v2: f64,
}

/// The planned times of one move: (start, cruise, end speed, duration).
type Planned = (f64, f64, f64, f64);

/// Klipper's plan of `pts` (the first point is the start), flushed whole.
fn klipper(pts: &[[f64; 3]], c: &Config) -> Vec<Planned> {
    let jd = c.square_corner_velocity.powi(2) * (2f64.sqrt() - 1.0) / c.max_accel;
    let pseudo_accel = c.max_accel * (1.0 - c.min_cruise_ratio);
    let velocity = c.feed.min(c.max_velocity);
    let mut moves: Vec<KMove> = Vec::new();
    for w in pts.windows(2) {
        let ad: Vec<f64> = (0..3).map(|i| w[1][i] - w[0][i]).collect();
        let d = ad.iter().map(|x| x * x).sum::<f64>().sqrt();
        assert!(d >= 1e-9, "the generators make no empty moves");
        let mut m = KMove {
            d,
            r: [ad[0] / d, ad[1] / d, ad[2] / d],
            accel: c.max_accel,
            max_cruise_v2: velocity * velocity,
            delta_v2: 2.0 * d * c.max_accel,
            mcr_delta_v2: 2.0 * d * pseudo_accel,
            max_start_v2: 0.0,
            max_mcr_start_v2: 0.0,
        };
        if let Some(p) = moves.last() {
            // calc_junction
            let mut max_start_v2 = m
                .max_cruise_v2
                .min(p.max_cruise_v2)
                .min(p.max_start_v2 + p.delta_v2);
            let cos_theta = -(m.r[0] * p.r[0] + m.r[1] * p.r[1] + m.r[2] * p.r[2]);
            let sin_d2 = (0.5 * (1.0 - cos_theta)).max(0.0).sqrt();
            let cos_d2 = (0.5 * (1.0 + cos_theta)).max(0.0).sqrt();
            let one_minus_sin_d2 = 1.0 - sin_d2;
            if one_minus_sin_d2 > 0.0 && cos_d2 > 0.0 {
                let r_jd = sin_d2 / one_minus_sin_d2;
                let move_jd_v2 = r_jd * jd * m.accel;
                let pmove_jd_v2 = r_jd * jd * p.accel;
                let quarter_tan_d2 = 0.25 * sin_d2 / cos_d2;
                let move_centripetal_v2 = m.delta_v2 * quarter_tan_d2;
                let pmove_centripetal_v2 = p.delta_v2 * quarter_tan_d2;
                max_start_v2 = max_start_v2
                    .min(move_jd_v2)
                    .min(pmove_jd_v2)
                    .min(move_centripetal_v2)
                    .min(pmove_centripetal_v2);
            }
            m.max_start_v2 = max_start_v2;
            m.max_mcr_start_v2 = max_start_v2.min(p.max_mcr_start_v2 + p.mcr_delta_v2);
        }
        moves.push(m);
    }
    // flush(lazy = false): backward pass.
    let n = moves.len();
    let mut info: Vec<(f64, Option<f64>, f64)> = vec![(0.0, None, 0.0); n];
    let (mut next_start_v2, mut next_mcr_start_v2, mut peak_cruise_v2) = (0.0, 0.0, 0.0);
    let mut pending = 0;
    for i in (0..n).rev() {
        let m = &moves[i];
        let reachable_start_v2 = next_start_v2 + m.delta_v2;
        let start_v2 = m.max_start_v2.min(reachable_start_v2);
        let mut cruise_v2 = None;
        pending += 1;
        let reach_mcr_start_v2 = next_mcr_start_v2 + m.mcr_delta_v2;
        let mcr_start_v2 = m.max_mcr_start_v2.min(reach_mcr_start_v2);
        if mcr_start_v2 < reach_mcr_start_v2 {
            if mcr_start_v2 + m.mcr_delta_v2 > next_mcr_start_v2 || pending > 1 {
                peak_cruise_v2 = (mcr_start_v2 + reach_mcr_start_v2) * 0.5;
            }
            cruise_v2 = Some(
                ((start_v2 + reachable_start_v2) * 0.5)
                    .min(m.max_cruise_v2)
                    .min(peak_cruise_v2),
            );
            pending = 0;
        }
        info[i] = (start_v2, cruise_v2, next_start_v2);
        next_start_v2 = start_v2;
        next_mcr_start_v2 = mcr_start_v2;
    }
    // Forward pass: propagate cruise_v2, set_junction.
    let mut prev_cruise_v2: f64 = 0.0;
    let mut out = Vec::with_capacity(n);
    for (m, &(start_v2, cruise_v2, next_start_v2)) in moves.iter().zip(&info) {
        let cruise_v2 = cruise_v2.unwrap_or_else(|| prev_cruise_v2.min(start_v2));
        let (s2, e2) = (start_v2.min(cruise_v2), next_start_v2.min(cruise_v2));
        let half_inv_accel = 0.5 / m.accel;
        let accel_d = (cruise_v2 - s2) * half_inv_accel;
        let decel_d = (cruise_v2 - e2) * half_inv_accel;
        let cruise_d = m.d - accel_d - decel_d;
        let (sv, cv, ev) = (s2.sqrt(), cruise_v2.sqrt(), e2.sqrt());
        let t = accel_d / ((sv + cv) * 0.5) + cruise_d / cv + decel_d / ((ev + cv) * 0.5);
        out.push((sv, cv, ev, t));
        prev_cruise_v2 = cruise_v2;
    }
    out
}

/// maxl's plan of the same path: vector limits from the configuration,
/// per-axis limits far above them.
fn maxl_plan(pts: &[[f64; 3]], c: &Config) -> maxl::blocks::planner::Plan<3> {
    let jd = square_corner_deviation(c.square_corner_velocity, c.max_accel).unwrap();
    let limits = Limits::new([1e6; 3], [1e8; 3], jd).unwrap();
    let vector = VectorLimits::new(c.max_velocity, c.max_accel)
        .and_then(|v| v.with_min_cruise_ratio(c.min_cruise_ratio))
        .unwrap();
    let mut p = Planner::with_vector_limits(limits, vector, pts.len()).unwrap();
    p.set_position(pts[0]).unwrap();
    for q in &pts[1..] {
        assert_eq!(p.line(*q, c.feed).unwrap(), 1);
    }
    p.plan()
}

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

/// An Archimedean spiral from radius `r0` to `r1`, chords of about `chord`.
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

/// A zigzag of `n` legs of length `leg` alternating ±`angle` from +x.
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

/// Raster hatching: rows of `chord` chords, `pitch` apart.
fn raster(w: f64, rows: usize, pitch: f64, chord: f64) -> Vec<[f64; 3]> {
    let per_row = (w / chord).round() as usize;
    let mut pts = Vec::new();
    for r in 0..rows {
        for k in 0..=per_row {
            let x = k as f64 * chord;
            pts.push([if r % 2 == 0 { x } else { w - x }, r as f64 * pitch, 0.0]);
        }
    }
    pts
}

/// A straight line from `a` to `b` in `n` equal pieces.
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
    for r in [1.0, 1.5, 2.0, 3.0, 5.0] {
        for chord in [0.1, 0.2, 0.5, 1.0] {
            circles.push(circle(r, chord, 2.0));
        }
    }
    let spirals = vec![
        spiral(0.5, 10.0, 1.0, 0.2),
        spiral(10.0, 0.5, 1.0, 0.5),
        spiral(1.0, 30.0, 2.0, 1.0),
        spiral(0.3, 5.0, 0.4, 0.1),
    ];
    let zigzags = vec![
        zigzag(40, 1.0, PI / 3.0),
        zigzag(40, 3.0, PI / 4.0),
        zigzag(60, 0.5, 1.4),
        zigzag(30, 10.0, 0.2),
        raster(20.0, 10, 1.0, 0.2),
        raster(50.0, 6, 0.5, 5.0),
    ];
    let diagonals = vec![
        line([0.0; 3], [50.0, 50.0, 0.0], 1),
        line([0.0; 3], [30.0, 17.3, 5.0], 1),
        line([0.0; 3], [20.0, 20.0, 0.0], 200),
        vec![
            [0.0; 3],
            [20.0, 20.0, 0.0],
            [40.0, 0.0, 0.0],
            [20.0, -20.0, 0.0],
            [0.0, 0.0, 0.0],
        ],
        vec![
            [0.0; 3],
            [10.0, 10.0, 10.0],
            [20.0, 0.0, 0.0],
            [0.0, 0.0, 0.0],
        ],
    ];
    let straights = vec![
        line([0.0; 3], [200.0, 0.0, 0.0], 1),
        line([0.0; 3], [200.0, 0.0, 0.0], 20),
        line([0.0; 3], [0.0, 100.0, 0.0], 1000),
        vec![
            [0.0; 3],
            [100.0, 0.0, 0.0],
            [0.0, 0.0, 0.0],
            [0.0, 80.0, 0.0],
        ],
    ];
    vec![
        ("circles", circles),
        ("spirals", spirals),
        ("zigzags", zigzags),
        ("diagonals", diagonals),
        ("straight", straights),
    ]
}

fn configs() -> Vec<Config> {
    let mut out = Vec::new();
    for (max_velocity, max_accel) in [(300.0, 3000.0), (500.0, 10_000.0), (150.0, 1000.0)] {
        for scv in [5.0, 1.0] {
            for min_cruise_ratio in [0.0, KLIPPER_MIN_CRUISE_RATIO, 0.8] {
                for feed in [100.0, 1000.0] {
                    out.push(Config {
                        max_velocity,
                        max_accel,
                        square_corner_velocity: scv,
                        min_cruise_ratio,
                        feed,
                    });
                }
            }
        }
    }
    out
}

#[test]
fn model_is_consistent() {
    // The reference model's own sanity: speeds join at every junction,
    // stay within the limits, and the path starts and ends at rest.
    for (_, paths) in families() {
        for pts in paths {
            for c in configs() {
                let k = klipper(&pts, &c);
                assert_eq!(k[0].0, 0.0);
                assert!(k.last().unwrap().2 < 1e-6);
                for w in k.windows(2) {
                    assert!((w[0].2 - w[1].0).abs() <= 1e-9 * (1.0 + w[0].2), "{w:?}");
                }
                for m in &k {
                    assert!(m.1 <= c.feed.min(c.max_velocity) * (1.0 + 1e-12));
                    assert!(m.3.is_finite() && m.3 > 0.0);
                }
            }
        }
    }
}

#[test]
fn durations_match_klipper_within_one_percent() {
    let mut report = Vec::new();
    for (family, paths) in families() {
        let mut worst = (0.0f64, String::new());
        let mut worst_mcr0 = 0.0f64;
        let mut count = 0;
        for pts in &paths {
            for c in configs() {
                let k: f64 = klipper(pts, &c).iter().map(|m| m.3).sum();
                let plan = maxl_plan(pts, &c);
                let m = plan.duration_us() * 1e-6;
                let rel = (m - k).abs() / k;
                count += 1;
                if c.min_cruise_ratio == 0.0 {
                    worst_mcr0 = worst_mcr0.max(rel);
                }
                if rel > worst.0 || worst.1.is_empty() {
                    worst = (
                        rel,
                        format!("{} points, {c:?}: maxl {m} s, Klipper {k} s", pts.len()),
                    );
                }
                assert!(
                    rel <= 0.005,
                    "{family}: {} points, {c:?}: maxl {m} s vs Klipper {k} s",
                    pts.len()
                );
            }
        }
        report.push(format!(
            "{family:9}: {count} plans, worst |maxl − Klipper| / Klipper = {:.2e} (ratio 0 only: {:.2e}); {}",
            worst.0, worst_mcr0, worst.1
        ));
    }
    for r in report {
        println!("{r}");
    }
}

#[test]
fn junction_and_cruise_speeds_match_klipper() {
    // Beyond the totals: every move's entry, peak and exit speeds.
    for (family, paths) in families() {
        for pts in &paths {
            for c in configs() {
                let k = klipper(pts, &c);
                let plan = maxl_plan(pts, &c);
                assert_eq!(plan.segments.len(), k.len());
                for (i, (s, m)) in plan.segments.iter().zip(&k).enumerate() {
                    let p = &s.profile;
                    let tol = 1e-6 * (1.0 + m.1);
                    let ok = (p.entry - m.0).abs() <= tol
                        && (p.exit - m.2).abs() <= tol
                        && (p.cruise - m.1).abs() <= tol
                        && (s.duration_us * 1e-6 - m.3).abs() <= 1e-6 * m.3 + 1e-9;
                    assert!(
                        ok,
                        "{family}, {} points, move {i}, {c:?}: maxl {:?} vs Klipper {m:?}",
                        pts.len(),
                        (p.entry, p.cruise, p.exit, s.duration_us * 1e-6)
                    );
                }
            }
        }
    }
}

/// A random polyline: steps of `len` turning by `turn` (radians) in the
/// plane, some with a z component.
fn polyline(steps: &[(f64, f64, f64)]) -> Vec<[f64; 3]> {
    let mut p = [0.0; 3];
    let mut heading = 0.0f64;
    let mut pts = vec![p];
    for &(len, turn, dz) in steps {
        heading += turn;
        p[0] += len * heading.cos();
        p[1] += len * heading.sin();
        p[2] += dz;
        pts.push(p);
    }
    pts
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(300))]

    /// Random paths (short and long steps, gentle turns to reversals) and
    /// random configurations: maxl's incremental lookahead (each append
    /// replanning only what can change) gives Klipper's whole-path plan,
    /// move by move; and replanning the whole queue changes nothing.
    #[test]
    fn random_paths_match_klipper(
        steps in proptest::collection::vec(
            // Any turn, and exact reversals.
            (0.01f64..5.0, proptest::prop_oneof![
                8 => -3.2f64..3.2,
                1 => proptest::strategy::Just(PI),
                1 => proptest::strategy::Just(-PI),
            ], proptest::prop_oneof![
                3 => proptest::strategy::Just(0.0),
                1 => -1.0f64..1.0,
            ]),
            1..120,
        ),
        accel in 200.0f64..20_000.0,
        velocity in 20.0f64..600.0,
        feed in 5.0f64..800.0,
        scv in 0.0f64..15.0,
        mcr in proptest::prop_oneof![
            1 => proptest::strategy::Just(0.0),
            2 => 0.0f64..0.95,
        ],
    ) {
        let pts = polyline(&steps);
        let c = Config {
            max_velocity: velocity,
            max_accel: accel,
            square_corner_velocity: scv,
            min_cruise_ratio: mcr,
            feed,
        };
        let k = klipper(&pts, &c);
        let plan = maxl_plan(&pts, &c);
        let total_k: f64 = k.iter().map(|m| m.3).sum();
        let total_m = plan.duration_us() * 1e-6;
        // At an exact reversal Klipper's rounding (|u| = 1 ± 1 ulp) leaves a
        // junction speed of up to ~1e-3 mm/s where maxl stops: 5 µm/s of
        // slack on speeds, 1e-4 on totals (the families above match to
        // 1e-13).
        proptest::prop_assert!((total_m - total_k).abs() <= 1e-4 * total_k, "{total_m} vs {total_k}");
        for (i, (s, m)) in plan.segments.iter().zip(&k).enumerate() {
            let p = &s.profile;
            let tol = 1e-6 * (1.0 + m.1) + 5e-3;
            proptest::prop_assert!(
                (p.entry - m.0).abs() <= tol && (p.exit - m.2).abs() <= tol
                    && (p.cruise - m.1).abs() <= tol,
                "move {}: maxl {:?} vs Klipper {:?}", i, (p.entry, p.cruise, p.exit), m
            );
        }
        // A full replan (the feed scale's) of the same queue.
        let jd = square_corner_deviation(scv, accel).unwrap();
        let limits = Limits::new([1e6; 3], [1e8; 3], jd).unwrap();
        let vector = VectorLimits::new(velocity, accel).unwrap().with_min_cruise_ratio(mcr).unwrap();
        let mut p = Planner::with_vector_limits(limits, vector, pts.len()).unwrap();
        for q in &pts[1..] {
            p.line(*q, feed).unwrap();
        }
        p.set_feed_scale(1.0).unwrap();
        let again = p.plan().duration_us() * 1e-6;
        proptest::prop_assert!((again - total_m).abs() <= 1e-9 * total_m, "{again} vs {total_m}");
    }
}
