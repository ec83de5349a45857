//! Reassembly cost: segments taken in per second by a `Reassembler`, for a
//! 512-byte datagram (the default reassembler's largest) cut for 64- and
//! 128-byte packets on a one-hop route, in order and in reverse order. Also
//! prints the RAM the reassembler and the sender take.
//!
//! Run: `cargo bench -p osap-core --bench segmentation`
//!
//! Each iteration hands every segment of one datagram to the reassembler
//! and takes the datagram out, so time per segment is the iteration time
//! divided by the segment count (criterion's throughput line, elements/s).

// criterion_main! writes an undocumented `main`.
#![allow(missing_docs)]

use criterion::{black_box, criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use osap_core::route::Route;
use osap_core::segment::{
    DefaultReassembler, Plan, SegmentHeader, SegmentSender, SegmentSource, DEFAULT_BYTES,
    HEADER_LEN,
};
use osap_core::time::Instant;
use osap_core::Instruction;

/// The segments of a `DEFAULT_BYTES` datagram sent over `route` at `mtu`.
fn segments(route: &Route, mtu: u16) -> Vec<Vec<u8>> {
    let room = usize::from(mtu) - route.header_len(Instruction::PortHandle { src: 1, dst: 1 });
    let data: Vec<u8> = (0..DEFAULT_BYTES).map(|i| (i * 7 + 2) as u8).collect();
    let plan = Plan::new(data.len(), room).unwrap();
    (0..plan.count)
        .map(|i| {
            let mut s = vec![0u8; HEADER_LEN + plan.body_len(i)];
            SegmentHeader {
                id: 0,
                index: i,
                count: plan.count,
                len: plan.len,
            }
            .encode(&mut s)
            .unwrap();
            data[..].read_at(plan.offset(i), &mut s[HEADER_LEN..]);
            s
        })
        .collect()
}

fn reassembly(c: &mut Criterion) {
    println!(
        "RAM: DefaultReassembler (2 x 512 B) = {} B, SegmentSender = {} B",
        core::mem::size_of::<DefaultReassembler>(),
        core::mem::size_of::<SegmentSender>()
    );
    let route = Route::through_links(&[1]).unwrap();
    let mut group = c.benchmark_group("reassemble_512B");
    for mtu in [64u16, 128] {
        let segs = segments(&route, mtu);
        group.throughput(Throughput::Elements(segs.len() as u64));
        for (order, reversed) in [("in_order", false), ("reversed", true)] {
            let mut list: Vec<&[u8]> = segs.iter().map(|s| &s[..]).collect();
            if reversed {
                list.reverse();
            }
            let mut r = DefaultReassembler::new();
            let id = BenchmarkId::new(order, format!("mtu{mtu}_{}seg", segs.len()));
            group.bench_with_input(id, &list, |b, list| {
                b.iter(|| {
                    let mut whole = 0;
                    for s in list {
                        if let Ok(Some(d)) = r.on_segment(Instant::ZERO, &route, 1, black_box(s)) {
                            whole = d.len();
                        }
                    }
                    // Free the delivered slot so every iteration starts alike.
                    r.expire(Instant::from_micros(u64::MAX));
                    assert_eq!(whole, DEFAULT_BYTES);
                })
            });
        }
    }
    group.finish();
}

criterion_group!(benches, reassembly);
criterion_main!(benches);
