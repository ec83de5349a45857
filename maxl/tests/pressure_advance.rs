//! Pressure advance against Klipper's formula: the advanced position is
//! the nominal position plus K times the velocity, averaged over a
//! triangle of half-width smooth_time/2 (kin_extruder.c), here integrated
//! independently with a fine midpoint rule on a trapezoidal extrusion.

use maxl::blocks::pressure_advance::{ExtruderState, PressureAdvance, PressureAdvanceError};

/// A printer's extruding move: 0.034 mm of e per mm of path, the toolhead
/// accelerating at 3000 mm/s² to 100 mm/s, cruising 0.2 s, braking; e
/// accelerates at 102 mm/s² to 3.4 mm/s. Starts at t = 0.1 s.
fn trapezoid(t: f64) -> ExtruderState {
    let (a, v, t0, cruise) = (102.0, 3.4, 0.1, 0.2);
    let ta = v / a;
    let (t1, t2, t3) = (t0 + ta, t0 + ta + cruise, t0 + 2.0 * ta + cruise);
    let e1 = 0.5 * a * ta * ta;
    let e2 = e1 + v * cruise;
    let (position, velocity) = if t < t0 {
        (0.0, 0.0)
    } else if t < t1 {
        let s = t - t0;
        (0.5 * a * s * s, a * s)
    } else if t < t2 {
        (e1 + v * (t - t1), v)
    } else if t < t3 {
        let s = t - t2;
        (e2 + v * s - 0.5 * a * s * s, v - a * s)
    } else {
        (e2 + e1, 0.0)
    };
    ExtruderState {
        position,
        velocity,
        advances: true,
    }
}

/// Klipper's formula, integrated with a fine midpoint rule.
fn klipper(t: f64, k: f64, smooth: f64, nominal: impl Fn(f64) -> ExtruderState) -> f64 {
    let h = smooth / 2.0;
    let n = 50_000;
    let d = 2.0 * h / n as f64;
    (0..n)
        .map(|i| {
            let tau = -h + (i as f64 + 0.5) * d;
            let s = nominal(t + tau);
            let w = (h - tau.abs()) / (h * h);
            w * (s.position + if s.advances { k * s.velocity } else { 0.0 }) * d
        })
        .sum()
}

#[test]
fn the_same_k_gives_klippers_extruder_motion() {
    let pa = PressureAdvance::new(0.04, 0.04).unwrap();
    assert_eq!(pa.reach(), 0.02);
    let mut worst: f64 = 0.0;
    let mut t = 0.05;
    while t < 0.45 {
        let got = pa.position(t, trapezoid);
        let want = klipper(t, 0.04, 0.04, trapezoid);
        worst = worst.max((got - want).abs());
        t += 0.0007;
    }
    // 1e-5 mm is 0.004 microsteps at 400 microsteps/mm (measured: 2.9e-6,
    // at the changes of acceleration); K off by 1 % is 1.4e-3.
    assert!(worst < 1e-5, "worst difference {worst} mm");
    // While cruising, the advance is exactly K·v ahead of the nominal.
    let cruise = pa.position(0.2, trapezoid) - trapezoid(0.2).position;
    assert!((cruise - 0.04 * 3.4).abs() < 1e-9, "{cruise}");
    // At rest afterwards, none.
    let rest = pa.position(0.5, trapezoid) - trapezoid(0.5).position;
    assert!(rest.abs() < 1e-12, "{rest}");
}

#[test]
fn no_smoothing_is_e_plus_k_v_and_retractions_do_not_advance() {
    let pa = PressureAdvance::new(0.05, 0.0).unwrap();
    let s = trapezoid(0.11);
    assert_eq!(pa.position(0.11, trapezoid), s.position + 0.05 * s.velocity);
    // A retraction: smoothed, never advanced.
    let retract = |t: f64| ExtruderState {
        advances: false,
        ..trapezoid(t)
    };
    let pa = PressureAdvance::new(0.05, 0.04).unwrap();
    let got = pa.position(0.2, retract);
    assert!((got - trapezoid(0.2).position).abs() < 1e-9, "{got}");
    let got = pa.position(0.12, retract);
    let want = klipper(0.12, 0.05, 0.04, retract);
    assert!((got - want).abs() < 1e-6, "{got} {want}");
}

#[test]
fn bad_settings_are_refused() {
    assert_eq!(
        PressureAdvance::new(-0.1, 0.04),
        Err(PressureAdvanceError::BadAdvance(-0.1))
    );
    assert!(PressureAdvance::new(0.04, f64::NAN).is_err());
    assert!(PressureAdvance::new(f64::INFINITY, 0.04).is_err());
}
