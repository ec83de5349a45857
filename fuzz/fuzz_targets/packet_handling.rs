//! Feeds arbitrary packets to a runtime from two links and checks that it
//! never panics, never holds more than its slots, and empties its stack
//! once every deadline has passed.
//!
//! Input: a sequence of records `[flags][len][bytes...]`. Flag bit 0 picks
//! the link; bit 1 wraps the bytes as the body of a well-formed netresponder
//! request (so the fuzzer reaches the query parsers quickly); bit 2 wraps
//! them as a packet to the echo port; the high bits advance the clock.
#![no_main]

use libfuzzer_sys::fuzz_target;
use osap_core::link::queue::QueueLink;
use osap_core::packet::Instruction;
use osap_core::port::{Delivery, Port, PortInfo, PortTx};
use osap_core::route::Route;
use osap_core::Runtime;

struct Echo;

impl Port for Echo {
    fn info(&self, _: u16) -> PortInfo<'_> {
        PortInfo {
            type_name: "echo",
            name: "",
        }
    }
    fn on_packet(&mut self, d: Delivery<'_>, tx: &mut PortTx<'_>) {
        let _ = tx.send(&d.reply_route, d.source_port, 1_000, d.payload);
    }
}

fn wrap(dst: u16, transport: &[u8], body: &[u8], out: &mut [u8; 128]) -> Option<usize> {
    let mut payload = [0u8; 128];
    let n = transport.len() + body.len();
    payload.get_mut(..transport.len())?.copy_from_slice(transport);
    payload.get_mut(transport.len()..n)?.copy_from_slice(body);
    let route = Route::through_links(&[0]).ok()?;
    route
        .write_packet(out, Instruction::PortHandle { src: 1, dst }, 5_000, 128, &payload[..n])
        .ok()
}

fuzz_target!(|data: &[u8]| {
    let mut rt: Runtime<8, 128, 4, 2> = match Runtime::new("fuzz", "rt") {
        Ok(rt) => rt,
        Err(_) => return,
    };
    let mut links = [QueueLink::<16, 128>::new(), QueueLink::<16, 128>::new()];
    let mut ports = [Echo];
    let mut now = osap_core::Instant::ZERO;
    let mut injected = 0u32;
    let mut rest = data;
    while let [flags, len, tail @ ..] = rest {
        let len = (*len as usize).min(tail.len());
        let (bytes, next) = tail.split_at(len);
        rest = next;
        let mut buf = [0u8; 128];
        let packet: &[u8] = if flags & 2 != 0 {
            match wrap(0, &[1, 0, 0], bytes, &mut buf) {
                Some(n) => &buf[..n],
                None => continue,
            }
        } else if flags & 4 != 0 {
            match wrap(1, &[0], bytes, &mut buf) {
                Some(n) => &buf[..n],
                None => continue,
            }
        } else {
            bytes
        };
        if links[usize::from(flags & 1)].inject(packet) {
            injected += 1;
        }
        now += osap_core::Duration::from_micros(u64::from(flags >> 3) * 50);
        rt.poll(now, &mut ports, &mut links);
        assert!(rt.stack().len() <= rt.stack().capacity());
        for link in &mut links {
            while link.take_sent().is_some() {}
        }
    }
    // Everything still queued expires; every injected packet was taken in
    // (a link's inbox drains at its quota per poll, so allow enough polls).
    for _ in 0..10 {
        now += osap_core::Duration::from_millis(70);
        rt.poll(now, &mut ports, &mut links);
        for link in &mut links {
            while link.take_sent().is_some() {}
        }
    }
    assert_eq!(rt.stack().len(), 0);
    assert_eq!(rt.counters().received, injected);
});
