//! Chirps: the frequency law (from zero crossings), rest at the ends,
//! amplitude bound and the PIPES class.

mod common;

use maxl::blocks::chirp::{Chirp, ChirpBlock, ChirpConfig, ChirpError, FAIL_BAD_NUMBER};
use pipes_core::class::PipesClass;
use pipes_core::function::CallError;
use pipes_core::Value;

/// Far from zero, to show nothing depends on the absolute time.
const START: u64 = 1 << 40;

fn chirp(f0: f64, f1: f64, dur: f64, exponential: bool, fade: f64) -> Chirp {
    Chirp::new(ChirpConfig {
        f0,
        f1,
        duration_s: dur,
        amplitude: 2.5,
        center: 0.0,
        exponential,
        fade_s: fade,
    })
    .unwrap()
}

/// Times (µs after the start) where the signal crosses zero upward or
/// downward, each the first µs with the new sign.
fn crossings(c: &Chirp) -> Vec<u64> {
    let end = c.duration_us();
    let x = |t: u64| c.position_from(START, START + t);
    let mut out = Vec::new();
    let mut prev = 1u64;
    let mut t = 1u64;
    while t < end {
        t = (t + 20).min(end - 1);
        if (x(prev) > 0.0) != (x(t) > 0.0) {
            let (mut lo, mut hi) = (prev, t);
            while hi - lo > 1 {
                let mid = (lo + hi) / 2;
                if (x(mid) > 0.0) == (x(lo) > 0.0) {
                    lo = mid
                } else {
                    hi = mid
                }
            }
            out.push(hi);
        }
        prev = t;
        if t == end - 1 {
            break;
        }
    }
    out
}

/// Time (s) of the k-th half cycle, from the sweep law written afresh.
fn law_time(f0: f64, f1: f64, dur: f64, exponential: bool, k: f64) -> f64 {
    // Cycles elapsed: k / 2.
    let c = k / 2.0;
    if exponential {
        let ln_k = (f1 / f0).ln();
        dur * (1.0 + c * ln_k / (f0 * dur)).ln() / ln_k
    } else {
        let a = (f1 - f0) / (2.0 * dur);
        if a == 0.0 {
            c / f0
        } else {
            (-f0 + (f0 * f0 + 4.0 * a * c).sqrt()) / (2.0 * a)
        }
    }
}

#[test]
fn zero_crossings_follow_the_frequency_law() {
    for (f0, f1, dur, exp) in [
        (2.0, 40.0, 2.0, false),
        (60.0, 5.0, 1.5, false),
        (1.0, 100.0, 3.0, true),
        (80.0, 8.0, 1.0, true),
    ] {
        let c = chirp(f0, f1, dur, exp, 0.0);
        let zs = crossings(&c);
        // Every half cycle the law puts strictly inside the sweep.
        let expected = (1..)
            .take_while(|&k| {
                law_time(f0, f1, dur, exp, f64::from(k)) * 1e6 < (c.duration_us() - 1) as f64
            })
            .count();
        assert_eq!(zs.len(), expected, "{f0}->{f1}");
        let mut worst = 0.0f64;
        for (i, &z) in zs.iter().enumerate() {
            let want = law_time(f0, f1, dur, exp, (i + 1) as f64) * 1e6;
            let err = (z as f64 - want).abs();
            worst = worst.max(err);
            assert!(err <= 1.001, "crossing {i}: {z} µs vs {want}");
        }
        // Instantaneous frequency from neighbouring crossings, where the
        // law changes little within the half cycle.
        let mut checked = 0;
        for w in zs.windows(2) {
            let (a, b) = (w[0] as f64 * 1e-6, w[1] as f64 * 1e-6);
            if (c.frequency(b) / c.frequency(a) - 1.0).abs() > 0.05 {
                continue;
            }
            let measured = 1.0 / (2.0 * (b - a));
            let law = c.frequency((a + b) / 2.0);
            assert!((measured - law).abs() / law < 0.01, "{measured} vs {law}");
            checked += 1;
        }
        assert!(checked * 2 > zs.len(), "most half cycles checked");
        println!(
            "{f0}->{f1} Hz exp={exp}: {} crossings, worst {worst:.2} µs",
            zs.len()
        );
    }
}

#[test]
fn starts_and_ends_at_rest_on_the_center() {
    let mut c = chirp(5.0, 50.0, 1.0, true, 0.1);
    c.set_center(12.0).unwrap();
    c.start(Some(START));
    let iv = 1024;
    assert_eq!(c.sample(START - iv), 12.0, "before the start");
    assert!(!c.done());
    assert_eq!(c.sample(START), 12.0);
    let first = c.sample(START + iv);
    assert!((first - 12.0).abs() < 1e-4, "starts at rest: {first}");
    let end = c.end_us().unwrap();
    assert_eq!(end, START + 1_000_000);
    let last = c.position_from(START, end - iv);
    assert!((last - 12.0).abs() < 1e-3, "ends at rest: {last}");
    assert_eq!(
        c.sample(end - (end % iv)),
        c.position_from(START, end - (end % iv))
    );
    assert!(!c.done());
    assert_eq!(c.sample(end), 12.0);
    assert!(c.done());
    assert_eq!(c.sample(end + 10 * iv), 12.0);
}

