//! The axis's limits (`set_limits`): off by default; with limits set, a
//! stream within them passes unchanged (the same steps as without limits),
//! and a point past the velocity, acceleration or jerk limit is refused
//! with `OverLimit`, recorded as an `OverLimit` fault that says which
//! limit, without moving the limiter on (the stream continues from its last
//! accepted point). Settings: `BadValue`, `Busy`, and a rebuilt limiter on
//! an interval or scale change.

use osap_core::clock::TimeMap;
use osap_core::time::Instant;
use osap_module::board::{Board, IoHw, StepperHw};
use osap_module::fault::{FaultKind, OVER_ACCELERATION, OVER_JERK, OVER_VELOCITY};
use osap_module::functions::{FnId, ModuleFn};
use osap_module::stepper::{Limits, StepperError};
use osap_module::Module;
use pipes_core::function::{call_direct, CallError};
use pipes_core::Value;
use std::cell::{Cell, RefCell};
use std::rc::Rc;

/// The interval, µs, and in seconds.
const IV: u64 = 2048;
const DT: f64 = IV as f64 * 1e-6;
/// The limits of these tests, in units (mm, say) per s, s², s³.
const V: f32 = 100.0;
const A: f32 = 2_000.0;
const J: f32 = 200_000.0;
const LIMITS: Limits = Limits {
    max_vel: V,
    max_acc: A,
    max_jerk: J,
};
/// The limits as differences of points: velocity·Δt, acceleration·Δt²,
/// jerk·Δt³, units.
const VD: f64 = V as f64 * DT;
const AD: f64 = A as f64 * DT * DT;
const JD: f64 = J as f64 * DT * DT * DT;
/// Where the streams start: far ahead of the step ticks.
const T0: u64 = 1_000 * IV;
const OVER_LIMIT: CallError = CallError::Failed(pipes_core::FailureCode::from_code(
    StepperError::OverLimit as u8,
));

struct Driver;

impl StepperHw for Driver {
    fn set_enable(&mut self, _on: bool) {}
    fn set_microsteps(&mut self, _microsteps: u16) -> bool {
        true
    }
}

struct TestBoard(Rc<Cell<Instant>>, Driver);

impl Board for TestBoard {
    fn stepper(&mut self) -> &mut dyn StepperHw {
        &mut self.1
    }
    fn io(&mut self) -> Option<&mut dyn IoHw> {
        None
    }
    fn now(&self) -> Instant {
        self.0.get()
    }
}

/// An enabled module on the identity time map, and its clock.
fn module() -> (Module<TestBoard>, Rc<Cell<Instant>>) {
    let now = Rc::new(Cell::new(Instant::ZERO));
    let mut m = Module::new(TestBoard(now.clone(), Driver));
    m.publish_time(TimeMap::IDENTITY);
    m.set_enable(true).unwrap();
    (m, now)
}

fn limited() -> (Module<TestBoard>, Rc<Cell<Instant>>) {
    let (mut m, now) = module();
    m.set_limits(V, A, J).unwrap();
    (m, now)
}

/// The positions of a stream that starts at rest at `p0` and whose third
/// differences (jerk·Δt³, units) are `jerks`, one per point after the
/// first.
fn from_jerks(p0: f64, jerks: &[f64]) -> Vec<f32> {
    let (mut p, mut d1, mut d2) = (p0, 0.0, 0.0);
    let mut out = vec![p0 as f32];
    for j in jerks {
        d2 += j;
        d1 += d2;
        p += d1;
        out.push(p as f32);
    }
    out
}

/// The largest |first, second, third difference| of `pts` (from rest).
fn max_diffs(pts: &[f32]) -> (f64, f64, f64) {
    let (mut d1p, mut d2p) = (0.0, 0.0);
    let (mut m1, mut m2, mut m3) = (0.0f64, 0.0f64, 0.0f64);
    for w in pts.windows(2) {
        let d1 = f64::from(w[1]) - f64::from(w[0]);
        let (d2, d3) = (d1 - d1p, d1 - d1p - d2p);
        (m1, m2, m3) = (m1.max(d1.abs()), m2.max(d2.abs()), m3.max(d3.abs()));
        (d1p, d2p) = (d1, d2);
    }
    (m1, m2, m3)
}

