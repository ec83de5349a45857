use super::*;
use crate::clock::{CODE_TIME_REPLY, CODE_TIME_REQUEST};
use crate::link::queue::QueueLink;
use crate::packet::Instruction;
use crate::port::Port;
use crate::route::Route;

type Lower = QueueLink<8, 64>;
type Station = BusLink<Lower, 64>;

/// Carries every frame any station sent to every other station.
fn carry(stations: &mut [&mut Station]) {
    for i in 0..stations.len() {
        while let Some(frame) = stations[i].lower.take_sent() {
            for (j, s) in stations.iter_mut().enumerate() {
                if j != i {
                    assert!(s.lower.inject(&frame));
                }
            }
        }
    }
}

fn packet_to(route: &Route, code: u8, body: &[u8]) -> heapless::Vec<u8, 64> {
    let mut buf = [0u8; 64];
    let n = route
        .write_packet(&mut buf, Instruction::SystemMsg(code), 1000, 64, body)
        .unwrap();
    heapless::Vec::from_slice(&buf[..n]).unwrap()
}

#[test]
fn head_polls_each_drop_and_takes_the_medium_back() {
    let mut head = Station::new(Lower::new(), BusConfig::head(2));
    let mut d1 = Station::new(Lower::new(), BusConfig::drop(1));
    let mut d2 = Station::new(Lower::new(), BusConfig::drop(2));
    let mut buf = [0u8; 64];
    // Drops are silent until granted.
    assert!(!d1.clear_to_send());
    head.poll(Instant::ZERO);
    assert_eq!(head.core.counters().grants, 1);
    carry(&mut [&mut head, &mut d1, &mut d2]);
    assert!(d1.receive(&mut buf).is_none()); // a bare grant
    assert!(d1.clear_to_send());
    assert!(d2.receive(&mut buf).is_none());
    assert!(!d2.clear_to_send());
    assert_eq!(d2.core.counters().other_drop, 1);
    // d1 has nothing: its next poll hands the medium back.
    d1.poll(Instant::from_micros(10));
    assert!(!d1.clear_to_send());
    carry(&mut [&mut head, &mut d1, &mut d2]);
    assert!(head.receive(&mut buf).is_none());
    assert!(head.clear_to_send());
    assert!(head.bus().unwrap().is_present(1));
    // Next turn goes to drop 2.
    head.poll(Instant::from_micros(20));
    carry(&mut [&mut head, &mut d1, &mut d2]);
    d2.receive(&mut buf);
    assert!(d2.clear_to_send());
}

#[test]
fn a_silent_drop_times_out_and_is_polled_rarely() {
    let mut head = Station::new(Lower::new(), BusConfig::head(3));
    head.poll(Instant::ZERO);
    let until = head.wake_at().unwrap();
    assert!(until > Instant::ZERO);
    head.poll(until);
    assert_eq!(head.core.counters().timeouts, 1);
    assert!(!head.bus().unwrap().is_present(1));
    // Drop 1 is now skipped until the next discovery cycle.
    head.poll(until + Duration::from_micros(1));
    let frame = head.lower.take_sent().unwrap();
    let frame = head.lower.take_sent().unwrap_or(frame);
    assert_eq!(BusHeader::parse(&frame).unwrap().0.dst, 2);
}

#[test]
fn a_drop_heard_once_stays_known_after_it_misses_a_turn() {
    let mut head = Station::new(Lower::new(), BusConfig::head(1));
    let mut d1 = Station::new(Lower::new(), BusConfig::drop(1));
    let mut buf = [0u8; 64];
    // Before its first turn drop 1 counts as present, but was never heard.
    assert!(head.bus().unwrap().is_present(1));
    assert!(!head.bus().unwrap().is_known(1));
    head.poll(Instant::ZERO);
    carry(&mut [&mut head, &mut d1]);
    assert!(d1.receive(&mut buf).is_none());
    d1.poll(Instant::from_micros(10));
    carry(&mut [&mut head, &mut d1]);
    assert!(head.receive(&mut buf).is_none());
    let info = head.bus().unwrap();
    assert!(info.is_present(1) && info.is_known(1));
    // Its next turn goes unanswered (the drop is busy): no longer present,
    // still known, so a scan still asks it.
    head.poll(Instant::from_micros(20));
    let until = head.wake_at().unwrap();
    head.poll(until);
    assert_eq!(head.core.counters().timeouts, 1);
    let info = head.bus().unwrap();
    assert!(!info.is_present(1));
    assert!(info.is_known(1));
    // The drop knows its head once heard, and no one else.
    let d = d1.bus().unwrap();
    assert!(d.is_known(HEAD) && d.known[1..] == [0; 7] && d.known[0] == 1);
}

