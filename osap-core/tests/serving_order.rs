//! Serving order through a runtime: the packets of one link (or port) go on
//! in the order they came, whatever deadlines they were given on arrival;
//! each still expires by its own deadline and carries its own TTL on; and a
//! link or port that clears in the middle of a walk takes no packet ahead
//! of one that was waiting for it.

use core::cell::Cell;
use osap_core::link::queue::QueueLink;
use osap_core::link::{LinkGateway, LinkInfo, LinkSendError, Received};
use osap_core::packet::{Instruction, Packet};
use osap_core::port::{Delivery, Port, PortInfo, PortTx};
use osap_core::route::Route;
use osap_core::time::Instant;
use osap_core::Runtime;

type Rt = Runtime<8, 128, 4, 2>;

fn runtime() -> Rt {
    let rt = Rt::new("order", "o").unwrap();
    // No clock requests of its own: every packet out is one of these.
    #[cfg(feature = "sync")]
    let rt = rt
        .with_time_config(osap_core::clock::TimeConfig {
            enabled: false,
            ..Default::default()
        })
        .unwrap();
    rt
}

/// A queue link whose other half is busy for its first `busy` checks, then
/// drains at once: a host link whose I/O task runs on another thread and
/// empties its queue while the runtime walks its stack.
struct Gate {
    queue: QueueLink<8, 128>,
    busy: Cell<u32>,
}

impl Gate {
    fn new(busy: u32) -> Gate {
        Gate {
            queue: QueueLink::new(),
            busy: Cell::new(busy),
        }
    }
}

impl LinkGateway for Gate {
    fn info(&self) -> LinkInfo<'_> {
        self.queue.info()
    }
    fn is_open(&self) -> bool {
        self.queue.is_open()
    }
    fn mtu(&self) -> u16 {
        self.queue.mtu()
    }
    fn clear_to_send(&self) -> bool {
        match self.busy.get() {
            0 => self.queue.clear_to_send(),
            n => {
                self.busy.set(n - 1);
                false
            }
        }
    }
    fn send(&mut self, packet: &[u8]) -> Result<(), LinkSendError> {
        self.queue.send(packet)
    }
    fn receive(&mut self, buf: &mut [u8]) -> Option<Received> {
        self.queue.receive(buf)
    }
}

/// A packet that came in on link 0, bound on over link 1 (`Some(1)`) or
/// for this runtime's port 1 (`None`), living `ttl` µs, carrying `tag`.
fn packet(out: Option<u8>, ttl: u16, tag: u8) -> Vec<u8> {
    let (hops, dst): (&[u8], u16) = match out {
        Some(l) => (&[0, l], 0),
        None => (&[0], 1),
    };
    let route = Route::through_links(hops).unwrap();
    let mut buf = [0u8; 128];
    let n = route
        .write_packet(
            &mut buf,
            Instruction::PortHandle { src: 1, dst },
            ttl,
            128,
            &[0, tag],
        )
        .unwrap();
    buf[..n].to_vec()
}

/// What left on `link`: (tag, TTL written on the way out), in order.
fn sent(link: &mut Gate) -> Vec<(u8, u16)> {
    let mut out = Vec::new();
    while let Some(p) = link.queue.take_sent() {
        let ttl = Packet::new_checked(&p[..]).unwrap().ttl();
        out.push((*p.last().unwrap(), ttl));
    }
    out
}

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

fn at(us: u64) -> Instant {
    Instant::from_micros(us)
}

#[test]
fn a_burst_with_falling_deadlines_goes_on_in_arrival_order() {
    let mut rt = runtime();
    let mut links = [Gate::new(0), Gate::new(0)];
    // Read in one go at t = 1 ms: deadlines 41, 31, 21 and 11 ms, each
    // earlier than the one before.
    for (tag, ttl) in [(0, 40_000), (1, 30_000), (2, 20_000), (3, 10_000)] {
        assert!(links[0].queue.inject(&packet(Some(1), ttl, tag)));
    }
    rt.poll(at(1_000), &mut [NoPort; 0], &mut links);
    // In the order they came, each with what is left of its own TTL (no
    // time passed, no wire time).
    assert_eq!(
        sent(&mut links[1]),
        [(0, 40_000), (1, 30_000), (2, 20_000), (3, 10_000)]
    );
}

