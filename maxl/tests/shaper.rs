//! Input shaping: the shapers' impulses, the streaming convolution, the
//! residual vibration of a mass-spring axis after a move (tuned and 10 %
//! off), the path deviation on a corner, and the PIPES class.
//!
//! `cargo test -p maxl --features std --test shaper -- --nocapture` prints
//! the measurements docs/motion-blocks.md quotes.

mod common;

use osap_core::time::SystemInstant;
use std::f64::consts::PI;

use maxl::blocks::interp::Interpolator;
use maxl::blocks::shaper::{
    residual_vibration, InputShaper, ShaperBlock, ShaperConfig, ShaperError, ShaperKind,
};
use maxl::Interval;
use pipes_core::class::PipesClass;
use pipes_core::function::CallError;
use pipes_core::Value;

/// The stamp interval of the simulations, µs.
const DT: u64 = 2048;
/// The first stamp.
const T0: u64 = 1 << 30;

fn cfg(kind: ShaperKind, f: f64, z: f64) -> ShaperConfig {
    ShaperConfig::new(kind, f, z).unwrap()
}

/// The duration each kind's formula gives.
fn formula_duration(kind: ShaperKind, f: f64, z: f64) -> f64 {
    let t_d = 1.0 / (f * (1.0 - z * z).sqrt());
    match kind {
        ShaperKind::Zv => 0.5 * t_d,
        ShaperKind::Mzv => 0.75 * t_d,
        ShaperKind::Ei | ShaperKind::Zvd => t_d,
        ShaperKind::TwoHumpEi => {
            (1.49920 - 0.09297 * z - 0.28338 * z * z + 1.85710 * z * z * z) / f
        }
        ShaperKind::ThreeHumpEi => 2.0 * t_d,
    }
}

#[test]
fn impulses_sum_to_one_ascend_and_last_the_formulas_duration() {
    for kind in ShaperKind::ALL {
        for f in [5.0, 23.5, 40.0, 120.0] {
            for z in [0.0, 0.05, 0.1, 0.2, kind.max_damping()] {
                let c = cfg(kind, f, z);
                let imp = c.impulses();
                let n = match kind {
                    ShaperKind::Zv => 2,
                    ShaperKind::TwoHumpEi => 4,
                    ShaperKind::ThreeHumpEi => 5,
                    _ => 3,
                };
                assert_eq!(imp.len(), n, "{kind:?}");
                let sum: f64 = imp.iter().map(|i| i.amplitude).sum();
                assert!((sum - 1.0).abs() < 1e-12, "{kind:?} {f} {z}: {sum}");
                assert!(imp.iter().all(|i| i.amplitude > 0.0), "{kind:?} {z}");
                assert_eq!(imp[0].time_s, 0.0);
                assert!(imp.windows(2).all(|w| w[0].time_s < w[1].time_s));
                let d = formula_duration(kind, f, z);
                assert!((c.duration_s() - d).abs() < 1e-12 * d.max(1.0), "{kind:?}");
                assert!(c.centroid_s() > 0.0 && c.centroid_s() < d);
            }
        }
    }
    // Known values, undamped.
    let a = |k, z| -> Vec<f64> {
        cfg(k, 40.0, z)
            .impulses()
            .iter()
            .map(|i| i.amplitude)
            .collect()
    };
    let close = |x: &[f64], y: &[f64]| x.iter().zip(y).all(|(a, b)| (a - b).abs() < 1e-12);
    assert!(close(&a(ShaperKind::Zv, 0.0), &[0.5, 0.5]));
    assert!(close(&a(ShaperKind::Zvd, 0.0), &[0.25, 0.5, 0.25]));
    let r = 1.0 - 1.0 / 2f64.sqrt();
    assert!(close(&a(ShaperKind::Mzv, 0.0), &[r, 2f64.sqrt() - 1.0, r]));
    assert!(close(
        &a(ShaperKind::Ei, 0.0),
        &[0.2621605, 0.4756125, 0.262227]
    ));
    // 3-hump EI, undamped: a₁ = (1 + 3v + 2√(2v(v+1)))/16 = 0.1124,
    // a₂ = (1 − v)/4, a₃ = (1 + v)/2 − 2a₁, symmetric; 5 % tolerance.
    let a1 = (1.0 + 0.15 + 2.0 * (2.0f64 * 0.05 * 1.05).sqrt()) / 16.0;
    let three = a(ShaperKind::ThreeHumpEi, 0.0);
    assert!((three[0] - 0.112_379_6).abs() < 1e-6, "{three:?}");
    assert!(close(&three, &[a1, 0.2375, 0.525 - 2.0 * a1, 0.2375, a1]));
    // Damped ZV: amplitudes 1 : exp(−ζπ/√(1−ζ²)).
    let z: f64 = 0.1;
    let k = (-z * PI / (1.0 - z * z).sqrt()).exp();
    assert!(close(
        &a(ShaperKind::Zv, z),
        &[1.0 / (1.0 + k), k / (1.0 + k)]
    ));
}

