//! Step generator: exact step accounting over long random trajectories,
//! overruns without lost steps, the SPSC queue and the PIO packing.

mod common;

use common::rng::Lcg;
use maxl::eval::{Fx, TickEval};
use maxl::step::{Dir, PioPacker, QueueFull, Rounding, StepEvent, StepGen, StepQueue};
use maxl::Interval;
use proptest::prelude::*;

/// Reference step index, computed independently in f64 (exact for Q16.16).
fn reference(p: Fx, r: Rounding) -> i64 {
    let x = p.0 as f64 / 65536.0;
    match r {
        Rounding::Nearest => (x + 0.5).floor() as i64,
        Rounding::Floor => x.floor() as i64,
    }
}

/// Feed positions and check the invariants at every tick. Returns the
/// generator.
fn check_run(positions: impl Iterator<Item = Fx>, start: Fx, r: Rounding) -> StepGen {
    let mut g = StepGen::new(start, r);
    let mut net = reference(start, r);
    let mut prev_ref = net;
    let mut overruns = 0u64;
    let mut abs_sum = 0u64;
    let mut ever_overrun = false;
    // An independent model of late steps: the steps owed, oldest first,
    // each with its direction and the tick it fell due at.
    let mut owed: std::collections::VecDeque<(i64, u64)> = Default::default();
    let mut late = 0u64;
    for (tick, p) in positions.enumerate() {
        let tick = tick as u64;
        let want = reference(p, r);
        // Boundaries crossed since the last tick: each either un-crosses
        // the newest owed step the other way, or is a new step due now.
        let dir = (want - prev_ref).signum();
        for _ in 0..(want - prev_ref).abs() {
            match owed.back() {
                Some(&(d, _)) if d == -dir => {
                    owed.pop_back();
                }
                _ => owed.push_back((dir, tick)),
            }
        }
        let before = g.position();
        let backlog_before = g.backlog();
        let s = g.tick(p);
        match s {
            Some(Dir::Up) => net += 1,
            Some(Dir::Down) => net -= 1,
            None => {}
        }
        assert_eq!(g.position(), net, "net step count");
        assert_eq!(g.target(), want, "target = step index of the position");
        // Every step moves toward the target; none is sent when caught up.
        let expect = (want - before).signum();
        let got = match s {
            Some(Dir::Up) => 1,
            Some(Dir::Down) => -1,
            None => 0,
        };
        assert_eq!(got, expect, "step direction at {p:?}");
        if got != 0 {
            let (d, due) = owed.pop_front().expect("a step sent was owed");
            assert_eq!(d, got, "the oldest owed step goes first");
            if due < tick {
                late += 1;
            }
        }
        assert_eq!(g.stats().late, late, "late steps at tick {tick}");
        if backlog_before == 0 && (want - prev_ref).abs() <= 1 {
            // No overrun: exactly the boundary crossing of this tick.
            assert_eq!(got, want - prev_ref);
        }
        assert_eq!(g.backlog(), (want - g.position()).unsigned_abs());
        if g.backlog() > 0 {
            overruns += 1;
            ever_overrun = true;
        }
        abs_sum += (want - prev_ref).unsigned_abs();
        prev_ref = want;
    }
    let st = g.stats();
    assert_eq!(st.overruns, overruns);
    if !ever_overrun {
        assert_eq!(st.up + st.down, abs_sum, "|Δ| accounting");
    } else {
        assert!(st.up + st.down <= abs_sum);
    }
    g
}

#[test]
fn long_random_trajectory_exact_accounting() {
    // 3 M ticks: a random walk in velocity, mostly below one step per tick,
    // hovering on boundaries at times, crossing zero and both signs.
    for r in [Rounding::Nearest, Rounding::Floor] {
        let mut rng = Lcg(3);
        let mut p: i64 = -5 << 16;
        let mut v: i64 = 0;
        let start = Fx(p as i32);
        let g = check_run(
            (0..3_000_000).map(|_| {
                v += rng.next() as i64 % 2001 - 1000;
                v = v.clamp(-60_000, 60_000);
                p = (p + v).clamp(-(1 << 30), 1 << 30);
                Fx(p as i32)
            }),
            start,
            r,
        );
        let st = g.stats();
        assert_eq!(st.overruns, 0);
        assert!(st.up + st.down > 100_000, "{st:?}");
        // The walk went both ways many times.
        assert!(st.up > 10_000 && st.down > 10_000, "{st:?}");
    }
}