#[test]
fn broadcast_reaches_every_drop_and_others_frames_are_ignored() {
    let mut head = Station::new(Lower::new(), BusConfig::head(2));
    let mut d1 = Station::new(Lower::new(), BusConfig::drop(1));
    let mut d2 = Station::new(Lower::new(), BusConfig::drop(2));
    let p = packet_to(&Route::local(), 9, &[1, 2, 3]);
    head.send_to(BROADCAST, &p).unwrap();
    head.send_to(2, &p).unwrap();
    carry(&mut [&mut head, &mut d1, &mut d2]);
    let mut buf = [0u8; 64];
    for d in [&mut d1, &mut d2] {
        let rx = d.receive(&mut buf).unwrap();
        assert_eq!(&buf[..rx.len], &p[..]);
        assert_eq!(d.received_from(), Some(HEAD));
    }
    assert!(d2.receive(&mut buf).is_some());
    assert!(d1.receive(&mut buf).is_none());
    assert_eq!(d1.core.counters().other_drop, 1);
}

#[test]
fn malformed_headers_and_echoes_are_counted_not_taken() {
    let mut d1 = Station::new(Lower::new(), BusConfig::drop(1));
    for frame in [
        &[][..],
        &[1, 0][..],
        &[1, 255, 0, 5][..],
        &[1, 0, 0x80, 5][..],
    ] {
        d1.lower.inject(frame);
    }
    d1.lower.inject(&[0, 1, 0, 5]); // our own address as sender
    let mut buf = [0u8; 64];
    assert!(d1.receive(&mut buf).is_none());
    assert_eq!(d1.core.counters().malformed, 4);
    assert_eq!(d1.core.counters().echo, 1);
    assert_eq!(d1.counters().unwrap().frame_errors, 4);
}

/// A runtime with no ports of its own.
struct NoPorts;
impl Port for NoPorts {
    fn info(&self, _: u16) -> crate::port::PortInfo<'_> {
        crate::port::PortInfo {
            type_name: "none",
            name: "",
        }
    }
    fn on_packet(&mut self, _: crate::port::Delivery<'_>, _: &mut crate::port::PortTx<'_>) {}
}

#[test]
fn a_runtime_answers_across_the_bus_with_the_senders_drop() {
    let mut rt: crate::Runtime<8, 64, 4, 2> = crate::Runtime::new("head", "h").unwrap();
    let mut links = [Station::new(Lower::new(), BusConfig::head(1))];
    let ports: &mut [NoPorts] = &mut [];
    // Drop 1's time request, addressed bus 3 drop 0 as drop 1 wrote it.
    let route = Route::local()
        .with_hop(Instruction::BusForward { bus: 3, drop: HEAD })
        .unwrap();
    let request = packet_to(&route, CODE_TIME_REQUEST, &42u64.to_le_bytes());
    // The head grants drop 1; drop 1 answers with its request and END.
    rt.poll(Instant::ZERO, ports, &mut links);
    while links[0].lower.take_sent().is_some() {}
    let end = END | turn_flags(links[0].core.turn_no);
    let mut frame: heapless::Vec<u8, 64> = heapless::Vec::from_slice(&[HEAD, 1, end]).unwrap();
    frame.extend_from_slice(&request).unwrap();
    links[0].lower.inject(&frame);
    rt.poll(Instant::from_micros(10), ports, &mut links);
    let reply = links[0]
        .lower
        .take_sent()
        .expect("a reply in the head's turn");
    let (h, packet) = BusHeader::parse(&reply).unwrap();
    // Addressed to one drop, it lends that drop the medium.
    assert_eq!((h.dst, h.src, h.flags & !TURN_MASK), (1, HEAD, GRANT));
    // The reply's route is the hop back: bus 0 (our index) to drop 1.
    let view = crate::packet::Packet::new_checked(packet).unwrap();
    assert_eq!(
        view.instruction(),
        Ok(Instruction::BusForward { bus: 0, drop: 1 })
    );
    assert_eq!(packet[7], CODE_TIME_REPLY);
    // A link_forward onto a bus link has no drop: dropped, not sent.
    let no_route = rt.counters().no_route;
    let mut frame: heapless::Vec<u8, 64> = heapless::Vec::from_slice(&[HEAD, 1, 0]).unwrap();
    // bus_forward(3, 0) as walked, then link_forward(0) (our bus), then a
    // system message.
    frame
        .extend_from_slice(&[5, 0xE8, 3, 64, 0, 0x80 | 3, HEAD, 0x40, 9])
        .unwrap();
    links[0].lower.inject(&frame);
    rt.poll(Instant::from_micros(20), ports, &mut links);
    assert_eq!(rt.counters().no_route, no_route + 1);
}

