//! Builds a small OSAP network in memory, routes packets across it and
//! prints what happened.
//!
//! ```text
//!  host[0] ── [0]hub[1] ── [0]x-axis
//!                 [2] ── [0]y-axis[1] ── [0]z-axis
//! ```
//!
//! The host asks every runtime's netresponder (port 0) who it is, pings an
//! echo port on the z axis three hops away, and then sends a packet with too
//! little time to live to a busy port, which the network drops and counts.

use osap_core::link::queue::{transfer, QueueLink};
use osap_core::netresponder::{key, BuildKey};
use osap_core::port::{Delivery, Port, PortInfo, PortTx};
use osap_core::route::Route;
use osap_core::transport::Transport;
use osap_core::{Duration, Instant, Runtime};

type Rt = Runtime<16, 256, 8, 4>;
type Link = QueueLink<8, 256>;

/// The host's port: sends what it is told to and keeps what comes back.
#[derive(Default)]
struct Console {
    outbox: Vec<(Route, u16, u16, Vec<u8>)>,
    inbox: Vec<(Route, u16, Vec<u8>)>,
}

impl Port for Console {
    fn info(&self, _: u16) -> PortInfo<'_> {
        PortInfo {
            type_name: "console",
            name: "",
        }
    }
    fn on_packet(&mut self, d: Delivery<'_>, _: &mut PortTx<'_>) {
        self.inbox
            .push((d.reply_route, d.source_port, d.payload.to_vec()));
    }
    fn poll(&mut self, tx: &mut PortTx<'_>) {
        while tx.clear_to_send() && !self.outbox.is_empty() {
            let (route, dst, ttl, payload) = self.outbox.remove(0);
            if let Err(e) = tx.send(&route, dst, ttl, &payload) {
                println!("  console: send failed: {e}");
            }
        }
    }
}

/// A module's port that answers every packet with the same payload, unless
/// it is busy.
struct Echo {
    busy: bool,
}

impl Port for Echo {
    fn info(&self, _: u16) -> PortInfo<'_> {
        PortInfo {
            type_name: "echo",
            name: "",
        }
    }
    fn clear_to_receive(&self, _: u16) -> bool {
        !self.busy
    }
    fn on_packet(&mut self, d: Delivery<'_>, tx: &mut PortTx<'_>) {
        let _ = tx.send(&d.reply_route, d.source_port, 10_000, d.payload);
    }
}

struct Module {
    rt: Rt,
    links: Vec<Link>,
    ports: Vec<Echo>,
}

struct Demo {
    host: Rt,
    host_link: [Link; 1],
    console: [Console; 1],
    modules: Vec<Module>, // hub, x, y, z
    now: Instant,
}

impl Demo {
    fn new() -> Self {
        let module = |type_name: &str, name: &str, links: usize| Module {
            rt: Rt::new(type_name, name)
                .expect("short names")
                .with_version([0, 1, 0], BuildKey::RustSimulated),
            links: (0..links).map(|_| Link::new()).collect(),
            ports: vec![Echo { busy: false }],
        };
        Demo {
            host: Rt::new("host", "demo-host").expect("short names"),
            host_link: [Link::new()],
            console: [Console::default()],
            modules: vec![
                module("hub", "hub", 3),
                module("stepper", "x-axis", 1),
                module("stepper", "y-axis", 2),
                module("stepper", "z-axis", 1),
            ],
            now: Instant::ZERO,
        }
    }

    /// One tick of every runtime, then the wires carry what was sent.
    fn step(&mut self) {
        self.host
            .poll(self.now, &mut self.console, &mut self.host_link);
        for m in &mut self.modules {
            m.rt.poll(self.now, &mut m.ports, &mut m.links);
        }
        let [hub, x, y, z] = &mut self.modules[..] else {
            unreachable!("four modules")
        };
        let [hub0, hub1, hub2] = &mut hub.links[..] else {
            unreachable!("hub has three links")
        };
        let [y0, y1] = &mut y.links[..] else {
            unreachable!("y-axis has two links")
        };
        for (a, b) in [
            (&mut self.host_link[0], hub0),
            (hub1, &mut x.links[0]),
            (hub2, y0),
            (y1, &mut z.links[0]),
        ] {
            transfer(a, b, usize::MAX);
            transfer(b, a, usize::MAX);
        }
        self.now += Duration::from_micros(100);
    }

    /// Sends one packet from the console and steps until a reply arrives.
    fn exchange(
        &mut self,
        route: Route,
        port: u16,
        payload: Vec<u8>,
    ) -> Option<(Route, u16, Vec<u8>)> {
        self.console[0].outbox.push((route, port, 10_000, payload));
        for _ in 0..50 {
            self.step();
            if !self.console[0].inbox.is_empty() {
                return Some(self.console[0].inbox.remove(0));
            }
        }
        None
    }
}

fn main() {
    osap_examples::init_logging();
    let mut demo = Demo::new();
    let routes = [
        ("hub", vec![0]),
        ("x-axis", vec![0, 1]),
        ("y-axis", vec![0, 2]),
        ("z-axis", vec![0, 2, 1]),
    ];

    println!("Asking each runtime's netresponder who it is:");
    for (seq, (label, links)) in routes.iter().enumerate() {
        let route = Route::through_links(links).expect("short route");
        let mut payload = vec![0u8; 3];
        Transport::Request(seq as u16).encode(&mut payload);
        payload.push(key::NAME);
        match demo.exchange(route, 0, payload) {
            Some((_, _, reply)) => {
                // [transport 3][key][status][str8 name]
                let name = std::str::from_utf8(&reply[6..]).unwrap_or("?");
                println!("  {:<12} -> {label}: name \"{name}\"", route.to_string());
            }
            None => println!("  {route}: no answer"),
        }
    }

    println!("\nPinging the echo port (port 1) on z-axis, three hops away:");
    let to_z = Route::through_links(&[0, 2, 1]).expect("short route");
    let sent_at = demo.now;
    match demo.exchange(to_z, 1, b"\x00ping".to_vec()) {
        Some((back, port, payload)) => println!(
            "  reply {:?} from port {port} after {} µs; the way back to it is {back}",
            String::from_utf8_lossy(&payload[1..]),
            demo.now - sent_at
        ),
        None => println!("  no reply"),
    }

    println!("\nSending a packet with 300 µs to live to a busy port on x-axis:");
    demo.modules[1].ports[0].busy = true;
    let to_x = Route::through_links(&[0, 1]).expect("short route");
    demo.console[0]
        .outbox
        .push((to_x, 1, 300, b"\x00too late".to_vec()));
    for _ in 0..10 {
        demo.step();
    }
    demo.modules[1].ports[0].busy = false;
    for _ in 0..5 {
        demo.step();
    }
    println!(
        "  delivered: {}, expired on x-axis: {}",
        !demo.console[0].inbox.is_empty(),
        demo.modules[1].rt.counters().expired
    );

    println!("\nCounters after {} µs of simulated time:", demo.now);
    println!(
        "  {:<10} {:>8} {:>9} {:>9} {:>8} {:>7}",
        "runtime", "received", "forwarded", "delivered", "expired", "dropped"
    );
    let host_row = (demo.host.identity().name.as_str(), *demo.host.counters());
    let rows = std::iter::once(host_row).chain(
        demo.modules
            .iter()
            .map(|m| (m.rt.identity().name.as_str(), *m.rt.counters())),
    );
    for (name, c) in rows {
        println!(
            "  {:<10} {:>8} {:>9} {:>9} {:>8} {:>7}",
            name,
            c.received,
            c.forwarded,
            c.delivered,
            c.expired,
            c.dropped()
        );
    }
}