#[test]
fn theoretical_residual_vibration() {
    println!("kind      dur@40Hz  lag@40Hz   V(36Hz)  V(40Hz)  V(44Hz)   (ζ = 0.05)");
    for kind in ShaperKind::ALL {
        let c = cfg(kind, 40.0, 0.05);
        let imp = c.impulses();
        let v = |f| residual_vibration(&imp, f, 0.05);
        println!(
            "{:9} {:6.2} ms {:6.2} ms  {:7.4}  {:7.4}  {:7.4}",
            kind.name(),
            c.duration_s() * 1e3,
            c.centroid_s() * 1e3,
            v(36.0),
            v(40.0),
            v(44.0)
        );
        match kind {
            ShaperKind::Zv | ShaperKind::Mzv | ShaperKind::Zvd => assert!(v(40.0) < 1e-12),
            ShaperKind::Ei | ShaperKind::TwoHumpEi | ShaperKind::ThreeHumpEi => {
                assert!(v(40.0) <= EI_TOL + 0.005, "{kind:?}: {}", v(40.0));
                assert!(v(36.0) < EI_TOL + 0.005 && v(44.0) < EI_TOL + 0.005);
            }
        }
        // No shaping: everything remains.
        let one = [maxl::blocks::shaper::Impulse {
            amplitude: 1.0,
            time_s: 0.0,
        }];
        assert!((residual_vibration(&one, 40.0, 0.05) - 1.0).abs() < 1e-12);
    }
}

const EI_TOL: f64 = maxl::blocks::shaper::EI_VIBRATION_TOLERANCE;

/// Position `s` seconds into a trapezoidal move of `d` at `v`, `a` (0
/// before it starts, `d` after it ends), and the move's duration.
fn trapezoid(d: f64, v: f64, a: f64) -> (impl Fn(f64) -> f64, f64) {
    let ta = (v / a).min((d / a).sqrt());
    let vp = a * ta;
    let tc = (d - vp * ta) / vp;
    let total = 2.0 * ta + tc;
    let pos = move |s: f64| {
        if s <= 0.0 {
            0.0
        } else if s < ta {
            0.5 * a * s * s
        } else if s < ta + tc {
            0.5 * vp * ta + vp * (s - ta)
        } else if s < total {
            let r = total - s;
            d - 0.5 * a * r * r
        } else {
            d
        }
    };
    (pos, total)
}

/// Stamped control points of a 1-D move, starting 4 stamps in, with rest
/// before and `tail_s` after.
fn move_points(pos: impl Fn(f64) -> f64, total_s: f64, tail_s: f64) -> Vec<(u64, f64)> {
    let start = T0 + 4 * DT;
    let end = start + ((total_s + tail_s) * 1e6) as u64;
    (T0..=end)
        .step_by(DT as usize)
        .map(|t| (t, pos((t as f64 - start as f64) * 1e-6)))
        .collect()
}

/// The stream through a one-axis shaper.
fn shaped(points: &[(u64, f64)], c: Option<ShaperConfig>) -> Vec<(u64, f64)> {
    let mut s = InputShaper::<1>::new([c]);
    points
        .iter()
        .map(|&(t, x)| (t, s.shape(t, [x]).unwrap()[0]))
        .collect()
}