#[test]
fn a_frame_to_one_drop_grants_it_a_turn_to_answer_in() {
    let mut head = Station::new(Lower::new(), BusConfig::head(2));
    let mut d1 = Station::new(Lower::new(), BusConfig::drop(1));
    let mut d2 = Station::new(Lower::new(), BusConfig::drop(2));
    let mut buf = [0u8; 64];
    let p = packet_to(&Route::local(), 9, &[1, 2, 3]);
    head.send_to(1, &p).unwrap();
    // The head waits for drop 1 now: nothing more of its own, no poll.
    assert!(!head.clear_to_send());
    head.poll(Instant::from_micros(1));
    let frame = head.lower.take_sent().unwrap();
    assert!(head.lower.take_sent().is_none());
    for d in [&mut d1, &mut d2] {
        d.lower.inject(&frame);
    }
    assert!(d1.receive(&mut buf).is_some());
    assert!(d1.clear_to_send());
    assert!(d2.receive(&mut buf).is_none());
    assert!(!d2.clear_to_send());
    // A port answering on the next pass still has the turn.
    d1.poll(Instant::from_micros(10));
    assert!(d1.clear_to_send());
    assert_eq!(d1.wake_at(), Some(Instant::from_micros(10)));
    d1.send_to(HEAD, &p).unwrap();
    d1.poll(Instant::from_micros(20));
    assert!(!d1.clear_to_send());
    let answer = d1.lower.take_sent().unwrap();
    assert_eq!(BusHeader::parse(&answer).unwrap().0.flags & !TURN_MASK, 0);
    let end = d1.lower.take_sent().unwrap();
    assert_eq!(
        BusHeader::parse(&end).unwrap(),
        (
            BusHeader {
                dst: HEAD,
                src: 1,
                flags: END | turn_flags(head.core.turn_no)
            },
            &[][..]
        )
    );
    head.lower.inject(&answer);
    head.lower.inject(&end);
    assert!(head.receive(&mut buf).is_some());
    assert_eq!(head.received_from(), Some(1));
    assert!(head.receive(&mut buf).is_none());
    assert!(head.clear_to_send());
    assert_eq!(head.core.counters().timeouts, 0);
}

#[test]
fn the_head_polls_in_address_order_after_its_burst() {
    let mut head = Station::new(Lower::new(), BusConfig::head(2));
    let p = packet_to(&Route::local(), 9, &[1]);
    let mut buf = [0u8; 64];
    for _ in 0..BusConfig::head(2).head_burst {
        assert!(head.clear_to_send());
        head.send_to(1, &p).unwrap();
        head.lower
            .inject(&[HEAD, 1, END | turn_flags(head.core.turn_no)]);
        assert!(head.receive(&mut buf).is_none());
    }
    // Burst spent: the next frame waits for a poll of drop 1 then 2.
    assert!(!head.clear_to_send());
    while head.lower.take_sent().is_some() {}
    head.poll(Instant::from_micros(5));
    let grant = head.lower.take_sent().unwrap();
    assert_eq!(
        BusHeader::parse(&grant).unwrap().0,
        BusHeader {
            dst: 1,
            src: HEAD,
            flags: GRANT | turn_flags(head.core.turn_no)
        }
    );
    head.lower
        .inject(&[HEAD, 1, END | turn_flags(head.core.turn_no)]);
    assert!(head.receive(&mut buf).is_none());
    assert!(head.clear_to_send());
}

