//! Simulated oscillators: rate error, offset and wander give the expected
//! local counters, and the inverse finds the first instant of a count.

use osap_core::time::{Duration, Instant};
use osap_sim::clock::{ClockModel, ClockSpec, Param};
use osap_sim::rng::Rng;

const S: u64 = 1_000_000_000;

#[test]
fn offset_and_rate_error_give_the_expected_counter() {
    let fast = ClockModel::new(5_000_000.0, 100.0);
    assert_eq!(fast.local_us(0), Instant::from_micros(5_000_000));
    assert_eq!(
        fast.local_us(S),
        Instant::from_micros(5_000_000 + 1_000_100)
    );
    assert_eq!(
        fast.local_us(600 * S),
        Instant::from_micros(5_000_000 + 600_060_000)
    );
    let slow = ClockModel::new(0.0, -100.0);
    assert_eq!(slow.local_us(S), Instant::from_micros(999_900));
    // The counter is the floor of the exact local time.
    let ideal = ClockModel::new(0.0, 0.0);
    assert_eq!(ideal.local_us(999), Instant::ZERO);
    assert_eq!(ideal.local_us(1_000), Instant::from_micros(1));
}

#[test]
fn wander_integrates_the_rate() {
    let c = ClockModel::new(0.0, 20.0).with_wander(1.0, 120.0, 0.7);
    // Integrate the instantaneous rate numerically over 10 minutes.
    let step = S / 100;
    let mut skew_ns = 0.0;
    let mut t = 0;
    while t < 600 * S {
        let mid = t + step / 2;
        skew_ns += c.rate_ppm_at(mid) * 1e-6 * step as f64;
        t += step;
    }
    let expected = (600 * S) as f64 + skew_ns;
    let got = c.local_ns(600 * S) as f64;
    assert!((got - expected).abs() < 2.0, "{got} vs {expected}");
    // The wander moves the rate around its fixed part by the amplitude.
    let rates: Vec<f64> = (0..1200).map(|k| c.rate_ppm_at(k * S / 10)).collect();
    let (lo, hi) = rates
        .iter()
        .fold((f64::MAX, f64::MIN), |(lo, hi), &r| (lo.min(r), hi.max(r)));
    assert!(
        (lo - 19.0).abs() < 0.01 && (hi - 21.0).abs() < 0.01,
        "{lo}..{hi}"
    );
}

#[test]
fn true_time_at_is_the_first_instant_of_a_count() {
    let mut rng = Rng::new(5);
    for _ in 0..200 {
        let c = ClockSpec::MCU.draw(&mut rng);
        let local = c.local_us(0) + Duration::from_micros((rng.unit() * 700e6) as u64);
        let t = c.true_time_at(local);
        assert!(c.local_us(t) >= local);
        assert!(t == 0 || c.local_us(t - 1) < local);
    }
}

#[test]
fn specs_draw_within_their_ranges() {
    let spec = ClockSpec {
        offset_us: Param::Uniform(10.0, 20.0),
        rate_ppm: Param::Uniform(-5.0, 5.0),
        wander_ppm: Param::Fixed(0.0),
        wander_period_s: Param::Fixed(60.0),
    };
    let mut rng = Rng::new(1);
    for _ in 0..100 {
        let c = spec.draw(&mut rng);
        assert!((-5.0..=5.0).contains(&c.rate_ppm()));
        assert!((10..=20).contains(&c.local_us(0).as_micros()));
        assert_eq!(c.rate_ppm_at(S), c.rate_ppm());
    }
    let bad = ClockSpec {
        offset_us: Param::Fixed(-1.0),
        ..spec
    };
    let e = bad.validate("m1").unwrap_err().to_string();
    assert!(e.contains("m1") && e.contains("offset_us"), "{e}");
}