/// A carriage on a spring (natural frequency `f`, damping ratio `z`)
/// following the B-spline of `points` (what the module executes): the
/// amplitude of its free vibration when the commanded motion ends, and the
/// largest excursion from the final position measured over the 0.3 s after.
fn residual(points: &[(u64, f64)], f: f64, z: f64) -> (f64, f64) {
    let mut ip =
        Interpolator::<1>::new(Interval::from_micros(DT as u32).unwrap(), 1 << 16).unwrap();
    for &(t, x) in points {
        ip.push(t, [x]).unwrap();
    }
    let last = points.last().unwrap().1;
    let moving = points.iter().rev().find(|p| p.1 != last).unwrap().0;
    // The spline at t uses the points up to ⌊t⌋ + 2Δt and from ⌊t⌋ − Δt.
    let t_end = moving + 2 * DT;
    let t_obs = t_end + 300_000;
    assert!(t_obs + 2 * DT <= points.last().unwrap().0, "tail too short");
    let w = 2.0 * PI * f;
    let u = |t: u64| ip.eval(t).unwrap().pos[0];
    let acc = |t: u64, c: f64, v: f64| w * w * (u(t) - c) - 2.0 * z * w * v;
    const H: u64 = 64;
    let h = H as f64 * 1e-6;
    let (mut t, mut c, mut v) = (T0 + DT, points[0].1, 0.0);
    let mut amp_end = None;
    let mut seen = 0.0f64;
    while t < t_obs {
        if t == t_end {
            let e = c - last;
            let wd = w * (1.0 - z * z).sqrt();
            amp_end = Some(e.hypot((v + z * w * e) / wd));
        }
        if t >= t_end {
            seen = seen.max((c - last).abs());
        }
        let (k1c, k1v) = (v, acc(t, c, v));
        let (k2c, k2v) = (
            v + 0.5 * h * k1v,
            acc(t + H / 2, c + 0.5 * h * k1c, v + 0.5 * h * k1v),
        );
        let (k3c, k3v) = (
            v + 0.5 * h * k2v,
            acc(t + H / 2, c + 0.5 * h * k2c, v + 0.5 * h * k2v),
        );
        let (k4c, k4v) = (v + h * k3v, acc(t + H, c + h * k3c, v + h * k3v));
        c += h / 6.0 * (k1c + 2.0 * k2c + 2.0 * k3c + k4c);
        v += h / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v);
        t += H;
    }
    (amp_end.expect("t_end on the grid"), seen)
}

#[test]
fn residual_vibration_of_a_mass_spring_axis() {
    // 50 mm at 200 mm/s, 3000 mm/s², points every 2048 µs; the spring at
    // 40 Hz, ζ = 0.05, and 10 % either side; the shapers tuned to 40 Hz.
    let (pos, total) = trapezoid(50.0, 200.0, 3000.0);
    let input = move_points(pos, total, 0.8);
    let z = 0.05;
    let springs = [40.0, 36.0, 44.0];
    let plain: Vec<(f64, f64)> = springs.iter().map(|&f| residual(&input, f, z)).collect();
    println!(
        "unshaped residual (mm, at the end / max after): 40 Hz {:.4}/{:.4}, 36 Hz {:.4}/{:.4}, 44 Hz {:.4}/{:.4}",
        plain[0].0, plain[0].1, plain[1].0, plain[1].1, plain[2].0, plain[2].1
    );
    println!("kind      duration  reduction@40Hz (theory)  @36Hz (theory)  @44Hz (theory)");
    for kind in ShaperKind::ALL {
        let c = cfg(kind, 40.0, z);
        let out = shaped(&input, Some(c));
        assert_eq!(out.last().unwrap().1, 50.0, "ends exactly at the target");
        let mut line = format!("{:9} {:6.2} ms", kind.name(), c.duration_s() * 1e3);
        for (k, &f) in springs.iter().enumerate() {
            let (amp, seen) = residual(&out, f, z);
            let reduction = plain[k].0 / amp;
            let theory = 1.0 / residual_vibration(&c.impulses(), f, z);
            let theory_s = if theory > 1e6 {
                "∞".to_string()
            } else {
                format!("{theory:.1}")
            };
            line += &format!("  {reduction:8.1}× ({theory_s:>6}×)");
            // The free vibration's amplitude bounds what is seen after.
            assert!(seen <= amp * 1.0001 + 1e-9, "{kind:?} {f}: {seen} > {amp}");
            if k == 0 {
                assert!(reduction >= 10.0, "{kind:?}: only {reduction:.1}×");
            } else {
                // Off-tune, the measured reduction follows the theory.
                let want = 1.0 / theory;
                let got = 1.0 / reduction;
                assert!((got - want).abs() < 0.01, "{kind:?} {f}: {got} vs {want}");
            }
        }
        println!("{line}");
    }
}

