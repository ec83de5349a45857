//! Packets per second through one runtime: forwarded link to link, delivered
//! from a link to a port, and answered by the netresponder.
//!
//! Run: `cargo bench -p osap-core --bench forwarding`
//!
//! The goal (issue "forwarding benchmark") is at least 2 million forwarded
//! 32-byte packets per second per core.
//!
//! Every measured iteration injects a batch of packets into link 0's inbox,
//! polls the runtime until it has served them, and drains what came out, so
//! the numbers include the cost of the in-memory link itself. The `bare`
//! variants replace [`QueueLink`] with a gateway that receives a fixed packet
//! and counts what it sends, which leaves almost only the runtime's own cost.
//!
//! Packet layout: a packet arriving on link 0 to leave on link 1 is
//! `[ptr=5][ttl][mtu][link_forward(0)][link_forward(1)][port_handle(1->1)][payload]`:
//! the first hop is the one the sender executed; this runtime's ingest
//! overwrites it with the way back and advances `ptr` to `link_forward(1)`.
//!
//! Clock sync: the runtimes keep the default time configuration, as a module
//! or hub runs it (with the default `sync` feature: synchronisation on,
//! following a neighbour). Such a runtime sends a time stamp request on every
//! open link at its first poll, to discover its neighbours, and then one per
//! interval (50 ms). Time stands still in the benchmarks, so [`settle`] polls
//! each runtime once before anything is measured, checks that exactly those
//! requests came out (one per open link with `sync`, none without) and
//! clears them; after that no request falls due, so every packet counted is
//! one the benchmark sent, while each poll still pays the clock's check of
//! its schedule. `cargo bench -p osap-core --no-default-features --bench
//! forwarding` measures the runtime without the clock controller.

// criterion_main! writes an undocumented `main`.
#![allow(missing_docs)]

use criterion::{black_box, criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use osap_core::clock::CODE_TIME_REQUEST;
use osap_core::link::queue::QueueLink;
use osap_core::link::{LinkGateway, LinkInfo, LinkSendError, Received};
use osap_core::packet::Packet;
use osap_core::port::{Delivery, Port, PortInfo, PortTx};
use osap_core::transport::Transport;
use osap_core::{Instant, Instruction, Route, Runtime, RuntimeConfig};

/// Total packet size on the wire, header included.
const PACKET_LEN: usize = 32;
/// Bytes per packet slot and link MTU.
const MTU: usize = 256;
/// TTL of the injected packets, µs; time stands still in the benchmarks.
const TTL: u16 = 50_000;
/// Largest batch measured, and the depth of the benchmark's link queues.
const MAX_BATCH: usize = 64;
/// The local time of every poll: time stands still in the benchmarks.
const NOW: Instant = Instant::from_micros(1_000);
/// Time stamp requests a fresh runtime sends on each open link at its first
/// poll: one with the clock controller (the default `sync` feature), none
/// without.
const SYNC_REQUESTS: usize = if cfg!(feature = "sync") { 1 } else { 0 };

type Link = QueueLink<MAX_BATCH, MTU>;

/// A port that counts what it receives and drops it.
#[derive(Default)]
struct CountingPort {
    packets: u64,
    bytes: u64,
}

impl Port for CountingPort {
    fn info(&self, _offset: u16) -> PortInfo<'_> {
        PortInfo {
            type_name: "bench_counter",
            name: "",
        }
    }

    fn on_packet(&mut self, delivery: Delivery<'_>, _tx: &mut PortTx<'_>) {
        self.packets += 1;
        self.bytes += delivery.payload.len() as u64;
    }
}

/// A link gateway with next to no cost of its own: every `receive` hands out
/// the same packet (while `budget` lasts) and `send` only counts.
struct BareLink {
    packet: [u8; PACKET_LEN],
    budget: usize,
    sent: u64,
}

impl BareLink {
    fn new(packet: &[u8]) -> Self {
        let mut p = [0u8; PACKET_LEN];
        p.copy_from_slice(packet);
        BareLink {
            packet: p,
            budget: 0,
            sent: 0,
        }
    }
}

