//! The netresponder's answers, request by request.

use super::*;
use crate::link::queue::QueueLink;
use crate::packet::Instruction;
use crate::port::{Delivery, PortInfo, PortTx};
use crate::route::Route;
use crate::time::Duration;
use crate::transport::Transport;
use crate::{time::Instant, Runtime};

struct NoPort;

impl Port for NoPort {
    fn info(&self, _: u16) -> PortInfo<'_> {
        PortInfo {
            type_name: "none",
            name: "",
        }
    }
    fn on_packet(&mut self, _: Delivery<'_>, _: &mut PortTx<'_>) {}
}

type Rt = Runtime<8, 128, 2, 2>;
type Link = QueueLink<8, 128>;

fn runtime() -> Rt {
    let rt = Rt::new("test", "t").unwrap();
    // No time requests of its own: link 0's outbox holds only replies.
    #[cfg(feature = "sync")]
    let rt = rt
        .with_time_config(crate::clock::TimeConfig {
            enabled: false,
            ..Default::default()
        })
        .unwrap();
    rt
}

/// A packet that arrives on a link, for port `dst` of the runtime.
fn packet(dst: u16, payload: &[u8]) -> heapless::Vec<u8, 128> {
    let route = Route::through_links(&[0]).unwrap();
    let mut buf = [0u8; 128];
    let n = route
        .write_packet(
            &mut buf,
            Instruction::PortHandle { src: 1, dst },
            10_000,
            128,
            payload,
        )
        .unwrap();
    heapless::Vec::from_slice(&buf[..n]).unwrap()
}

fn poll(rt: &mut Rt, links: &mut [Link; 2], now: Instant) {
    let mut ports: [NoPort; 0] = [];
    rt.poll(now, &mut ports, links);
}

/// The `open` byte link information gives for link 1, asked over
/// link 0 at `now`.
fn open_byte(rt: &mut Rt, links: &mut [Link; 2], now: Instant) -> u8 {
    let mut payload = [0u8; 5];
    let n = Transport::Request(7).encode(&mut payload).unwrap();
    payload[n..n + 2].copy_from_slice(&[key::LINK_INFO, 1]);
    assert!(links[0].inject(&packet(0, &payload[..n + 2])));
    poll(rt, links, now);
    let reply = links[0].take_sent().expect("a reply");
    // [header 5][link_forward(0)][port_handle(0 -> 1)][reply 3]
    // [key][status][index][open]...
    assert_eq!(&reply[12..15], &[key::LINK_INFO, Status::Ok as u8, 1]);
    reply[15]
}

#[test]
fn a_link_never_heard_is_open_without_a_neighbour() {
    let (mut rt, mut links) = (runtime(), [Link::new(), Link::new()]);
    assert_eq!(
        open_byte(&mut rt, &mut links, Instant::from_micros(1_000)),
        LINK_UNHEARD
    );
    assert_eq!(rt.link_heard(1), None);
    // The link the question came in on was heard, by the question.
    assert_eq!(rt.link_heard(0), Some(Instant::from_micros(1_000)));
}

#[test]
fn a_packet_in_makes_a_neighbour_heard_for_the_window_only() {
    let (mut rt, mut links) = (runtime(), [Link::new(), Link::new()]);
    let t = 5_000_000;
    // A packet for a port the runtime lacks: dropped, but heard.
    assert!(links[1].inject(&packet(9, b"hi")));
    let t = Instant::from_micros(t);
    poll(&mut rt, &mut links, t);
    assert_eq!(rt.link_heard(1), Some(t));
    assert_eq!(
        open_byte(&mut rt, &mut links, t + Duration::from_micros(10)),
        LINK_HEARD
    );
    assert_eq!(
        open_byte(&mut rt, &mut links, t + NEIGHBOUR_HEARD),
        LINK_HEARD
    );
    assert_eq!(
        open_byte(
            &mut rt,
            &mut links,
            t + NEIGHBOUR_HEARD + Duration::from_micros(1)
        ),
        LINK_UNHEARD
    );
}

#[test]
fn a_malformed_packet_is_heard_too() {
    let (mut rt, mut links) = (runtime(), [Link::new(), Link::new()]);
    assert!(links[1].inject(&[0xff; 12]));
    poll(&mut rt, &mut links, Instant::from_micros(1_000));
    assert_eq!(rt.counters().malformed, 1);
    assert_eq!(
        open_byte(&mut rt, &mut links, Instant::from_micros(2_000)),
        LINK_HEARD
    );
}

