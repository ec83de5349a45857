//! The lookahead planner: limits at every stamp, junction speeds, endpoints,
//! rest at the end, feeding while running, arcs, bad input.

mod common;

use common::rng::XorShiftStar;
use maxl::blocks::planner::{Arc, Limits, PlanError, Planner, PlannerBlock, WIRE_CHORD_TOLERANCE};
use pipes_core::class::PipesClass;
use pipes_core::export::INPUT_DECODE_FAILED;
use pipes_core::function::CallError;
use pipes_core::Value;

const STEP: u64 = 1024;

fn iso(v: f64, a: f64, jd: f64) -> Limits<3> {
    Limits::new([v; 3], [a; 3], jd).unwrap()
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f64>().sqrt()
}

/// Samples until idle; returns the stamp after the last.
fn run_to_rest(
    p: &mut Planner<3>,
    mut t: u64,
    mut each: impl FnMut(u64, &maxl::blocks::planner::Kin<3>),
) -> u64 {
    for _ in 0..10_000_000 {
        let k = p.sample_kin(t).unwrap();
        each(t, &k);
        if p.is_idle() {
            return t;
        }
        t += STEP;
    }
    panic!("planner never came to rest");
}

#[test]
fn limits_hold_at_every_stamp_on_a_random_path() {
    let limits = Limits::new([300.0, 150.0, 20.0], [3000.0, 1500.0, 200.0], 0.05).unwrap();
    let mut p = Planner::new(limits.clone()).unwrap();
    let mut rng = XorShiftStar(0x1234_5678);
    let mut pos = [0.0; 3];
    let mut ends = Vec::new();
    for _ in 0..400 {
        for c in pos.iter_mut() {
            *c += (rng.next() - 0.5) * 6.0;
        }
        p.line(pos, 50.0 + 400.0 * rng.next()).unwrap();
        ends.push(pos);
    }
    // Check the whole plan against the limits.
    p.start(1 << 30).unwrap();
    let plan = p.plan();
    assert_eq!(plan.segments.len(), 400);
    for s in &plan.segments {
        let pr = &s.profile;
        assert!(pr.entry <= s.junction_max + 1e-9, "{s:?}");
        assert!(pr.cruise >= pr.entry - 1e-9 && pr.cruise >= pr.exit - 1e-9);
        for i in 0..3 {
            assert!(pr.cruise * s.dir[i].abs() <= limits.max_vel[i] * (1.0 + 1e-9));
            assert!(pr.accel * s.dir[i].abs() <= limits.max_acc[i] * (1.0 + 1e-9));
        }
    }
    // The incremental passes give the optimum a full recomputation gives:
    // entries as high as the junction, reaching rest at the tail, and
    // accelerating from the start allow.
    let segs = &plan.segments;
    let reach = |v: f64, s: &maxl::blocks::planner::PlannedSegment<3>| {
        (v * v + 2.0 * s.profile.accel * s.profile.length).sqrt()
    };
    let mut back = vec![0.0; segs.len() + 1];
    for i in (0..segs.len()).rev() {
        back[i] = segs[i].junction_max.min(reach(back[i + 1], &segs[i]));
    }
    let mut v = 0.0;
    for (i, s) in segs.iter().enumerate() {
        if i > 0 {
            v = back[i].min(reach(v, &segs[i - 1]));
        }
        assert!((s.profile.entry - v).abs() < 1e-9, "segment {i}");
    }
    // Adjacent segments meet at the same speed and time.
    for w in plan.segments.windows(2) {
        assert!((w[0].profile.exit - w[1].profile.entry).abs() < 1e-9);
        assert!((w[0].end_us() - w[1].start_us).abs() < 1e-6);
    }
    assert_eq!(plan.segments.last().unwrap().profile.exit, 0.0);

    // Sampled at the stamps: velocity and acceleration within limits, and
    // every stamp's position agrees with the plan made before running.
    let mut n = 0;
    let t_end = run_to_rest(&mut p, 1 << 30, |t, k| {
        n += 1;
        for i in 0..3 {
            assert!(k.vel[i].abs() <= limits.max_vel[i] * (1.0 + 1e-9), "{k:?}");
            assert!(k.acc[i].abs() <= limits.max_acc[i] * (1.0 + 1e-9), "{k:?}");
        }
        let want = plan.state_at(t as f64);
        assert!(dist(want.pos, k.pos) < 1e-6, "t {t}: {want:?} vs {k:?}");
    });
    assert!(n > 100);
    let st = p.stats();
    assert_eq!((st.queued_total, st.executed, st.pending), (400, 400, 0));
    assert!(st.idle);
    assert!(dist(p.sample(t_end + STEP).unwrap(), *ends.last().unwrap()) < 1e-12);
}

