//! Toolhead axes and following axes (an extruder, a rotary table): the
//! path's length and feed are the toolhead's, the vector limits bound the
//! toolhead only, a move of the following axes alone runs within their own
//! limits, and the two kinds of move meet at rest, as Klipper plans an
//! extruder. Six axes plan together.

use maxl::blocks::planner::{Limits, Planner, VectorLimits};

const DT_US: u64 = 1_000;

/// x, y, z and e: a 300 mm/s, 3 000 mm/s² toolhead; e at 40 mm/s and
/// 1 000 mm/s², its velocity jump at a corner held to 1 mm/s (Klipper's
/// `instantaneous_corner_velocity`).
fn printer() -> Planner<4> {
    let limits = Limits::new(
        [300.0, 300.0, 10.0, 40.0],
        [3000.0, 3000.0, 100.0, 1000.0],
        0.02,
    )
    .unwrap()
    .with_max_jump([f64::INFINITY, f64::INFINITY, f64::INFINITY, 1.0])
    .unwrap();
    let vector = VectorLimits::new(200.0, 2000.0).unwrap().with_path_axes(3);
    Planner::with_vector_limits(limits, vector, 64).unwrap()
}

/// Samples every millisecond until rest: (stamp, position).
fn run<const N: usize>(p: &mut Planner<N>) -> Vec<(u64, [f64; N])> {
    let mut out = Vec::new();
    let mut t = 0;
    loop {
        out.push((t, p.sample(t).unwrap()));
        if p.is_idle() {
            return out;
        }
        t += DT_US;
    }
}

/// Largest speed of axis `i` between samples.
fn peak_speed<const N: usize>(s: &[(u64, [f64; N])], i: usize) -> f64 {
    s.windows(2)
        .map(|w| (w[1].1[i] - w[0].1[i]).abs() / ((w[1].0 - w[0].0) as f64 * 1e-6))
        .fold(0.0, f64::max)
}

#[test]
fn an_extruding_move_runs_at_the_toolheads_feed_and_the_extruder_follows() {
    let mut p = printer();
    // 100 mm of x laying 3.3 mm of filament (a 0.45 × 0.2 mm line of
    // 1.75 mm filament) at 50 mm/s.
    p.line([100.0, 0.0, 0.0, 3.3], 50.0).unwrap();
    let plan = p.plan();
    let seg = &plan.segments[0];
    assert!((seg.profile.length - 100.0).abs() < 1e-12, "{seg:?}");
    assert!((seg.profile.cruise - 50.0).abs() < 1e-12, "{seg:?}");
    assert!((seg.dir[0] - 1.0).abs() < 1e-15 && (seg.dir[3] - 0.033).abs() < 1e-15);
    let s = run(&mut p);
    assert!((peak_speed(&s, 0) - 50.0).abs() < 1e-6);
    assert!((peak_speed(&s, 3) - 50.0 * 0.033).abs() < 1e-6);
    assert_eq!(s.last().unwrap().1, [100.0, 0.0, 0.0, 3.3]);
}

#[test]
fn the_vector_limits_bound_the_toolhead_and_not_a_retraction() {
    let mut p = printer();
    // Asked for 500 mm/s: the toolhead's 200 holds it.
    p.line([100.0, 0.0, 0.0, 0.0], 500.0).unwrap();
    assert!((p.plan().segments[0].profile.cruise - 200.0).abs() < 1e-12);
    let s = run(&mut p);
    assert!(peak_speed(&s, 0) <= 200.0 + 1e-6);

    // A 0.8 mm retraction at 35 mm/s: e's own 40 mm/s and 1 000 mm/s²,
    // not the toolhead's; at 60 mm/s, e's 40.
    let mut p = printer();
    p.line([0.0, 0.0, 0.0, -0.8], 35.0).unwrap();
    let seg = p.plan().segments[0].clone();
    assert!((seg.profile.length - 0.8).abs() < 1e-12 && seg.dir[3] == -1.0);
    assert!(seg.profile.accel == 1000.0, "{seg:?}");
    assert!(seg.profile.cruise <= 35.0 + 1e-12);
    let mut p = printer();
    p.line([0.0, 0.0, 0.0, -20.0], 60.0).unwrap();
    assert!((p.plan().segments[0].profile.cruise - 40.0).abs() < 1e-12);
    // An extruding move whose extruder would pass its 40 mm/s: slowed
    // for it (0.5 mm of e per mm of x at 100 mm/s would be 50 mm/s).
    let mut p = printer();
    p.line([10.0, 0.0, 0.0, 5.0], 100.0).unwrap();
    assert!((p.plan().segments[0].profile.cruise - 80.0).abs() < 1e-9);
}