/// Queues `pts` from stamp `t0` on, running the step generator 20
/// intervals behind the newest point; the first refusal ends it, with its
/// index. Returns the step words made.
fn stream(
    m: &mut Module<TestBoard>,
    t0: u64,
    pts: &[f32],
) -> (Vec<u32>, Option<(usize, CallError)>) {
    let mut words = Vec::new();
    let mut local = t0 - 20 * IV;
    let mut run_until = |m: &mut Module<TestBoard>, until: u64, words: &mut Vec<u32>| {
        while local < until {
            words.push(m.fill_step_word(Instant::from_micros(local)));
            local += 160;
        }
    };
    for (k, p) in pts.iter().enumerate() {
        let stamp = t0 + k as u64 * IV;
        run_until(m, stamp - 20 * IV, &mut words);
        if let Err(e) = m.add_point(stamp, *p) {
            return (words, Some((k, e)));
        }
    }
    let end = t0 + (pts.len() as u64 + 30) * IV;
    run_until(m, end, &mut words);
    (words, None)
}

#[test]
fn limits_are_off_by_default() {
    let (mut m, _) = module();
    assert_eq!(m.stepper.limits(), Limits::OFF);
    assert!(Limits::OFF.is_off());
    // A 400-step jump from rest: no limiter stands in its way.
    for (k, p) in [0.0, 0.0, 5.0, 5.0].into_iter().enumerate() {
        m.add_point(T0 + k as u64 * IV, p).unwrap();
    }
    assert_eq!(m.get_fault().unwrap().1, FaultKind::None.code());
}

/// An S-curve move: jerk `±0.9 J` ramps the acceleration to `4·0.9 J·Δt`
/// (74 % of A), held until the speed is 90 % of V, then the mirror image
/// down to rest at `start + distance`.
fn s_curve(start: f64) -> Vec<f32> {
    let j = 0.9 * JD;
    let ramp = 4;
    let hold = 25;
    let mut jerks = vec![0.0; 2];
    let accelerate: Vec<f64> = [vec![j; ramp], vec![0.0; hold], vec![-j; ramp]].concat();
    jerks.extend(&accelerate);
    jerks.extend(vec![0.0; 10]);
    jerks.extend(accelerate.iter().map(|j| -j));
    jerks.extend(vec![0.0; 4]);
    from_jerks(start, &jerks)
}

#[test]
fn a_stream_within_the_limits_passes_unchanged() {
    let pts = s_curve(0.0);
    let (m1, m2, m3) = max_diffs(&pts);
    assert!(
        m1 < 0.91 * VD && m2 < 0.75 * AD && m3 < 0.91 * JD,
        "{m1} {m2} {m3}"
    );
    assert!(m1 > 0.85 * VD, "near the velocity limit: {m1}");
    // With and without limits: every point accepted, the same step words.
    let (mut with, _) = limited();
    let (mut without, _) = module();
    let (words, refused) = stream(&mut with, T0, &pts);
    assert_eq!(refused, None);
    let (plain, refused) = stream(&mut without, T0, &pts);
    assert_eq!(refused, None);
    assert_eq!(words, plain);
    let (points, refused, _, _) = with.get_counters().unwrap();
    assert_eq!((points as usize, refused), (pts.len(), 0));
    assert_eq!(with.get_steps().unwrap(), without.get_steps().unwrap());
    let end = *pts.last().unwrap();
    assert!((with.get_position().unwrap().1 - end).abs() < 0.02, "{end}");
    assert_eq!(with.get_fault().unwrap(), (0, 0, 0, 0), "no fault");
    // The stream ended at rest: a new one starts there, back again.
    let (_, here) = with.get_position().unwrap();
    let back: Vec<f32> = s_curve(0.0).iter().map(|p| here - p).collect();
    let t1 = T0 + (pts.len() as u64 + 40) * IV;
    assert_eq!(stream(&mut with, t1, &back).1, None);
    assert_eq!(with.get_counters().unwrap().1, 0);
}

/// The fault `get_fault` reports: its kind and detail.
fn fault(m: &mut Module<TestBoard>) -> (u8, u32) {
    let (_, kind, detail, _) = m.get_fault().unwrap();
    (kind, detail)
}

