//! The stepper logic on its own: streams in, step ticks out.

use maxl::{Fx, Interval, Track};
use osap_core::time::SystemInstant;
use osap_module::stepper::{Mode, Stepper, StepperError, QUEUE, STEP_TICK_US, TICKS_PER_WORD};

const IV: u64 = 2048;
const WORD_US: u64 = (STEP_TICK_US * TICKS_PER_WORD) as u64;

/// Net steps in a packed word, and the steps up and down.
fn decode(word: u32) -> (i64, u64, u64) {
    let (mut net, mut up, mut down) = (0, 0, 0);
    for k in 0..TICKS_PER_WORD {
        let bits = (word >> (2 * k)) & 3;
        if bits & 1 == 1 {
            if bits & 2 == 2 {
                net += 1;
                up += 1;
            } else {
                net -= 1;
                down += 1;
            }
        }
    }
    (net, up, down)
}

fn enabled() -> Stepper {
    let mut s = Stepper::new();
    s.set_enable(true);
    s
}

/// Runs the step generator from `t0` to `t1`, returning the net steps the
/// words carry.
fn run(s: &mut Stepper, t0: u64, t1: u64) -> i64 {
    let mut net = 0;
    let mut t = t0;
    while t < t1 {
        net += decode(s.fill_word(SystemInstant::from_micros(t))).0;
        t += WORD_US;
    }
    net
}

#[test]
fn a_stream_becomes_exactly_its_steps() {
    let mut s = enabled();
    // 80 steps/unit: out 10 units (800 steps) and back to 2.5 (200 steps).
    let t0 = 1000 * IV;
    let mut pts: Vec<f32> = vec![0.0; 3];
    pts.extend((1..=40).map(|k| k as f32 * 0.25));
    pts.extend((1..=30).map(|k| 10.0 - k as f32 * 0.25));
    pts.extend([2.5; 4]);
    let mut sent = 0;
    let mut t = t0 - 10 * IV;
    let mut net = 0;
    // Feed points 8 intervals ahead of the ticks, as a stream would.
    for (k, p) in pts.iter().enumerate() {
        let stamp = t0 + k as u64 * IV;
        s.add_point(SystemInstant::from_micros(stamp), *p).unwrap();
        sent += 1;
        let until = stamp.saturating_sub(8 * IV);
        if until > t {
            net += run(&mut s, t, until);
            t = until;
        }
    }
    assert_eq!(sent, pts.len());
    net += run(&mut s, t, t0 + (pts.len() as u64 + 40) * IV);
    assert_eq!(net, 200, "net steps");
    let (steps, up, down, overruns) = s.step_counts();
    // The spline rounds the sharp turn: its peak is (9.75 + 4·10 + 9.75)/6
    // units = 793.3 steps, not the 800 of the turning point.
    assert_eq!((steps, up, down), (200, 793, 593));
    assert_eq!(overruns, 0);
    assert_eq!(s.counters().faults, 0);
    assert_eq!(s.mode(), Mode::Backstop);
    let (_, pos) = s.position();
    assert!((pos - 2.5).abs() < 1e-6);
}

#[test]
fn per_tick_positions_match_the_track() {
    // The fast per-segment evaluator against the track's own evaluation,
    // tick for tick, on a wiggly stream.
    let iv = Interval::from_micros(IV as u32).unwrap();
    let mut track: Track<Fx, 128> = Track::new(
        iv,
        maxl::BackstopLimits {
            max_acc: 1e6,
            max_jerk: 1e8,
        },
    );
    let mut s = enabled();
    let mut pts = vec![0.0f32; 3];
    pts.extend((1..100).map(|k| (k as f32 * 0.37).sin() * 2.0 * (k as f32 / 100.0)));
    for (k, p) in pts.iter().enumerate() {
        let stamp = k as u64 * IV;
        if k < QUEUE - 1 {
            s.add_point(SystemInstant::from_micros(stamp), *p).unwrap();
        }
        track
            .push(
                SystemInstant::from_micros(stamp),
                Fx::from_f64(f64::from(*p) * 80.0),
            )
            .unwrap();
    }
    // Steps follow the exact track position at every tick: the step index
    // after each tick equals the track position rounded.
    let mut t = 2 * IV;
    while t < 50 * IV {
        let word = s.fill_word(SystemInstant::from_micros(t));
        let _ = word;
        let expect = track
            .sample(SystemInstant::from_micros(
                t + WORD_US - STEP_TICK_US as u64,
            ))
            .unwrap()
            .kin
            .pos;
        let steps = s.step_counts().0;
        let target = (i64::from(expect.0) + 32768) >> 16;
        assert!((steps - target).abs() <= 1, "at {t}: {steps} vs {target}");
        t += WORD_US;
    }
    assert_eq!(s.step_counts().3, 0, "no overruns");
}

