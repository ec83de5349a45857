//! The reference interpolator: linear motion, agreement with `Track<f32>`,
//! the deviation helper and the PIPES class.

mod common;

use common::rng::XorShift;
use maxl::blocks::interp::{InterpError, Interpolator, InterpolatorBlock, Pushed};
use maxl::{BackstopLimits, Interval, Track};
use osap_core::time::SystemInstant;
use pipes_core::class::PipesClass;
use pipes_core::function::CallError;
use pipes_core::Value;

const T0: u64 = 1 << 36;

fn iv(us: u32) -> Interval {
    Interval::from_micros(us).unwrap()
}

#[test]
fn linear_motion_is_reproduced_exactly() {
    let step = 2048u64;
    let mut ip = Interpolator::<3>::new(iv(2048), 1000).unwrap();
    let line = |t: u64| {
        let s = (t - T0) as f64 * 1e-6;
        [1.5 + 20.0 * s, -3.0 - 7.25 * s, 0.125 * s]
    };
    for k in 0..100 {
        assert_eq!(
            ip.push(T0 + k * step, line(T0 + k * step)),
            Ok(Pushed::Appended)
        );
    }
    assert!(ip.eval(T0 + 1000).is_none(), "needs the point before");
    assert!(ip.eval(T0 + 98 * step).is_none(), "needs two points ahead");
    assert!(ip.eval(T0 + 98 * step - 1).is_some(), "the last known µs");
    assert!(ip.eval(T0 + 97 * step).is_some());
    let mut worst = 0.0f64;
    for t in (T0 + step..T0 + 98 * step).step_by(37) {
        let k = ip.eval(t).unwrap();
        let want = line(t);
        for (x, w) in k.pos.iter().zip(&want) {
            worst = worst.max((x - w).abs());
        }
        assert!((k.vel[0] - 20.0).abs() < 1e-9 && (k.vel[1] + 7.25).abs() < 1e-9);
        assert!((k.vel[2] - 0.125).abs() < 1e-9);
    }
    assert!(worst < 1e-12, "{worst}");
    let d = ip
        .max_deviation(line, T0, T0 + 100 * step, 100)
        .unwrap()
        .unwrap();
    assert!(d.max < 1e-12);
}

#[test]
fn matches_the_modules_f32_track() {
    let interval = iv(1024);
    let limits = BackstopLimits {
        max_acc: 1e6,
        max_jerk: 1e9,
    };
    let mut track: Track<f32, 64> = Track::new(interval, limits);
    let mut ip = Interpolator::<1>::new(interval, 64).unwrap();
    let mut rng = XorShift(0x2545_f491_4f6c_dd1d);
    let step = 1024u64;
    let mut x = 0.0f64;
    let (mut worst, mut span) = (0.0f64, 0.0f64);
    for k in 0..2000u64 {
        x += (rng.unit() - 0.5) * 40.0;
        span = span.max(x.abs());
        let p = x as f32;
        track
            .push(SystemInstant::from_micros(T0 + k * step), p)
            .unwrap();
        ip.push(T0 + k * step, [f64::from(p)]).unwrap();
        if k >= 4 {
            // Inside the known curve: the segment before the newest two.
            let t = T0 + (k - 2) * step + rng.next() % step;
            let a = track.sample(SystemInstant::from_micros(t)).unwrap().kin;
            let b = ip.eval(t).unwrap();
            let tol = 1e-5 * f64::from(a.pos.abs()).max(1.0);
            let err = (f64::from(a.pos) - b.pos[0]).abs();
            assert!(err <= tol, "{err} at {t}");
            worst = worst.max(err / f64::from(a.pos.abs()).max(1.0));
            let vtol = 1e-4 * b.vel[0].abs().max(1000.0);
            assert!((f64::from(a.vel) - b.vel[0]).abs() <= vtol);
        }
    }
    println!("worst relative f32 position error: {worst:.2e} (|x| up to {span:.0})");
}

#[test]
fn gaps_like_a_module() {
    let step = 512u64;
    let mut ip = Interpolator::<2>::new(iv(512), 16).unwrap();
    ip.push(T0, [0.0, 0.0]).unwrap();
    assert_eq!(ip.push(T0 + 2 * step, [2.0, -2.0]), Ok(Pushed::FilledGap));
    assert_eq!(ip.points().nth(1), Some((T0 + step, [1.0, -1.0])));
    assert_eq!(
        ip.push(T0 + 5 * step, [5.0, 0.0]),
        Ok(Pushed::Gap { missing: 2 })
    );
    ip.push(T0 + 6 * step, [6.0, 0.0]).unwrap();
    ip.push(T0 + 7 * step, [7.0, 0.0]).unwrap();
    ip.push(T0 + 8 * step, [8.0, 0.0]).unwrap();
    assert!(ip.eval(T0 + 3 * step).is_none(), "across the gap");
    assert!(ip.eval(T0 + 6 * step).is_some());
    assert_eq!(
        ip.push(T0 + 8 * step, [0.0, 0.0]),
        Err(InterpError::Stale {
            stamp: T0 + 8 * step,
            newest: T0 + 8 * step
        })
    );
    assert_eq!(
        ip.push(T0 + 1, [0.0, 0.0]),
        Err(InterpError::Misaligned(T0 + 1))
    );
    assert_eq!(
        ip.push(T0 + 9 * step, [f64::NAN, 0.0]),
        Err(InterpError::BadNumber)
    );
    for k in 9..40 {
        ip.push(T0 + k * step, [k as f64, 0.0]).unwrap();
    }
    assert_eq!(ip.len(), 16, "bounded");
    assert_eq!(ip.span(), Some((T0 + 24 * step, T0 + 39 * step)));
    assert_eq!(ip.executed(T0, T0 + 100, 0), Err(InterpError::BadStep));
    assert!(Interpolator::<1>::new(iv(512), 3).is_err());
}

