//! The fitting is not about plastic: a milling cutter's force law (the
//! Kienzle law, as docs/rheo.md shows it) fitted from a stepped
//! experiment, feed per tooth stepped at three widths of cut.

use osap_fit::experiment::{steady_states, Plan, RanStep};
use osap_fit::{fit, Model, Point};

/// F = k_c · h^(1 − m_c) · b: chip thickness h (mm per tooth), width b (mm).
struct Kienzle;

impl Model for Kienzle {
    fn names(&self) -> &'static [&'static str] {
        &["k_c", "m_c"]
    }
    fn predict(&self, p: &[f64], x: &[f64]) -> f64 {
        p[0] * x[0].powf(1.0 - p[1]) * x[1]
    }
}

#[test]
fn a_cutting_force_law_is_fitted_from_a_stepped_experiment() {
    // Aluminium: k_c 700 N/mm², m_c 0.25; the force through 2 % noise.
    let (k_c, m_c) = (700.0, 0.25);
    let plan = Plan::grid(&[1.0, 2.0, 3.0], &[0.02, 0.04, 0.06, 0.08], 1.0);
    let ran: Vec<RanStep> = plan
        .steps
        .iter()
        .enumerate()
        .map(|(i, &spec)| RanStep {
            spec,
            start_s: i as f64,
            end_s: i as f64 + 1.0,
        })
        .collect();
    let mut seed = 3u64;
    let record: Vec<(f64, f64)> = (0..1200)
        .map(|k| {
            let t = f64::from(k) * 0.01;
            let s = &ran[(t as usize).min(ran.len() - 1)];
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let u = (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
            let f = k_c * s.spec.setpoint.powf(1.0 - m_c) * s.spec.condition;
            (t, f * (1.0 + 0.04 * u))
        })
        .collect();
    let (steady, skipped) = steady_states(&ran, &record, 0.2, 20);
    assert_eq!(skipped, 0);
    let points: Vec<Point> = steady
        .iter()
        .map(|s| Point {
            x: vec![s.spec.setpoint, s.spec.condition],
            y: s.mean,
        })
        .collect();
    let f = fit(&Kienzle, &points, &[1500.0, 0.5]).unwrap();
    assert!((f.params[0] / k_c - 1.0).abs() < 0.02, "{:?}", f.params);
    assert!((f.params[1] - m_c).abs() < 0.01, "{:?}", f.params);
    assert!(f.std_errors.iter().all(|e| e.is_finite() && *e > 0.0));
}
