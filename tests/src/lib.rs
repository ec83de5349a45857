//! Shared helpers for the cross-crate tests: an in-memory network of
//! runtimes joined by queue links, driven by a fake clock.

use osap_core::link::queue::{transfer, QueueLink};
use osap_core::port::{Delivery, Port, PortInfo, PortTx};
use osap_core::route::Route;
use osap_core::transport::Transport;
use osap_core::{Instant, Runtime, SystemInstant};
use std::collections::VecDeque;

/// The runtime used in tests: 16 slots of 256 bytes, 8 ports, 4 links.
pub type TestRuntime = Runtime<16, 256, 8, 4>;
/// The link used in tests.
pub type TestLink = QueueLink<8, 256>;

/// A packet a [`TestPort`] received.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Received {
    /// Payload, transport key included.
    pub payload: Vec<u8>,
    /// Route back to the sender.
    pub reply_route: Route,
    /// Port it came from.
    pub source_port: u16,
    /// When it arrived (the receiving runtime's local time).
    pub arrival: Instant,
}

/// A port that records what it receives, can echo it back, and sends what is
/// queued on it when the runtime polls it.
#[derive(Debug, Default)]
pub struct TestPort {
    /// Everything received, oldest first.
    pub received: Vec<Received>,
    /// Reply to every packet with the same payload.
    pub echo: bool,
    /// Refuse packets (not clear to receive).
    pub busy: bool,
    /// Sends waiting for the next poll: route, destination port, TTL, payload.
    pub outbox: VecDeque<(Route, u16, u16, Vec<u8>)>,
    /// Sends that failed.
    pub send_errors: usize,
}

impl TestPort {
    /// A port that echoes what it receives.
    pub fn echo() -> Self {
        TestPort {
            echo: true,
            ..Default::default()
        }
    }

    /// Queues a send for the next poll.
    pub fn queue(&mut self, route: Route, dst: u16, ttl: u16, payload: &[u8]) {
        self.outbox.push_back((route, dst, ttl, payload.to_vec()));
    }
}

impl Port for TestPort {
    fn info(&self, _offset: u16) -> PortInfo<'_> {
        PortInfo {
            type_name: "test",
            name: if self.echo { "echo" } else { "" },
        }
    }

    fn clear_to_receive(&self, _offset: u16) -> bool {
        !self.busy
    }

    fn on_packet(&mut self, d: Delivery<'_>, tx: &mut PortTx<'_>) {
        if self.echo
            && tx
                .send(&d.reply_route, d.source_port, 10_000, d.payload)
                .is_err()
        {
            self.send_errors += 1;
        }
        self.received.push(Received {
            payload: d.payload.to_vec(),
            reply_route: d.reply_route,
            source_port: d.source_port,
            arrival: d.arrival,
        });
    }

    fn poll(&mut self, tx: &mut PortTx<'_>) {
        while tx.clear_to_send() {
            let Some((route, dst, ttl, payload)) = self.outbox.pop_front() else {
                break;
            };
            if tx.send(&route, dst, ttl, &payload).is_err() {
                self.send_errors += 1;
            }
        }
    }
}

/// One runtime with its links and ports.
pub struct Node {
    /// The runtime.
    pub runtime: TestRuntime,
    /// This node's local clock: µs ahead of the network's fake clock ...
    pub clock_offset: u64,
    /// ... and running this many ppm fast.
    pub clock_ppm: f64,
    /// Its link gateways, by index.
    pub links: Vec<TestLink>,
    /// Its ports; `ports[k]` is runtime port `k + 1`.
    pub ports: Vec<TestPort>,
}

impl std::fmt::Debug for Node {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Its parts are tasks, locks and buffers: the name says enough.
        f.debug_struct("Node").finish_non_exhaustive()
    }
}

impl Node {
    /// This node's local clock at network time `now` (µs of the fake
    /// clock that drives the whole network).
    pub fn local_time(&self, now: u64) -> Instant {
        Instant::from_micros(self.clock_offset + now + (now as f64 * self.clock_ppm * 1e-6) as u64)
    }

    /// This node's synchronised system time at network time `now`.
    pub fn system_time(&self, now: u64) -> SystemInstant {
        self.runtime.system_time(self.local_time(now))
    }
}

/// A wire between link `a.1` of node `a.0` and link `b.1` of node `b.0`.
#[derive(Debug, Clone, Copy)]
pub struct Wire {
    /// One end: node, link.
    pub a: (usize, usize),
    /// Other end: node, link.
    pub b: (usize, usize),
    /// Packets per step the wire moves in each direction.
    pub rate: usize,
    /// A stalled wire moves nothing (a peer that stopped reading).
    pub stalled: bool,
}