#[test]
fn a_jerk_step_is_refused_and_the_stream_goes_on() {
    let (mut m, now) = limited();
    now.set(Instant::from_micros(77_000));
    for k in 0..3 {
        m.add_point(T0 + k * IV, 0.0).unwrap();
    }
    // A jump of 1.5 J·Δt³ from rest: within the acceleration and velocity
    // windows, past the jerk limit.
    const { assert!(1.5 * JD < AD) };
    let stamp = T0 + 3 * IV;
    assert_eq!(m.add_point(stamp, (1.5 * JD) as f32), Err(OVER_LIMIT));
    assert_eq!(
        m.get_fault().unwrap(),
        (77_000, FaultKind::OverLimit.code(), OVER_JERK, 1)
    );
    let (points, refused, last, _) = m.get_counters().unwrap();
    assert_eq!((points, refused, last), (3, 1, 11));
    assert_eq!(m.stepper.queued(), 3, "not queued");
    // The limiter did not move on: the stream continues from its last
    // accepted point (had it taken the clamped point, going back to
    // 0.5 J·Δt³ would break the jerk limit).
    let go_on = from_jerks(0.0, &[0.0, 0.0, 0.5 * JD, 0.5 * JD, 0.0, -0.8 * JD]);
    for (k, p) in go_on.iter().enumerate().skip(3) {
        m.add_point(T0 + k as u64 * IV, *p).unwrap();
    }
    assert_eq!(m.get_counters().unwrap().0, 7);
    assert_eq!(m.get_fault().unwrap().3, 1, "no new fault");
}

#[test]
fn an_acceleration_step_is_refused() {
    let (mut m, _) = limited();
    // Jerk 0.8 J: the acceleration reaches 4.8 J·Δt = 98 % of A in six
    // points; a seventh would take it to 5.6 J·Δt, past A, its jerk within.
    const { assert!(4.8 * JD < AD && 5.6 * JD > AD) };
    let pts = from_jerks(0.0, &[0.8 * JD; 7]);
    let (_, refused) = stream(&mut m, T0, &pts);
    assert_eq!(refused, Some((7, OVER_LIMIT)));
    assert_eq!(
        fault(&mut m),
        (FaultKind::OverLimit.code(), OVER_ACCELERATION)
    );
    // The stream goes on from the sixth point, its acceleration held.
    let mut jerks = vec![0.8 * JD; 6];
    jerks.extend([0.0, -0.8 * JD]);
    let go_on = from_jerks(0.0, &jerks);
    for (k, p) in go_on.iter().enumerate().skip(7) {
        m.add_point(T0 + k as u64 * IV, *p).unwrap();
    }
}

#[test]
fn a_velocity_step_is_refused() {
    // The velocity limit alone (0 turns the others off): a jump of
    // 1.5 V·Δt from rest.
    let (mut m, _) = module();
    m.set_limits(V, 0.0, 0.0).unwrap();
    for k in 0..3 {
        m.add_point(T0 + k * IV, 0.0).unwrap();
    }
    assert_eq!(m.add_point(T0 + 3 * IV, (1.5 * VD) as f32), Err(OVER_LIMIT));
    assert_eq!(fault(&mut m), (FaultKind::OverLimit.code(), OVER_VELOCITY));
    // 0.9 V·Δt is within it, acceleration and jerk being off.
    m.add_point(T0 + 3 * IV, (0.9 * VD) as f32).unwrap();
}

#[test]
fn a_stream_that_speeds_up_past_the_velocity_limit_is_refused() {
    // All three limits: the acceleration ramps to 3.2 J·Δt at 0.8 J and
    // stays, within both; the velocity window looks ahead (the axis must
    // be able to ramp its acceleration down at J without passing V), so
    // the refusal comes while the stream is still just under V.
    let (mut m, _) = limited();
    let mut jerks = vec![0.0, 0.0];
    jerks.extend([0.8 * JD; 4]);
    jerks.extend([0.0; 60]);
    let pts = from_jerks(0.0, &jerks);
    let (_, refused) = stream(&mut m, T0, &pts);
    let (k, e) = refused.expect("refused");
    assert_eq!(e, OVER_LIMIT);
    assert_eq!(fault(&mut m), (FaultKind::OverLimit.code(), OVER_VELOCITY));
    let (v_accepted, ..) = max_diffs(&pts[..k]);
    let (v_refused, ..) = max_diffs(&pts[..=k]);
    assert!(v_accepted <= VD && v_accepted > 0.9 * VD, "{v_accepted}");
    assert!(v_refused > 0.95 * VD, "{v_refused}");
}

