//! One-axis moves, velocity mode, units and homing against a simulated switch.

mod common;

use common::rng::XorShift;
use maxl::blocks::onedof::{OneDof, OneDofBlock, OneDofConfig, OneDofError};
use maxl::blocks::timer::Timer;
use maxl::Interval;
use pipes_core::class::PipesClass;
use pipes_core::export::INPUT_DECODE_FAILED;
use pipes_core::function::CallError;
use pipes_core::Value;

const IV: u32 = 1024;
const T0: u64 = 1 << 30;

fn cfg(scale: f64, offset: f64) -> OneDofConfig {
    OneDofConfig {
        max_vel: 100.0,
        max_acc: 1000.0,
        scale,
        offset,
        interval: Interval::from_micros(IV).unwrap(),
        history_len: 1024,
    }
}

fn axis(scale: f64, offset: f64) -> OneDof {
    let mut a = OneDof::new(cfg(scale, offset)).unwrap();
    a.sample(T0).unwrap();
    a
}

/// Samples every stamp from the last one through `until`, returning them.
fn run(a: &mut OneDof, until: u64) -> Vec<(u64, f64)> {
    let mut out = Vec::new();
    let mut t = a.state().unwrap().stamp + u64::from(IV);
    while t <= until {
        out.push((t, a.sample(t).unwrap()));
        t += u64::from(IV);
    }
    out
}

/// Asserts per-stamp finite differences stay within the limits (axis units).
fn assert_within(points: &[(u64, f64)], vmax: f64, amax: f64) {
    let dt = f64::from(IV) * 1e-6;
    let v: Vec<f64> = points.windows(2).map(|w| (w[1].1 - w[0].1) / dt).collect();
    for x in &v {
        assert!(x.abs() <= vmax * (1.0 + 1e-9), "velocity {x} over {vmax}");
    }
    for w in v.windows(2) {
        let a = (w[1] - w[0]) / dt;
        assert!(
            a.abs() <= amax * (1.0 + 1e-6),
            "acceleration {a} over {amax}"
        );
    }
}

/// Rest-to-rest trapezoid duration, s.
fn trapezoid_time(d: f64, v: f64, a: f64) -> f64 {
    if d >= v * v / a {
        d / v + v / a
    } else {
        2.0 * (d / a).sqrt()
    }
}

#[test]
fn trapezoid_arrives_exactly_at_the_computed_time() {
    // 80 steps/mm: 8000 steps/s, 80000 steps/s².
    for (target, scale) in [(50.0, 80.0), (-3.0, 80.0), (0.01, 80.0), (20.0, -80.0)] {
        let mut a = axis(scale, 0.0);
        let plan = a.move_to(target).unwrap();
        assert_eq!(plan.start_us, T0);
        let d = (target * scale).abs();
        let expect = trapezoid_time(d, 100.0 * scale.abs(), 1000.0 * scale.abs());
        let end = T0 + (expect * 1e6).ceil() as u64;
        assert!(plan.end_us.abs_diff(end) <= 1, "{} vs {end}", plan.end_us);
        assert_eq!(plan.target_axis, target * scale);

        let mut pts = vec![(T0, 0.0)];
        pts.extend(run(&mut a, plan.end_us + 10 * u64::from(IV)));
        for &(t, x) in &pts {
            if t >= plan.end_us {
                assert_eq!(x, target * scale, "at rest on the target from the end time");
            } else {
                assert!((x - target * scale).abs() > 0.0, "not there before {t}");
                assert!(x.abs() <= d.abs() + 1e-9, "no overshoot");
            }
        }
        assert_within(&pts, 100.0 * scale.abs(), 1000.0 * scale.abs());
        let (pos, vel, moving, homed) = a.status();
        assert!((pos - target).abs() < 1e-12);
        assert_eq!((vel, moving, homed), (0.0, false, false));
    }
}

