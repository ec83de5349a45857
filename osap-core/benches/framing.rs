//! Frames encoded and decoded per second, for short and long packets.
//!
//! Run: `cargo bench -p osap-core --bench framing`

// criterion_main! writes an undocumented `main`.
#![allow(missing_docs)]

use criterion::{black_box, criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use osap_core::framing::{encode_frame, max_frame_len, FrameDecoder};

const SIZES: [usize; 2] = [32, 200];
const MAX: usize = max_frame_len(256);

/// Packet-like bytes: mostly non-zero with the odd 0x00, as in real headers
/// and little-endian fields. Deterministic so runs are comparable.
fn packet(len: usize) -> Vec<u8> {
    let mut x = 0x2545_F491u32;
    (0..len)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            if x.is_multiple_of(16) {
                0
            } else {
                x as u8
            }
        })
        .collect()
}

fn encode(c: &mut Criterion) {
    let mut group = c.benchmark_group("encode_frame");
    group.throughput(Throughput::Elements(1));
    for len in SIZES {
        let p = packet(len);
        let mut out = [0u8; MAX];
        group.bench_with_input(BenchmarkId::from_parameter(len), &p, |b, p| {
            b.iter(|| encode_frame(black_box(p), black_box(&mut out)).unwrap())
        });
    }
    group.finish();
}

fn decode(c: &mut Criterion) {
    // Many frames per iteration, so the per-call overhead of the loop is
    // amortised the way it is on a busy link.
    const FRAMES: usize = 64;
    let mut group = c.benchmark_group("decode_frame");
    group.throughput(Throughput::Elements(FRAMES as u64));
    for len in SIZES {
        let p = packet(len);
        let mut stream = Vec::new();
        let mut out = [0u8; MAX];
        for _ in 0..FRAMES {
            let n = encode_frame(&p, &mut out).unwrap();
            stream.extend_from_slice(&out[..n]);
        }
        let mut dec = FrameDecoder::<MAX>::new();
        group.bench_with_input(BenchmarkId::from_parameter(len), &stream, |b, stream| {
            b.iter(|| {
                let mut input = black_box(&stream[..]);
                let mut ok = 0usize;
                while let Some(r) = dec.decode(&mut input) {
                    ok += r.map_or(0, |p| p.len());
                }
                ok
            })
        });
    }
    group.finish();
}

criterion_group!(benches, encode, decode);
criterion_main!(benches);
