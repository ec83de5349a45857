//! The optimizer interface: `sample` never waits for a slow solver, misses
//! are counted, and a prompt solver's points come through for their stamps.

use maxl::blocks::optimizer::{Optimizer, OptimizerBlock, OptimizerConfig, OptimizerError};
use std::sync::mpsc::{channel, Receiver};
use std::time::{Duration, Instant};

/// Solves `stamp ↦ [stamp as f64 / 1000, 1, 2]` after sleeping `delay`.
struct Slow {
    delay: Duration,
}
impl Optimizer for Slow {
    type Point = [f64; 3];
    fn solve(&mut self, stamp_us: u64) -> Option<[f64; 3]> {
        std::thread::sleep(self.delay);
        Some([stamp_us as f64 / 1000.0, 1.0, 2.0])
    }
}

/// Never returns until told to (the test never tells it).
struct Stuck(Receiver<()>);
impl Optimizer for Stuck {
    type Point = f64;
    fn solve(&mut self, _: u64) -> Option<f64> {
        let _ = self.0.recv();
        Some(1.0)
    }
}

const IV: u64 = 1000;

fn cfg(lead_us: u64) -> OptimizerConfig {
    OptimizerConfig {
        interval_us: IV,
        lead_us,
        channel: 8,
    }
}

/// Samples stamps 1 ms apart in wall time; returns the longest call.
fn run_paced<P: Copy + Send + 'static>(
    b: &mut OptimizerBlock<P>,
    n: u64,
) -> (Duration, Vec<(u64, P, bool)>) {
    let mut worst = Duration::ZERO;
    let mut out = Vec::new();
    let t0 = Instant::now();
    for i in 1..=n {
        let due = t0 + Duration::from_millis(i);
        if let Some(d) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(d);
        }
        let s = Instant::now();
        let r = b.sample(i * IV).unwrap();
        worst = worst.max(s.elapsed());
        out.push((i * IV, r.point, r.fresh));
    }
    (worst, out)
}

#[test]
fn slow_solver_never_blocks_sample_and_misses_are_counted() {
    // 50 ms per point against 1 ms stamps: most samples must miss.
    let mut b = OptimizerBlock::new(
        Slow {
            delay: Duration::from_millis(50),
        },
        [0.0; 3],
        cfg(5 * IV),
    )
    .unwrap();
    let (worst, out) = run_paced(&mut b, 200);
    assert!(worst < Duration::from_millis(20), "a sample took {worst:?}");
    let st = b.stats();
    assert_eq!(st.samples, 200);
    assert_eq!(st.hits + st.misses, 200);
    assert!(st.misses > 150, "{st:?}");
    assert!(st.solver_alive);
    // A held point is the last fresh one (or the initial point); a fresh
    // one is the solver's answer for that very stamp.
    let mut held = [0.0; 3];
    for (stamp, p, fresh) in out {
        if fresh {
            assert_eq!(p, [stamp as f64 / 1000.0, 1.0, 2.0]);
            held = p;
        } else {
            assert_eq!(p, held);
        }
    }
    // The solver skipped stamps that had passed instead of solving them.
    assert!(st.skipped > 0 || st.requests_refused > 0, "{st:?}");
}

#[test]
fn stuck_solver_does_not_block_either() {
    let (_keep, rx) = channel();
    let mut b = OptimizerBlock::new(Stuck(rx), 7.5, cfg(3 * IV)).unwrap();
    let t = Instant::now();
    for i in 1..=10_000 {
        let r = b.sample(i * IV).unwrap();
        assert_eq!((r.point, r.fresh), (7.5, false));
    }
    assert!(t.elapsed() < Duration::from_secs(1), "{:?}", t.elapsed());
    let st = b.stats();
    assert_eq!((st.misses, st.hits), (10_000, 0));
    assert!(st.requests_refused > 0, "the full request channel refuses");
}

#[test]
fn prompt_solver_with_lead_hits() {
    let mut b = OptimizerBlock::new(
        Slow {
            delay: Duration::from_micros(50),
        },
        [0.0; 3],
        cfg(10 * IV),
    )
    .unwrap();
    let (_, out) = run_paced(&mut b, 300);
    let st = b.stats();
    // The first samples come before anything was asked; after that the
    // lead keeps the solver ahead (allowing a few scheduler hiccups).
    assert!(st.hits > 250, "{st:?}");
    for (stamp, p, fresh) in out {
        if fresh {
            assert_eq!(p[0], stamp as f64 / 1000.0);
        }
    }
}