#[test]
fn path_visits_every_endpoint_and_ends_at_rest() {
    let mut p = Planner::new(iso(200.0, 2000.0, 0.02)).unwrap();
    let pts = [
        [10.0, 0.0, 0.0],
        [10.0, 10.0, 0.0],
        [0.0, 10.0, 1.0],
        [5.0, 5.0, 1.0],
        [5.0, 5.0, 3.0],
        [0.0, 0.0, 0.0],
    ];
    for q in pts {
        assert_eq!(p.line(q, 150.0).unwrap(), 1);
    }
    let plan = p.plan();
    // Each segment ends where planned, and the planned state at each
    // segment's end time is its end point.
    for (s, q) in plan.segments.iter().zip(pts) {
        assert_eq!(s.end, q);
        assert!(dist(plan.state_at(s.end_us() - 1e-3).pos, q) < 1e-3);
    }
    let last = plan.segments.last().unwrap();
    assert_eq!(last.profile.exit, 0.0);
    let k = plan.state_at(last.end_us() + 10.0);
    assert_eq!(k.vel, [0.0; 3]);
    // Sampled, the position passes close to each endpoint (within the
    // distance covered in one stamp at the junction speed).
    let mut closest = [f64::INFINITY; 6];
    run_to_rest(&mut p, 0, |_, k| {
        for (c, q) in closest.iter_mut().zip(pts) {
            *c = c.min(dist(k.pos, q));
        }
    });
    for (i, s) in plan.segments.iter().enumerate() {
        let v = s.profile.exit;
        assert!(
            closest[i] <= v * STEP as f64 * 1e-6 + 1e-9,
            "endpoint {i}: {} (exit {v})",
            closest[i]
        );
    }
    assert_eq!(p.sample(u64::MAX / 2).unwrap(), [0.0; 3]);
}

fn junction(a: [f64; 3], b: [f64; 3], limits: Limits<3>) -> f64 {
    let mut p = Planner::new(limits).unwrap();
    p.line(a, 100.0).unwrap();
    p.line(b, 100.0).unwrap();
    let plan = p.plan();
    assert_eq!(
        plan.segments[0].profile.exit,
        plan.segments[1].profile.entry
    );
    plan.segments[1].profile.entry
}

#[test]
fn junction_speeds_on_known_angles() {
    let (a, d) = (1000.0, 0.05);
    // 90°: v = sqrt(a_j δ sin(θ/2) / (1 − sin(θ/2))), θ/2 = 45°, where a_j
    // is the acceleration along the velocity change (−1, 1)/√2 that keeps
    // each axis within a: a·√2.
    let s = 0.5f64.sqrt();
    let v90 = (a * 2f64.sqrt() * d * s / (1.0 - s)).sqrt();
    let got = junction([100.0, 0.0, 0.0], [100.0, 100.0, 0.0], iso(500.0, a, d));
    assert!((got - v90).abs() < 1e-9, "{got} vs {v90}");
    // Collinear: the feed.
    let got = junction([100.0, 0.0, 0.0], [200.0, 0.0, 0.0], iso(500.0, a, d));
    assert!((got - 100.0).abs() < 1e-9, "{got}");
    // Reversal: a stop.
    let got = junction([100.0, 0.0, 0.0], [50.0, 0.0, 0.0], iso(500.0, a, d));
    assert_eq!(got, 0.0);
    // Zero deviation stops at a corner.
    let got = junction([100.0, 0.0, 0.0], [100.0, 100.0, 0.0], iso(500.0, a, 0.0));
    assert_eq!(got, 0.0);
    // A per-axis jump limit: at 90° each of x and y changes by v.
    let l = iso(500.0, a, d).with_max_jump([5.0; 3]).unwrap();
    let got = junction([100.0, 0.0, 0.0], [100.0, 100.0, 0.0], l);
    assert!((got - 5.0).abs() < 1e-9, "{got}");
    // Anisotropic: the corner's acceleration is that along (−1, 1)/√2,
    // limited by the slower axis: min(ax, ay)·√2.
    let l = Limits::new([500.0; 3], [2000.0, 500.0, 500.0], d).unwrap();
    let got = junction([100.0, 0.0, 0.0], [100.0, 100.0, 0.0], l);
    let want = (500.0 * 2f64.sqrt() * d * s / (1.0 - s)).sqrt();
    assert!((got - want).abs() < 1e-9, "{got} vs {want}");
}