#[test]
fn amplitude_is_a_bound_and_is_reached() {
    for exp in [false, true] {
        let mut c = chirp(3.0, 30.0, 2.0, exp, 0.2);
        c.set_center(-4.0).unwrap();
        let mut peak = 0.0f64;
        for k in 0..2_000_000 / 97 {
            let x = c.position_from(START, START + 97 * k) + 4.0;
            assert!(x.abs() <= 2.5, "{x}");
            peak = peak.max(x.abs());
        }
        assert!(peak > 2.49, "reaches the amplitude: {peak}");
    }
}

#[test]
fn start_at_the_next_stamp_and_bad_numbers() {
    let mut c = chirp(1.0, 2.0, 0.5, false, 0.0);
    assert_eq!(c.sample(4096), 0.0, "not started: center");
    c.start(None);
    assert_eq!(c.start_us(), None);
    c.sample(8192);
    assert_eq!(c.start_us(), Some(8192));
    for bad in [
        ChirpConfig {
            f0: -1.0,
            ..*c.config()
        },
        ChirpConfig {
            f0: 0.0,
            exponential: true,
            ..*c.config()
        },
        ChirpConfig {
            duration_s: 0.0,
            ..*c.config()
        },
        ChirpConfig {
            amplitude: f64::NAN,
            ..*c.config()
        },
        ChirpConfig {
            fade_s: 0.3,
            ..*c.config()
        },
    ] {
        assert!(Chirp::new(bad).is_err(), "{bad:?}");
    }
    assert_eq!(c.set_fade(-0.1), Err(ChirpError::BadFade));
    assert_eq!(
        ChirpError::BadFade.to_string(),
        "bad chirp parameter: fade must be >= 0 and at most half the duration"
    );
    assert!(c.set_center(f64::INFINITY).is_err());
}

#[test]
fn pipes_class_wire_api() {
    common::assert_wire_api::<ChirpBlock>(
        "Chirp",
        "Chirp(f0: f32, f1: f32, duration_s: f32, amplitude: f32, exponential: bool) -> ()",
        &[
            "Chirp.start(at: u64) -> ()",
            "Chirp.sample(stamp: u64) -> (stamp: u64, position: f32)",
            "Chirp.done() -> (done: bool)",
            "Chirp.set_center(center: f32) -> ()",
            "Chirp.set_fade(fade_s: f32) -> ()",
        ],
    );
}

#[test]
fn pipes_class() {
    let args = |f0: f32| {
        [
            Value::F32(f0),
            Value::F32(10.0),
            Value::F32(1.0),
            Value::F32(1.0),
            Value::Bool(true),
        ]
    };
    assert_eq!(
        ChirpBlock::construct(&args(0.0)).err(),
        Some(CallError::Failed(pipes_core::FailureCode::from_code(
            FAIL_BAD_NUMBER
        )))
    );
    let mut c = ChirpBlock::construct(&args(1.0)).unwrap();
    let cfg = *c.0.config();
    assert_eq!(
        (cfg.f0, cfg.f1, cfg.duration_s, cfg.amplitude),
        (1.0, 10.0, 1.0, 1.0)
    );
    assert!(cfg.exponential && cfg.center == 0.0 && cfg.fade_s == 0.0);
    c.start(0);
    assert_eq!(c.sample(START), (START, 0.0));
    let (_, x) = c.sample(START + 100_000);
    assert!((f64::from(x) - c.0.position_from(START, START + 100_000)).abs() < 1e-6);
    assert!(!c.done());
    c.sample(START + 1_000_000);
    assert!(c.done());

    assert_eq!(
        c.set_fade(0.6).map_err(CallError::from),
        Err(CallError::Failed(pipes_core::FailureCode::from_code(
            FAIL_BAD_NUMBER
        )))
    );
    assert_eq!(
        c.set_center(f32::INFINITY).map_err(CallError::from),
        Err(CallError::Failed(pipes_core::FailureCode::from_code(
            FAIL_BAD_NUMBER
        )))
    );
    c.set_center(2.5).unwrap();
    c.set_fade(0.1).unwrap();
    // A start at a given stamp; before it the position is the center.
    c.start(START + 2048);
    assert_eq!(c.sample(START + 1024), (START + 1024, 2.5));
    assert_eq!(c.0.start_us(), Some(START + 2048));
    assert!(!c.done());
}