impl LinkGateway for BareLink {
    fn info(&self) -> LinkInfo<'_> {
        LinkInfo {
            type_name: "bench_bare",
            name: "",
        }
    }

    fn is_open(&self) -> bool {
        true
    }

    fn mtu(&self) -> u16 {
        MTU as u16
    }

    fn clear_to_send(&self) -> bool {
        true
    }

    fn send(&mut self, packet: &[u8]) -> Result<(), LinkSendError> {
        self.sent += 1;
        black_box(packet);
        Ok(())
    }

    fn receive(&mut self, buf: &mut [u8]) -> Option<Received> {
        if self.budget == 0 {
            return None;
        }
        self.budget -= 1;
        buf.get_mut(..PACKET_LEN)?.copy_from_slice(&self.packet);
        Some(Received {
            len: PACKET_LEN,
            timestamp: None,
        })
    }
}

/// A 32-byte packet that arrives on link 0 and is walked along `hops`
/// (the first of which is consumed by its arrival) to `terminal`.
fn packet_via(hops: &[u8], terminal: Instruction, body: &[u8]) -> Vec<u8> {
    let route = Route::through_links(hops).unwrap();
    let header = route.header_len(terminal);
    let mut payload = body.to_vec();
    payload.resize(PACKET_LEN - header, 0xA5);
    let mut buf = [0u8; MTU];
    let n = route
        .write_packet(&mut buf, terminal, TTL, MTU as u16, &payload)
        .unwrap();
    assert_eq!(n, PACKET_LEN);
    buf[..n].to_vec()
}

/// Link 0 in, link 1 out, to port 1 of the runtime beyond.
fn forward_packet() -> Vec<u8> {
    packet_via(
        &[0, 1],
        Instruction::PortHandle { src: 1, dst: 1 },
        &[0], // raw datagram
    )
}

/// Link 0 in, delivered to this runtime's port 1.
fn deliver_packet() -> Vec<u8> {
    packet_via(&[0], Instruction::PortHandle { src: 1, dst: 1 }, &[0])
}

/// Link 0 in, a runtime-info request to the netresponder (port 0).
fn netresponder_request(seq: u16) -> Vec<u8> {
    let mut body = [0u8; 8];
    let n = Transport::Request(seq).encode(&mut body).unwrap();
    body[n] = 0x01; // runtime info
    body[n + 1..n + 5].copy_from_slice(&0x1234_5678u32.to_le_bytes());
    let route = Route::through_links(&[0]).unwrap();
    let mut buf = [0u8; MTU];
    let len = route
        .write_packet(
            &mut buf,
            Instruction::PortHandle { src: 1, dst: 0 },
            TTL,
            MTU as u16,
            &body[..n + 5],
        )
        .unwrap();
    buf[..len].to_vec()
}

fn large(slots: usize) -> RuntimeConfig {
    RuntimeConfig {
        port_quota: slots as u8,
        link_quota: slots as u8,
        system_quota: 4,
        max_packets_per_poll: 1024,
        ..RuntimeConfig::default()
    }
}

/// Polls until the stack is empty (the runtime may need more than one pass
/// when quotas make packets wait).
fn run<
    const S: usize,
    const M: usize,
    const P: usize,
    const L: usize,
    Po: Port,
    Li: LinkGateway,
>(
    rt: &mut Runtime<S, M, P, L>,
    now: Instant,
    ports: &mut [Po],
    links: &mut [Li],
) {
    loop {
        let r = rt.poll(now, ports, links);
        if r.waiting == 0 && !r.more {
            break;
        }
    }
}

/// Whether `packet`, as it leaves on `link`, is a time stamp request of the
/// runtime's own clock.
fn is_time_request(packet: &[u8], link: u8) -> bool {
    let Ok(p) = Packet::new_checked(packet) else {
        return false;
    };
    p.instruction() == Ok(Instruction::LinkForward(link))
        && p.after_instruction()
            .and_then(Instruction::decode)
            .is_ok_and(|i| i == Instruction::SystemMsg(CODE_TIME_REQUEST))
}

