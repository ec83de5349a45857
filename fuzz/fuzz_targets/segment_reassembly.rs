//! Feeds arbitrary segments to a `Reassembler<2, 128>` and checks:
//! - no panic on any header or body;
//! - a delivered datagram is exactly the bytes its segments carried (kept
//!   alongside in a model keyed by sender and id), never longer than the
//!   buffer, never itself a segment;
//! - no more datagrams are delivered than segments were accepted;
//! - the counters add up: every segment handed in is accepted, a
//!   duplicate, or refused under exactly one counter.
//!
//! Input: a stream of records `[sender: u8][dt: u8][len: u8][len bytes]`;
//! the record's bytes (with the segment key forced) are the segment,
//! `sender` picks one of four (route, port) pairs and `dt` advances the clock.

#![no_main]

use libfuzzer_sys::fuzz_target;
use osap_core::route::Route;
use osap_core::segment::{Reassembler, SegmentHeader, KEY_SEGMENT};
use std::collections::HashMap;

const BYTES: usize = 128;

fuzz_target!(|data: &[u8]| {
    let mut r: Reassembler<2, BYTES> = Reassembler::new().with_timeout(osap_core::Duration::from_micros(200));
    let routes = [Route::local(), Route::through_links(&[1]).unwrap()];
    // (sender, id, index) -> body, for the segments taken in.
    let mut held: HashMap<(u8, u8, u8), Vec<u8>> = HashMap::new();
    let mut now = osap_core::Instant::ZERO;
    let mut handed = 0u32;
    let mut rest = data;
    while let [sender, dt, len, tail @ ..] = rest {
        let n = usize::from(*len).min(tail.len());
        let mut seg = tail[..n].to_vec();
        rest = &tail[n..];
        if let Some(k) = seg.first_mut() {
            *k = KEY_SEGMENT;
        }
        now += osap_core::Duration::from_micros(u64::from(*dt));
        let s = sender % 4;
        let (route, port) = (&routes[usize::from(s & 1)], u16::from(s >> 1));
        handed += 1;
        let before = *r.stats();
        let result = r
            .on_segment(now, route, port, &seg)
            .map(|d| d.map(|d| d.to_vec()));
        let after = *r.stats();
        if after.segments > before.segments {
            let (h, _, body) = SegmentHeader::decode(&seg).expect("accepted a bad header");
            held.insert((s, h.id, h.index), body.to_vec());
        }
        if let Ok(Some(d)) = result {
            assert!(!d.is_empty() && d.len() <= BYTES);
            assert_ne!(d[0], KEY_SEGMENT);
            let (h, plan, _) = SegmentHeader::decode(&seg).unwrap();
            assert_eq!(d.len(), usize::from(h.len));
            for i in 0..h.count {
                let body = &held[&(s, h.id, i)];
                let at = plan.offset(i);
                assert_eq!(&d[at..at + body.len()], &body[..]);
            }
        }
    }
    let st = r.stats();
    assert!(st.delivered <= st.segments);
    let counted = st.segments + st.duplicates + st.malformed + st.too_large + st.no_slot;
    // A nested datagram counts its completing segment and a refusal.
    assert!(counted >= handed && counted <= handed + st.malformed);
});
