//! The planner's controlled stop (`halt`) and feed override
//! (`set_feed_scale`): stopping distance and deceleration, following the
//! path through short chords, continuity at the halt stamp, moves after a
//! halt, the feed scale's effect and bounds, and their wire members.

mod common;

use common::rng::XorShiftStar;
use maxl::blocks::planner::{
    Kin, Limits, PlanError, Planner, PlannerBlock, Profile, MAX_FEED_SCALE,
};
use pipes_core::function::CallError;

const STEP: u64 = 1024;
const DT: f64 = STEP as f64 * 1e-6;

fn iso(v: f64, a: f64, jd: f64) -> Limits<3> {
    Limits::new([v; 3], [a; 3], jd).unwrap()
}

fn norm(v: [f64; 3]) -> f64 {
    v.iter().map(|c| c * c).sum::<f64>().sqrt()
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    norm([a[0] - b[0], a[1] - b[1], a[2] - b[2]])
}

/// Distance from `p` to the segment `a`–`b`.
fn dist_to_segment(p: [f64; 3], a: [f64; 3], b: [f64; 3]) -> f64 {
    let ab = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
    let ap = [p[0] - a[0], p[1] - a[1], p[2] - a[2]];
    let l2: f64 = ab.iter().map(|c| c * c).sum();
    let t = if l2 > 0.0 {
        ((0..3).map(|i| ab[i] * ap[i]).sum::<f64>() / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    dist(p, [a[0] + ab[0] * t, a[1] + ab[1] * t, a[2] + ab[2] * t])
}

/// Distance from `p` to the polyline through `pts`.
fn dist_to_polyline(p: [f64; 3], pts: &[[f64; 3]]) -> f64 {
    pts.windows(2)
        .map(|w| dist_to_segment(p, w[0], w[1]))
        .fold(f64::INFINITY, f64::min)
}

/// The largest acceleration along unit `u` keeping every axis within
/// `max_acc` (the planner's rule, computed independently).
fn acc_along(max_acc: [f64; 3], u: [f64; 3]) -> f64 {
    (0..3)
        .filter(|&i| u[i].abs() > 1e-12)
        .map(|i| max_acc[i] / u[i].abs())
        .fold(f64::INFINITY, f64::min)
}

/// Samples from `t` on until idle; returns every (stamp, state).
fn run_to_rest(p: &mut Planner<3>, mut t: u64) -> Vec<(u64, Kin<3>)> {
    let mut out = Vec::new();
    for _ in 0..10_000_000 {
        let k = p.sample_kin(t).unwrap();
        out.push((t, k));
        if p.is_idle() {
            return out;
        }
        t += STEP;
    }
    panic!("planner never came to rest");
}

/// Checks that the positions move as the reported speeds say: between
/// consecutive stamps the distance is the trapezoid of the speeds within
/// `a_max·dt²/4` (speeds change at most at `a_max`), up to `rel` of it for
/// a path that bends between stamps. `exact_below` false checks only that
/// it does not move farther (corners shorten the straight distance).
fn check_moves_at_speed(states: &[(u64, Kin<3>)], a_max: f64, rel: f64, exact_below: bool) {
    for w in states.windows(2) {
        let ((t0, k0), (t1, k1)) = (w[0], w[1]);
        let dt = (t1 - t0) as f64 * 1e-6;
        let moved = dist(k0.pos, k1.pos);
        let want = 0.5 * (norm(k0.vel) + norm(k1.vel)) * dt;
        let tol = a_max * dt * dt / 4.0 + rel * want + 1e-9;
        assert!(
            moved <= want + tol,
            "{t0}..{t1}: moved {moved}, speeds say {want}"
        );
        if exact_below {
            assert!(
                moved >= want - tol,
                "{t0}..{t1}: moved {moved}, speeds say {want}"
            );
        }
    }
}

/// Samples stamps 0, STEP, .. up to `ts`; returns the states.
fn run_until(p: &mut Planner<3>, ts: u64) -> Vec<(u64, Kin<3>)> {
    (0..=ts / STEP)
        .map(|i| (i * STEP, p.sample_kin(i * STEP).unwrap()))
        .collect()
}

/// Checks the states after a halt at `before` (the last sampled state):
/// the resampled halt stamp is unchanged, the speed only falls and by at
/// most `a_max·dt` per stamp, every axis stays within its acceleration
/// limit, and the last state is at rest at `stop`.
fn check_stop(after: &[(u64, Kin<3>)], before: &Kin<3>, limits: &Limits<3>, stop: [f64; 3]) {
    let (_, first) = after[0];
    assert_eq!(first.pos, before.pos, "position at the halt stamp");
    let v0 = norm(before.vel);
    for i in 0..3 {
        assert!(
            (first.vel[i] - before.vel[i]).abs() <= 1e-9 * v0.max(1e-9),
            "velocity at the halt stamp: {:?} vs {:?}",
            first.vel,
            before.vel
        );
    }
    let a_max = (0..3).map(|i| limits.max_acc[i]).fold(0.0, f64::max) * 3f64.sqrt();
    for w in after.windows(2) {
        let (s0, s1) = (norm(w[0].1.vel), norm(w[1].1.vel));
        assert!(s1 <= s0 + 1e-9, "speed rose after the halt: {s0} -> {s1}");
        assert!(s0 - s1 <= a_max * DT * (1.0 + 1e-9) + 1e-9, "{s0} -> {s1}");
    }
    for (_, k) in after {
        for i in 0..3 {
            assert!(
                k.acc[i].abs() <= limits.max_acc[i] * (1.0 + 1e-9),
                "axis {i} acceleration {k:?}"
            );
        }
    }
    let (_, last) = after[after.len() - 1];
    assert_eq!(last.pos, stop, "at rest at the stop point");
    assert_eq!(last.vel, [0.0; 3]);
}

#[test]
fn halt_mid_long_segment_stops_within_v2_over_2a_at_the_limit() {
    let (v, a) = (100.0, 1000.0);
    let limits = iso(200.0, a, 0.05);
    let mut p = Planner::new(limits.clone()).unwrap();
    p.line([100.0, 0.0, 0.0], v).unwrap();
    let ts = 300 * STEP; // 0.3 s: cruising at 100 mm/s since 0.1 s
    let before = run_until(&mut p, ts);
    let (_, k0) = *before.last().unwrap();
    assert!((k0.vel[0] - v).abs() < 1e-9, "cruising: {k0:?}");
    assert_eq!(p.last_stamp(), Some(ts));

    let stop = p.halt().unwrap();
    let want = k0.pos[0] + v * v / (2.0 * a);
    assert!((stop[0] - want).abs() < 1e-9, "{stop:?} vs {want}");
    assert_eq!(&stop[1..], &[0.0, 0.0]);
    assert_eq!(p.tail(), stop, "new moves continue from the stop point");
    assert!(!p.is_idle(), "the stop still has to run");

    // The plan: one running segment from the halt state, decelerating at
    // the limit to rest at the stop point.
    let plan = p.plan();
    assert_eq!(plan.segments.len(), 1);
    let s = &plan.segments[0];
    assert!(s.running);
    assert_eq!((s.start, s.end), (k0.pos, stop));
    assert!((s.start_us - ts as f64).abs() < 1e-6);
    let pr = s.profile;
    assert_eq!((pr.entry, pr.cruise, pr.exit, pr.accel), (v, v, 0.0, a));
    assert!((s.duration_us - 1e6 * v / a).abs() < 1e-3);

    let after = run_to_rest(&mut p, ts);
    check_stop(&after, &k0, &limits, stop);
    check_moves_at_speed(&after, a, 0.0, true);
    // Decelerating at exactly the limit until rest.
    for (t, k) in &after[1..after.len() - 1] {
        assert!((k.acc[0] + a).abs() < 1e-9, "at {t}: {k:?}");
        assert!(k.pos[0] <= stop[0] && k.pos[0] >= k0.pos[0]);
    }
    // At rest within one stamp after v/a.
    let t_rest = after[after.len() - 1].0;
    assert!(t_rest as f64 - ts as f64 <= 1e6 * v / a + STEP as f64);
    assert!(p.is_idle());
    assert_eq!(p.stats().executed, 1);
    assert_eq!(p.halt(), Ok(stop), "halting at rest stays put");
}

#[test]
fn halt_follows_a_path_of_short_chords() {
    // A circle of radius 30 mm in 0.2 mm chords on a machine whose axes
    // accelerate differently: the stop spans dozens of chords, each braking
    // at its own limit, and never leaves the polyline.
    let limits = Limits::new([300.0, 300.0, 50.0], [2000.0, 1000.0, 500.0], 0.05).unwrap();
    let mut p = Planner::new(limits.clone()).unwrap();
    let r = 30.0;
    let n = (2.0 * std::f64::consts::PI * r / 0.2).ceil() as usize;
    let mut pts = vec![[r, 0.0, 0.0]];
    p.set_position(pts[0]).unwrap();
    for k in 1..=n {
        let th = 2.0 * std::f64::consts::PI * k as f64 / n as f64;
        pts.push([r * th.cos(), r * th.sin(), 0.0]);
        p.line(pts[k], 150.0).unwrap();
    }
    let ts = 400 * STEP;
    let before = run_until(&mut p, ts);
    let (_, k0) = *before.last().unwrap();
    let v0 = norm(k0.vel);
    assert!(v0 > 140.0, "running fast: {v0}");

    // The expected stop, walked independently along the chords.
    let (mut i, mut best) = (0, f64::INFINITY);
    for j in 0..n {
        let d = dist_to_segment(k0.pos, pts[j], pts[j + 1]);
        if d < best {
            (i, best) = (j, d);
        }
    }
    assert!(best < 1e-9);
    let mut at = k0.pos;
    let mut v2 = v0 * v0;
    let mut chords = 0;
    let want = loop {
        let l = dist(at, pts[i + 1]);
        let u = [0, 1, 2].map(|c| (pts[i + 1][c] - pts[i][c]) / dist(pts[i], pts[i + 1]));
        let a = acc_along(limits.max_acc, u);
        if v2 <= 2.0 * a * l {
            let d = v2 / (2.0 * a);
            break [0, 1, 2].map(|c| at[c] + u[c] * d);
        }
        v2 -= 2.0 * a * l;
        at = pts[i + 1];
        i += 1;
        chords += 1;
    };
    assert!(chords > 20, "the stop spans {chords} chords");

    let stop = p.halt().unwrap();
    assert!(dist(stop, want) < 1e-6, "{stop:?} vs {want:?}");
    assert_eq!(p.plan().segments.len(), chords + 1);
    let after = run_to_rest(&mut p, ts);
    check_stop(&after, &k0, &limits, stop);
    check_moves_at_speed(&after, 2000.0 * 3f64.sqrt(), 1e-4, true);
    // Every sampled point lies on the original polyline (no cut corners).
    for (t, k) in before.iter().chain(&after) {
        let d = dist_to_polyline(k.pos, &pts);
        assert!(d < 1e-9, "at {t}: {:?} is {d} mm off the path", k.pos);
    }
    assert_eq!(p.tail(), stop);
    assert!(p.is_idle());
}

#[test]
fn halt_at_rest_and_before_the_first_sample() {
    let mut p = Planner::new(iso(100.0, 1000.0, 0.05)).unwrap();
    assert_eq!((p.epoch(), p.last_stamp()), (None, None));
    p.set_position([1.0, 2.0, 3.0]).unwrap();
    assert_eq!(p.halt(), Ok([1.0, 2.0, 3.0]), "idle");
    assert!(p.is_idle());

    // Queued but never sampled: dropped, the machine never moved.
    p.line([10.0, 2.0, 3.0], 50.0).unwrap();
    p.line([10.0, 9.0, 3.0], 50.0).unwrap();
    assert_eq!(p.halt(), Ok([1.0, 2.0, 3.0]));
    assert!(p.is_idle());
    assert!(p.plan().segments.is_empty());
    assert_eq!(p.tail(), [1.0, 2.0, 3.0]);
    assert_eq!(p.sample(5000), Ok([1.0, 2.0, 3.0]));
    assert_eq!((p.epoch(), p.last_stamp()), (Some(5000), Some(5000)));

    // A pending start is dropped too.
    p.line([4.0, 2.0, 3.0], 50.0).unwrap();
    p.start(10_000).unwrap();
    assert_eq!(p.halt(), Ok([1.0, 2.0, 3.0]));
    assert_eq!(p.sample(20_000), Ok([1.0, 2.0, 3.0]));
    assert!(p.is_idle());

    // After a move finished: where it ended.
    p.line([4.0, 2.0, 3.0], 50.0).unwrap();
    let end = run_to_rest(&mut p, 30_000);
    assert_eq!(end.last().unwrap().1.pos, [4.0, 2.0, 3.0]);
    let executed = p.stats().executed;
    assert_eq!(p.halt(), Ok([4.0, 2.0, 3.0]));
    assert_eq!(p.stats().executed, executed);

    // Sampled at the very stamp a segment starts (from rest): stops there.
    p.line([9.0, 2.0, 3.0], 50.0).unwrap();
    let k = p.sample_kin(1_000_000).unwrap();
    assert_eq!((k.pos, k.vel), ([4.0, 2.0, 3.0], [0.0; 3]));
    assert!(!p.is_idle());
    assert_eq!(p.halt(), Ok([4.0, 2.0, 3.0]));
    assert!(p.is_idle());
    assert_eq!(p.sample(1_000_000 + STEP), Ok([4.0, 2.0, 3.0]));
}

/// A random path with corners and short segments at random feeds.
fn random_path(p: &mut Planner<3>, seed: u64, n: usize) -> Vec<[f64; 3]> {
    let mut rng = XorShiftStar(seed);
    let mut pos = [0.0; 3];
    let mut pts = vec![pos];
    for _ in 0..n {
        let len = if rng.next() < 0.5 { 0.2 } else { 5.0 };
        for c in pos.iter_mut().take(2) {
            *c += (rng.next() - 0.5) * len;
        }
        pos[2] += (rng.next() - 0.5) * 0.1 * len;
        if p.line(pos, 50.0 + 250.0 * rng.next()).unwrap() == 1 {
            pts.push(pos);
        }
    }
    pts
}

#[test]
fn halting_at_any_stamp_keeps_what_was_sampled() {
    let limits = Limits::new([300.0, 200.0, 30.0], [3000.0, 1500.0, 300.0], 0.05).unwrap();
    let mut base = Planner::new(limits.clone()).unwrap();
    let pts = random_path(&mut base, 0xfeed, 120);
    // The unhalted run, for reference.
    let reference = run_to_rest(&mut base.clone(), 0);
    let mut p = base;
    let mut halts = 0;
    for (idx, &(t, k)) in reference.iter().enumerate() {
        // Keep sampling the base planner stamp by stamp; halt a copy every
        // 13th stamp (in every phase: accelerating, cruising, braking,
        // through corners and chords).
        let got = p.sample_kin(t).unwrap();
        assert_eq!(got, k);
        if idx % 13 != 5 || p.is_idle() {
            continue;
        }
        halts += 1;
        let mut h = p.clone();
        assert_eq!(h.last_stamp(), Some(t));
        let stop = h.halt().unwrap();
        assert_eq!(h.tail(), stop);
        // Stamps up to the halt stamp are unchanged: sampling the halt
        // stamp again gives what was sent.
        let after = run_to_rest(&mut h, t);
        check_stop(&after, &k, &limits, stop);
        check_moves_at_speed(&after, 3000.0 * 3f64.sqrt(), 1e-9, false);
        for (ta, ka) in &after {
            let d = dist_to_polyline(ka.pos, &pts);
            assert!(d < 1e-9, "halt at {t}, at {ta}: {d} mm off the path");
        }
        assert!(dist_to_polyline(stop, &pts) < 1e-9);
        assert!(h.is_idle());
    }
    assert!(halts > 20, "{halts} halts");
}

#[test]
fn new_moves_after_a_halt_start_from_the_stop_point() {
    let a_lim = 1000.0;
    let limits = iso(200.0, a_lim, 0.05);
    let mut p = Planner::new(limits.clone()).unwrap();
    p.line([100.0, 0.0, 0.0], 100.0).unwrap();
    p.line([100.0, 50.0, 0.0], 100.0).unwrap();
    let ts = 250 * STEP;
    let before = run_until(&mut p, ts);
    let (_, k0) = *before.last().unwrap();
    let stop = p.halt().unwrap();
    assert!(stop[0] < 100.0 && stop[1] == 0.0);
    // A second halt changes nothing.
    let again = p.halt().unwrap();
    assert!(dist(again, stop) < 1e-9, "{again:?} vs {stop:?}");
    let stop = again;

    // Queued during the stop: it starts from rest at the stop point.
    assert_eq!(p.line([stop[0], 10.0, 0.0], 100.0), Ok(1));
    let plan = p.plan();
    assert_eq!(plan.segments.len(), 2);
    assert_eq!(plan.segments[1].start, stop);
    assert_eq!(plan.segments[1].profile.entry, 0.0);
    assert_eq!(plan.segments[0].profile.exit, 0.0);
    let after = run_to_rest(&mut p, ts + STEP);
    check_moves_at_speed(&after, a_lim, 0.0, false);
    for (t, k) in &after {
        if k.pos[1] > 0.0 {
            assert_eq!(k.pos[0], stop[0], "at {t}: y moves only after the stop");
        } else {
            assert!(k.pos[0] <= stop[0] && k.pos[0] >= k0.pos[0]);
        }
    }
    assert_eq!(after.last().unwrap().1.pos, [stop[0], 10.0, 0.0]);

    // Queued once idle again: from the new rest, as usual.
    p.line([0.0, 10.0, 0.0], 100.0).unwrap();
    assert_eq!(p.plan().segments[0].start, [stop[0], 10.0, 0.0]);
    let t = after.last().unwrap().0 + STEP;
    assert_eq!(
        run_to_rest(&mut p, t).last().unwrap().1.pos,
        [0.0, 10.0, 0.0]
    );
}

#[test]
fn feed_scale_half_doubles_a_cruise_dominated_move() {
    let limits = iso(500.0, 20_000.0, 0.05);
    let mut p = Planner::new(limits.clone()).unwrap();
    assert_eq!(p.feed_scale(), 1.0);
    p.line([200.0, 0.0, 0.0], 100.0).unwrap();
    let full = p.plan().duration_us();
    // Scaling the queued move replans it.
    p.set_feed_scale(0.5).unwrap();
    assert_eq!(p.feed_scale(), 0.5);
    let half = p.plan().duration_us();
    assert!((half / full - 2.0).abs() < 0.02, "{half} / {full}");
    assert_eq!(p.plan().segments[0].profile.cruise, 50.0);
    // The scale applies to moves queued later too, and to the run itself.
    let mut q = Planner::new(limits).unwrap();
    q.set_feed_scale(0.5).unwrap();
    q.line([200.0, 0.0, 0.0], 100.0).unwrap();
    assert_eq!(q.plan().duration_us(), half);
    let t_end = run_to_rest(&mut q, 0).last().unwrap().0 as f64;
    assert!((t_end / full - 2.0).abs() < 0.02, "{t_end} / {full}");
}

#[test]
fn feed_scale_stays_within_the_axis_limits() {
    let limits = Limits::new([100.0, 50.0, 20.0], [1000.0; 3], 0.05).unwrap();
    let mut p = Planner::new(limits.clone()).unwrap();
    p.set_feed_scale(MAX_FEED_SCALE).unwrap();
    p.line([500.0, 0.0, 0.0], 80.0).unwrap();
    p.line([500.0, 500.0, 0.0], 40.0).unwrap();
    p.line([0.0, 0.0, 0.0], 30.0).unwrap();
    p.line([0.0, 0.0, 100.0], 1.0).unwrap();
    let plan = p.plan();
    let cruise: Vec<f64> = plan.segments.iter().map(|s| s.profile.cruise).collect();
    assert_eq!(cruise[..2], [100.0, 50.0], "axis limits, not 800 and 400");
    assert!((cruise[2] - 50.0 * 2f64.sqrt()).abs() < 1e-9, "{cruise:?}");
    assert_eq!(cruise[3], 10.0, "the scaled feed where it is lower");
    for s in &plan.segments {
        for i in 0..3 {
            assert!(s.profile.cruise * s.dir[i].abs() <= limits.max_vel[i] * (1.0 + 1e-12));
        }
    }
    // Bad scales are refused and change nothing.
    for k in [0.0, -1.0, f64::NAN, f64::INFINITY, 10.000_001] {
        assert!(
            matches!(p.set_feed_scale(k), Err(PlanError::InvalidFeedScale(_))),
            "{k}"
        );
    }
    assert_eq!(p.feed_scale(), MAX_FEED_SCALE);
    assert_eq!(p.plan(), plan);
    assert_eq!(PlanError::InvalidFeedScale(0.0).code(), 9);
}

#[test]
fn feed_scale_keeps_the_running_segment_and_the_acceleration_limits() {
    // A straight line in 1 mm pieces at 200 mm/s (axis limit 300); lowering the scale to 0.1
    // mid-way leaves the path 180 mm/s above its new limit, which takes
    // about 20 mm (20 pieces) of braking at the limit.
    let (v, a) = (200.0, 1000.0);
    let limits = iso(300.0, a, 0.05);
    for k in [0.1, 0.6, 2.0] {
        let mut p = Planner::new(limits.clone()).unwrap();
        for i in 1..=150 {
            p.line([i as f64, 0.0, 0.0], v).unwrap();
        }
        let ts = 250 * STEP; // past 20 mm: cruising at 200 mm/s
        let before = run_until(&mut p, ts);
        let running = p.plan().segments[0].clone();
        assert!(running.running && running.profile.cruise == v);
        p.set_feed_scale(k).unwrap();
        let plan = p.plan();
        assert_eq!(
            plan.segments[0], running,
            "the running segment is unchanged"
        );
        let new_max = (v * k).min(300.0);
        // Beyond the running segment's end (entered at `v`), the speed is at
        // most the new limit or what braking at the limit from `v` allows.
        let x_e = running.end[0];
        let bound = |x: f64| new_max.max((v * v - 2.0 * a * (x - x_e)).max(0.0).sqrt());
        for s in &plan.segments[1..] {
            let pr = s.profile;
            assert_eq!(pr.accel, a);
            assert!(pr.entry <= bound(s.start[0]) + 1e-9, "k {k}: {s:?}");
            assert!(pr.cruise <= new_max.max(pr.entry) + 1e-9, "k {k}: {s:?}");
        }
        // Halting while braking to the new limit (segments entered above
        // it) still stops at the limit, on the line.
        let mut h = p.clone();
        let th = ts + 20 * STEP;
        let mut k0 = Kin::rest([0.0; 3]);
        for t in (ts + STEP..=th).step_by(STEP as usize) {
            k0 = h.sample_kin(t).unwrap();
        }
        let stop = h.halt().unwrap();
        let want = k0.pos[0] + k0.vel[0] * k0.vel[0] / (2.0 * a);
        assert!((stop[0] - want).abs() < 1e-9, "k {k}: {stop:?} vs {want}");
        let after = run_to_rest(&mut h, th);
        check_stop(&after, &k0, &limits, stop);
        check_moves_at_speed(&after, a, 0.0, true);

        let mut all = before;
        all.extend(run_to_rest(&mut p, ts + STEP));
        check_moves_at_speed(&all, a, 0.0, true);
        for w in all.windows(2) {
            let (v0, v1) = (w[0].1.vel[0], w[1].1.vel[0]);
            assert!(
                (v1 - v0).abs() <= a * DT * (1.0 + 1e-9),
                "k {k}: {v0} -> {v1}"
            );
            assert!(w[1].1.acc[0].abs() <= a * (1.0 + 1e-12));
            assert!(w[1].1.pos[0] >= w[0].1.pos[0]);
        }
        for (t, s) in all.iter().filter(|(t, _)| *t > ts) {
            if s.pos[0] > x_e {
                assert!(s.vel[0] <= bound(s.pos[0]) + 1e-9, "k {k} at {t}: {s:?}");
            }
        }
        // Once braked (or sped up) to it, the new limit is the cruise speed
        // until the final braking.
        let settled = x_e + (v * v - new_max * new_max).abs() / (2.0 * a) + 1.0;
        let braking = 150.0 - new_max * new_max / (2.0 * a) - 1.0;
        let fastest = all
            .iter()
            .filter(|(_, s)| s.pos[0] > settled && s.pos[0] < braking)
            .map(|(_, s)| s.vel[0])
            .fold(0.0, f64::max);
        assert!((fastest - new_max).abs() < 1e-9, "k {k}: {fastest}");
        assert_eq!(all.last().unwrap().1.pos, [150.0, 0.0, 0.0]);
    }
}

#[test]
fn a_profile_entered_above_its_limit_brakes_first() {
    let p = Profile::plan(10.0, 100.0, 0.0, 50.0, 1000.0);
    assert_eq!((p.entry, p.cruise, p.exit), (100.0, 50.0, 0.0));
    assert!((p.t_acc - 0.05).abs() < 1e-15 && (p.t_dec - 0.05).abs() < 1e-15);
    // Decelerating, continuous into the cruise, and ending at the length.
    let (s, v, acc) = p.at(0.01);
    assert!((v - 90.0).abs() < 1e-12 && acc == -1000.0);
    assert!((s - (100.0 * 0.01 - 500.0 * 1e-4)).abs() < 1e-12);
    let (s1, v1, _) = p.at(p.t_acc);
    assert!((s1 - 3.75).abs() < 1e-12 && v1 == 50.0);
    assert_eq!(p.at(p.duration()), (10.0, 0.0, 0.0));
    // Straight to the exit when that is above the limit.
    let q = Profile::plan(3.0, 100.0, (100.0f64.powi(2) - 6000.0).sqrt(), 50.0, 1000.0);
    assert_eq!(q.cruise, q.exit);
    assert!(q.t_cruise < 1e-12 && q.t_dec == 0.0);
}

#[test]
fn wire_halt_and_feed_scale() {
    let mut b = PlannerBlock::new(
        300.0,
        300.0,
        20.0,
        3000.0,
        3000.0,
        200.0,
        0.05,
        f64::INFINITY,
    )
    .unwrap();
    assert_eq!(b.halt(), Ok((0.0, 0.0, 0.0)));
    b.line(50.0, 0.0, 0.0, 100.0).unwrap();
    for i in 0..=100 {
        b.sample(i * STEP).unwrap();
    }
    let (x, y, z) = b.halt().unwrap();
    assert_eq!(b.planner().tail(), [x, y, z]);
    assert!(x > 0.0 && x < 50.0 && y == 0.0 && z == 0.0);
    assert_eq!(b.set_feed_scale(2.0), Ok(()));
    assert_eq!(b.planner().feed_scale(), 2.0);
    for k in [0.0, 11.0, f64::NAN] {
        assert_eq!(
            b.set_feed_scale(k).map_err(CallError::from),
            Err(CallError::Failed(pipes_core::FailureCode::Other(9)))
        );
    }
}