/// Runs a fresh runtime's first poll with nothing to receive, so its clock
/// sends the time stamp requests it sends at start (see the module's
/// header); returns what each link sent. Then checks that, with time
/// standing still at [`NOW`], no further request can fall due while the
/// benchmark runs.
fn first_poll<
    const S: usize,
    const M: usize,
    const P: usize,
    const L: usize,
    Po: Port,
    Li: LinkGateway,
>(
    rt: &mut Runtime<S, M, P, L>,
    ports: &mut [Po],
    links: &mut [Li],
) {
    run(rt, NOW, ports, links);
    if let Some(t) = rt.clock().next_request() {
        assert!(t > NOW, "a time request would fall due while measuring");
    }
}

/// [`first_poll`] on `QueueLink`s: takes the time stamp requests out of
/// every link's outbox and checks there are exactly [`SYNC_REQUESTS`] each.
fn settle<const S: usize, const M: usize, const P: usize, const L: usize, Po: Port>(
    rt: &mut Runtime<S, M, P, L>,
    ports: &mut [Po],
    links: &mut [Link],
) {
    first_poll(rt, ports, links);
    for (i, link) in links.iter_mut().enumerate() {
        let mut requests = 0;
        while let Some(p) = link.take_sent() {
            assert!(
                is_time_request(&p, i as u8),
                "link {i}: a packet other than a time request at start: {p:?}"
            );
            requests += 1;
        }
        assert_eq!(requests, SYNC_REQUESTS, "link {i}: time requests at start");
    }
}

type Group<'a> = criterion::BenchmarkGroup<'a, criterion::measurement::WallTime>;

/// Runs `step` (which handles one batch and returns how many packets came
/// out) once to check that the whole batch really went through, then
/// measures it.
fn measure(g: &mut Group<'_>, label: &str, batch: usize, mut step: impl FnMut() -> usize) {
    assert_eq!(step(), batch, "{label}: a batch did not come through whole");
    g.throughput(Throughput::Elements(batch as u64));
    g.bench_function(BenchmarkId::new(label, batch), |b| {
        b.iter(|| black_box(step()))
    });
}

/// Forwarding through `QueueLink`s: inject `batch`, poll, drain link 1.
fn forward_queue<const S: usize>(
    g: &mut Group<'_>,
    label: &str,
    config: RuntimeConfig,
    batch: usize,
) {
    let mut rt = Runtime::<S, MTU, 8, 4>::new("bench", "fwd")
        .unwrap()
        .with_config(config);
    let mut links = [Link::new(), Link::new()];
    let mut ports: [CountingPort; 0] = [];
    let packet = forward_packet();
    settle(&mut rt, &mut ports, &mut links);
    // What leaves on link 1: the same packet with the first hop rewritten to
    // the way back (link_forward(0)) and ptr moved on to link_forward(1).
    links[0].inject(&packet);
    run(&mut rt, NOW, &mut ports, &mut links);
    let out = links[1].take_sent().expect("the packet was forwarded");
    let mut expected = packet.clone();
    expected[0] = 6;
    assert_eq!(out.as_slice(), expected.as_slice());
    assert_eq!(links[1].take_sent(), None, "one packet in, one out");
    assert_eq!(links[0].take_sent(), None, "nothing goes back on link 0");
    measure(g, label, batch, || {
        for _ in 0..batch {
            links[0].inject(&packet);
        }
        // Ingest takes at most `link_quota` packets per poll; keep polling
        // until the inbox is drained.
        while links[0].inbox_len() > 0 {
            run(&mut rt, NOW, &mut ports, &mut links);
        }
        let mut n = 0;
        while let Some(p) = links[1].take_sent() {
            black_box(&p);
            n += 1;
        }
        n
    });
}

