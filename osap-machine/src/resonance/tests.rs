//! Resonance plans, the accelerometer keys and the measurement's pieces.

use super::*;

#[test]
fn the_shaper_line_replaces_or_is_inserted() {
    let text = "[axes.x]\nmin = 0.0\n\n[axes.y]\nmin = 1.0\nshaper = { kind = \"zv\", freq_hz = 10.0, damping = 0.1 }\n";
    let l = "shaper = NEW";
    let s = with_shaper_line(text, "x", l).unwrap();
    assert!(s.starts_with("[axes.x]\nshaper = NEW\nmin = 0.0\n"));
    let s = with_shaper_line(text, "y", l).unwrap();
    assert!(s.ends_with("min = 1.0\nshaper = NEW\n"), "{s}");
    assert!(with_shaper_line(text, "z", l).is_none());
}

#[test]
fn bad_keys_are_refused_naming_them() {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/machines/plotter.toml"
    ))
    .unwrap();
    let err = |from: &str, to: &str| {
        assert!(text.contains(from), "{from}");
        MachineFile::parse(&text.replacen(from, to, 1))
            .and_then(|c| c.validate())
            .unwrap_err()
            .to_string()
    };
    let acc = r#"accelerometer = { module = "a", channel = 0, range = 50000.0 }"#;
    let e = err(acc, r#"accelerometer = { module = "q", range = 50000.0 }"#);
    assert!(e.contains("axes.x.accelerometer.module"), "{e}");
    let e = err(acc, r#"accelerometer = { module = "a", range = -1.0 }"#);
    assert!(e.contains("axes.x.accelerometer.range"), "{e}");
    let e = err(
        acc,
        &format!("{acc}\nshaper = {{ kind = \"zz\", freq_hz = 40.0, damping = 0.1 }}"),
    );
    assert!(e.contains("axes.x.shaper") && e.contains("mzv"), "{e}");
    let e = err(
        acc,
        &format!("{acc}\nshaper = {{ kind = \"ei\", freq_hz = 40.0, damping = 0.9 }}"),
    );
    assert!(e.contains("axes.x.shaper"), "{e}");
    // Both accelerometers on one module: not simulated.
    let cfg = MachineFile::parse(&text.replace(
        r#"accelerometer = { module = "b", channel = 0"#,
        r#"accelerometer = { module = "a", channel = 1"#,
    ))
    .unwrap();
    let (key, m) = crate::sim::accel::sim_accel(&cfg, "a").unwrap_err();
    assert!(
        key.contains("accelerometer.module") && m.contains("one per module"),
        "{m}"
    );
}

#[test]
fn the_spline_velocity_of_a_ramp_is_its_slope() {
    let iv = u64::from(INTERVAL_US);
    let sent: Vec<(u64, f64)> = (0..10).map(|i| (i * iv, i as f64 * 2.0)).collect();
    let v = spline_velocity(&sent, 3 * iv + 100).unwrap();
    assert!((v - 2.0 * 1e6 / iv as f64).abs() < 1e-6);
    assert!(spline_velocity(&sent, 0).is_none());
    assert!(spline_velocity(&sent, 9 * iv).is_none());
}

#[test]
fn the_plan_follows_the_limits() {
    let cfg = MachineFile::load(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/machines/plotter.toml"
    ))
    .unwrap();
    let p = Plan::for_axis(&cfg, "x", 8.0).unwrap();
    // 2500 units/s² × 0.9 at 12.5 µm steps: 1.5 steps at 55.1 Hz.
    assert!((p.f1 - 55.1).abs() < 0.5, "{p:?}");
    for f in [5.0, 20.0, 47.0, 55.0] {
        let w = 2.0 * PI * f;
        let a = p.amplitude(f);
        assert!(a * w * w <= p.acceleration * 1.0001);
        assert!(a * w <= p.velocity * 1.0001);
    }
    assert!(Plan::for_axis(&cfg, "q", 8.0).is_err());
    assert!(Plan::for_axis(&cfg, "x", 0.0).is_err());
}
