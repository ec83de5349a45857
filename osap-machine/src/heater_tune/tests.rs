//! The gains, the relay's peaks and the file edit.

use super::*;

fn near(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol
}

#[test]
fn the_gains_are_klippers_ziegler_nichols_by_hand() {
    // Ku = 4/(π·2.5) = 0.509296; kp = 0.6·Ku·255 = 77.9223;
    // Ti = 3 s: ki = 25.9741; Td = 0.75 s: kd = 58.4417.
    let g = ziegler_nichols(1.0, 2.5, 6.0);
    assert!(near(g.kp, 77.922_260, 1e-5), "{g:?}");
    assert!(near(g.ki, 25.974_087, 1e-5), "{g:?}");
    assert!(near(g.kd, 58.441_695, 1e-5), "{g:?}");
    // Half power, 4 °C, 50 s: Ku = 2/(4π) = 0.159155; kp = 24.3507,
    // ki = kp/25 = 0.974028, kd = kp·6.25 = 152.1919.
    let g = ziegler_nichols(0.5, 4.0, 50.0);
    assert!(near(g.kp, 24.350_706, 1e-5), "{g:?}");
    assert!(near(g.ki, 0.974_028, 1e-6), "{g:?}");
    assert!(near(g.kd, 152.191_914, 1e-5), "{g:?}");
}

#[test]
fn the_relay_records_klippers_peaks_and_takes_the_median_cycle() {
    // About 10 °C: heats below 5, stops at 10. (time, °C).
    let readings = [
        (0.0, 0.0),
        (1.0, 10.0),
        (2.0, 12.0),
        (3.0, 5.0),
        (4.0, 3.0),
        (5.0, 10.0),
        (6.0, 13.0),
        (7.0, 5.0),
        (8.0, 2.0),
        (9.0, 10.0),
        (11.0, 14.0),
        (12.0, 5.0),
        (13.0, 4.0),
        (14.0, 10.0),
        (15.0, 12.0),
        (16.0, 5.0),
        (17.0, 1.0),
        (18.0, 10.0),
        (20.0, 15.0),
        (21.0, 5.0),
        (22.0, 3.0),
        (23.0, 10.0),
    ];
    let mut r = Relay::new(10.0, 1.0, MIN_PEAKS);
    let duties: Vec<f64> = readings
        .iter()
        .map(|&(t, c)| {
            assert!(!r.done(), "done before {t} s");
            r.update(t, c)
        })
        .collect();
    assert!(r.done());
    assert_eq!(&duties[..5], &[1.0, 0.0, 0.0, 1.0, 1.0]);
    let want = [
        (0.0, 0.0), // the start (Klipper's first, unused)
        (0.0, 0.0), // the heat-up's low
        (2.0, 12.0),
        (4.0, 3.0),
        (6.0, 13.0),
        (8.0, 2.0),
        (11.0, 14.0),
        (13.0, 4.0),
        (15.0, 12.0),
        (17.0, 1.0),
        (20.0, 15.0),
        (22.0, 3.0),
    ];
    let got: Vec<(f64, f64)> = r.peaks().iter().map(|p| (p.time_s, p.celsius)).collect();
    assert_eq!(got, want);
    // Cycles (peak i − peak i−2) for i = 4..11: 4 4 5 5 4 4 5 5 s; sorted
    // by (cycle, i) the middle one (index 4 of 8) is peak 6's, 5 s, whose
    // swing from peak 5 is 14 − 2: amplitude 6 °C.
    let res = r.result().unwrap();
    assert_eq!((res.amplitude_c, res.period_s), (6.0, 5.0));
    assert_eq!(res.gains, ziegler_nichols(1.0, 6.0, 5.0));
    // Ku = 4/(6π): kp = 32.4676, ki = kp/2.5 = 12.9870, kd = kp·0.625.
    assert!(near(res.gains.kp, 32.467_608, 1e-5), "{res:?}");
    assert!(near(res.gains.ki, 12.987_043, 1e-5), "{res:?}");
    assert!(near(res.gains.kd, 20.292_255, 1e-5), "{res:?}");
}

#[test]
fn a_relay_on_a_first_order_block_swings_by_its_hysteresis() {
    // The simulated hotend (40 W, 13 J/K, 0.12 W/K, 25 °C room) read
    // every 0.1 s, its duty applied at the reading: the swing is the
    // 5 °C band plus at most one step's rise past either edge.
    let (p, c, loss, dt) = (40.0, 13.0, 0.12, 0.1);
    let mut r = Relay::new(210.0, 1.0, MIN_PEAKS);
    let (mut t, mut temp, mut duty) = (0.0, 25.0, 0.0);
    while !r.done() {
        duty = r.update(t, temp);
        let settle = 25.0 + p * duty / loss;
        temp = settle + (temp - settle) * (-dt * loss / c).exp();
        t += dt;
        assert!(t < 300.0, "no end");
    }
    assert_eq!(duty, 0.0);
    let res = r.result().unwrap();
    // At most 0.15 °C past either edge: half the swing is 2.5 to 2.65.
    assert!((2.5..2.65).contains(&res.amplitude_c), "{res:?}");
    // 5 °C up at (40 − 0.12·182.5)/13 = 1.39 °C/s, down at 1.68: 6.6 s.
    assert!(near(res.period_s, 6.56, 0.3), "{res:?}");
}

#[test]
fn the_gains_replace_their_values_keeping_comments() {
    let text = "# top\n[heaters.hotend]\nmodule = \"e\"\nkp = 21.5      # p\n  ki = 1.06\nkd=109.0 # d\n\n[heaters.bed]\nkp = 1.0\nki = 2.0\nkd = 3.0\n";
    let g = Gains {
        kp: 70.12345,
        ki: 20.0,
        kd: 55.5,
    };
    let s = with_gains(text, "hotend", &g).unwrap();
    assert_eq!(
        s,
        "# top\n[heaters.hotend]\nmodule = \"e\"\nkp = 70.123    # p\n  ki = 20.000\nkd = 55.500 # d\n\n[heaters.bed]\nkp = 1.0\nki = 2.0\nkd = 3.0\n"
    );
    let s = with_gains(text, "bed", &g).unwrap();
    assert!(
        s.ends_with("[heaters.bed]\nkp = 70.123\nki = 20.000\nkd = 55.500\n"),
        "{s}"
    );
    assert!(with_gains(text, "chamber", &g).is_none());
    assert!(with_gains("[heaters.x]\nkp = 1.0\n", "x", &g).is_none());
}

#[test]
fn an_unknown_heater_is_refused_naming_the_known_ones() {
    let cfg = MachineFile::load(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/machines/printer.toml"
    ))
    .unwrap();
    let e = check(&cfg, "chamber", 50.0).unwrap_err().to_string();
    assert!(
        e.contains("\"chamber\"") && e.contains("bed, hotend"),
        "{e}"
    );
    let e = check(&cfg, "hotend", 300.0).unwrap_err().to_string();
    assert!(e.contains("max_temp 290"), "{e}");
    check(&cfg, "hotend", 210.0).unwrap();
    assert_eq!(
        (default_target("hotend"), default_target("bed")),
        (210.0, 60.0)
    );
}