#[test]
fn a_grant_waits_out_what_the_head_queued_before_it() {
    // 100 µs a byte.
    let mut head = Station::new(Lower::new().with_wire_time(0, 100_000), BusConfig::head(1));
    let p = packet_to(&Route::local(), 9, &[0; 40]);
    head.send_to(BROADCAST, &p).unwrap();
    head.send_to(BROADCAST, &p).unwrap();
    head.poll(Instant::ZERO);
    let queued =
        Instant::ZERO + head.transmit_time(p.len()) * 2 + head.lower.transmit_time(HEADER_LEN);
    let until = head.wake_at().unwrap();
    assert!(
        until >= queued + BusConfig::head(1).reply_timeout,
        "{until} {queued}"
    );
    head.poll(until - Duration::from_micros(1));
    assert_eq!(head.core.counters().timeouts, 0);
    head.poll(until);
    assert_eq!(head.core.counters().timeouts, 1);
}

#[test]
fn a_late_end_from_an_earlier_turn_does_not_end_the_current_one() {
    let mut head = Station::new(Lower::new(), BusConfig::head(2));
    let mut buf = [0u8; 64];
    head.poll(Instant::ZERO);
    let stale = END | turn_flags(head.core.turn_no);
    let until = head.wake_at().unwrap();
    head.poll(until); // drop 1 timed out
    head.poll(until + Duration::from_micros(1)); // polls drop 2
    assert_eq!(head.core.counters().grants, 2);
    // Drop 1's END to the first grant comes only now.
    head.lower.inject(&[HEAD, 1, stale]);
    assert!(head.receive(&mut buf).is_none());
    assert!(!head.clear_to_send());
    assert_eq!(head.core.counters().out_of_turn, 1);
    head.lower
        .inject(&[HEAD, 2, END | turn_flags(head.core.turn_no)]);
    assert!(head.receive(&mut buf).is_none());
    assert!(head.clear_to_send());
}

#[test]
fn a_runtime_keeps_reading_a_bus_at_its_quota_so_turns_end() {
    let mut rt: crate::Runtime<8, 64, 4, 2> = crate::Runtime::new("head", "h").unwrap();
    let mut links = [Station::new(Lower::new(), BusConfig::head(2))];
    let ports: &mut [NoPorts] = &mut [];
    // The head polls drop 1.
    rt.poll(Instant::ZERO, ports, &mut links);
    while links[0].lower.take_sent().is_some() {}
    let turn = turn_flags(links[0].core.turn_no);
    // Drop 1 sends five packets for drop 2 (they wait: the medium is drop
    // 1's) and ends its turn: one more than the link's quota of 4.
    let route = Route::local()
        .with_hop(Instruction::BusForward { bus: 3, drop: HEAD })
        .unwrap()
        .with_hop(Instruction::BusForward { bus: 0, drop: 2 })
        .unwrap();
    let p = packet_to(&route, 9, &[1]);
    for _ in 0..5 {
        let frame = [&[HEAD, 1, turn][..], &p[..]].concat();
        assert!(links[0].lower.inject(&frame));
    }
    assert!(links[0].lower.inject(&[HEAD, 1, END | turn]));
    rt.poll(Instant::from_micros(10), ports, &mut links);
    // Four taken, the fifth dropped and counted, and the END seen: the
    // head has the medium back and forwards to drop 2 at once.
    assert_eq!(rt.counters().quota_refused, 1);
    assert_eq!(rt.link_counters(0).unwrap().rx_dropped, 1);
    assert_eq!(links[0].core.counters().timeouts, 0);
    let sent = links[0].lower.take_sent().expect("forwarded to drop 2");
    let (h, _) = BusHeader::parse(&sent).unwrap();
    // With its quota taken it has no room for an answer: no grant.
    assert_eq!((h.dst, h.flags & GRANT), (2, 0));
    assert!(links[0].clear_to_send());
}