#[test]
fn overruns_catch_up_without_losing_steps() {
    let mut rng = Lcg(9);
    let mut p: i64 = 0;
    let mut positions = Vec::new();
    for k in 0..2_000_000u64 {
        // Bursts of up to 4 steps per tick now and then.
        let jump = if k % 50_000 < 200 {
            (rng.next() % (4 << 16)) as i64 - (1 << 15)
        } else {
            (rng.next() % 40_000) as i64 - 20_000
        };
        p = (p + jump).clamp(-(1 << 30), 1 << 30);
        positions.push(Fx(p as i32));
    }
    let last = *positions.last().unwrap();
    // Then hold still long enough to drain any backlog.
    positions.extend(std::iter::repeat_n(last, 100_000));
    let g = check_run(positions.into_iter(), Fx(0), Rounding::Nearest);
    let st = g.stats();
    assert!(st.overruns > 100, "{st:?}");
    assert!(st.late > 100, "{st:?}");
    assert!(st.max_backlog > 1);
    assert_eq!(g.backlog(), 0);
    assert_eq!(g.position(), reference(last, Rounding::Nearest));
}

#[test]
fn driven_by_the_tick_evaluator() {
    // A move of 3000 steps and back over 1024 µs segments, 100 kHz ticks:
    // at most ~0.3 steps per tick, so no overrun, and every step matches a
    // boundary crossing of the evaluated position.
    let iv = Interval::from_micros(1024).unwrap();
    let mut e = TickEval::new(iv, 10).unwrap();
    let pts: Vec<Fx> = (0..600)
        .map(|k| {
            let x = (k as f64 / 599.0 * std::f64::consts::TAU).sin();
            Fx::from_f64(3000.0 * x * x)
        })
        .collect();
    let mut positions = Vec::new();
    let mut du = 0;
    for i in 1..pts.len() - 2 {
        e.load(&[pts[i - 1], pts[i], pts[i + 1], pts[i + 2]], du)
            .unwrap();
        for p in e.by_ref() {
            positions.push(p);
        }
        du = e.next_offset();
    }
    let n = positions.len();
    let g = check_run(positions.into_iter(), pts[0], Rounding::Nearest);
    assert!(n > 55_000);
    assert_eq!(g.stats().overruns, 0);
    assert_eq!(g.stats().late, 0);
    assert!(g.stats().up > 2900 && g.stats().down > 2900);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]
    #[test]
    fn random_increments(start in any::<i32>(), steps in proptest::collection::vec(-300_000i32..300_000, 1..3000)) {
        let mut p = start as i64;
        let pos: Vec<Fx> = steps.iter().map(|d| {
            p = (p + *d as i64).clamp(i32::MIN as i64, i32::MAX as i64);
            Fx(p as i32)
        }).collect();
        let last = *pos.last().unwrap();
        let drain = std::iter::repeat_n(last, 20_000);
        let g = check_run(pos.into_iter().chain(drain), Fx(start), Rounding::Nearest);
        prop_assert_eq!(g.backlog(), 0);
        prop_assert_eq!(g.position(), reference(last, Rounding::Nearest));
    }
}

#[test]
fn rounding_rule_at_boundaries() {
    let g = StepGen::new(Fx(0), Rounding::Nearest);
    assert_eq!(g.count(Fx(32767)), 0);
    assert_eq!(g.count(Fx(32768)), 1);
    assert_eq!(g.count(Fx(-32768)), 0);
    assert_eq!(g.count(Fx(-32769)), -1);
    let f = StepGen::new(Fx(0), Rounding::Floor);
    assert_eq!(f.count(Fx(65535)), 0);
    assert_eq!(f.count(Fx(-1)), -1);
    assert_eq!(f.count(Fx(i32::MIN)), -32768);
    assert_eq!(g.count(Fx(i32::MAX)), 32768);
}

#[test]
fn queue_is_fifo_and_reports_full() {
    let q: StepQueue<4> = StepQueue::new();
    assert!(q.is_empty());
    let ev = |tick, dir| StepEvent { tick, dir };
    q.push(ev(1, Dir::Up)).unwrap();
    q.push(ev(2, Dir::Down)).unwrap();
    q.push(ev(3, Dir::Up)).unwrap();
    assert_eq!(q.push(ev(4, Dir::Up)), Err(QueueFull(ev(4, Dir::Up))));
    assert_eq!(q.len(), 3);
    assert_eq!(q.peek(), Some(ev(1, Dir::Up)));
    assert_eq!(q.pop(), Some(ev(1, Dir::Up)));
    q.push(ev(4, Dir::Down)).unwrap();
    assert_eq!(q.pop(), Some(ev(2, Dir::Down)));
    assert_eq!(q.pop(), Some(ev(3, Dir::Up)));
    assert_eq!(q.pop(), Some(ev(4, Dir::Down)));
    assert_eq!(q.pop(), None);
}