/// Forwarding through bare links: the runtime's own cost.
fn forward_bare<const S: usize>(
    g: &mut Group<'_>,
    label: &str,
    config: RuntimeConfig,
    batch: usize,
) {
    let mut rt = Runtime::<S, MTU, 8, 4>::new("bench", "fwd")
        .unwrap()
        .with_config(config);
    let packet = forward_packet();
    let mut links = [BareLink::new(&packet), BareLink::new(&packet)];
    let mut ports: [CountingPort; 0] = [];
    // A bare link only counts what it sends: the first poll's sends are the
    // clock's requests.
    first_poll(&mut rt, &mut ports, &mut links);
    for (i, link) in links.iter().enumerate() {
        assert_eq!(link.sent, SYNC_REQUESTS as u64, "link {i}: time requests");
    }
    measure(g, label, batch, || {
        let before = links[1].sent;
        links[0].budget = batch;
        while links[0].budget > 0 {
            run(&mut rt, NOW, &mut ports, &mut links);
        }
        (links[1].sent - before) as usize
    });
}

fn forwarding(c: &mut Criterion) {
    let mut g = c.benchmark_group("forward_32B");
    // Default quotas: a link may hold 4 slots, so one poll forwards 4.
    forward_queue::<16>(&mut g, "queue_default_quota", RuntimeConfig::default(), 4);
    forward_queue::<64>(&mut g, "queue_large_batch", large(64), MAX_BATCH);
    forward_bare::<16>(&mut g, "bare_default_quota", RuntimeConfig::default(), 4);
    forward_bare::<64>(&mut g, "bare_large_batch", large(64), MAX_BATCH);
    g.finish();
}

/// The two configurations measured: default quotas with a batch of one
/// link quota, and quotas raised to the 64 slots with a large batch.
fn configs(large_batch: usize) -> [(&'static str, RuntimeConfig, usize); 2] {
    [
        ("queue_default_quota", RuntimeConfig::default(), 4),
        ("queue_large_batch", large(64), large_batch),
    ]
}

fn delivery(c: &mut Criterion) {
    let mut g = c.benchmark_group("deliver_32B");
    for (label, config, batch) in configs(MAX_BATCH) {
        let mut rt = Runtime::<64, MTU, 8, 4>::new("bench", "dlv")
            .unwrap()
            .with_config(config);
        let mut links = [Link::new()];
        let mut ports = [CountingPort::default()];
        let packet = deliver_packet();
        settle(&mut rt, &mut ports, &mut links);
        measure(&mut g, label, batch, || {
            let before = ports[0].packets;
            for _ in 0..batch {
                links[0].inject(&packet);
            }
            while links[0].inbox_len() > 0 {
                run(&mut rt, NOW, &mut ports, &mut links);
            }
            (ports[0].packets - before) as usize
        });
        assert!(ports[0].bytes > 0);
    }
    g.finish();
}

fn netresponder(c: &mut Criterion) {
    let mut g = c.benchmark_group("netresponder_runtime_info");
    for (label, config, batch) in configs(32) {
        let mut rt = Runtime::<64, MTU, 8, 4>::new("bench", "nr")
            .unwrap()
            .with_config(config);
        let mut links = [Link::new()];
        let mut ports: [CountingPort; 0] = [];
        let request = netresponder_request(7);
        settle(&mut rt, &mut ports, &mut links);
        measure(&mut g, label, batch, || {
            for _ in 0..batch {
                links[0].inject(&request);
            }
            let mut replies = 0;
            // Port 0 may hold only `port_quota` replies at once, so requests
            // beyond that wait for the next poll.
            for _ in 0..4 * batch {
                run(&mut rt, NOW, &mut ports, &mut links);
                while let Some(p) = links[0].take_sent() {
                    black_box(&p);
                    replies += 1;
                }
                if replies >= batch {
                    break;
                }
            }
            replies
        });
        // Every request was answered with a well-formed reply.
        assert_eq!(rt.counters().netresponder_errors, 0);
    }
    g.finish();
}

criterion_group!(benches, forwarding, delivery, netresponder);
criterion_main!(benches);