#[test]
fn moves_from_motion_stay_within_limits() {
    let mut a = axis(80.0, 0.0);
    a.velocity(80.0).unwrap();
    let mut pts = vec![(T0, 0.0)];
    pts.extend(run(&mut a, T0 + 150_000));
    // Heading away from the target: stop, come back, arrive on time.
    let plan = a.move_to(-10.0).unwrap();
    pts.extend(run(&mut a, plan.end_us + 5 * u64::from(IV)));
    assert_eq!(pts.last().unwrap().1, -800.0);
    let before_end = pts.iter().rev().find(|p| p.0 < plan.end_us).unwrap();
    assert_ne!(before_end.1, -800.0);
    // Moving toward a target too close to stop at: overshoot and return.
    a.velocity(-100.0).unwrap();
    let until = a.state().unwrap().stamp + 100_000;
    pts.extend(run(&mut a, until));
    let here = a.status().0;
    let plan = a.move_to(here - 0.5).unwrap();
    pts.extend(run(&mut a, plan.end_us + u64::from(IV)));
    assert_eq!(pts.last().unwrap().1, a.to_axis(here - 0.5));
    assert_within(&pts, 8000.0, 80000.0);
}

#[test]
fn velocity_mode_ramps_within_the_acceleration_limit() {
    let mut a = axis(80.0, 0.0);
    a.velocity(50.0).unwrap();
    let mut pts = vec![(T0, 0.0)];
    pts.extend(run(&mut a, T0 + 100_000));
    // 50 mm/s at 1000 mm/s² takes 50 ms; after that it cruises.
    let (_, v, moving, _) = a.status();
    assert!((v - 50.0).abs() < 1e-9 && moving);
    let dt = f64::from(IV) * 1e-6;
    let n = pts.len();
    let cruise = (pts[n - 1].1 - pts[n - 2].1) / dt;
    assert!((cruise - 4000.0).abs() < 1e-6, "{cruise}");
    a.velocity(-30.0).unwrap();
    pts.extend(run(&mut a, T0 + 300_000));
    assert!((a.status().1 + 30.0).abs() < 1e-9);
    a.stop().unwrap();
    pts.extend(run(&mut a, T0 + 400_000));
    let (_, v, moving, _) = a.status();
    assert_eq!((v, moving), (0.0, false));
    let n = pts.len();
    assert_eq!(pts[n - 1].1, pts[n - 2].1, "at rest");
    assert_within(&pts, 8000.0, 80000.0);
    assert!(matches!(
        a.velocity(100.5),
        Err(OneDofError::OverLimit { .. })
    ));
}

#[test]
fn units_and_offset_round_trip() {
    for (scale, offset) in [(80.0, 0.0), (-200.0, 12.5), (0.1, -1000.0)] {
        let mut a = axis(scale, offset);
        for u in [-123.25, 0.0, 1.0, 77.7] {
            assert!((a.to_user(a.to_axis(u)) - u).abs() < 1e-9);
        }
        assert_eq!(
            a.to_axis(offset),
            0.0,
            "offset is the user coordinate of axis 0"
        );
        assert!((a.status().0 - offset).abs() < 1e-12);
        let plan = a.move_to(offset + 2.0).unwrap();
        assert_eq!(plan.target_axis, 2.0 * scale);
        run(&mut a, plan.end_us + u64::from(IV));
        assert!((a.status().0 - (offset + 2.0)).abs() < 1e-9);
        // Redefining the position moves nothing.
        let before = a.state().unwrap().pos;
        a.set_position(5.0).unwrap();
        assert_eq!(a.state().unwrap().pos, before);
        assert!((a.status().0 - 5.0).abs() < 1e-9);
    }
}

/// Uniform cubic B-spline through `(stamp, point)` pairs, written from the
/// basis functions (independent of maxl's evaluator).
fn spline(points: &[(u64, f64)], t: u64) -> Option<f64> {
    let step = u64::from(IV);
    let seg = t / step * step;
    let first = seg.checked_sub(step)?;
    let i = points.iter().position(|p| p.0 == first)?;
    let p = points.get(i..i + 4)?;
    for (k, q) in p.iter().enumerate() {
        assert_eq!(q.0, seg - step + k as u64 * step, "contiguous");
    }
    let u = (t - seg) as f64 / step as f64;
    let b0 = (1.0 - u).powi(3);
    let b1 = 3.0 * u.powi(3) - 6.0 * u * u + 4.0;
    let b2 = -3.0 * u.powi(3) + 3.0 * u * u + 3.0 * u + 1.0;
    let b3 = u.powi(3);
    Some((b0 * p[0].1 + b1 * p[1].1 + b2 * p[2].1 + b3 * p[3].1) / 6.0)
}

