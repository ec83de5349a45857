//! The graph timer: lead, start, catch-up and its PIPES class.

mod common;

use common::rng::XorShift;
use maxl::blocks::timer::{
    Timer, TimerBlock, TimerError, FAIL_BAD_INTERVAL, FAIL_LEAD_TOO_SHORT, FAIL_NO_TIME,
};
use maxl::Interval;
use osap_core::time::SystemInstant;
use pipes_core::class::PipesClass;
use pipes_core::export::INPUT_DECODE_FAILED;
use pipes_core::function::CallError;
use pipes_core::Value;

fn iv(us: u32) -> Interval {
    Interval::from_micros(us).unwrap()
}

#[test]
fn lead_must_cover_two_intervals() {
    assert_eq!(
        Timer::new(iv(1024), 2047).unwrap_err(),
        TimerError::LeadTooShort {
            lead_us: 2047,
            min_us: 2048
        }
    );
    assert!(Timer::new(iv(1024), 2048).is_ok());
    assert_eq!(
        Timer::from_micros(1000, 5000).unwrap_err(),
        TimerError::BadInterval(1000)
    );
    assert_eq!(Timer::with_default_lead(iv(512)).lead_us(), 1536);
    assert!(TimerError::BadInterval(3)
        .to_string()
        .contains("power of two"));
}

#[test]
fn first_call_emits_the_horizon_stamp() {
    let mut t = Timer::new(iv(1024), 3072).unwrap();
    // now + lead = 4072 -> 3072 is the newest aligned stamp not after it.
    assert_eq!(t.due(1000).collect::<Vec<_>>(), [3072]);
    assert!(t.due(1000).next().is_none(), "nothing twice");
    assert_eq!(t.due(1023).count(), 0, "4095 < 4096");
    assert_eq!(t.due(1024).collect::<Vec<_>>(), [4096]);
    assert_eq!(t.last_stamp(), Some(4096));
}

#[test]
fn every_stamp_once_in_order_with_the_lead() {
    for (us, lead_iv) in [(256u32, 2u64), (1024, 3), (16384, 2)] {
        let step = u64::from(us);
        let lead = lead_iv * step;
        let mut t = Timer::new(iv(us), lead).unwrap();
        let mut rng = XorShift(0x1234_5678_9abc_def1);
        let mut now = (1u64 << 40) + 77;
        let mut seen: Vec<u64> = Vec::new();
        for _ in 0..20_000 {
            // Irregular calls, sometimes late by up to 40 intervals.
            now += if rng.next().is_multiple_of(50) {
                rng.next() % (40 * step)
            } else {
                rng.next() % step
            };
            seen.extend(t.due(now));
            let last = *seen.last().unwrap();
            assert!(last <= now + lead, "never beyond now + lead");
            assert!(last + step > now + lead, "everything due was emitted");
            // The spline's lookahead: the point at floor(now) + 2 intervals.
            assert!(last >= (now / step) * step + 2 * step);
            assert_eq!(last % step, 0);
        }
        for w in seen.windows(2) {
            assert_eq!(w[1], w[0] + step, "consecutive, never skipped");
        }
        let s = t.stats();
        assert_eq!(s.emitted, seen.len() as u64);
        assert!(s.max_burst >= 39, "a stall of 40 intervals is caught up");
        assert!(s.catch_ups > 0);
    }
}

#[test]
fn stall_is_caught_up_as_a_burst() {
    let mut t = Timer::new(iv(1024), 3072).unwrap();
    assert_eq!(t.due(0).collect::<Vec<_>>(), [3072]);
    assert_eq!(t.pending(10 * 1024), 10);
    let burst: Vec<u64> = t.due(10 * 1024).collect();
    assert_eq!(burst, (4..=13).map(|k| k * 1024).collect::<Vec<_>>());
    assert_eq!(t.stats().max_burst, 10);
    assert_eq!(t.stats().emitted, 11);
    // Time going backwards emits nothing.
    assert_eq!(t.due(5).count(), 0);
}

#[test]
fn next_due_drains_one_stamp_per_call() {
    let mut t = Timer::new(iv(256), 512).unwrap();
    assert_eq!(t.next_due(0), Some(512));
    assert_eq!(t.next_due(0), None);
    // Five intervals late: five calls each give the next stamp.
    let got: Vec<u64> = (0..5).filter_map(|_| t.next_due(5 * 256)).collect();
    assert_eq!(got, [768, 1024, 1280, 1536, 1792]);
    assert_eq!(t.next_due(5 * 256), None);
    assert_eq!(t.stats().max_burst, 5);
    t.reset();
    assert_eq!(t.last_stamp(), None);
    assert_eq!(t.next_due(2000), Some(2304), "2000 + 512 rounded down");
}

#[test]
fn pipes_class_wire_api() {
    common::assert_wire_api::<TimerBlock>(
        "Timer",
        "Timer(interval_us: u32, lead_us: u32) -> ()",
        &[
            "Timer.tick() -> (stamp: u64)",
            "Timer.status() -> (last: u64, emitted: u64, max_burst: u64, now: u64)",
            "Timer.reset() -> ()",
        ],
    );
}

#[test]
fn pipes_class_constructor_and_tick() {
    let bad = TimerBlock::construct(&[Value::U32(1000), Value::U32(5000)]);
    assert_eq!(
        bad.err(),
        Some(CallError::Failed(pipes_core::FailureCode::from_code(
            FAIL_BAD_INTERVAL
        )))
    );
    let short = TimerBlock::construct(&[Value::U32(1024), Value::U32(1024)]);
    assert_eq!(
        short.err(),
        Some(CallError::Failed(pipes_core::FailureCode::from_code(
            FAIL_LEAD_TOO_SHORT
        )))
    );
    let wrong_type = TimerBlock::construct(&[Value::U64(1024), Value::U32(3072)]);
    assert_eq!(
        wrong_type.err(),
        Some(CallError::Failed(pipes_core::FailureCode::from_code(
            INPUT_DECODE_FAILED
        )))
    );
    let mut t = TimerBlock::construct(&[Value::U32(1024), Value::U32(3072)]).unwrap();
    assert_eq!(t.timer.lead_us(), 3072);
    assert_eq!(t.timer.interval().micros(), 1024);

    assert_eq!(t.tick(), Err(TimerError::NoTime));
    assert_eq!(
        CallError::from(TimerError::NoTime),
        CallError::Failed(pipes_core::FailureCode::from_code(FAIL_NO_TIME))
    );
    assert_eq!(t.status(), (0, 0, 0, 0));
    t.loop_hook(SystemInstant::from_micros(1000));
    assert_eq!(t.now(), Some(SystemInstant::from_micros(1000)));
    assert_eq!(t.tick(), Ok(3072));
    // Nothing new due: the same stamp again, which "on change" suppresses.
    assert_eq!(t.tick(), Ok(3072));
    // A stall of three intervals drains at one stamp per run.
    t.loop_hook(SystemInstant::from_micros(1000 + 3 * 1024));
    let runs: Vec<u64> = (0..5).map(|_| t.tick().unwrap()).collect();
    assert_eq!(runs, [4096, 5120, 6144, 6144, 6144]);
    assert_eq!(t.status(), (6144, 4, 3, 1000 + 3 * 1024));
    // Reset: the next tick starts again at the horizon.
    t.reset();
    t.set_now(SystemInstant::from_micros(10_000));
    assert_eq!(t.tick(), Ok(12_288), "10000 + 3072 rounded down");
}
