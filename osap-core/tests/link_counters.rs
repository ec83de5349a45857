//! The netresponder's link-counters request: per link, what the runtime
//! took in, sent, and dropped (at ingest, expired, closed), and the
//! gateway's own counts, read remotely.

use osap_core::codec::Reader;
use osap_core::counters::{GatewayCounters, LinkCounters};
use osap_core::link::queue::QueueLink;
use osap_core::netresponder::{key, Status};
use osap_core::packet::Instruction;
use osap_core::port::{Delivery, Port, PortInfo, PortTx};
use osap_core::route::Route;
use osap_core::time::Instant;
use osap_core::transport::Transport;
use osap_core::Runtime;

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

/// A packet that arrives on link 0 and leaves by `out` (or ends at port 0
/// with no `out`), living `ttl` µs.
fn packet(out: Option<u8>, ttl: u16, payload: &[u8]) -> heapless::Vec<u8, 128> {
    let hops: &[u8] = match &out {
        Some(l) => &[0, *l][..],
        None => &[0][..],
    };
    let route = Route::through_links(hops).unwrap();
    let mut buf = [0u8; 128];
    let n = route
        .write_packet(
            &mut buf,
            Instruction::PortHandle { src: 1, dst: 0 },
            ttl,
            128,
            payload,
        )
        .unwrap();
    heapless::Vec::from_slice(&buf[..n]).unwrap()
}

/// Asks for the counters of link `index` over link 0: the reply's status
/// and fields.
fn ask(rt: &mut Rt, links: &mut [Link; 2], now: u64, body: &[u8]) -> (Status, Vec<u8>) {
    let mut payload = [0u8; 16];
    Transport::Request(9).encode(&mut payload).unwrap();
    payload[3..3 + body.len()].copy_from_slice(body);
    assert!(links[0].inject(&packet(None, 10_000, &payload[..3 + body.len()])));
    let mut ports: [NoPort; 0] = [];
    rt.poll(Instant::from_micros(now), &mut ports, links);
    let reply = links[0].take_sent().expect("a reply");
    // [header 5][link_forward(0)][port_handle(0 -> 1)][request 3][key][status]
    assert_eq!(reply[12], body[0]);
    (Status::from_u8(reply[13]).unwrap(), reply[14..].to_vec())
}

fn counters_of(rt: &mut Rt, links: &mut [Link; 2], now: u64, index: u8) -> LinkCounters {
    let (status, fields) = ask(rt, links, now, &[key::LINK_COUNTERS, index]);
    assert_eq!(status, Status::Ok);
    assert_eq!(fields.len(), 1 + LinkCounters::ENCODED_LEN);
    assert_eq!(fields[0], index);
    let mut r = Reader::new(&fields[1..]);
    let c = LinkCounters::decode(&mut r).unwrap();
    assert!(r.is_empty());
    c
}