#[test]
fn anisotropic_segment_limits() {
    // CoreXY-like: x twice as fast as y. A diagonal is limited by y.
    let l = Limits::new([400.0, 200.0, 10.0], [4000.0, 2000.0, 100.0], 0.05).unwrap();
    let mut p = Planner::new(l).unwrap();
    p.line([1000.0, 1000.0, 0.0], 10_000.0).unwrap();
    let pr = p.plan().segments[0].profile;
    let s2 = 2f64.sqrt();
    assert!((pr.cruise - 200.0 * s2).abs() < 1e-9, "{pr:?}");
    assert!((pr.accel - 2000.0 * s2).abs() < 1e-9, "{pr:?}");
    // The feed caps it too.
    p.line([2000.0, 1000.0, 0.0], 50.0).unwrap();
    assert!((p.plan().segments[1].profile.cruise - 50.0).abs() < 1e-12);
}

#[test]
fn feeding_while_running() {
    let limits = iso(200.0, 2000.0, 0.05);
    let mut p = Planner::new(limits).unwrap();
    let mut rng = XorShiftStar(99);
    let mut pos = [0.0; 3];
    let mut t = 5_000_000;
    let mut queued = 0u64;
    let mut last = p.sample(t).unwrap();
    // Keep 3 to 8 segments ahead; sample between appends.
    while queued < 300 {
        while p.stats().pending < 8 && queued < 300 {
            pos[0] += 1.0 + 3.0 * rng.next();
            pos[1] += (rng.next() - 0.5) * 4.0;
            p.line(pos, 150.0).unwrap();
            queued += 1;
        }
        for _ in 0..(1 + (rng.next() * 20.0) as usize) {
            t += STEP;
            let k = p.sample_kin(t).unwrap();
            // Continuous: no step beyond the speed limit over one stamp.
            assert!(dist(k.pos, last) <= 200.0 * 3f64.sqrt() * STEP as f64 * 1e-6 + 1e-9);
            last = k.pos;
        }
        // The tail of the plan always ends at rest.
        if let Some(s) = p.plan().segments.last() {
            assert_eq!(s.profile.exit, 0.0);
        }
    }
    let end = run_to_rest(&mut p, t + STEP, |_, _| {});
    assert!(dist(p.sample(end).unwrap(), pos) < 1e-12);
    assert_eq!(p.stats().executed, 300);
    // Fed faster than it runs, the path does not stop between segments.
    let mut p = Planner::new(iso(200.0, 2000.0, 0.05)).unwrap();
    for i in 1..=10 {
        p.line([i as f64 * 10.0, 0.0, 0.0], 100.0).unwrap();
    }
    let mut t = 0;
    let mut min_speed_mid = f64::INFINITY;
    while p.stats().executed < 5 {
        let k = p.sample_kin(t).unwrap();
        if t > 100_000 {
            min_speed_mid = min_speed_mid.min(k.vel[0]);
        }
        if t == 200 * STEP {
            for i in 11..=20 {
                p.line([i as f64 * 10.0, 0.0, 0.0], 100.0).unwrap();
            }
        }
        t += STEP;
    }
    assert!(min_speed_mid > 99.999, "{min_speed_mid}");
    let plan = p.plan();
    assert_eq!(plan.segments.last().unwrap().end, [200.0, 0.0, 0.0]);
}

#[test]
fn starts_at_first_stamp_or_at_start() {
    let mut p = Planner::new(iso(100.0, 1000.0, 0.05)).unwrap();
    assert_eq!(p.sample(1000).unwrap(), [0.0; 3]);
    p.line([10.0, 0.0, 0.0], 100.0).unwrap();
    // Queued after stamp 1000: starts at the next stamp, from rest.
    assert_eq!(p.sample(50_000).unwrap(), [0.0; 3]);
    let x = p.sample(60_000).unwrap()[0];
    assert!((x - 0.5 * 1000.0 * 0.01f64.powi(2)).abs() < 1e-9, "{x}");
    assert!(p.start(70_000).is_err(), "start while running");
    run_to_rest(&mut p, 70_000, |_, _| {});
    // A start stamp in the future holds the path until then.
    p.line([0.0, 0.0, 0.0], 100.0).unwrap();
    p.start(10_000_000).unwrap();
    assert_eq!(p.sample(9_999_000).unwrap(), [10.0, 0.0, 0.0]);
    assert!(p.sample(10_010_000).unwrap()[0] < 10.0);
    assert_eq!(
        p.sample(1),
        Err(PlanError::StampNotMonotonic {
            stamp: 1,
            last: 10_010_000
        })
    );
}