/// The distance from `p` to the path (−L, 0) → (0, 0) → (0, L).
fn to_corner(p: [f64; 2], l: f64) -> f64 {
    let leg1 = (p[1].abs()).hypot((p[0].clamp(-l, 0.0) - p[0]).abs());
    let leg2 = (p[0].abs()).hypot((p[1].clamp(0.0, l) - p[1]).abs());
    leg1.min(leg2)
}

#[test]
fn corner_path_deviation() {
    // A 90° corner at a constant 100 mm/s: 20 mm along +x into (0, 0), then
    // 20 mm along +y; the same shaper on x and y, tuned to 40 Hz, ζ = 0.05.
    let (v, l) = (100.0, 20.0);
    let leg = l / v;
    let start = T0 + 8 * DT;
    let path = |t: u64| {
        let s = (t as f64 - start as f64) * 1e-6;
        let s = s.clamp(0.0, 2.0 * leg);
        if s <= leg {
            [-l + v * s, 0.0]
        } else {
            [0.0, v * (s - leg)]
        }
    };
    let stamps: Vec<u64> = (T0..T0 + 600_000).step_by(DT as usize).collect();
    let iv = Interval::from_micros(DT as u32).unwrap();
    let executed_dev = |pts: &[(u64, [f64; 2])]| {
        let mut ip = Interpolator::<2>::new(iv, 1 << 12).unwrap();
        for &(t, p) in pts {
            ip.push(t, p).unwrap();
        }
        let (a, b) = ip.span().unwrap();
        ip.executed(a + DT, b - 2 * DT, 50)
            .unwrap()
            .iter()
            .map(|&(_, p)| to_corner(p, l))
            .fold(0.0, f64::max)
    };
    let plain: Vec<(u64, [f64; 2])> = stamps.iter().map(|&t| (t, path(t))).collect();
    let spline_only = executed_dev(&plain);
    println!(
        "corner at {v} mm/s: the unshaped spline alone deviates {:.4} mm",
        spline_only
    );
    println!("kind      duration  v·duration  stream dev  executed dev  dev/(v·duration)  |s(t) − x(t − L)|");
    for kind in ShaperKind::ALL {
        let c = cfg(kind, 40.0, 0.05);
        let mut s = InputShaper::<2>::new([Some(c), Some(c)]);
        let out: Vec<(u64, [f64; 2])> = stamps
            .iter()
            .map(|&t| (t, s.shape(t, path(t)).unwrap()))
            .collect();
        let dev = out
            .iter()
            .map(|&(_, p)| to_corner(p, l))
            .fold(0.0, f64::max);
        let executed = executed_dev(&out);
        // Against the input delayed by the lag, at the same time.
        let lag_us = s.lag_s() * 1e6;
        let delayed = |t: u64| {
            let t = t as f64 - lag_us;
            let lo = path(t.floor() as u64);
            let hi = path(t.floor() as u64 + 1);
            let a = t - t.floor();
            [lo[0] + a * (hi[0] - lo[0]), lo[1] + a * (hi[1] - lo[1])]
        };
        let timed = out
            .iter()
            .map(|&(t, p)| {
                let d = delayed(t);
                (p[0] - d[0]).hypot(p[1] - d[1])
            })
            .fold(0.0, f64::max);
        let bound = v * c.duration_s();
        println!(
            "{:9} {:6.2} ms  {:6.3} mm  {:7.4} mm  {:8.4} mm   {:8.3}          {:.4} mm",
            kind.name(),
            c.duration_s() * 1e3,
            bound,
            dev,
            executed,
            dev / bound,
            timed
        );
        assert!(dev > 0.0 && dev <= bound, "{kind:?}: {dev} > {bound}");
        assert!(executed <= bound + spline_only);
        assert!(timed <= bound);
        // The shaped corner ends exactly where the path does.
        assert_eq!(out.last().unwrap().1, [0.0, l]);
    }
}