#[test]
fn deviation_helper_finds_a_known_deviation() {
    // A straight line with one control point pushed off by delta: at that
    // point's own stamp the curve moves by 4·delta/6, its largest effect.
    let step = 1024u64;
    let delta = 0.3;
    let bump = 40u64;
    let line = |t: u64| {
        let s = (t - T0) as f64 * 1e-6;
        [10.0 * s, 5.0 * s]
    };
    let mut ip = Interpolator::<2>::new(iv(1024), 200).unwrap();
    for k in 0..100 {
        let mut p = line(T0 + k * step);
        if k == bump {
            p[1] += delta;
        }
        ip.push(T0 + k * step, p).unwrap();
    }
    let d = ip
        .max_deviation(line, T0, T0 + 100 * step, 64)
        .unwrap()
        .unwrap();
    assert_eq!(d.at, T0 + bump * step);
    assert!((d.max - 4.0 * delta / 6.0).abs() < 1e-12, "{}", d.max);
    assert!((d.executed[1] - d.planned[1] - 0.2).abs() < 1e-12);
    let exec = ip.executed(T0, T0 + 100 * step, 64).unwrap();
    assert_eq!(exec.first().unwrap().0, T0 + step, "first known time");
    assert_eq!(exec.last().unwrap().0, T0 + 98 * step - 64);
    assert!(ip.max_deviation(line, T0, T0 + 10, 1).unwrap().is_none());
}

#[test]
fn pipes_class_wire_api() {
    common::assert_wire_api::<InterpolatorBlock>(
        "Interpolator",
        "Interpolator(interval_us: u32, capacity: u32) -> ()",
        &[
            "Interpolator.push(stamp: u64, x: f64, y: f64, z: f64) -> ()",
            "Interpolator.eval(t: u64) -> (x: f64, y: f64, z: f64)",
            "Interpolator.vel(t: u64) -> (vx: f64, vy: f64, vz: f64)",
            "Interpolator.span() -> (points: u32, oldest: u64, newest: u64)",
            "Interpolator.clear() -> ()",
        ],
    );
}

#[test]
fn pipes_class() {
    let failed = |code: u8| Some(CallError::Failed(code.into()));
    assert_eq!(
        InterpolatorBlock::construct(&[Value::U32(1000), Value::U32(100)]).err(),
        failed(2)
    );
    assert_eq!(
        InterpolatorBlock::construct(&[Value::U32(1024), Value::U32(2)]).err(),
        failed(6)
    );
    let mut ip = InterpolatorBlock::construct(&[Value::U32(1024), Value::U32(100)]).unwrap();
    assert_eq!(ip.0.interval().micros(), 1024);
    assert_eq!(ip.span(), (0, 0, 0));
    assert_eq!(ip.eval(T0).map_err(CallError::from).err(), failed(5));
    for k in 0..4u64 {
        ip.push(T0 + k * 1024, k as f64, 2.0 * k as f64, 1.0)
            .unwrap();
    }
    assert_eq!(ip.span(), (4, T0, T0 + 3 * 1024));
    let (x, y, z) = ip.eval(T0 + 1024 + 512).unwrap();
    assert!((x - 1.5).abs() < 1e-12 && (y - 3.0).abs() < 1e-12 && (z - 1.0).abs() < 1e-12);
    let (vx, _, vz) = ip.vel(T0 + 1024).unwrap();
    assert!((vx - 1e6 / 1024.0).abs() < 1e-9 && vz.abs() < 1e-12);
    assert_eq!(ip.vel(T0).map_err(CallError::from).err(), failed(5));

    let push = |ip: &mut InterpolatorBlock, stamp, x| {
        ip.push(stamp, x, 0.0, 0.0).map_err(CallError::from).err()
    };
    assert_eq!(push(&mut ip, T0 + 4 * 1024, f64::NAN), failed(1));
    assert_eq!(push(&mut ip, T0 + 4 * 1024 + 1, 0.0), failed(3));
    assert_eq!(push(&mut ip, T0 + 3 * 1024, 0.0), failed(4));
    ip.clear();
    assert_eq!(ip.span(), (0, 0, 0));
}