/// An in-memory network driven by a fake clock.
#[derive(Default)]
pub struct Net {
    /// The nodes.
    pub nodes: Vec<Node>,
    /// The wires.
    pub wires: Vec<Wire>,
    /// Current time of the fake clock, µs: the reference every node's
    /// local clock is derived from.
    pub now: u64,
}

impl std::fmt::Debug for Net {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Its parts are tasks, locks and buffers: the name says enough.
        f.debug_struct("Net").finish_non_exhaustive()
    }
}

impl Net {
    /// An empty network at time 0.
    pub fn new() -> Self {
        Net::default()
    }

    /// Adds a runtime with `links` link gateways and `ports` test ports.
    /// Clock sync is off, so tests that count packets see only their own;
    /// tests of sync turn it on with [`Net::sync`].
    pub fn node(&mut self, name: &str, links: usize, ports: usize) -> usize {
        let quiet = osap_core::clock::TimeConfig {
            enabled: false,
            ..Default::default()
        };
        let mut runtime = TestRuntime::new("test_node", name).expect("short name");
        runtime.clock_mut().set_config(quiet).expect("valid config");
        self.nodes.push(Node {
            runtime,
            clock_offset: 0,
            clock_ppm: 0.0,
            links: (0..links).map(|_| TestLink::new()).collect(),
            ports: (0..ports).map(|_| TestPort::default()).collect(),
        });
        self.nodes.len() - 1
    }

    /// Turns clock sync on for `node`, as the root or as a follower.
    pub fn sync(&mut self, node: usize, root: bool) {
        let cfg = osap_core::clock::TimeConfig {
            root,
            ..Default::default()
        };
        self.nodes[node]
            .runtime
            .clock_mut()
            .set_config(cfg)
            .expect("valid config");
    }

    /// Joins link `la` of node `a` to link `lb` of node `b`; returns the wire index.
    pub fn wire(&mut self, a: usize, la: usize, b: usize, lb: usize) -> usize {
        self.wires.push(Wire {
            a: (a, la),
            b: (b, lb),
            rate: usize::MAX,
            stalled: false,
        });
        self.wires.len() - 1
    }

    /// Polls every node once at the current time, then lets every wire
    /// carry packets, then advances the clock by `dt`.
    pub fn step(&mut self, dt: u64) {
        for node in &mut self.nodes {
            let local = node.local_time(self.now);
            node.runtime.poll(local, &mut node.ports, &mut node.links);
        }
        for w in self.wires.clone() {
            if w.stalled {
                continue;
            }
            self.carry(w.a, w.b, w.rate);
            self.carry(w.b, w.a, w.rate);
        }
        self.now += dt;
    }

    fn carry(&mut self, from: (usize, usize), to: (usize, usize), rate: usize) {
        if from.0 == to.0 {
            let links = &mut self.nodes[from.0].links;
            let (lo, hi) = (from.1.min(to.1), from.1.max(to.1));
            let (left, right) = links.split_at_mut(hi);
            let (a, b) = (&mut left[lo], &mut right[0]);
            if from.1 < to.1 {
                transfer(a, b, rate);
            } else {
                transfer(b, a, rate);
            }
            return;
        }
        let (src, dst) = two_mut(&mut self.nodes, from.0, to.0);
        transfer(&mut src.links[from.1], &mut dst.links[to.1], rate);
    }

    /// Steps until `done` holds or `max_steps` pass; returns the steps taken.
    pub fn run_until(
        &mut self,
        dt: u64,
        max_steps: usize,
        mut done: impl FnMut(&Net) -> bool,
    ) -> Option<usize> {
        for i in 0..max_steps {
            if done(self) {
                return Some(i);
            }
            self.step(dt);
        }
        done(self).then_some(max_steps)
    }

    /// Port `port` (1-based runtime index) of node `node`.
    pub fn port(&mut self, node: usize, port: u16) -> &mut TestPort {
        &mut self.nodes[node].ports[usize::from(port) - 1]
    }
}

fn two_mut<T>(v: &mut [T], a: usize, b: usize) -> (&mut T, &mut T) {
    assert_ne!(a, b);
    if a < b {
        let (l, r) = v.split_at_mut(b);
        (&mut l[a], &mut r[0])
    } else {
        let (l, r) = v.split_at_mut(a);
        (&mut r[0], &mut l[b])
    }
}

/// A raw-transport payload: key 0, then `body`.
pub fn raw(body: &[u8]) -> Vec<u8> {
    let mut p = vec![0u8];
    p.extend_from_slice(body);
    p
}

/// A sequential request payload to the netresponder.
pub fn request(seq: u16, body: &[u8]) -> Vec<u8> {
    let mut p = vec![0u8; 3];
    Transport::Request(seq).encode(&mut p).unwrap();
    p.extend_from_slice(body);
    p
}