#[test]
fn a_filled_gap_is_checked_with_its_midpoint() {
    let (mut m, _) = limited();
    for k in 0..3 {
        m.add_point(T0 + k * IV, 0.0).unwrap();
    }
    // One missing point: filled from its neighbours, both within.
    let gentle = from_jerks(0.0, &[0.0, 0.0, 0.3 * JD, 0.3 * JD, 0.0]);
    m.add_point(T0 + 3 * IV, gentle[3]).unwrap();
    m.add_point(T0 + 5 * IV, gentle[5]).unwrap();
    assert_eq!(m.get_counters().unwrap().3, 1, "filled");
    // Across a second gap, a point whose midpoint breaks the jerk limit.
    let last = gentle[5];
    assert_eq!(m.add_point(T0 + 7 * IV, last + 0.05), Err(OVER_LIMIT));
    assert_eq!(m.get_counters().unwrap().3, 1, "not filled");
    assert_eq!(fault(&mut m).0, FaultKind::OverLimit.code());
    // Refused, the gap is still open and the limiter where the filled
    // point (at the midpoint, 1.5 J·Δt³) and the one after it left it:
    // moving at 1.2 J·Δt³ per interval, not accelerating. The point that
    // goes on so is taken.
    m.add_point(T0 + 6 * IV, last + (1.2 * JD) as f32).unwrap();
    assert_eq!(m.get_counters().unwrap().0, 6);
}

#[test]
fn a_new_stream_starts_the_limiter_afresh() {
    let (mut m, _) = limited();
    // A stream cut off moving (its limiter at speed), the motor cycled.
    let pts = from_jerks(0.0, &[0.0, 0.0, JD * 0.5, JD * 0.5, JD * 0.5]);
    for (k, p) in pts.iter().enumerate() {
        m.add_point(T0 + k as u64 * IV, *p).unwrap();
    }
    m.set_enable(false).unwrap();
    m.set_enable(true).unwrap();
    // A new stream at rest where the axis stands (0: no steps were made):
    // to the old limiter state this would be a jump back.
    let t1 = T0 + 100 * IV;
    for k in 0..4 {
        m.add_point(t1 + k * IV, 0.0).unwrap();
    }
    assert_eq!(m.get_counters().unwrap().1, 0);
}

#[test]
fn limits_follow_the_scale_in_user_units() {
    // Twice the steps per unit and 4 microsteps: the same stream in units
    // is refused and accepted as before.
    for (scale, microsteps) in [(80.0, 1), (160.0, 4)] {
        let (mut m, _) = module();
        m.set_scale(scale).unwrap();
        m.set_microsteps(microsteps).unwrap();
        m.set_limits(V, A, J).unwrap();
        for k in 0..3 {
            m.add_point(T0 + k * IV, 0.0).unwrap();
        }
        assert_eq!(m.add_point(T0 + 3 * IV, (1.5 * JD) as f32), Err(OVER_LIMIT));
        m.add_point(T0 + 3 * IV, (0.7 * JD) as f32).unwrap();
        // Set first, then rescaled: the limiter is rebuilt in the new steps.
        let (mut m, _) = module();
        m.set_limits(V, A, J).unwrap();
        m.set_scale(scale).unwrap();
        m.set_microsteps(microsteps).unwrap();
        for k in 0..3 {
            m.add_point(T0 + k * IV, 0.0).unwrap();
        }
        assert_eq!(m.add_point(T0 + 3 * IV, (1.5 * JD) as f32), Err(OVER_LIMIT));
        m.add_point(T0 + 3 * IV, (0.7 * JD) as f32).unwrap();
    }
}