/// Homes against a switch at `switch` (axis units), delivering the trigger
/// time `delay` µs late. Returns |reconciled − switch| in axis units.
fn home_once(scale: f64, dir: i8, speed: f64, switch: f64, delay: u64, home: f64) -> f64 {
    let mut timer = Timer::new(Interval::from_micros(IV).unwrap(), 3 * u64::from(IV)).unwrap();
    let mut a = OneDof::new(cfg(scale, 3.0)).unwrap();
    a.set_home(home).unwrap();
    let mut now = (1u64 << 36) + 4321;
    let mut pts: Vec<(u64, f64)> = Vec::new();
    let mut tick = |a: &mut OneDof, now: u64, pts: &mut Vec<(u64, f64)>| {
        for s in timer.due(now) {
            pts.push((s, a.sample(s).unwrap()));
        }
    };
    tick(&mut a, now, &mut pts);
    assert_eq!(a.limit_hit(now), Err(OneDofError::NotHoming));
    a.home(dir, speed).unwrap();
    assert_eq!(a.move_to(1.0), Err(OneDofError::Homing));
    // The module follows the spline in real time; the switch is where the
    // axis passes `switch` (axis direction = dir · sign(scale)).
    let sense = f64::from(dir) * scale.signum();
    let past = |x: f64| (x - switch) * sense >= 0.0;
    let mut prev = now;
    let t_cross = loop {
        now += u64::from(IV) / 4;
        tick(&mut a, now, &mut pts);
        if let Some(x) = spline(&pts, now) {
            if past(x) {
                // First µs past the switch, by bisection.
                let (mut lo, mut hi) = (prev, now);
                while hi - lo > 1 {
                    let mid = (lo + hi) / 2;
                    if spline(&pts, mid).is_some_and(past) {
                        hi = mid
                    } else {
                        lo = mid
                    }
                }
                break hi;
            }
            prev = now;
        }
        assert!(now < (1 << 36) + 60_000_000, "never reached the switch");
    };
    // The trigger arrives late; the axis has moved on meanwhile.
    while now < t_cross + delay {
        now += u64::from(IV) / 4;
        tick(&mut a, now, &mut pts);
    }
    let r = a.limit_hit(t_cross).unwrap();
    assert!(a.is_homed() && !a.is_homing());
    assert!((a.to_user(r.switch_axis) - home).abs() < 1e-9);
    // It stops within the limits and the stream has no jump.
    while a.is_moving() {
        now += u64::from(IV);
        tick(&mut a, now, &mut pts);
    }
    assert_eq!(a.state().unwrap().pos, r.rest_axis);
    assert!(
        (r.rest_axis - switch) * sense > 0.0,
        "stops past the switch"
    );
    assert_within(&pts, 100.0 * scale.abs(), 1000.0 * scale.abs());
    (r.switch_axis - switch).abs()
}

#[test]
fn homing_reconciles_a_late_switch_on_the_spline() {
    let mut rng = XorShift(0x9e37_79b9_7f4a_7c15);
    let (mut worst, mut worst_abs): (f64, f64) = (0.0, 0.0);
    for k in 0..40 {
        let scale: f64 = if k % 3 == 0 { -80.0 } else { 80.0 };
        let dir = if k % 2 == 0 { -1 } else { 1 };
        let speed = 5.0 + (rng.next() % 1500) as f64 / 100.0; // 5..20 mm/s
                                                              // Mostly while cruising; the last few while still accelerating.
        let distance = if k >= 36 {
            2.0 + (rng.next() % 1000) as f64 / 100.0
        } else {
            50.0 + (rng.next() % 300_000) as f64 / 100.0
        };
        let switch = f64::from(dir) * scale.signum() * distance;
        let delay = 100 + rng.next() % 50_000; // up to 50 ms late
        let err = home_once(scale, dir, speed, switch, delay, -2.5);
        let one_interval = speed * scale.abs() * f64::from(IV) * 1e-6;
        assert!(
            err < one_interval,
            "{err} over one interval's travel {one_interval}"
        );
        // The trigger time is resolved to 1 µs: that is the whole error.
        let one_us = speed * scale.abs() * 1e-6;
        assert!(
            err <= one_us * (1.0 + 1e-6),
            "{err} over 1 µs of travel {one_us}"
        );
        worst = worst.max(err / one_us);
        worst_abs = worst_abs.max(err);
    }
    println!("worst homing error: {worst:.3} µs of travel, {worst_abs:.2e} axis units");
}

