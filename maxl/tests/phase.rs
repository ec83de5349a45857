//! Phase output: accuracy against f64 sin/cos over a whole electrical
//! period, exact full steps and table nodes, near-constant magnitude.

use maxl::eval::Fx;
use maxl::phase::{unit, Coils, PhaseOut, QUARTER_SINE, TABLE_STEPS, UNIT};

/// Stated bound for the unit amplitudes, in Q15 LSB (see docs/maxl.md):
/// table rounding ½ + interpolation (π/512)²/8 · 32768 = 0.154 + rounding ½.
const BOUND: f64 = 1.16;

#[test]
fn table_is_the_rounded_quarter_sine() {
    assert_eq!(QUARTER_SINE.len(), TABLE_STEPS + 1);
    assert_eq!(QUARTER_SINE[0], 0);
    assert_eq!(QUARTER_SINE[TABLE_STEPS], UNIT as u16);
    for (i, &v) in QUARTER_SINE.iter().enumerate() {
        let x = std::f64::consts::FRAC_PI_2 * i as f64 / TABLE_STEPS as f64;
        let want = (x.sin() * UNIT as f64).round();
        assert_eq!(v as f64, want, "entry {i}");
    }
}

#[test]
fn every_angle_of_a_period_within_bound() {
    let (mut worst, mut mag_lo, mut mag_hi) = (0.0f64, f64::MAX, 0.0f64);
    // Every Q16.16 position over 4 full steps, and the same shifted by
    // whole periods in both directions.
    for base in [0i64, -4 << 16, 4000 << 16, -(8192 << 16)] {
        for raw in 0..(4i64 << 16) {
            let p = Fx((base + raw) as i32);
            let c = unit(p);
            let th = std::f64::consts::FRAC_PI_2 * (raw as f64 / 65536.0);
            let (ea, eb) = (
                (c.a as f64 - th.cos() * UNIT as f64).abs(),
                (c.b as f64 - th.sin() * UNIT as f64).abs(),
            );
            worst = worst.max(ea).max(eb);
            let m = ((c.a as f64).powi(2) + (c.b as f64).powi(2)).sqrt();
            mag_lo = mag_lo.min(m);
            mag_hi = mag_hi.max(m);
        }
    }
    println!("max error {worst:.3} LSB, magnitude {mag_lo:.2}..{mag_hi:.2}");
    assert!(worst <= BOUND, "{worst}");
    // Magnitude within 1.5 LSB of 32768 (4.6e-5 relative).
    assert!(mag_lo >= UNIT as f64 - 1.5 && mag_hi <= UNIT as f64 + 1.5);
}

#[test]
fn full_steps_and_table_nodes_are_exact() {
    let full = [
        Coils { a: UNIT, b: 0 },
        Coils { a: 0, b: UNIT },
        Coils { a: -UNIT, b: 0 },
        Coils { a: 0, b: -UNIT },
    ];
    for k in -12i32..12 {
        assert_eq!(
            unit(Fx(k << 16)),
            full[k.rem_euclid(4) as usize],
            "step {k}"
        );
    }
    for i in 0..=TABLE_STEPS {
        let c = unit(Fx((i as i32) << 8));
        assert_eq!(c.b, QUARTER_SINE[i] as i32);
        assert_eq!(c.a, QUARTER_SINE[TABLE_STEPS - i] as i32);
    }
}

#[test]
fn scaled_outputs() {
    for peak in [1u16, 255, 1000, 4095, 32767, 65535] {
        let out = PhaseOut::new(peak);
        let mut worst = 0.0f64;
        for raw in (0..(4i32 << 16)).step_by(37) {
            let c = out.coils(Fx(raw));
            assert!(c.a.abs() <= peak as i32 && c.b.abs() <= peak as i32);
            let th = std::f64::consts::FRAC_PI_2 * (raw as f64 / 65536.0);
            let e = (c.a as f64 - th.cos() * peak as f64)
                .abs()
                .max((c.b as f64 - th.sin() * peak as f64).abs());
            worst = worst.max(e);
        }
        // Unit error scaled, plus the final rounding.
        assert!(
            worst <= BOUND * peak as f64 / UNIT as f64 + 0.5,
            "{peak}: {worst}"
        );
        assert_eq!(
            out.coils(Fx(0)),
            Coils {
                a: peak as i32,
                b: 0
            }
        );
        assert_eq!(
            out.coils(Fx(3 << 16)),
            Coils {
                a: 0,
                b: -(peak as i32)
            }
        );
    }
    let mut o = PhaseOut::new(100);
    o.set_peak(0);
    assert_eq!(o.peak(), 0);
    assert_eq!(o.coils(Fx(12345)), Coils { a: 0, b: 0 });
}