#[test]
#[cfg(feature = "sync")] // only the controller sends time requests
fn a_drop_keeps_one_time_request_waiting_at_the_plain_rate() {
    let mut rt: crate::Runtime<8, 64, 4, 2> = crate::Runtime::new("drop", "d").unwrap();
    let mut links = [Station::new(Lower::new(), BusConfig::drop(1))];
    let ports: &mut [NoPorts] = &mut [];
    // Never granted: whatever the clock asks for waits in the stack.
    // Discovery would ask many times an interval on a point-to-point link.
    let mut now = 0;
    while now < 15_000 {
        rt.poll(Instant::from_micros(now), ports, &mut links);
        now += 500;
    }
    assert_eq!(rt.stack().held(crate::stack::Owner::System), Some(1));
    // Granted, it sends that one; the next waits for the interval.
    links[0].lower.inject(&[1, HEAD, GRANT]);
    rt.poll(Instant::from_micros(now), ports, &mut links);
    let frame = links[0].lower.take_sent().expect("the time request");
    let (h, packet) = BusHeader::parse(&frame).unwrap();
    assert_eq!(h.dst, HEAD);
    assert_eq!(packet[7], CODE_TIME_REQUEST);
    // Stamped as it goes onto the wire (a `bus_forward` hop is two bytes
    // long), not when the clock asked for it 15 ms before.
    let stamp = u64::from_le_bytes(packet[8..16].try_into().unwrap());
    assert_eq!(stamp, now + links[0].lower.queue_delay().as_micros());
    // The request's frame ends the turn itself: no bare END on a later pass.
    assert_ne!(h.flags & END, 0);
    assert!(!links[0].clear_to_send());
    assert_eq!(rt.stack().held(crate::stack::Owner::System), Some(0));
    rt.poll(Instant::from_micros(now + 1_000), ports, &mut links);
    assert!(links[0].lower.take_sent().is_none());
    assert_eq!(rt.stack().held(crate::stack::Owner::System), Some(0));
}

#[test]
fn a_drop_ends_its_turn_on_its_time_request() {
    let mut head = Station::new(Lower::new(), BusConfig::head(1));
    let mut d1 = Station::new(Lower::new(), BusConfig::drop(1));
    let mut buf = [0u8; 64];
    let to_head = Route::local()
        .with_hop(Instruction::BusForward { bus: 0, drop: HEAD })
        .unwrap();
    // Any other packet leaves burst for more (burst 2): no END.
    head.poll(Instant::ZERO);
    carry(&mut [&mut head, &mut d1]);
    d1.receive(&mut buf);
    d1.send(&packet_to(&to_head, 9, &[1])).unwrap();
    let frame = d1.lower.take_sent().unwrap();
    let (h, _) = BusHeader::parse(&frame).unwrap();
    assert_eq!(h.flags & END, 0);
    assert!(head.lower.inject(&frame));
    assert!(d1.clear_to_send());
    d1.poll(Instant::from_micros(10)); // bare END
    carry(&mut [&mut head, &mut d1]);
    assert!(head.receive(&mut buf).is_some());
    assert!(head.receive(&mut buf).is_none());
    // A time request, first in the turn, ends it at once.
    head.poll(Instant::from_micros(20));
    carry(&mut [&mut head, &mut d1]);
    d1.receive(&mut buf);
    assert!(d1.clear_to_send());
    let request = packet_to(&to_head, CODE_TIME_REQUEST, &7u64.to_le_bytes());
    d1.send(&request).unwrap();
    let frame = d1.lower.take_sent().unwrap();
    let (h, _) = BusHeader::parse(&frame).unwrap();
    assert_ne!(h.flags & END, 0);
    assert!(!d1.clear_to_send());
    assert_eq!(d1.wake_at(), None);
    // The head has the medium back with the request, and may answer now.
    assert!(head.lower.inject(&frame));
    assert!(head.receive(&mut buf).is_some());
    assert!(head.clear_to_send());
    assert_eq!(head.core.counters().timeouts, 0);
}