#[test]
fn a_retraction_meets_the_print_moves_at_rest() {
    let mut p = printer();
    p.line([50.0, 0.0, 0.0, 1.65], 60.0).unwrap();
    p.line([50.0, 0.0, 0.0, 0.85], 35.0).unwrap();
    p.line([80.0, 30.0, 0.0, 0.85], 150.0).unwrap();
    let plan = p.plan();
    assert_eq!(plan.segments.len(), 3);
    assert_eq!(plan.segments[1].profile.entry, 0.0);
    assert_eq!(plan.segments[2].profile.entry, 0.0);
}

#[test]
fn the_extruders_jump_at_a_corner_is_held_to_its_max_jump() {
    let mut p = printer();
    // Straight on in x, the extrusion ratio changing from 0.033 to 0.066
    // mm/mm: e's velocity jumps by v · 0.033 at the junction, so v ≤ 1 /
    // 0.033 = 30.3 mm/s.
    p.line([50.0, 0.0, 0.0, 1.65], 100.0).unwrap();
    p.line([100.0, 0.0, 0.0, 4.95], 100.0).unwrap();
    p.line([150.0, 0.0, 0.0, 8.25], 100.0).unwrap();
    let j = p.plan().segments[1].profile.entry;
    assert!((j - 1.0 / 0.033).abs() < 1e-9, "{j}");
    // The same ratio both sides: full speed straight through.
    let j = p.plan().segments[2].profile.entry;
    assert!((j - 100.0).abs() < 1e-9, "{j}");
}

#[test]
fn six_axes_plan_together() {
    // x, y, z and a, b, c (degrees) on a five-axis mill with a tool
    // changer carousel: a helix of the toolhead while three rotaries turn.
    let limits = Limits::new(
        [100.0, 100.0, 20.0, 90.0, 90.0, 360.0],
        [1000.0, 1000.0, 200.0, 900.0, 900.0, 3600.0],
        0.01,
    )
    .unwrap();
    let vector = VectorLimits::new(100.0, 1000.0).unwrap().with_path_axes(3);
    let mut p = Planner::<6>::with_vector_limits(limits, vector, 64).unwrap();
    let targets = [
        [10.0, 0.0, -1.0, 30.0, 0.0, 0.0],
        [10.0, 10.0, -2.0, 30.0, 45.0, 0.0],
        [0.0, 10.0, -3.0, 0.0, 45.0, 180.0],
        [0.0, 0.0, -3.0, 0.0, 0.0, 180.0],
        [0.0, 0.0, -3.0, 0.0, 0.0, 0.0],
    ];
    for t in targets {
        p.line(t, 80.0).unwrap();
    }
    let s = run(&mut p);
    assert_eq!(s.last().unwrap().1, targets[4]);
    for (i, limit) in [100.0, 100.0, 20.0, 90.0, 90.0, 360.0].iter().enumerate() {
        let v = peak_speed(&s, i);
        assert!(v <= limit * (1.0 + 1e-6), "axis {i}: {v} > {limit}");
        assert!(v > 0.0, "axis {i} never moved");
    }
    // Each target is passed through (within the samples' spacing of it).
    for t in &targets[..4] {
        let near = s
            .iter()
            .map(|(_, q)| {
                q.iter()
                    .zip(t)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max)
            })
            .fold(f64::INFINITY, f64::min);
        assert!(near < 0.4, "{t:?}: {near}");
    }
}
