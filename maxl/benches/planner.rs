//! Planner throughput: segments per second through append + plan + sample,
//! on a 3D random walk of short segments with varied corner angles.
//! The `*_klipper` cases add toolhead (vector) limits and Klipper's minimum
//! cruise ratio 0.5 to the same per-axis limits.
//!
//! `cargo bench -p maxl --features std --bench planner`

// criterion_main! writes an undocumented `main`.
#![allow(missing_docs)]

use criterion::{black_box, criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use maxl::blocks::planner::{Limits, Planner, VectorLimits, KLIPPER_MIN_CRUISE_RATIO};

// The generator the tests use.
#[path = "../tests/common/rng.rs"]
mod rng;
use rng::XorShiftStar;

/// Segments per iteration.
const SEGMENTS: usize = 10_000;
/// Sample stamp interval (µs).
const STEP: u64 = 1024;

/// A random walk of 0.05..0.5 mm steps whose heading turns by up to ±`turn`
/// radians (in azimuth and elevation) per step.
fn walk(n: usize, turn: f64) -> Vec<[f64; 3]> {
    // A fixed seed: the same path in every run.
    let mut rng = XorShiftStar(0x9E37_79B9_7F4A_7C15);
    let (mut az, mut el) = (0.0f64, 0.0f64);
    let mut p = [0.0; 3];
    (0..n)
        .map(|_| {
            az += (rng.next() - 0.5) * 2.0 * turn;
            el = (el + (rng.next() - 0.5) * turn).clamp(-1.0, 1.0);
            let len = 0.05 + 0.45 * rng.next();
            p[0] += len * az.cos() * el.cos();
            p[1] += len * az.sin() * el.cos();
            p[2] += len * el.sin();
            p
        })
        .collect()
}

fn limits() -> Limits<3> {
    Limits::new([500.0, 300.0, 50.0], [10_000.0, 6_000.0, 1_000.0], 0.02).unwrap()
}

/// Toolhead limits within the per-axis ones, and Klipper's minimum cruise
/// ratio.
fn vector() -> VectorLimits {
    VectorLimits::new(400.0, 8_000.0)
        .and_then(|v| v.with_min_cruise_ratio(KLIPPER_MIN_CRUISE_RATIO))
        .unwrap()
}

/// Queue everything, then sample every stamp until rest.
fn batch(path: &[[f64; 3]], vector: VectorLimits) -> u64 {
    let mut p = Planner::with_vector_limits(limits(), vector, path.len()).unwrap();
    for q in path {
        p.line(*q, 250.0).unwrap();
    }
    let mut t = 0;
    let mut acc = 0.0;
    while !p.is_idle() {
        acc += p.sample(t).unwrap()[0];
        t += STEP;
    }
    black_box(acc);
    t
}

/// Feed while running: keep `depth` segments ahead, sampling one stamp at a
/// time and appending whenever the queue drops below it.
fn fed(path: &[[f64; 3]], depth: usize, vector: VectorLimits) -> u64 {
    let mut p = Planner::with_vector_limits(limits(), vector, depth).unwrap();
    let mut next = path.iter();
    let mut t = 0;
    let mut acc = 0.0;
    loop {
        while p.stats().pending < depth {
            match next.next() {
                Some(q) => {
                    p.line(*q, 250.0).unwrap();
                }
                None => break,
            }
        }
        acc += p.sample(t).unwrap()[0];
        t += STEP;
        if p.is_idle() && next.len() == 0 {
            break;
        }
    }
    black_box(acc);
    t
}

/// Append and plan only (no sampling), in a queue as long as the path.
fn append_only(path: &[[f64; 3]], vector: VectorLimits) -> usize {
    let mut p = Planner::with_vector_limits(limits(), vector, path.len()).unwrap();
    for q in path {
        p.line(*q, 250.0).unwrap();
    }
    p.stats().pending
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("planner");
    g.throughput(Throughput::Elements(SEGMENTS as u64));
    for (name, turn) in [("turn45", 0.785), ("turn10", 0.175)] {
        let path = walk(SEGMENTS, turn);
        for (suffix, v) in [("", VectorLimits::NONE), ("_klipper", vector())] {
            let id = BenchmarkId::new(format!("append_only{suffix}"), name);
            g.bench_with_input(id, &path, |b, p| b.iter(|| append_only(p, v)));
            let id = BenchmarkId::new(format!("batch{suffix}"), name);
            g.bench_with_input(id, &path, |b, p| b.iter(|| batch(p, v)));
            for depth in [16, 256] {
                let id = BenchmarkId::new(format!("fed{depth}{suffix}"), name);
                g.bench_with_input(id, &path, |b, p| b.iter(|| fed(p, depth, v)));
            }
        }
    }
    g.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = bench
}
criterion_main!(benches);