#[test]
fn output_is_the_impulse_sum_of_the_input() {
    // A smooth input: the output at each stamp is Σ A_i x(T − t_i) within
    // linear interpolation's error, |x''|·Δt²/8.
    let (amp, f) = (3.0, 4.5);
    let w = 2.0 * PI * f;
    let x = |t: f64| amp * (w * t).sin() + 0.7 * t;
    let bound = amp * w * w * (DT as f64 * 1e-6).powi(2) / 8.0;
    for kind in ShaperKind::ALL {
        let c = cfg(kind, 33.0, 0.1);
        let imp = c.impulses();
        let mut s = InputShaper::<1>::new([Some(c)]);
        // One axis: no alignment delay.
        for (k, i) in s.kernel(0).iter().zip(&imp) {
            assert_eq!(k.amplitude, i.amplitude);
            assert!((k.time_s - i.time_s).abs() < 1e-15);
        }
        assert!((s.lag_s() - c.centroid_s()).abs() < 1e-15);
        let mut worst = 0.0f64;
        for k in 0..400u64 {
            let t = T0 + k * DT;
            let ts = (t - T0) as f64 * 1e-6;
            let out = s.shape(t, [x(ts)]).unwrap()[0];
            if ts > c.duration_s() {
                let want: f64 = imp.iter().map(|i| i.amplitude * x(ts - i.time_s)).sum();
                worst = worst.max((out - want).abs());
            }
            assert!(s.len() as f64 <= s.window_s() * 1e6 / DT as f64 + 2.0);
        }
        assert!(worst <= bound, "{kind:?}: {worst} > {bound}");
    }
}

#[test]
fn starts_at_rest_holds_rest_exactly_and_refuses_bad_samples() {
    let mut s = InputShaper::<2>::new([Some(cfg(ShaperKind::Mzv, 40.0, 0.1)), None]);
    assert!(s.settled() && s.is_empty());
    // The first sample: at rest there before.
    assert_eq!(s.shape(T0, [1.25, -3.0]).unwrap(), [1.25, -3.0]);
    // A step is spread over the kernel: the first impulse's share at once.
    let a0 = cfg(ShaperKind::Mzv, 40.0, 0.1).impulses()[0].amplitude;
    let out = s.shape(T0 + DT, [2.25, -3.0]).unwrap();
    assert!((out[0] - (1.25 + a0)).abs() < 1e-12, "{out:?}");
    assert_eq!(out[1], -3.0);
    assert!(!s.settled());
    // The same stamp again replaces the sample.
    let again = s.shape(T0 + DT, [2.25, -3.0]).unwrap();
    assert_eq!(again, out);
    // Refused samples change nothing.
    assert_eq!(
        s.shape(T0, [0.0, 0.0]),
        Err(ShaperError::Stale {
            stamp: T0,
            newest: T0 + DT
        })
    );
    assert_eq!(
        s.shape(T0 + 2 * DT, [f64::NAN, 0.0]),
        Err(ShaperError::BadNumber)
    );
    assert_eq!(s.newest(), Some(T0 + DT));
    // Settles exactly at the input once the window has passed.
    let mut t = T0 + DT;
    let mut last = out;
    while (t - T0 - DT) as f64 * 1e-6 <= s.window_s() + 2.0 * DT as f64 * 1e-6 {
        t += DT;
        last = s.shape(t, [2.25, -3.0]).unwrap();
    }
    assert_eq!(last, [2.25, -3.0]);
    assert!(s.settled());
    assert!(s.len() <= (s.window_s() * 1e6) as usize / DT as usize + 2);
    // Uneven stamps are fine (interpolation between whatever is held).
    assert!(s.shape(t + 5000, [2.25, -3.0]).is_ok());
    s.reset();
    assert!(s.is_empty());
    assert_eq!(s.shape(t + 6000, [9.0, 9.0]).unwrap(), [9.0, 9.0]);
}

#[test]
fn axes_share_one_lag_so_lines_stay_straight() {
    // x MZV at 40 Hz, y EI at 55 Hz, z unshaped: at constant velocity every
    // axis is the input delayed by the same lag, so a diagonal stays on
    // its line.
    let cx = cfg(ShaperKind::Mzv, 40.0, 0.1);
    let cy = cfg(ShaperKind::Ei, 55.0, 0.1);
    let mut s = InputShaper::<3>::new([Some(cx), Some(cy), None]);
    let lag = cx.centroid_s().max(cy.centroid_s());
    assert_eq!(s.lag_s(), lag);
    for k in 0..3 {
        let c: f64 = s.kernel(k).iter().map(|i| i.amplitude * i.time_s).sum();
        assert!((c - lag).abs() < 1e-15, "axis {k}: centroid {c} vs {lag}");
    }
    assert_eq!(s.kernel(2).len(), 1, "z: a pure delay");
    let vel = [120.0, -45.0, 3.0];
    let mut worst = 0.0f64;
    for k in 0..300u64 {
        let t = T0 + k * DT;
        let ts = k as f64 * DT as f64 * 1e-6;
        let out = s.shape(t, vel.map(|v| v * ts)).unwrap();
        if ts > s.window_s() + 0.005 {
            for a in 0..3 {
                worst = worst.max((out[a] - vel[a] * (ts - lag)).abs());
            }
        }
    }
    assert!(worst < 1e-9, "{worst}");
}