#[test]
fn homing_errors() {
    let mut a = OneDof::new(cfg(80.0, 0.0)).unwrap();
    assert_eq!(a.home(1, 10.0), Err(OneDofError::NotSampled));
    assert_eq!(a.move_to(1.0), Err(OneDofError::NotSampled));
    a.sample(T0).unwrap();
    assert!(matches!(a.home(0, 10.0), Err(OneDofError::BadNumber(_))));
    assert!(matches!(a.home(1, -1.0), Err(OneDofError::BadNumber(_))));
    assert!(matches!(
        a.home(1, 200.0),
        Err(OneDofError::OverLimit { .. })
    ));
    a.set_history_len(8).unwrap();
    a.home(1, 10.0).unwrap();
    assert_eq!(a.velocity(1.0), Err(OneDofError::Homing));
    assert_eq!(a.home(1, 10.0), Err(OneDofError::Homing));
    let pts = run(&mut a, T0 + 20 * u64::from(IV));
    assert_eq!(a.history().count(), 8, "bounded");
    let step = u64::from(IV);
    assert_eq!(
        a.limit_hit(T0 - 1),
        Err(OneDofError::SwitchBeforeHoming {
            time: T0 - 1,
            started: T0
        })
    );
    let oldest = pts[pts.len() - 8].0;
    assert_eq!(
        a.limit_hit(oldest),
        Err(OneDofError::TooOld {
            time: oldest,
            oldest
        })
    );
    let newest = pts.last().unwrap().0;
    assert_eq!(
        a.limit_hit(newest - step),
        Err(OneDofError::NotYetEmitted {
            time: newest - step,
            newest
        })
    );
    assert!(a.is_homing(), "a refused trigger keeps homing");
    assert!(a.limit_hit(oldest + step + 17).is_ok());
    assert_eq!(a.limit_hit(newest), Err(OneDofError::NotHoming));
    // Samples: alignment and order.
    assert_eq!(
        a.sample(newest + 1),
        Err(OneDofError::Misaligned(newest + 1))
    );
    assert_eq!(
        a.sample(newest - step),
        Err(OneDofError::Stale {
            stamp: newest - step,
            last: newest
        })
    );
    assert_eq!(
        a.sample(newest),
        Ok(pts.last().unwrap().1),
        "same stamp, same point"
    );
    // A gap in the stream shows in the history.
    a.home(-1, 10.0).unwrap();
    a.sample(newest + 3 * step).unwrap();
    for k in 4..10 {
        a.sample(newest + k * step).unwrap();
    }
    assert_eq!(
        a.limit_hit(newest + 2 * step),
        Err(OneDofError::HistoryGap(newest + 2 * step))
    );
    assert!(a.stop().is_ok() && !a.is_homing());
    assert!(OneDofError::NotHoming.to_string().contains("not homing"));
}

#[test]
fn bad_numbers_are_refused() {
    for c in [
        OneDofConfig {
            max_vel: 0.0,
            ..cfg(1.0, 0.0)
        },
        OneDofConfig {
            max_acc: f64::NAN,
            ..cfg(1.0, 0.0)
        },
        OneDofConfig {
            scale: 0.0,
            ..cfg(1.0, 0.0)
        },
        OneDofConfig {
            offset: f64::INFINITY,
            ..cfg(1.0, 0.0)
        },
        OneDofConfig {
            history_len: 3,
            ..cfg(1.0, 0.0)
        },
    ] {
        assert!(matches!(OneDof::new(c), Err(OneDofError::BadNumber(_))));
    }
    let mut a = axis(1.0, 0.0);
    assert!(matches!(
        a.move_to(f64::NAN),
        Err(OneDofError::BadNumber(_))
    ));
    assert!(matches!(
        a.velocity(f64::INFINITY),
        Err(OneDofError::BadNumber(_))
    ));
    assert!(matches!(
        a.set_home(f64::NAN),
        Err(OneDofError::BadNumber(_))
    ));
    a.velocity(10.0).unwrap();
    run(&mut a, T0 + 10 * u64::from(IV));
    assert_eq!(a.set_position(0.0), Err(OneDofError::Moving));
    assert_eq!(
        OneDof::from_parts(1.0, 1.0, 1.0, 0.0, 1000).unwrap_err(),
        OneDofError::BadInterval(1000)
    );
}