#[test]
fn a_closed_link_reports_closed_and_forgets_its_neighbour() {
    let (mut rt, mut links) = (runtime(), [Link::new(), Link::new()]);
    assert!(links[1].inject(&packet(9, b"hi")));
    poll(&mut rt, &mut links, Instant::from_micros(1_000));
    assert_eq!(
        open_byte(&mut rt, &mut links, Instant::from_micros(2_000)),
        LINK_HEARD
    );
    links[1].set_open(false);
    assert_eq!(
        open_byte(&mut rt, &mut links, Instant::from_micros(3_000)),
        LINK_CLOSED
    );
    // Reopened within the window: whoever is there now is not heard yet.
    links[1].set_open(true);
    assert_eq!(
        open_byte(&mut rt, &mut links, Instant::from_micros(4_000)),
        LINK_UNHEARD
    );
}

/// Asks `SET_BUS` with `body` over link 0 and returns the reply's
/// `[key][status][fields]`.
fn set_bus<L: LinkGateway>(
    rt: &mut Rt,
    links: &mut [L; 2],
    inject: impl Fn(&mut L, &[u8]) -> bool,
    take: impl Fn(&mut L) -> Option<heapless::Vec<u8, 128>>,
    body: &[u8],
) -> heapless::Vec<u8, 16> {
    let mut payload = [0u8; 16];
    let n = Transport::Request(3).encode(&mut payload).unwrap();
    payload[n] = key::SET_BUS;
    payload[n + 1..n + 1 + body.len()].copy_from_slice(body);
    assert!(inject(
        &mut links[0],
        &packet(0, &payload[..n + 1 + body.len()])
    ));
    let mut ports: [NoPort; 0] = [];
    rt.poll(Instant::from_micros(1_000), &mut ports, links);
    let reply = take(&mut links[0]).expect("a reply");
    heapless::Vec::from_slice(&reply[12..]).unwrap()
}

#[test]
fn set_bus_takes_a_role_on_a_switchable_link_only() {
    use crate::bus::{BusRole, Switchable};
    type Sw = Switchable<Link, 128>;
    let inject = |l: &mut Sw, p: &[u8]| l.lower.inject(p);
    let take = |l: &mut Sw| l.lower.take_sent();
    let mut rt = runtime();
    let mut links = [
        Sw::new(Link::new(), BusRole::Off),
        Sw::new(Link::new(), BusRole::Off),
    ];
    let ok = set_bus(&mut rt, &mut links, inject, take, &[1, 2, 5]);
    assert_eq!(&ok[..], &[key::SET_BUS, Status::Ok as u8, 1, 2, 5]);
    assert!(rt.take_changes().bus);
    assert_eq!(rt.take_bus_request(), Some((1, BusRole::Drop(5))));
    assert_eq!(rt.take_bus_request(), None);
    // A drop address out of range, an unknown link, a short body.
    let bad = set_bus(&mut rt, &mut links, inject, take, &[1, 2, 255]);
    assert_eq!(&bad[..], &[key::SET_BUS, Status::InvalidValue as u8]);
    let none = set_bus(&mut rt, &mut links, inject, take, &[7, 0, 0]);
    assert_eq!(&none[..], &[key::SET_BUS, Status::NoSuchIndex as u8]);
    let short = set_bus(&mut rt, &mut links, inject, take, &[1, 2]);
    assert_eq!(&short[..], &[key::SET_BUS, Status::Malformed as u8]);
    assert_eq!(rt.take_bus_request(), None);

    // A link that cannot change roles refuses.
    let mut plain = [Link::new(), Link::new()];
    let refused = set_bus(
        &mut rt,
        &mut plain,
        |l, p| l.inject(p),
        |l| l.take_sent(),
        &[1, 1, 8],
    );
    assert_eq!(&refused[..], &[key::SET_BUS, Status::Refused as u8]);
    assert_eq!(rt.take_bus_request(), None);
}