#[test]
fn refuses_bad_points_with_codes() {
    let mut s = Stepper::new();
    assert_eq!(
        s.add_point(SystemInstant::ZERO, 0.0),
        Err(StepperError::Disabled)
    );
    s.set_enable(true);
    assert_eq!(
        s.add_point(SystemInstant::ZERO, f32::NAN),
        Err(StepperError::OutOfRange)
    );
    // Beyond 2^46 microsteps (1e13 units at 80 per unit).
    assert_eq!(
        s.add_point(SystemInstant::ZERO, 1e13),
        Err(StepperError::OutOfRange)
    );
    // Far, but in range (positions wrap, an axis has no end): refused
    // only because a stream starts where the axis stands.
    assert_eq!(
        s.add_point(SystemInstant::ZERO, 1e6),
        Err(StepperError::Discontinuous)
    );
    assert_eq!(
        s.add_point(SystemInstant::ZERO, 5.0),
        Err(StepperError::Discontinuous)
    );
    assert_eq!(
        s.add_point(SystemInstant::from_micros(7), 0.0),
        Err(StepperError::Misaligned)
    );
    assert_eq!(s.add_point(SystemInstant::from_micros(IV), 0.0), Ok(()));
    assert_eq!(
        s.add_point(SystemInstant::from_micros(IV), 0.0),
        Err(StepperError::Stale)
    );
    assert_eq!(
        s.add_point(SystemInstant::from_micros(4 * IV), 0.0),
        Err(StepperError::Gap)
    );
    assert_eq!(
        s.add_point(SystemInstant::from_micros(3 * IV), 0.0),
        Ok(()),
        "one missing point is filled"
    );
    assert_eq!(s.counters().filled, 1);
    assert_eq!(s.counters().refused, 8);
    assert_eq!(s.counters().last_refused, Some(StepperError::Gap));
    // Settings wait for an idle axis.
    assert_eq!(s.set_interval(1024), Err(StepperError::Busy));
    assert_eq!(s.set_scale(100.0), Err(StepperError::Busy));
    // A stream too far ahead fills the queue and is refused, not dropped.
    for k in 4..=QUEUE as u64 {
        assert_eq!(
            s.add_point(SystemInstant::from_micros(k * IV), 0.0),
            Ok(()),
            "{k}"
        );
    }
    let next = (QUEUE as u64 + 1) * IV;
    assert_eq!(
        s.add_point(SystemInstant::from_micros(next), 0.0),
        Err(StepperError::QueueFull)
    );
    // Once the oldest points have run, the stream goes on.
    run(&mut s, 0, 10 * IV);
    assert_eq!(s.add_point(SystemInstant::from_micros(next), 0.0), Ok(()));
}

