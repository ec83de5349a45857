//! Feeds arbitrary frames to bus stations (a head and a drop) and to the
//! bus header parser.
//!
//! The first input byte picks the station (even: the head of drops 1..=8,
//! odd: drop 3) and, in its upper bits, a time step; the rest is split into
//! frames at zero bytes. Each frame is parsed on its own, then fed to the
//! station between polls at advancing times. Checks:
//! - no panic;
//! - an accepted header re-encodes to the bytes it came from, and its
//!   packet is the rest of the frame;
//! - a refused header is refused for a stated reason: short, a broadcast
//!   source, a reserved flag, or a grant not from the head to one drop;
//! - the station returns only packets that came in a frame for it (its
//!   address or broadcast), byte for byte, with the sender it names;
//! - a drop never sends unless granted, and a station never sends more
//!   frames than its turn allows.

#![no_main]

use libfuzzer_sys::fuzz_target;
use osap_core::bus::{
    BusConfig, BusFrameError, BusHeader, BusLink, BROADCAST, END, GRANT, HEAD, HEADER_LEN,
    TURN_MASK,
};
use osap_core::link::queue::QueueLink;
use osap_core::link::LinkGateway;

fuzz_target!(|data: &[u8]| {
    let Some((&first, rest)) = data.split_first() else {
        return;
    };
    let config = if first & 1 == 0 {
        BusConfig::head(8)
    } else {
        BusConfig::drop(3)
    };
    let step = u64::from(first >> 1) * 37;
    let mut station: BusLink<QueueLink<4, 64>, 64> = BusLink::new(QueueLink::new(), config);
    let mut buf = [0u8; 64];
    let mut now = osap_core::Instant::ZERO;
    for frame in rest.split(|&b| b == 0).take(64) {
        match BusHeader::parse(frame) {
            Ok((h, packet)) => {
                assert_eq!(&h.to_bytes()[..], &frame[..HEADER_LEN]);
                assert_eq!(packet, &frame[HEADER_LEN..]);
                assert_ne!(h.src, BROADCAST);
                assert_eq!(h.flags & !(GRANT | END | TURN_MASK), 0);
            }
            Err(BusFrameError::Truncated) => assert!(frame.len() < HEADER_LEN),
            Err(BusFrameError::BadSource) => assert_eq!(frame[1], BROADCAST),
            Err(BusFrameError::BadFlags) => {
                let flags = frame[2];
                let bad_grant = flags & GRANT != 0
                    && (frame[1] != HEAD || frame[0] == HEAD || frame[0] == BROADCAST);
                assert!(flags & !(GRANT | END | TURN_MASK) != 0 || bad_grant);
            }
            Err(e) => panic!("a refusal this target does not know: {e}"),
        }
        if frame.len() > 64 || !station.lower.inject(frame) {
            continue;
        }
        let granted_before = station.clear_to_send();
        if let Some(rx) = station.receive(&mut buf) {
            let (h, packet) =
                BusHeader::parse(frame).expect("a returned packet had a valid header");
            assert!(h.dst == config.drop || h.dst == BROADCAST);
            assert_eq!(&buf[..rx.len], packet);
            assert_eq!(station.received_from(), Some(h.src));
        }
        // Whatever the station may send now, it sends; a drop only when
        // granted, and never more than its turn allows.
        let mut sent = 0;
        while station.clear_to_send() {
            let to = if config.is_head() {
                1 + (sent % 8) as u8
            } else {
                HEAD
            };
            if station.send_to(to, &[9, 9]).is_err() {
                break;
            }
            sent += 1;
            assert!(sent <= usize::from(config.head_burst.max(config.burst)));
        }
        if !config.is_head() && !granted_before && sent > 0 {
            // Only a grant in this very frame lets a drop talk.
            let (h, _) = BusHeader::parse(frame).expect("a drop granted by a valid frame");
            assert!(h.flags & GRANT != 0 && h.dst == config.drop && h.src == HEAD);
        }
        while station.lower.take_sent().is_some() {}
        now += osap_core::Duration::from_micros(step);
        station.poll(now);
        while station.lower.take_sent().is_some() {}
    }
});