#[test]
fn shapers_change_only_at_rest() {
    let mut s = InputShaper::<3>::unshaped();
    assert_eq!(s.lag_s(), 0.0);
    assert_eq!(s.shape(T0, [1.0, 2.0, 3.0]).unwrap(), [1.0, 2.0, 3.0]);
    assert_eq!(s.shape(T0 + DT, [1.5, 2.0, 3.0]).unwrap(), [1.5, 2.0, 3.0]);
    let zv = Some(cfg(ShaperKind::Zv, 40.0, 0.0));
    assert_eq!(s.set_axis(1, zv), Err(ShaperError::Moving));
    assert_eq!(s.set_axis(3, zv), Err(ShaperError::BadAxis(3)));
    s.shape(T0 + 2 * DT, [1.5, 2.0, 3.0]).unwrap();
    assert_eq!(s.set_axis(1, zv), Ok(()));
    assert_eq!(s.axis(1), zv);
    assert_eq!(s.len(), 1);
    assert!((s.lag_s() - 0.00625).abs() < 1e-12);
    // No step when the new kernel takes over, and a move afterwards is
    // shaped on y and delayed on x.
    assert_eq!(
        s.shape(T0 + 3 * DT, [1.5, 2.0, 3.0]).unwrap(),
        [1.5, 2.0, 3.0]
    );
    let out = s.shape(T0 + 4 * DT, [2.5, 4.0, 3.0]).unwrap();
    assert_eq!(out[0], 1.5, "x is delayed by the lag");
    assert!((out[1] - 3.0).abs() < 1e-12, "half of y's step at once");
}

#[test]
fn bad_configurations_are_refused() {
    use ShaperError::*;
    let e = |k, f, z| ShaperConfig::new(k, f, z).err();
    assert_eq!(e(ShaperKind::Zv, 0.0, 0.1), Some(BadFrequency(0.0)));
    assert_eq!(e(ShaperKind::Zv, 0.5, 0.1), Some(BadFrequency(0.5)));
    assert_eq!(e(ShaperKind::Zv, 2000.0, 0.1), Some(BadFrequency(2000.0)));
    assert!(matches!(
        e(ShaperKind::Zv, f64::NAN, 0.1),
        Some(BadFrequency(_))
    ));
    assert_eq!(
        e(ShaperKind::Mzv, 40.0, -0.01),
        Some(BadDamping {
            damping: -0.01,
            max: 0.99
        })
    );
    assert_eq!(
        e(ShaperKind::Zvd, 40.0, 1.0),
        Some(BadDamping {
            damping: 1.0,
            max: 0.99
        })
    );
    assert_eq!(
        e(ShaperKind::Ei, 40.0, 0.5),
        Some(BadDamping {
            damping: 0.5,
            max: 0.4
        })
    );
    assert_eq!(
        e(ShaperKind::TwoHumpEi, 40.0, 0.31),
        Some(BadDamping {
            damping: 0.31,
            max: 0.3
        })
    );
    assert!(matches!(
        e(ShaperKind::Zv, 40.0, f64::INFINITY),
        Some(BadDamping { .. })
    ));
    assert_eq!(ShaperKind::from_code(7), Err(UnknownKind(7)));
    assert_eq!(ShaperKind::from_code(0), Ok(None));
    for k in ShaperKind::ALL {
        assert_eq!(ShaperKind::from_code(k.code()), Ok(Some(k)));
    }
    // Kind 0 ignores its numbers.
    assert_eq!(ShaperConfig::from_wire(0, f64::NAN, 7.0), Ok(None));
    let codes = [
        BadFrequency(0.0),
        BadDamping {
            damping: 2.0,
            max: 0.99,
        },
        UnknownKind(9),
        Stale {
            stamp: 1,
            newest: 2,
        },
        BadNumber,
        BadAxis(3),
        Moving,
    ];
    for (i, e) in codes.iter().enumerate() {
        assert_eq!(e.code() as usize, i + 1);
        assert_eq!(
            CallError::from(*e),
            CallError::Failed(pipes_core::FailureCode::from_code(i as u8 + 1))
        );
        assert!(!e.to_string().is_empty());
    }
}

