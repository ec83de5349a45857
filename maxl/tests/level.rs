//! Level and event tracks: value in force, one-shot events, and every
//! refused push reported.

use maxl::level::{EventTrack, Fired, LevelTrack, TimedPushError};

#[test]
fn level_in_force_is_the_latest_stamp_at_or_before_t() {
    let mut l: LevelTrack<u16, 4> = LevelTrack::new(0);
    assert_eq!(l.level(0), 0);
    l.push(1_000, 500).unwrap();
    l.push(2_000, 800).unwrap();
    l.push(5_000, 0).unwrap();
    assert_eq!(l.level(999), 0);
    assert_eq!(l.level(1_000), 500);
    assert_eq!(l.level(1_999), 500);
    assert_eq!(l.level(2_000), 800);
    assert_eq!(l.level(4_999), 800);
    assert_eq!(l.level(u64::MAX), 0);
    assert_eq!(l.next_change(), Some(1_000));
    assert_eq!(l.advance(1_500), 500);
    assert_eq!(l.pending(), 2);
    assert_eq!(l.next_change(), Some(2_000));
    // Time going back changes nothing.
    assert_eq!(l.advance(10), 500);
    assert_eq!(l.advance(2_000), 800);
    assert_eq!(l.advance(100_000), 0);
    assert_eq!(l.pending(), 0);
    assert_eq!(l.next_change(), None);
}

#[test]
fn level_push_errors() {
    let mut l: LevelTrack<bool, 2> = LevelTrack::new(false);
    l.push(100, true).unwrap();
    assert_eq!(l.push(100, false), Err(TimedPushError::Duplicate));
    assert_eq!(
        l.push(50, false),
        Err(TimedPushError::OutOfOrder { newest: 100 })
    );
    l.push(200, false).unwrap();
    assert_eq!(l.push(300, true), Err(TimedPushError::Full));
    assert_eq!(l.pending(), 2);
    // Applied changes still order later pushes.
    assert!(!l.advance(250));
    assert_eq!(l.push(240, true), Err(TimedPushError::Late { now: 250 }));
    assert_eq!(l.push(250, true), Ok(()));
    assert!(l.advance(250));
    assert_eq!(l.push(250, false), Err(TimedPushError::Duplicate));
}

#[test]
fn level_matches_a_brute_force_reference() {
    let mut l: LevelTrack<u32, 8> = LevelTrack::new(7);
    let mut all: Vec<(u64, u32)> = Vec::new();
    let mut next = 0u64;
    let mut rng = 1u64;
    for now in (0..200_000u64).step_by(13) {
        rng = rng.wrapping_mul(6364136223846793005).wrapping_add(1);
        if rng >> 60 == 0 && l.pending() < 8 {
            next = next.max(now) + (rng >> 40) % 3000 + 1;
            l.push(next, (rng >> 20) as u32).unwrap();
            all.push((next, (rng >> 20) as u32));
        }
        let want = all.iter().rev().find(|(t, _)| *t <= now).map_or(7, |x| x.1);
        assert_eq!(l.level(now), want);
        assert_eq!(l.advance(now), want);
    }
    assert!(all.len() > 20);
}

#[test]
fn events_fire_once_in_order() {
    let mut e: EventTrack<u8, 4> = EventTrack::new(0);
    e.push(100, 1).unwrap();
    e.push(100, 2).unwrap();
    e.push(250, 3).unwrap();
    assert_eq!(e.poll(99), None);
    assert_eq!(e.next_time(), Some(100));
    assert_eq!(
        e.poll(110),
        Some(Fired {
            time: 100,
            late_us: 10,
            event: 1
        })
    );
    assert_eq!(e.poll(110).map(|f| f.event), Some(2));
    assert_eq!(e.poll(110), None);
    assert_eq!(e.poll(250).map(|f| (f.event, f.late_us)), Some((3, 0)));
    assert_eq!(e.poll(10_000), None);
    assert_eq!(e.fired(), 3);
    assert_eq!(e.pending(), 0);
}

#[test]
fn event_push_errors() {
    let mut e: EventTrack<u8, 2> = EventTrack::default();
    e.push(500, 1).unwrap();
    assert_eq!(
        e.push(400, 2),
        Err(TimedPushError::OutOfOrder { newest: 500 })
    );
    e.push(600, 2).unwrap();
    assert_eq!(e.push(700, 3), Err(TimedPushError::Full));
    assert_eq!(e.poll(550).map(|f| f.event), Some(1));
    // The moment has passed: refused, not fired late.
    assert_eq!(e.push(549, 4), Err(TimedPushError::Late { now: 550 }));
    // Time going back does not re-open the past.
    assert_eq!(e.poll(100), None);
    assert_eq!(e.push(549, 4), Err(TimedPushError::Late { now: 550 }));
    assert_eq!(
        e.push(550, 5),
        Err(TimedPushError::OutOfOrder { newest: 600 })
    );
    e.push(600, 5).unwrap();
    assert_eq!(e.poll(599), None);
    assert_eq!(e.pending(), 2);
    assert_eq!(e.fired(), 1);
}

#[test]
fn errors_display() {
    let s = TimedPushError::Late { now: 5 }.to_string();
    assert!(s.contains("5"));
    assert!(!TimedPushError::Full.to_string().is_empty());
}

#[test]
fn a_ramp_reads_its_ends_and_a_stop_clears_what_waits() {
    let mut l: LevelTrack<f32, 4> = LevelTrack::new(0.0);
    assert_eq!((l.since(), l.next()), (None, None));
    l.push(100, 0.5).unwrap();
    l.push(200, 1.0).unwrap();
    assert_eq!(l.next(), Some((100, 0.5)));
    assert_eq!(l.advance(150), 0.5);
    assert_eq!((l.since(), l.next()), (Some(100), Some((200, 1.0))));
    l.clear_to(0.25);
    assert_eq!((l.since(), l.next(), l.pending()), (None, None, 0));
    assert_eq!(l.advance(300), 0.25);
    // The past stays closed after a stop.
    assert_eq!(l.push(299, 1.0), Err(TimedPushError::Late { now: 300 }));
    // A new change after a stop is not out of order against the old one.
    l.push(300, 0.75).unwrap();
    assert_eq!(l.advance(300), 0.75);

    let mut e: EventTrack<u8, 2> = EventTrack::default();
    e.push(10, 1).unwrap();
    e.push(20, 2).unwrap();
    assert_eq!(e.poll(10).map(|f| f.event), Some(1));
    e.clear();
    assert_eq!((e.pending(), e.poll(30), e.fired()), (0, None, 1));
}