#[test]
fn settings_refuse_bad_values_and_a_queued_stream() {
    let bad = CallError::Failed(pipes_core::FailureCode::from_code(
        StepperError::BadValue as u8,
    ));
    let busy = CallError::Failed(pipes_core::FailureCode::from_code(StepperError::Busy as u8));
    let (mut m, _) = module();
    for x in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -1.0] {
        assert_eq!(m.set_limits(x, A, J), Err(bad));
        assert_eq!(m.set_limits(V, x, J), Err(bad));
        assert_eq!(m.set_limits(V, A, x), Err(bad));
    }
    // A jerk limit that rounds to nothing at the interval.
    assert_eq!(m.set_limits(V, A, 1e-3), Err(bad));
    assert_eq!(m.stepper.limits(), Limits::OFF, "unchanged");
    // 1 000 units/s³ is 80 000 steps/s³: 45 Q16.16 units per interval³
    // at 2 048 µs, 0.09 at 256 µs. The interval change is refused, and so
    // is a scale that would take it below one unit.
    m.set_limits(V, A, 1_000.0).unwrap();
    assert_eq!(m.set_interval(256), Err(bad));
    assert_eq!(m.stepper.interval_us(), 2048);
    assert_eq!(m.set_scale(0.01), Err(bad));
    m.set_limits(V, A, J).unwrap();
    m.set_interval(1024).unwrap();
    m.set_interval(2048).unwrap();
    // Busy while a stream is queued, whatever the values; a bad value is
    // refused as such first (as set_interval does).
    m.add_point(T0, 0.0).unwrap();
    assert_eq!(m.set_limits(V, A, J), Err(busy));
    assert_eq!(m.set_limits(0.0, 0.0, 0.0), Err(busy));
    assert_eq!(m.set_limits(f32::NAN, A, J), Err(bad));
    assert_eq!(m.stepper.limits(), LIMITS);
    // Refused points are counted; a cycled motor drops the stream, and
    // limits may change again. All zero turns them off.
    m.set_enable(false).unwrap();
    m.set_enable(true).unwrap();
    m.set_limits(0.0, 0.0, 0.0).unwrap();
    assert!(m.stepper.limits().is_off());
    for (k, p) in [0.0, 0.0, 5.0].into_iter().enumerate() {
        m.add_point(T0 + k as u64 * IV, p).unwrap();
    }
}

#[test]
fn set_limits_is_a_module_function() {
    #[derive(Clone)]
    struct Shared(Rc<RefCell<Module<TestBoard>>>);
    impl osap_module::ModuleHandle for Shared {
        type Board = TestBoard;
        fn with<R>(&self, f: impl FnOnce(&mut Module<TestBoard>) -> R) -> Option<R> {
            Some(f(&mut self.0.borrow_mut()))
        }
    }
    let h = Shared(Rc::new(RefCell::new(module().0)));
    let mut f = ModuleFn::new(FnId::set_limits, h.clone());
    let mut buf = [0u8; 16];
    let args = [Value::F32(V), Value::F32(A), Value::F32(J)];
    assert_eq!(
        call_direct(&mut f, &args, &mut buf).unwrap().iter().count(),
        0
    );
    assert_eq!(h.0.borrow().stepper.limits(), LIMITS);
    let args = [Value::F32(V), Value::F32(-A), Value::F32(J)];
    assert_eq!(
        call_direct(&mut f, &args, &mut buf).map(|_| ()),
        Err(CallError::Failed(pipes_core::FailureCode::Other(10)))
    );
    assert!(call_direct(&mut f, &[Value::F32(V)], &mut buf).is_err());
    let named = osap_module::failure::failure("set_limits", 9).unwrap();
    assert_eq!(named.name, "Busy");
    let named = osap_module::failure::failure("add_point", 11).unwrap();
    assert_eq!(named.name, "OverLimit");
}

#[test]
fn the_gap_behind_a_refused_point_keeps_the_refusal_as_the_fault() {
    let gap = CallError::Failed(pipes_core::FailureCode::from_code(StepperError::Gap as u8));
    let (mut m, _) = module();
    m.set_limits(V, 0.0, 0.0).unwrap();
    for k in 0..3 {
        m.add_point(T0 + k * IV, 0.0).unwrap();
    }
    // Refused past the velocity limit, then the stream goes on past the
    // hole its refusals left: those points are refused for the gap, and
    // counted, but the fault a host reads later still says why.
    assert_eq!(m.add_point(T0 + 3 * IV, (1.5 * VD) as f32), Err(OVER_LIMIT));
    assert_eq!(m.add_point(T0 + 4 * IV, (3.0 * VD) as f32), Err(OVER_LIMIT));
    assert_eq!(m.add_point(T0 + 5 * IV, 0.0), Err(gap));
    assert_eq!(m.add_point(T0 + 6 * IV, 0.0), Err(gap));
    let (_, kind, detail, count) = m.get_fault().unwrap();
    assert_eq!(
        (kind, detail, count),
        (FaultKind::OverLimit.code(), OVER_VELOCITY, 4)
    );
    // A gap the module did not open is the fault.
    let (mut m, _) = module();
    for k in 0..3 {
        m.add_point(T0 + k * IV, 0.0).unwrap();
    }
    assert_eq!(m.add_point(T0 + 6 * IV, 0.0), Err(gap));
    assert_eq!(
        fault(&mut m),
        (
            FaultKind::Refused.code(),
            u32::from(StepperError::Gap as u8)
        )
    );
}