#[test]
fn pipes_class_wire_api() {
    common::assert_wire_api::<ShaperBlock>(
        "Shaper",
        "Shaper(kind: u8, freq_hz: f32, damping: f32) -> ()",
        &[
            "Shaper.shape(stamp: u64, x: f32, y: f32, z: f32) -> (stamp: u64, x: f32, y: f32, z: f32)",
            "Shaper.set_axis(axis: u8, kind: u8, freq_hz: f32, damping: f32) -> ()",
            "Shaper.axis(axis: u8) -> (kind: u8, freq_hz: f32, damping: f32, duration_us: u32)",
            "Shaper.status() -> (lag_us: u32, window_us: u32, samples: u32, settled: bool)",
            "Shaper.reset() -> ()",
        ],
    );
}

#[test]
fn pipes_class() {
    let failed = |code: u8| Some(CallError::Failed(code.into()));
    let ctor = |k, f, z| ShaperBlock::construct(&[Value::U8(k), Value::F32(f), Value::F32(z)]);
    assert_eq!(ctor(1, 0.0, 0.1).err(), failed(1));
    assert_eq!(ctor(1, 40.0, 1.0).err(), failed(2));
    assert_eq!(ctor(9, 40.0, 0.1).err(), failed(3));
    assert_eq!(ctor(3, 40.0, 0.41).err(), failed(2));
    // Each kind's damping limit, sent as f32, is within the limit.
    for k in ShaperKind::ALL {
        let mut s = ctor(k.code(), 40.0, k.max_damping() as f32).unwrap();
        assert_eq!(s.0.axis(0).unwrap().damping(), k.max_damping());
        assert_eq!(
            s.set_axis(2, k.code(), 40.0, k.max_damping() as f32),
            Ok(())
        );
    }
    let mut s = ctor(2, 40.0, 0.1).unwrap();
    let (kind, f, z, dur) = s.axis(0).unwrap();
    assert_eq!((kind, f, z), (2, 40.0, 0.1));
    assert_eq!(s.0.axis(0).unwrap().damping(), 0.1, "as typed");
    let want = 0.75 / (40.0 * (1.0 - 0.1f64 * 0.1).sqrt());
    assert_eq!(dur, (want * 1e6).round() as u32);
    assert_eq!(s.axis(1).unwrap().0, 2);
    assert_eq!(s.axis(2).unwrap(), (0, 0.0, 0.0, 0));
    assert_eq!(s.axis(3).map_err(CallError::from).err(), failed(6));
    let (lag, window, n, settled) = s.status();
    assert!(lag > 0 && window >= lag && n == 0 && settled);

    assert_eq!(s.shape(T0, 1.0, 2.0, 3.0).unwrap(), (T0, 1.0, 2.0, 3.0));
    let (t, x, y, z) = s.shape(T0 + DT, 2.0, 2.0, 3.0).unwrap();
    assert_eq!(t, T0 + DT);
    assert!(x > 1.0 && x < 2.0 && y == 2.0 && z == 3.0);
    assert!(!s.status().3);
    let shape = |s: &mut ShaperBlock, t, x| s.shape(t, x, 0.0, 0.0).map_err(CallError::from).err();
    assert_eq!(shape(&mut s, T0, 0.0), failed(4));
    assert_eq!(shape(&mut s, T0 + 2 * DT, f32::NAN), failed(5));
    let set =
        |s: &mut ShaperBlock, a, k| s.set_axis(a, k, 40.0, 0.1).map_err(CallError::from).err();
    assert_eq!(set(&mut s, 2, 3), failed(7));
    assert_eq!(set(&mut s, 3, 3), failed(6));
    assert_eq!(set(&mut s, 0, 8), failed(3));
    // At rest: settle, then reconfigure z.
    let mut t = T0 + DT;
    while !s.status().3 {
        t += DT;
        assert_eq!(s.shape(t, 2.0, 2.0, 3.0).unwrap().0, t);
    }
    assert_eq!(
        s.shape(t + DT, 2.0, 2.0, 3.0).unwrap(),
        (t + DT, 2.0, 2.0, 3.0)
    );
    assert_eq!(set(&mut s, 2, 3), None);
    assert_eq!(s.axis(2).unwrap().0, 3);
    assert_eq!(s.0.axis(2).unwrap().kind(), ShaperKind::Ei);
    s.reset();
    assert_eq!(s.status().2, 0);
    // Kind 0 shapes nothing: the stream passes through unchanged.
    let mut none = ctor(0, 0.0, 0.0).unwrap();
    assert_eq!(none.status().0, 0);
    for k in 0..10u64 {
        let p = k as f32 * 1.5;
        assert_eq!(
            none.shape(T0 + k * DT, p, -p, 1.0).unwrap(),
            (T0 + k * DT, p, -p, 1.0)
        );
    }
}