#[test]
fn bus_known_answers_for_bus_links_only() {
    use crate::bus::{BusRole, Switchable, HEADER_LEN};
    type Sw = Switchable<Link, 128>;
    let mut rt = runtime();
    // Link 0 point to point (the request comes in there), link 1 a head.
    let mut links = [
        Sw::new(Link::new(), BusRole::Off),
        Sw::new(Link::new(), BusRole::Head { max_drop: 3 }),
    ];
    let mut ports: [NoPort; 0] = [];
    rt.poll(Instant::from_micros(10), &mut ports, &mut links);
    // Drop 1 answers its turn with a bare END: heard.
    let grant = links[1].lower.take_sent().expect("a grant");
    assert_eq!((grant.len(), grant[0]), (HEADER_LEN, 1));
    let turn = grant[2] & crate::bus::TURN_MASK;
    assert!(links[1].lower.inject(&[0, 1, crate::bus::END | turn]));
    rt.poll(Instant::from_micros(20), &mut ports, &mut links);
    let ask = |rt: &mut Rt, links: &mut [Sw; 2], body: &[u8]| {
        let mut payload = [0u8; 8];
        let n = Transport::Request(9).encode(&mut payload).unwrap();
        payload[n] = key::BUS_KNOWN;
        payload[n + 1..n + 1 + body.len()].copy_from_slice(body);
        assert!(links[0]
            .lower
            .inject(&packet(0, &payload[..n + 1 + body.len()])));
        let mut ports: [NoPort; 0] = [];
        rt.poll(Instant::from_micros(1_000), &mut ports, links);
        let reply = links[0].lower.take_sent().expect("a reply");
        heapless::Vec::<u8, 64>::from_slice(&reply[12..]).unwrap()
    };
    let known = ask(&mut rt, &mut links, &[1]);
    assert_eq!(&known[..3], &[key::BUS_KNOWN, Status::Ok as u8, 1]);
    assert_eq!(known.len(), 3 + 32);
    // Drop 1 answered: bit 1 of word 0; no other station was heard.
    assert_eq!(&known[3..7], &2u32.to_le_bytes());
    assert!(known[7..].iter().all(|&b| b == 0));
    // Not a bus, no such link, a short body.
    let plain = ask(&mut rt, &mut links, &[0]);
    assert_eq!(&plain[..], &[key::BUS_KNOWN, Status::NoSuchIndex as u8]);
    let none = ask(&mut rt, &mut links, &[5]);
    assert_eq!(&none[..], &[key::BUS_KNOWN, Status::NoSuchIndex as u8]);
    let short = ask(&mut rt, &mut links, &[]);
    assert_eq!(&short[..], &[key::BUS_KNOWN, Status::Malformed as u8]);
}

/// A port of 40 sub-ports, named by offset.
struct ManyPorts;

const NAMES: [&str; 4] = ["alpha", "beta.pipe", "gamma", "a_longer_name"];

impl Port for ManyPorts {
    fn port_count(&self) -> u16 {
        40
    }
    fn info(&self, offset: u16) -> PortInfo<'_> {
        PortInfo {
            type_name: "pipes_function",
            name: NAMES[usize::from(offset) % NAMES.len()],
        }
    }
    fn on_packet(&mut self, _: Delivery<'_>, _: &mut PortTx<'_>) {}
}

/// Asks `body` of a runtime with [`ManyPorts`]; the reply from its key.
fn ask_many(rt: &mut Rt, links: &mut [Link; 2], body: &[u8]) -> heapless::Vec<u8, 128> {
    let mut payload = [0u8; 16];
    let n = Transport::Request(5).encode(&mut payload).unwrap();
    payload[n..n + body.len()].copy_from_slice(body);
    assert!(links[0].inject(&packet(0, &payload[..n + body.len()])));
    let mut ports = [ManyPorts];
    rt.poll(Instant::from_micros(1_000), &mut ports, links);
    let reply = links[0].take_sent().expect("a reply");
    heapless::Vec::from_slice(&reply[12..]).unwrap()
}

#[test]
fn a_port_list_holds_whole_records_and_agrees_with_port_information() {
    let mut rt = runtime();
    let mut links = [Link::new(), Link::new()];
    type Name = heapless::String<32>;
    let mut listed: heapless::Vec<(u16, Name, Name), 64> = heapless::Vec::new();
    let mut from = 0u16;
    let mut replies = 0;
    loop {
        let [a, b] = from.to_le_bytes();
        let reply = ask_many(&mut rt, &mut links, &[key::PORT_LIST, a, b]);
        assert_eq!(&reply[..2], &[key::PORT_LIST, Status::Ok as u8]);
        let mut r = Reader::new(&reply[2..]);
        assert_eq!(r.u16().unwrap(), from);
        let count = r.u8().unwrap();
        for k in 0..u16::from(count) {
            let t = Name::try_from(r.str8().unwrap()).unwrap();
            let n = Name::try_from(r.str8().unwrap()).unwrap();
            listed.push((from + k, t, n)).unwrap();
        }
        assert!(r.is_empty(), "whole records only");
        if count == 0 {
            break;
        }
        replies += 1;
        from += u16::from(count);
    }
    // Port 0 (the netresponder) and the 40: several replies of a 128-byte
    // MTU, far fewer than one each.
    assert_eq!(listed.len(), 41);
    assert!((3..=10).contains(&replies), "{replies} replies");
    for (index, type_name, name) in &listed {
        let [a, b] = index.to_le_bytes();
        let reply = ask_many(&mut rt, &mut links, &[key::PORT_INFO, a, b]);
        let mut r = Reader::new(&reply[2..]);
        assert_eq!(r.u16().unwrap(), *index);
        assert_eq!(r.str8().unwrap(), type_name.as_str());
        assert_eq!(r.str8().unwrap(), name.as_str());
    }
    // A malformed request is refused as such.
    let reply = ask_many(&mut rt, &mut links, &[key::PORT_LIST, 0]);
    assert_eq!(&reply[..2], &[key::PORT_LIST, Status::Malformed as u8]);
}