#[test]
fn arcs_stay_within_chord_tolerance() {
    let mut p = Planner::new(iso(200.0, 2000.0, 0.02)).unwrap();
    p.set_position([10.0, 0.0, 0.0]).unwrap();
    for (tol, cw) in [(0.01, false), (0.001, true)] {
        let arc = Arc {
            end: [0.0, 10.0, 2.0],
            plane: (0, 1),
            center: [0.0, 0.0],
            clockwise: cw,
            chord_tolerance: tol,
        };
        let start = p.tail();
        let n = p.arc(&arc, 100.0).unwrap();
        let plan = p.plan();
        let segs = &plan.segments[plan.segments.len() - n..];
        let mut prev = start;
        let mut swept = 0.0;
        for s in segs {
            assert_eq!(s.start, prev);
            // Vertices on the circle; chord midpoints within tol inside it.
            let r_end = s.end[0].hypot(s.end[1]);
            assert!((r_end - 10.0).abs() < 1e-9);
            let mid = [(s.start[0] + s.end[0]) / 2.0, (s.start[1] + s.end[1]) / 2.0];
            let sag = 10.0 - mid[0].hypot(mid[1]);
            assert!(sag <= tol + 1e-12 && sag > 0.0, "{sag}");
            let a0 = s.start[1].atan2(s.start[0]);
            let a1 = s.end[1].atan2(s.end[0]);
            swept += (a1 - a0 + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
                - std::f64::consts::PI;
            prev = s.end;
        }
        assert_eq!(prev, arc.end);
        // Counter-clockwise from (10,0) to (0,10): a quarter; clockwise from
        // there back around to (0,10): a full turn (start = end in plane).
        let want = if cw {
            -std::f64::consts::TAU
        } else {
            std::f64::consts::FRAC_PI_2
        };
        assert!((swept - want).abs() < 1e-9, "{swept}");
        // Enough chords for the tolerance, not many more.
        let step = 2.0 * (1.0 - tol / 10.0).acos();
        assert_eq!(n, (want.abs() / step).ceil() as usize);
        assert!(segs.iter().all(|s| (s.end[2] - 2.0).abs() <= 2.0));
    }
}

#[test]
fn bad_input_is_refused() {
    let bad = [
        Limits::new([0.0, 1.0, 1.0], [1.0; 3], 0.1),
        Limits::new([1.0; 3], [1.0, -1.0, 1.0], 0.1),
        Limits::new([f64::NAN, 1.0, 1.0], [1.0; 3], 0.1),
        Limits::new([1.0; 3], [f64::INFINITY, 1.0, 1.0], 0.1),
        Limits::new([1.0; 3], [1.0; 3], -0.1),
        Limits::new([1.0; 3], [1.0; 3], f64::NAN),
        Limits::new([1.0; 3], [1.0; 3], 0.1).and_then(|l| l.with_max_jump([0.0; 3])),
    ];
    for b in bad {
        assert!(matches!(b, Err(PlanError::InvalidLimit { .. })), "{b:?}");
    }
    let mut l = iso(1.0, 1.0, 0.1);
    l.max_vel[2] = -3.0;
    assert!(matches!(
        Planner::new(l),
        Err(PlanError::InvalidLimit { axis: Some(2), .. })
    ));
    assert_eq!(
        Planner::with_capacity(iso(1.0, 1.0, 0.1), 0).err(),
        Some(PlanError::InvalidCapacity)
    );

    let mut p = Planner::with_capacity(iso(100.0, 1000.0, 0.1), 2).unwrap();
    assert_eq!(
        p.line([f64::NAN, 0.0, 0.0], 10.0),
        Err(PlanError::NonFiniteCoordinate { axis: 0 })
    );
    assert_eq!(
        p.line([0.0, 0.0, f64::INFINITY], 10.0),
        Err(PlanError::NonFiniteCoordinate { axis: 2 })
    );
    for feed in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        assert!(matches!(
            p.line([1.0, 0.0, 0.0], feed),
            Err(PlanError::InvalidFeed(_))
        ));
    }
    assert_eq!(p.line([0.0, 0.0, 0.0], 10.0), Ok(0), "zero-length move");
    p.line([1.0, 0.0, 0.0], 10.0).unwrap();
    p.line([2.0, 0.0, 0.0], 10.0).unwrap();
    assert_eq!(
        p.line([3.0, 0.0, 0.0], 10.0),
        Err(PlanError::QueueFull { capacity: 2 })
    );
    assert_eq!(p.set_position([0.0; 3]), Err(PlanError::Busy));
    assert_eq!(p.stats().pending, 2, "refused calls queue nothing");

    let mut p = Planner::new(iso(100.0, 1000.0, 0.1)).unwrap();
    p.set_position([1.0, 0.0, 0.0]).unwrap();
    let arc = |end: [f64; 3], center: [f64; 2], tol: f64, plane| Arc {
        end,
        plane,
        center,
        clockwise: false,
        chord_tolerance: tol,
    };
    let cases = [
        arc([0.0, 2.0, 0.0], [0.0, 0.0], 0.01, (0, 1)), // radius mismatch
        arc([0.0, 1.0, 0.0], [1.0, 0.0], 0.01, (0, 1)), // start on centre
        arc([0.0, 1.0, 0.0], [0.0, 0.0], 0.0, (0, 1)),
        arc([0.0, 1.0, 0.0], [0.0, 0.0], f64::NAN, (0, 1)),
        arc([0.0, 1.0, 0.0], [0.0, 0.0], 0.01, (1, 1)),
        arc([0.0, 1.0, 0.0], [0.0, 0.0], 0.01, (0, 3)),
        arc([0.0, 1.0, 0.0], [0.0, 0.0], 1e-300, (0, 1)), // too many chords
    ];
    for c in cases {
        assert!(
            matches!(p.arc(&c, 10.0), Err(PlanError::InvalidArc(_))),
            "{c:?}"
        );
    }
    let c = arc([0.0, 1.0, 0.0], [f64::NAN, 0.0], 0.01, (0, 1));
    assert_eq!(
        p.arc(&c, 10.0),
        Err(PlanError::NonFiniteCoordinate { axis: 0 })
    );
    assert!(p.is_idle(), "nothing queued by refused arcs");
    let mut small = Planner::with_capacity(iso(100.0, 1000.0, 0.1), 3).unwrap();
    small.set_position([1.0, 0.0, 0.0]).unwrap();
    let c = arc([0.0, 1.0, 0.0], [0.0, 0.0], 1e-4, (0, 1));
    assert_eq!(
        small.arc(&c, 10.0),
        Err(PlanError::QueueFull { capacity: 3 })
    );
    assert!(small.is_idle());
}