#[test]
fn each_packet_expires_by_its_own_deadline_and_wakes_the_runtime_for_it() {
    let mut rt = runtime();
    // Link 1 busy for the first walk.
    let mut links = [Gate::new(0), Gate::new(1)];
    assert!(links[0].queue.inject(&packet(Some(1), 40_000, 0)));
    assert!(links[0].queue.inject(&packet(Some(1), 10_000, 1)));
    let r = rt.poll(at(0), &mut [NoPort; 0], &mut links);
    assert_eq!(r.waiting, 2);
    // The second is served after the first but expires first: the runtime
    // must look again by its deadline.
    assert_eq!(r.wake_at, Some(at(10_000)));
    assert!(sent(&mut links[1]).is_empty());
    // At 20 ms the second has expired (dropped, counted); the first goes
    // on with the 20 ms left of its own 40.
    let expired = rt.counters().expired;
    let r = rt.poll(at(20_000), &mut [NoPort; 0], &mut links);
    assert_eq!(r.dropped, 1);
    assert_eq!(rt.counters().expired, expired + 1);
    assert_eq!(sent(&mut links[1]), [(0, 20_000)]);
    assert_eq!(r.waiting, 0);
}

#[test]
fn a_link_that_clears_mid_walk_takes_nothing_ahead_of_a_waiting_packet() {
    let mut rt = runtime();
    // Link 1 refuses its first check only: as if its I/O task drained its
    // queue just after the runtime asked for the first packet.
    let mut links = [Gate::new(0), Gate::new(1)];
    assert!(links[0].queue.inject(&packet(Some(1), 40_000, 0)));
    assert!(links[0].queue.inject(&packet(Some(1), 40_000, 1)));
    rt.poll(at(0), &mut [NoPort; 0], &mut links);
    // The second did not slip past the first: nothing went this walk.
    assert!(sent(&mut links[1]).is_empty());
    rt.poll(at(100), &mut [NoPort; 0], &mut links);
    assert_eq!(sent(&mut links[1]), [(0, 39_900), (1, 39_900)]);
}

/// A port that is full for its first `busy` checks, recording what it
/// takes.
struct Inbox {
    busy: Cell<u32>,
    got: Vec<u8>,
}

impl Port for Inbox {
    fn info(&self, _: u16) -> PortInfo<'_> {
        PortInfo {
            type_name: "inbox",
            name: "",
        }
    }
    fn clear_to_receive(&self, _: u16) -> bool {
        match self.busy.get() {
            0 => true,
            n => {
                self.busy.set(n - 1);
                false
            }
        }
    }
    fn on_packet(&mut self, d: Delivery<'_>, _: &mut PortTx<'_>) {
        self.got.push(*d.payload.last().unwrap());
    }
}

#[test]
fn a_port_takes_one_links_packets_in_arrival_order() {
    let mut rt = runtime();
    let mut links = [Gate::new(0), Gate::new(0)];
    let mut ports = [Inbox {
        busy: Cell::new(1),
        got: Vec::new(),
    }];
    for (tag, ttl) in [(0, 30_000), (1, 20_000), (2, 10_000)] {
        assert!(links[0].queue.inject(&packet(None, ttl, tag)));
    }
    // The port clears right after refusing the first: the others wait.
    rt.poll(at(0), &mut ports, &mut links);
    assert!(ports[0].got.is_empty());
    rt.poll(at(100), &mut ports, &mut links);
    assert_eq!(ports[0].got, [0, 1, 2]);
    // A burst into a clear port, likewise.
    for (tag, ttl) in [(3, 30_000), (4, 20_000), (5, 10_000)] {
        assert!(links[0].queue.inject(&packet(None, ttl, tag)));
    }
    rt.poll(at(200), &mut ports, &mut links);
    assert_eq!(ports[0].got, [0, 1, 2, 3, 4, 5]);
}