struct Panics;
impl Optimizer for Panics {
    type Point = u8;
    fn solve(&mut self, _: u64) -> Option<u8> {
        panic!("solver bug (expected by the test)")
    }
}

struct NoAnswer;
impl Optimizer for NoAnswer {
    type Point = u8;
    fn solve(&mut self, _: u64) -> Option<u8> {
        None
    }
}

#[test]
fn failing_solvers_and_bad_input() {
    let mut b = OptimizerBlock::new(Panics, 3u8, cfg(2 * IV)).unwrap();
    b.sample(IV).unwrap();
    let t = Instant::now();
    while b.stats().solver_alive && t.elapsed() < Duration::from_secs(5) {
        std::thread::sleep(Duration::from_millis(1));
    }
    assert!(!b.stats().solver_alive);
    for i in 2..100 {
        assert_eq!(b.sample(i * IV).unwrap().point, 3);
    }

    let mut b = OptimizerBlock::new(NoAnswer, 4u8, cfg(2 * IV)).unwrap();
    for i in 1..50 {
        b.sample(i * IV).unwrap();
        std::thread::sleep(Duration::from_micros(200));
    }
    assert!(b.stats().failures > 0);
    assert_eq!(b.stats().hits, 0);
    assert!(matches!(
        b.sample(0),
        Err(OptimizerError::StampNotMonotonic { stamp: 0, .. })
    ));

    for bad in [
        OptimizerConfig {
            interval_us: 0,
            lead_us: 0,
            channel: 1,
        },
        OptimizerConfig {
            interval_us: 1,
            lead_us: 0,
            channel: 0,
        },
    ] {
        assert!(matches!(
            OptimizerBlock::new(NoAnswer, 0u8, bad),
            Err(OptimizerError::InvalidConfig(_))
        ));
    }
}

#[test]
fn block_is_send() {
    fn send<T: Send>() {}
    send::<OptimizerBlock<[f64; 3]>>();
}

#[test]
fn pipes_class_wraps_a_script_built_block() {
    use maxl::blocks::optimizer::{OptimizerClass, NOT_REMOTE};
    use pipes_core::class::PipesClass;
    use pipes_core::function::CallError;

    assert_eq!(OptimizerClass::NAME, "Optimizer");
    assert!(OptimizerClass::CONSTRUCTOR.inputs.is_empty());
    let names: Vec<&str> = OptimizerClass::MEMBERS.iter().map(|s| s.name).collect();
    assert_eq!(names, ["Optimizer.sample", "Optimizer.stats"]);
    let outs: Vec<&str> = OptimizerClass::MEMBERS[0]
        .outputs
        .iter()
        .map(|a| a.name)
        .collect();
    assert_eq!(outs, ["stamp", "x", "y", "z", "fresh"]);
    // It cannot be rebuilt over the network.
    assert!(matches!(
        OptimizerClass::construct(&[]),
        Err(CallError::Failed(code)) if code.code() == NOT_REMOTE
    ));

    let block = OptimizerBlock::new(
        Slow {
            delay: Duration::from_micros(10),
        },
        [0.0; 3],
        cfg(10 * IV),
    )
    .unwrap();
    let mut class = OptimizerClass(block);
    let give_up = Instant::now() + Duration::from_secs(5);
    let mut stamp = IV;
    let fresh = loop {
        let (s, x, y, z, fresh) = class.sample(stamp).unwrap();
        assert_eq!(s, stamp);
        if fresh {
            break (x, y, z);
        }
        assert!(Instant::now() < give_up, "no fresh point");
        std::thread::sleep(Duration::from_millis(1));
        stamp += IV;
    };
    assert_eq!(fresh, ((stamp as f64 / 1000.0) as f32, 1.0, 2.0));
    let (samples, hits, misses, alive) = class.stats();
    assert_eq!(samples, hits + misses);
    assert!(hits >= 1 && alive);
    // A stamp going backwards is refused with code 2.
    assert!(matches!(
        class.sample(IV).map_err(CallError::from),
        Err(CallError::Failed(pipes_core::FailureCode::Other(2)))
    ));
}
