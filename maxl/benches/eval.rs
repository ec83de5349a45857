//! Evaluations per second on this host: fixed point (position only through
//! the per-tick `TickEval`, position only and full kinematics through
//! `Point::eval`) and `f32` for comparison.
//!
//! Run: `cargo bench -p maxl --bench eval`.

// criterion_main! writes an undocumented `main`.
#![allow(missing_docs)]

use criterion::{black_box, criterion_group, criterion_main, Criterion, Throughput};
use maxl::eval::{Fx, Point, TickEval};
use maxl::Interval;

/// Evaluations per benchmark iteration.
const N: u32 = 1000;

fn segment_fx() -> [Fx; 4] {
    [Fx(1_234_567), Fx(2_345_678), Fx(5_432_100), Fx(9_876_543)]
}

fn segment_f32() -> [f32; 4] {
    segment_fx().map(|p| p.0 as f32 / 65536.0)
}

fn bench(c: &mut Criterion) {
    let iv = Interval::from_micros(1024).unwrap();
    let mut g = c.benchmark_group("eval");
    g.throughput(Throughput::Elements(N as u64));

    let seg = segment_fx();
    g.bench_function("fx_point_eval_pos", |b| {
        b.iter(|| {
            let mut acc = 0i32;
            for k in 0..N {
                let du = black_box(k) & 1023;
                acc = acc.wrapping_add(Fx::eval(black_box(&seg), du, iv).pos.0);
            }
            acc
        })
    });
    g.bench_function("fx_point_eval_full", |b| {
        b.iter(|| {
            let mut acc = 0i64;
            for k in 0..N {
                let du = black_box(k) & 1023;
                let q = Fx::eval(black_box(&seg), du, iv);
                acc = acc
                    .wrapping_add(q.pos.0 as i64)
                    .wrapping_add(q.vel)
                    .wrapping_add(q.acc)
                    .wrapping_add(q.jerk);
            }
            acc
        })
    });
    // 100 kHz ticks over 1024 µs segments: a load every 102-103 ticks, as
    // in firmware (setup included in the per-evaluation time).
    g.bench_function("fx_tick_eval_pos", |b| {
        let mut e = TickEval::new(iv, 10).unwrap();
        b.iter(|| {
            let mut acc = 0i32;
            for _ in 0..N {
                let p = match e.next() {
                    Some(p) => p,
                    None => {
                        let du = e.next_offset();
                        e.load(black_box(&seg), du).unwrap();
                        e.next().unwrap()
                    }
                };
                acc = acc.wrapping_add(p.0);
            }
            acc
        })
    });
    let sf = segment_f32();
    g.bench_function("f32_eval_pos", |b| {
        b.iter(|| {
            let mut acc = 0.0f32;
            for k in 0..N {
                let du = black_box(k) & 1023;
                acc += f32::eval(black_box(&sf), du, iv).pos;
            }
            acc
        })
    });
    g.bench_function("f32_eval_full", |b| {
        b.iter(|| {
            let mut acc = 0.0f32;
            for k in 0..N {
                let du = black_box(k) & 1023;
                let q = f32::eval(black_box(&sf), du, iv);
                acc += q.pos + q.vel + q.acc + q.jerk;
            }
            acc
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