#[test]
fn queue_across_threads_keeps_every_event_in_order() {
    static Q: StepQueue<16> = StepQueue::new();
    const N: u32 = 200_000;
    let producer = std::thread::spawn(|| {
        let mut t = 0;
        while t < N {
            let dir = if t % 3 == 0 { Dir::Down } else { Dir::Up };
            if Q.push(StepEvent { tick: t, dir }).is_ok() {
                t += 1;
            } else {
                std::thread::yield_now();
            }
        }
    });
    let mut want = 0;
    while want < N {
        if let Some(e) = Q.pop() {
            assert_eq!(e.tick, want);
            assert_eq!(e.dir, if want % 3 == 0 { Dir::Down } else { Dir::Up });
            want += 1;
        } else {
            std::thread::yield_now();
        }
    }
    producer.join().unwrap();
    assert!(Q.is_empty());
}

#[test]
fn pio_words() {
    let mut pk = PioPacker::new();
    // Up, hold, down, then twelve idle ticks.
    let ticks = [Some(Dir::Up), None, Some(Dir::Down)]
        .into_iter()
        .chain([None; 12]);
    for t in ticks {
        assert_eq!(pk.push(t), None);
    }
    assert_eq!(pk.pending(), 15);
    let w = pk.push(Some(Dir::Up)).unwrap();
    // tick 0: step+up = 0b11; tick 1: up held = 0b10; tick 2: step, down =
    // 0b01; ticks 3..14: 0b00; tick 15: 0b11.
    assert_eq!(w, 0b11 | (0b10 << 2) | (0b01 << 4) | (0b11 << 30));
    assert_eq!(pk.pending(), 0);
}

#[test]
fn queue_of_any_size_wraps_in_order() {
    // 5 slots (4 events): not a power of two, so the wrap is the compare.
    let q: StepQueue<5> = StepQueue::new();
    let mut next_in = 0u32;
    let mut next_out = 0u32;
    for round in 0..50u32 {
        // Fill to a varying depth, then drain part of it.
        for _ in 0..(round % 4 + 1) {
            let ev = StepEvent {
                tick: next_in,
                dir: if next_in.is_multiple_of(3) {
                    Dir::Up
                } else {
                    Dir::Down
                },
            };
            if q.push(ev).is_ok() {
                next_in += 1;
            }
        }
        assert_eq!(q.len() as u32, next_in - next_out);
        assert!(q.len() <= 4);
        for _ in 0..(round % 3 + 1) {
            if let Some(ev) = q.pop() {
                assert_eq!(ev.tick, next_out);
                assert_eq!(ev.dir == Dir::Up, next_out.is_multiple_of(3));
                next_out += 1;
            }
        }
    }
    while let Some(ev) = q.pop() {
        assert_eq!(ev.tick, next_out);
        next_out += 1;
    }
    assert_eq!(next_in, next_out);
    assert!(next_in > 40, "only {next_in} events went through");
    assert!(q.is_empty());
}

/// Positions wrap every 65 536 steps (`Fx`); the generator's step index
/// does not: a ramp up through the end of the range and back sends every
/// step once, and its index counts on past 32 767.
#[test]
fn a_ramp_through_the_end_of_the_range_steps_exactly() {
    let start = Fx(i32::MAX - 40 * Fx::ONE);
    let mut g = StepGen::new(start, Rounding::Nearest);
    let first = g.position();
    assert_eq!(first, 32_728);
    // 0.3 steps a tick: 300 steps up in 1 000 ticks, through the wrap.
    let mut p = start;
    for _ in 0..1000 {
        p = Fx(p.0.wrapping_add(3 * Fx::ONE / 10));
        g.tick(p);
    }
    for _ in 0..10 {
        g.tick(p);
    }
    let s = g.stats();
    assert_eq!((s.up, s.down, s.overruns), (300, 0, 0));
    assert_eq!(g.position(), first + 300);
    assert_eq!(g.target(), first + 300);
    assert_eq!(g.backlog(), 0);
    // And back down through it.
    for _ in 0..1000 {
        p = Fx(p.0.wrapping_sub(3 * Fx::ONE / 10));
        g.tick(p);
    }
    assert_eq!(g.position(), first);
    assert_eq!(g.stats().down, 300);
}