#[test]
fn sits_between_the_planner_and_kinematics() {
    use maxl::blocks::kinematics::CoreXyBlock;
    use maxl::blocks::planner::PlannerBlock;
    use maxl::blocks::timer::TimerBlock;

    // The wire types chain: Planner.sample → Shaper.shape → CoreXY.inverse.
    let member = |ms: &[&'static pipes_core::signature::Signature], name: &str| {
        *ms.iter().find(|s| s.name == name).unwrap()
    };
    let types =
        |a: &[pipes_core::signature::Arg]| a.iter().map(|a| a.ty.to_string()).collect::<Vec<_>>();
    let sample = member(PlannerBlock::MEMBERS, "Planner.sample");
    let shape = member(ShaperBlock::MEMBERS, "Shaper.shape");
    let inverse = member(CoreXyBlock::MEMBERS, "CoreXY.inverse");
    assert_eq!(types(sample.outputs), types(shape.inputs));
    assert_eq!(types(shape.outputs), types(inverse.inputs));

    // Timer → Planner.sample → Shaper.shape → CoreXY.inverse, called as the
    // pipes would: a planned 90° corner (junction deviation 0.05 mm) at
    // 100 mm/s, 3000 mm/s², through each shaper at 40 Hz, ζ = 0.1.
    for kind in ShaperKind::ALL {
        let mut timer = TimerBlock::new(DT as u32, 3 * DT as u32).unwrap();
        let mut planner = PlannerBlock::new(
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
        let mut shaper = ShaperBlock::new(kind.code(), 40.0, 0.1).unwrap();
        let kin = CoreXyBlock::wire_new(80.0).unwrap();
        planner.line(20.0, 0.0, 0.0, 100.0).unwrap();
        planner.line(20.0, 20.0, 0.0, 100.0).unwrap();
        let (mut planned, mut out) = (Vec::new(), Vec::new());
        let mut now = T0;
        let mut rest = 0;
        while rest < 40 {
            timer.set_now(SystemInstant::from_micros(now));
            let stamp = timer.tick().unwrap();
            now += DT;
            let (t, x, y, z) = planner.sample(stamp).unwrap();
            let (t, sx, sy, sz) = shaper.shape(t, x, y, z).unwrap();
            let (t, a, b, _) = kin.inverse(t, sx, sy, sz).unwrap();
            assert_eq!(t, stamp);
            planned.push([f64::from(x), f64::from(y)]);
            out.push([f64::from(sx), f64::from(sy)]);
            let (ta, tb) = (80.0 * (sx + sy), 80.0 * (sx - sy));
            assert!((a - ta).abs() <= 1e-3 && (b - tb).abs() <= 1e-3);
            rest = if shaper.status().3 && planner.status().2 {
                rest + 1
            } else {
                0
            };
        }
        assert_eq!(*out.last().unwrap(), [20.0, 20.0]);
        // Distance of the shaped path from the planned one (its polyline).
        let dist = |p: [f64; 2]| {
            planned
                .windows(2)
                .map(|w| {
                    let (a, b) = (w[0], w[1]);
                    let d = [b[0] - a[0], b[1] - a[1]];
                    let l2 = d[0] * d[0] + d[1] * d[1];
                    let s = if l2 > 0.0 {
                        (((p[0] - a[0]) * d[0] + (p[1] - a[1]) * d[1]) / l2).clamp(0.0, 1.0)
                    } else {
                        0.0
                    };
                    (p[0] - a[0] - s * d[0]).hypot(p[1] - a[1] - s * d[1])
                })
                .fold(f64::INFINITY, f64::min)
        };
        let dev = out.iter().map(|&p| dist(p)).fold(0.0, f64::max);
        let c = shaper.0.axis(0).unwrap();
        println!(
            "planned corner (junction deviation 0.05 mm, 100 mm/s) through {:9}: {dev:.4} mm from the planned path (v·duration {:.3} mm)",
            kind.name(),
            100.0 * c.duration_s()
        );
        assert!(dev <= 100.0 * c.duration_s());
    }
}
