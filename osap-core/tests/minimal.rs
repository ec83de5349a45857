//! A runtime built without the clock-synchronisation controller (osap-core
//! without its `sync` feature): it answers every netresponder query except
//! the time-controller ones, which are unknown keys, and still answers time
//! stamp requests so others can synchronise through it.
//!
//! Run with `cargo test -p osap-core --no-default-features --test minimal`.
#![cfg(not(feature = "sync"))]

use osap_core::clock::TimeReply;
use osap_core::link::queue::QueueLink;
use osap_core::netresponder::{key, Status};
use osap_core::packet::{Instruction, Packet};
use osap_core::port::{Delivery, Port, PortInfo, PortTx};
use osap_core::route::Route;
use osap_core::transport::Transport;
use osap_core::{Instant, Runtime};

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

/// Sends `packet` in on link 0 and returns what the runtime sent back.
fn exchange(packet: &[u8]) -> heapless::Vec<u8, 128> {
    let mut rt: Runtime<8, 128, 2, 1> = Runtime::new("minimal", "m").unwrap();
    let mut links = [QueueLink::<4, 128>::new()];
    let mut ports: [NoPort; 0] = [];
    assert!(links[0].inject(packet));
    rt.poll(Instant::from_micros(1_000), &mut ports, &mut links);
    links[0].take_sent().expect("a reply")
}

fn query(body: &[u8]) -> Status {
    let mut payload = [0u8; 16];
    Transport::Request(7).encode(&mut payload).unwrap();
    payload[3..3 + body.len()].copy_from_slice(body);
    let mut buf = [0u8; 64];
    // Arrives on our link 0 from a neighbour's port 1.
    let route = Route::through_links(&[0]).unwrap();
    let n = route
        .write_packet(
            &mut buf,
            Instruction::PortHandle { src: 1, dst: 0 },
            10_000,
            128,
            &payload[..3 + body.len()],
        )
        .unwrap();
    let reply = exchange(&buf[..n]);
    // [header 5][link_forward(0)][port_handle(0 -> 1)][payload]
    assert_eq!(
        Packet::new_checked(&reply[..]).unwrap().instruction(),
        Ok(Instruction::LinkForward(0))
    );
    assert_eq!(
        Instruction::decode(&reply[6..]),
        Ok(Instruction::PortHandle { src: 0, dst: 1 })
    );
    let payload = &reply[9..];
    assert_eq!(payload[..3], [2, 7, 0], "sequential reply to request 7");
    assert_eq!(payload[3], body[0], "reply echoes the key");
    Status::from_u8(payload[4]).unwrap()
}

#[test]
fn core_queries_work_and_time_controller_keys_are_unknown() {
    assert_eq!(query(&[key::NAME]), Status::Ok);
    assert_eq!(query(&[key::RUNTIME_INFO, 1, 0, 0, 0]), Status::Ok);
    assert_eq!(query(&[key::COUNTERS]), Status::Ok);
    for k in [
        key::GET_TIME_CONFIG,
        key::SET_TIME_CONFIG,
        key::TIME_STATUS,
        key::SET_CLOCK_RATE,
    ] {
        assert_eq!(query(&[k]), Status::UnknownKey, "key {k:#x}");
    }
}

#[test]
fn time_stamp_requests_are_still_answered() {
    let route = Route::through_links(&[0]).unwrap();
    let mut buf = [0u8; 64];
    let n = route
        .write_packet(
            &mut buf,
            Instruction::SystemMsg(0),
            10_000,
            128,
            &123_456u64.to_le_bytes(),
        )
        .unwrap();
    let reply = exchange(&buf[..n]);
    let p = Packet::new_checked(&reply[..]).unwrap();
    assert_eq!(p.instruction(), Ok(Instruction::LinkForward(0)));
    let body = &reply[7..];
    let r = TimeReply::decode(body).unwrap();
    assert_eq!(r.request_time, Instant::from_micros(123_456));
    assert_eq!(r.responder_tier, 255);
}
