//! Properties of segmentation (osap_core::segment): any datagram cut by
//! any room comes back whole whatever the order and duplicates; a datagram
//! missing a segment is never delivered, only counted as lost; no input
//! panics the reassembler.

use osap_core::route::Route;
use osap_core::segment::{
    Plan, Reassembler, SegmentError, SegmentHeader, SegmentSource, HEADER_LEN,
};
use osap_core::time::{Duration, Instant};
use proptest::prelude::*;

/// Every segment of `data` cut for `room`, in order.
fn segments(id: u8, data: &[u8], room: usize) -> Vec<Vec<u8>> {
    let plan = Plan::new(data.len(), room).unwrap();
    (0..plan.count)
        .map(|i| {
            let mut s = vec![0u8; HEADER_LEN + plan.body_len(i)];
            SegmentHeader {
                id,
                index: i,
                count: plan.count,
                len: plan.len,
            }
            .encode(&mut s)
            .unwrap();
            let n = data.read_at(plan.offset(i), &mut s[HEADER_LEN..]);
            assert_eq!(n, plan.body_len(i));
            s
        })
        .collect()
}

/// A datagram that is not itself a segment.
fn datagram() -> impl Strategy<Value = Vec<u8>> {
    prop::collection::vec(any::<u8>(), 1..600).prop_map(|mut d| {
        if d[0] == 3 {
            d[0] = 2;
        }
        d
    })
}

proptest! {
    #[test]
    fn plans_cover_the_datagram_exactly(len in 1usize..5000, room in 7usize..300) {
        match Plan::new(len, room) {
            Ok(p) => {
                prop_assert_eq!(Plan::from_header(p.len, p.count), Ok(p));
                let mut at = 0;
                for i in 0..p.count {
                    let n = p.body_len(i);
                    prop_assert!(n > 0 && n <= room - HEADER_LEN);
                    prop_assert_eq!(p.offset(i), at);
                    at += n;
                }
                prop_assert_eq!(at, len);
            }
            Err(e) => {
                prop_assert_eq!(e, SegmentError::TooLarge);
                prop_assert!(len.div_ceil(room - HEADER_LEN) > 255);
            }
        }
    }

    #[test]
    fn any_order_and_duplicates_give_the_datagram_once(
        data in datagram(),
        room in 12usize..120,
        order in prop::collection::vec(any::<prop::sample::Index>(), 0..40),
        seed in any::<u64>(),
    ) {
        let segs = segments(9, &data, room);
        // A shuffled copy of every segment, plus some duplicates.
        let mut sends: Vec<usize> = (0..segs.len()).collect();
        let mut x = seed | 1;
        for i in (1..sends.len()).rev() {
            x ^= x << 13; x ^= x >> 7; x ^= x << 17;
            sends.swap(i, (x % (i as u64 + 1)) as usize);
        }
        for o in &order {
            let at = o.index(sends.len() + 1);
            sends.insert(at, o.index(segs.len()));
        }
        let route = Route::through_links(&[2, 5]).unwrap();
        let mut r: Reassembler<2, 600> = Reassembler::new();
        let mut delivered = Vec::new();
        for &i in &sends {
            if let Some(d) = r.on_segment(Instant::from_micros(1), &route, 7, &segs[i]).unwrap() {
                delivered.push(d.to_vec());
            }
        }
        prop_assert_eq!(delivered.len(), 1);
        prop_assert_eq!(&delivered[0], &data);
        let st = *r.stats();
        prop_assert_eq!(st.delivered, 1);
        prop_assert_eq!(st.segments as usize, segs.len());
        prop_assert_eq!(st.duplicates as usize, order.len());
        prop_assert_eq!(r.in_progress(), 0);
    }

    #[test]
    fn a_missing_segment_delivers_nothing(
        data in datagram(),
        room in 12usize..60,
        missing in any::<prop::sample::Index>(),
        dups in 0usize..4,
    ) {
        let segs = segments(1, &data, room);
        prop_assume!(segs.len() >= 2);
        let gone = missing.index(segs.len());
        let mut r: Reassembler<1, 600> = Reassembler::new().with_timeout(Duration::from_micros(500));
        let route = Route::local();
        for _ in 0..=dups {
            for (i, s) in segs.iter().enumerate().rev() {
                if i != gone {
                    prop_assert_eq!(r.on_segment(Instant::from_micros(10), &route, 1, s), Ok(None));
                }
            }
        }
        prop_assert_eq!(r.stats().lost, 0);
        r.expire(Instant::from_micros(509));
        prop_assert_eq!(r.in_progress(), 1);
        r.expire(Instant::from_micros(510));
        prop_assert_eq!(r.in_progress(), 0);
        let st = *r.stats();
        prop_assert_eq!((st.lost, st.delivered), (1, 0));
        // The missing segment, late, starts a new datagram and never
        // completes the old one.
        prop_assert_eq!(r.on_segment(Instant::from_micros(600), &route, 1, &segs[gone]), Ok(None));
        prop_assert_eq!(r.stats().delivered, 0);
    }

    #[test]
    fn interleaved_senders_are_kept_apart(
        a in datagram(),
        b in datagram(),
        room in 12usize..80,
    ) {
        let sa = segments(4, &a, room);
        let sb = segments(4, &b, room);
        let (ra, rb) = (Route::through_links(&[1]).unwrap(), Route::through_links(&[2]).unwrap());
        let mut r: Reassembler<2, 600> = Reassembler::new();
        let mut got = Vec::new();
        for i in 0..sa.len().max(sb.len()) {
            if let Some(s) = sa.get(i) {
                if let Some(d) = r.on_segment(Instant::ZERO, &ra, 3, s).unwrap() {
                    got.push(("a", d.to_vec()));
                }
            }
            if let Some(s) = sb.get(i) {
                if let Some(d) = r.on_segment(Instant::ZERO, &rb, 3, s).unwrap() {
                    got.push(("b", d.to_vec()));
                }
            }
        }
        got.sort();
        prop_assert_eq!(got, vec![("a", a), ("b", b)]);
    }

    #[test]
    fn arbitrary_input_never_panics(
        packets in prop::collection::vec(
            (prop::collection::vec(any::<u8>(), 0..80), 0u16..3, 0u64..1000),
            0..60,
        ),
    ) {
        let mut r: Reassembler<2, 64> = Reassembler::new().with_timeout(Duration::from_micros(100));
        let route = Route::local();
        let mut now = 0;
        for (mut p, port, dt) in packets {
            if let Some(k) = p.first_mut() {
                *k = 3;
            }
            now += dt;
            if let Ok(Some(d)) = r.on_segment(Instant::from_micros(now), &route, port, &p) {
                prop_assert!(!d.is_empty() && d.len() <= 64 && d[0] != 3);
            }
        }
    }
}