#[test]
fn link_counters_count_what_each_link_took_sent_and_dropped() {
    let rt = Rt::new("counted", "c").unwrap();
    // No clock requests of its own: every packet out is counted here.
    #[cfg(feature = "sync")]
    let rt = rt
        .with_time_config(osap_core::clock::TimeConfig {
            enabled: false,
            ..Default::default()
        })
        .unwrap();
    let mut rt = rt;
    // Link 1 takes 5 ms to put a packet on the wire.
    let mut links = [Link::new(), Link::new().with_wire_time(5_000, 0)];
    let mut ports: [NoPort; 0] = [];
    // In on link 0: garbage (dropped at ingest), a packet for link 1 that
    // would land after its deadline (expired), one that lands in time
    // (sent).
    assert!(links[0].inject(&[0xff; 12]));
    assert!(links[0].inject(&packet(Some(1), 100, b"late")));
    assert!(links[0].inject(&packet(Some(1), 60_000, b"fine")));
    rt.poll(Instant::from_micros(1_000), &mut ports, &mut links);
    assert!(
        links[1].take_sent().is_some(),
        "the packet in time went out"
    );
    assert!(links[1].take_sent().is_none(), "the late one did not");
    // Link 1 goes down: a packet for it is dropped as closed.
    links[1].set_open(false);
    assert!(links[0].inject(&packet(Some(1), 60_000, b"shut")));
    rt.poll(Instant::from_micros(2_000), &mut ports, &mut links);

    let one = counters_of(&mut rt, &mut links, 3_000, 1);
    assert_eq!(
        one,
        LinkCounters {
            received: 0,
            sent: 1,
            rx_dropped: 0,
            expired: 1,
            closed: 1,
            send_errors: 0,
            gateway: Some(GatewayCounters {
                frames: 0,
                disconnects: 1,
                ..Default::default()
            }),
            tx_bytes: one.tx_bytes,
            // 1 KiB takes 5 ms on link 1's wire.
            capacity_bytes_per_s: 204_800,
            held: 0,
            slots: one.slots,
            ..Default::default()
        }
    );
    // The one packet sent: its header, route and "fine".
    assert!((10..40).contains(&one.tx_bytes), "{one:?}");
    assert!(one.slots > 0, "{one:?}");
    // Link 0: four packets and this query in, one dropped, one reply out
    // before this query's (counted when sent).
    let zero = counters_of(&mut rt, &mut links, 4_000, 0);
    assert_eq!((zero.received, zero.rx_dropped), (6, 1), "{zero:?}");
    assert_eq!(zero.sent, 1, "{zero:?}");
    assert_eq!(zero.gateway.map(|g| g.frames), Some(6));
    // Bytes of the five packets taken in (the garbage never was), and a
    // link that cannot tell its wire time has no capacity.
    assert!(zero.rx_bytes > 3 * 10, "{zero:?}");
    assert_eq!(zero.capacity_bytes_per_s, 0);
    assert_eq!(rt.link_counters(0).map(|c| c.sent), Some(2));

    // No such link; a request with a byte too many.
    let (status, fields) = ask(&mut rt, &mut links, 5_000, &[key::LINK_COUNTERS, 2]);
    assert_eq!((status, fields.len()), (Status::NoSuchIndex, 0));
    let (status, _) = ask(&mut rt, &mut links, 6_000, &[key::LINK_COUNTERS, 0, 0]);
    assert_eq!(status, Status::Malformed);
    let (status, _) = ask(&mut rt, &mut links, 7_000, &[key::LINK_COUNTERS]);
    assert_eq!(status, Status::Malformed);
}

#[test]
fn link_counters_round_trip_and_reject_truncation() {
    let c = LinkCounters {
        received: 1,
        sent: 2,
        rx_dropped: 3,
        expired: 4,
        closed: 5,
        send_errors: 6,
        gateway: Some(GatewayCounters {
            frames: 7,
            frame_errors: 8,
            rx_dropped: 9,
            tx_dropped: 10,
            disconnects: u32::MAX,
        }),
        rx_bytes: 11,
        tx_bytes: 12,
        capacity_bytes_per_s: 13,
        held: 14,
        slots: 15,
    };
    for c in [c, LinkCounters { gateway: None, ..c }] {
        let mut buf = [0u8; LinkCounters::ENCODED_LEN];
        let mut w = osap_core::codec::Writer::new(&mut buf);
        c.encode(&mut w).unwrap();
        assert_eq!(w.len(), LinkCounters::ENCODED_LEN);
        assert_eq!(LinkCounters::decode(&mut Reader::new(&buf)), Ok(c));
        // The first layout (45 bytes) reads with the load fields 0; any
        // other truncation is an error.
        const FIRST: usize = 45;
        for n in (0..buf.len()).filter(|n| *n != FIRST) {
            assert!(LinkCounters::decode(&mut Reader::new(&buf[..n])).is_err());
        }
        let old = LinkCounters::decode(&mut Reader::new(&buf[..FIRST])).unwrap();
        assert_eq!(
            old,
            LinkCounters {
                rx_bytes: 0,
                tx_bytes: 0,
                capacity_bytes_per_s: 0,
                held: 0,
                slots: 0,
                ..c
            }
        );
    }
    let mut small = [0u8; LinkCounters::ENCODED_LEN - 1];
    assert!(c
        .encode(&mut osap_core::codec::Writer::new(&mut small))
        .is_err());
}