#[test]
fn pipes_class_signatures() {
    common::assert_wire_api::<PlannerBlock>(
        "Planner",
        "Planner(vx: f64, vy: f64, vz: f64, ax: f64, ay: f64, az: f64, \
         junction_deviation: f64, max_jump: f64) -> ()",
        &[
            "Planner.line(x: f64, y: f64, z: f64, feed: f64) -> (queued: u32)",
            "Planner.arc(x: f64, y: f64, z: f64, cx: f64, cy: f64, clockwise: bool, \
             feed: f64) -> (queued: u32)",
            "Planner.sample(stamp: u64) -> (stamp: u64, x: f32, y: f32, z: f32)",
            "Planner.start(stamp: u64) -> ()",
            "Planner.set_position(x: f64, y: f64, z: f64) -> ()",
            "Planner.status() -> (queued: u32, executed: u64, idle: bool)",
            "Planner.halt() -> (x: f64, y: f64, z: f64)",
            "Planner.set_feed_scale(k: f64) -> ()",
            "Planner.set_vector_limits(speed: f64, accel: f64, min_cruise_ratio: f64) -> ()",
        ],
    );
}

#[test]
fn pipes_class_wire_api() {
    let construct = |v: [f64; 8]| <PlannerBlock as PipesClass>::construct(&v.map(Value::F64));
    let good = [
        300.0,
        300.0,
        20.0,
        3000.0,
        3000.0,
        200.0,
        0.05,
        f64::INFINITY,
    ];
    // Every bad limit is refused with code 1, none builds a class.
    for (i, bad) in [0.0, -1.0, f64::NAN, f64::INFINITY].into_iter().enumerate() {
        for k in 0..8 {
            let mut v = good;
            v[k] = bad;
            // A junction deviation of 0 is allowed; a jump limit of inf too.
            if (k == 6 && bad == 0.0) || (k == 7 && bad == f64::INFINITY) {
                assert!(construct(v).is_ok(), "arg {k} = {bad}");
                continue;
            }
            assert_eq!(
                construct(v).err(),
                Some(CallError::Failed(pipes_core::FailureCode::Other(1))),
                "case {i}, arg {k} = {bad}"
            );
        }
    }
    assert_eq!(
        <PlannerBlock as PipesClass>::construct(&good.map(Value::F64)[..7]).err(),
        Some(CallError::Failed(pipes_core::FailureCode::from_code(
            INPUT_DECODE_FAILED
        )))
    );
    let mut b = construct(good).unwrap();
    let l = b.planner().limits();
    assert_eq!(
        (l.max_vel, l.max_acc, l.max_jump),
        (
            [300.0, 300.0, 20.0],
            [3000.0, 3000.0, 200.0],
            [f64::INFINITY; 3]
        )
    );
    assert_eq!(
        b.status(),
        (0, 0, true),
        "a new planner is empty and at rest"
    );

    // The wire methods, with their failure codes.
    let code = |e: PlanError| CallError::from(e);
    assert_eq!(b.line(10.0, 0.0, 0.0, 100.0), Ok(1));
    let queued = b.arc(0.0, 10.0, 0.0, 0.0, 0.0, false, 100.0).unwrap();
    // A quarter turn of radius 10 in chords within the wire tolerance.
    let step = 2.0 * (1.0 - WIRE_CHORD_TOLERANCE / 10.0).acos();
    let chords = (std::f64::consts::FRAC_PI_2 / step).ceil() as u32;
    assert_eq!(queued, 1 + chords);
    assert_eq!(
        b.line(f64::NAN, 0.0, 0.0, 1.0).map_err(code),
        Err(CallError::Failed(pipes_core::FailureCode::Other(2)))
    );
    assert_eq!(
        b.line(1.0, 0.0, 0.0, 0.0).map_err(code),
        Err(CallError::Failed(pipes_core::FailureCode::Other(3)))
    );
    assert_eq!(
        b.arc(0.0, 20.0, 0.0, 0.0, 0.0, true, 100.0).map_err(code),
        Err(CallError::Failed(pipes_core::FailureCode::Other(4))),
        "radius mismatch"
    );
    assert_eq!(
        b.set_position(0.0, 0.0, 0.0).map_err(code),
        Err(CallError::Failed(pipes_core::FailureCode::Other(7)))
    );
    assert_eq!(
        b.status(),
        (queued, 0, false),
        "refused calls queue nothing"
    );
    assert_eq!(b.sample(4096), Ok((4096, 0.0, 0.0, 0.0)));
    assert_eq!(
        b.sample(0).map_err(code),
        Err(CallError::Failed(pipes_core::FailureCode::Other(6)))
    );
    assert_eq!(
        b.start(8192).map_err(code),
        Err(CallError::Failed(pipes_core::FailureCode::Other(7))),
        "start while running"
    );
    let mut t = 4096;
    while !b.status().2 {
        t += 4096;
        b.sample(t).unwrap();
    }
    let (st, x, y, z) = b.sample(t).unwrap();
    assert_eq!(st, t);
    assert!(x.abs() < 1e-9 && (y - 10.0).abs() < 1e-9 && z == 0.0);
    assert_eq!(b.status(), (0, u64::from(queued), true));

    // At rest: set the position, hold the next move until a start stamp.
    b.set_position(1.0, 2.0, 3.0).unwrap();
    assert_eq!(b.planner().tail(), [1.0, 2.0, 3.0]);
    assert_eq!(b.line(1.0, 2.0, 5.0, 10.0), Ok(1));
    let later = t + 1_000_000;
    b.start(later).unwrap();
    assert_eq!(b.sample(later - 4096), Ok((later - 4096, 1.0, 2.0, 3.0)));
    assert!(b.sample(later + 40_960).unwrap().3 > 3.0);

    // A block around a planner of its own capacity.
    let limits = Limits::new([100.0; 3], [1000.0; 3], 0.05).unwrap();
    let mut small = PlannerBlock::from_planner(Planner::with_capacity(limits, 1).unwrap());
    assert_eq!(small.line(1.0, 0.0, 0.0, 10.0), Ok(1));
    assert_eq!(
        small.line(2.0, 0.0, 0.0, 10.0).map_err(code),
        Err(CallError::Failed(pipes_core::FailureCode::Other(5)))
    );
    small.planner_mut().sample(0).unwrap();
    assert_eq!(small.status(), (1, 0, false));
}