#[test]
fn pipes_class_wire_api() {
    common::assert_wire_api::<OneDofBlock>(
        "OneDof",
        "OneDof(max_vel: f32, max_acc: f32, scale: f32, offset: f32, interval_us: u32) -> ()",
        &[
            "OneDof.move_to(pos: f32) -> (eta_us: u64)",
            "OneDof.velocity(v: f32) -> ()",
            "OneDof.stop() -> ()",
            "OneDof.sample(stamp: u64) -> (stamp: u64, position: f32)",
            "OneDof.home(dir: i8, speed: f32) -> ()",
            "OneDof.set_home(position: f32) -> ()",
            "OneDof.limit_hit(time: u64) -> (switch: f32)",
            "OneDof.set_position(pos: f32) -> ()",
            "OneDof.status() -> (position: f32, velocity: f32, moving: bool, homed: bool)",
        ],
    );
}

/// The failure code a wire member's error reports.
fn code(e: OneDofError) -> CallError {
    CallError::from(e)
}

#[test]
fn pipes_class() {
    let args = |v: f32, iv: u32| {
        [
            Value::F32(v),
            Value::F32(1000.0),
            Value::F32(80.0),
            Value::F32(0.0),
            Value::U32(iv),
        ]
    };
    assert_eq!(
        OneDofBlock::construct(&args(-1.0, 1024)).err(),
        Some(CallError::Failed(pipes_core::FailureCode::Other(1)))
    );
    assert_eq!(
        OneDofBlock::construct(&args(100.0, 1000)).err(),
        Some(CallError::Failed(pipes_core::FailureCode::Other(2)))
    );
    assert_eq!(
        OneDofBlock::construct(&args(100.0, 1024)[..4]).err(),
        Some(CallError::Failed(pipes_core::FailureCode::from_code(
            INPUT_DECODE_FAILED
        )))
    );
    let mut a = OneDofBlock::construct(&args(100.0, 1024)).unwrap();
    let cfg = *a.0.config();
    assert_eq!(
        (cfg.max_vel, cfg.max_acc, cfg.scale, cfg.offset),
        (100.0, 1000.0, 80.0, 0.0)
    );
    assert_eq!(cfg.interval.micros(), IV);
    assert_eq!(
        a.move_to(1.0).map_err(code),
        Err(CallError::Failed(pipes_core::FailureCode::Other(3)))
    );
    assert_eq!(a.sample(T0), Ok((T0, 0.0)));
    let eta = a.move_to(1.0).unwrap();
    assert_eq!(a.status(), (0.0, 0.0, true, false));
    let mut t = T0;
    while t < eta {
        t += u64::from(IV);
        a.sample(t).unwrap();
    }
    assert_eq!(a.sample(t), Ok((t, 80.0)));
    assert_eq!(a.status(), (1.0, 0.0, false, false));
    assert_eq!(
        a.limit_hit(t).map_err(code),
        Err(CallError::Failed(pipes_core::FailureCode::Other(5)))
    );
    assert_eq!(
        a.sample(t + 1).map_err(code),
        Err(CallError::Failed(pipes_core::FailureCode::Other(7)))
    );
    assert_eq!(
        a.sample(t - 1024).map_err(code),
        Err(CallError::Failed(pipes_core::FailureCode::Other(8)))
    );
    assert_eq!(
        a.velocity(101.0).map_err(code),
        Err(CallError::Failed(pipes_core::FailureCode::Other(6)))
    );
    assert_eq!(
        a.home(0, 5.0).map_err(code),
        Err(CallError::Failed(pipes_core::FailureCode::Other(1)))
    );
    assert_eq!(
        a.set_home(f32::NAN).map_err(code),
        Err(CallError::Failed(pipes_core::FailureCode::Other(1)))
    );
    a.set_position(2.0).unwrap();
    assert_eq!(a.status(), (2.0, 0.0, false, false));
    a.home(1, 10.0).unwrap();
    assert_eq!(
        a.move_to(0.0).map_err(code),
        Err(CallError::Failed(pipes_core::FailureCode::Other(4)))
    );
    assert_eq!(
        a.limit_hit(t - 1024).map_err(code),
        Err(CallError::Failed(pipes_core::FailureCode::Other(12)))
    );
    a.stop().unwrap();
    assert!(!a.0.is_homing());
}