#[test]
fn a_cut_stream_faults_and_a_halt_latches() {
    let mut s = enabled();
    let mut pts: Vec<f32> = vec![0.0; 3];
    pts.extend((1..=10).map(|k| k as f32 * 0.5));
    for (k, p) in pts.iter().enumerate() {
        s.add_point(SystemInstant::from_micros(k as u64 * IV), *p)
            .unwrap();
    }
    run(&mut s, 0, 200 * IV);
    assert_eq!(s.counters().faults, 1);
    assert_eq!(s.mode(), Mode::Backstop);
    let (_, here) = s.position();
    assert!(here > 4.5, "braked beyond the last point it had: {here}");
    assert_eq!(
        s.add_point(SystemInstant::from_micros(300 * IV), here),
        Err(StepperError::Faulted)
    );
    // Cycling the motor clears the fault where the axis stands.
    s.set_enable(false);
    s.set_enable(true);
    assert_eq!(
        s.add_point(SystemInstant::from_micros(300 * IV), here),
        Ok(())
    );
    // A halt stops stepping at once and latches until the motor cycles.
    s.halt();
    assert_eq!(s.mode(), Mode::Halted);
    let before = s.step_counts().0;
    assert_eq!(run(&mut s, 300 * IV, 310 * IV), 0);
    assert_eq!(s.step_counts().0, before);
    assert_eq!(
        s.add_point(SystemInstant::from_micros(301 * IV), here),
        Err(StepperError::Faulted)
    );
    s.set_enable(false);
    s.set_enable(true);
    assert_eq!(
        s.add_point(SystemInstant::from_micros(320 * IV), here),
        Ok(())
    );
}

#[test]
fn settings_change_while_idle_and_keep_the_place() {
    let mut s = enabled();
    for k in 0..4u64 {
        s.add_point(SystemInstant::from_micros(k * IV), 0.0)
            .unwrap();
    }
    for k in 4..12u64 {
        s.add_point(SystemInstant::from_micros(k * IV), 1.0)
            .unwrap();
    }
    run(&mut s, 0, 40 * IV);
    assert_eq!(s.step_counts().0, 80);
    // 16 microsteps: the same place is now 1280 microsteps.
    assert_eq!(s.set_microsteps(16), Ok(()));
    assert_eq!(s.set_microsteps(3), Err(StepperError::BadValue));
    assert_eq!(s.steps_per_unit(), 1280.0);
    assert!((s.position().1 - 1.0).abs() < 1e-6);
    assert_eq!(s.set_scale(f32::INFINITY), Err(StepperError::BadValue));
    assert_eq!(s.set_scale(-1.0), Err(StepperError::BadValue));
    // 1 unit at 1e13 full steps × 16 is beyond 2^46 microsteps.
    assert_eq!(s.set_scale(1e13), Err(StepperError::OutOfRange));
    assert_eq!(s.set_interval(1000), Err(StepperError::BadValue));
    assert_eq!(s.set_interval(1024), Ok(()));
    assert_eq!(s.interval_us(), 1024);
    // A new stream starts where it stands, in the new units and interval.
    let t = 100 * 2048;
    assert_eq!(s.add_point(SystemInstant::from_micros(t), 1.0), Ok(()));
    assert_eq!(
        s.add_point(SystemInstant::from_micros(t + 1024), 1.0),
        Ok(())
    );
}

#[test]
fn a_disabled_axis_makes_no_steps() {
    let mut s = Stepper::new();
    for k in 0..40u64 {
        assert_eq!(s.fill_word(SystemInstant::from_micros(k * WORD_US)), 0);
    }
    assert_eq!(s.mode(), Mode::Disabled);
}

#[test]
fn an_axis_stands_once_a_stream_has_stopped_at_rest() {
    let mut s = enabled();
    assert!(s.is_standing(), "no stream");
    let t0 = 100 * IV;
    let points = [0.0, 0.0, 0.0, 0.5, 1.0, 1.0, 1.0, 1.0];
    for (k, p) in points.iter().enumerate() {
        s.add_point(SystemInstant::from_micros(t0 + k as u64 * IV), *p)
            .unwrap();
    }
    assert!(!s.is_standing(), "a stream is queued");
    let end = t0 + (points.len() as u64 + 4) * IV;
    assert_eq!(run(&mut s, t0 - 4 * IV, end), 80);
    assert_eq!(
        s.mode(),
        Mode::Backstop,
        "the stream ended on repeated points"
    );
    assert!(
        s.is_standing(),
        "stopped at rest: words may take the idle path"
    );
    // Standing words make no steps and keep the mode; a new stream starts
    // where the axis stands.
    assert_eq!(run(&mut s, end, end + 8 * IV), 0);
    assert_eq!(s.mode(), Mode::Backstop);
    let t1 = end + 16 * IV;
    s.add_point(SystemInstant::from_micros(t1), 1.0).unwrap();
    assert!(!s.is_standing());
}
