//! The discrete-event simulator.
//!
//! True time is a `u64` of nanoseconds. Events are kept in a priority queue
//! ordered by time and then by the order they were scheduled, so a run is a
//! pure function of the topology and the seed. There are two kinds:
//!
//! - **poll**: a node's main loop polls its runtime at the node's local time.
//!   Polls follow a frame becoming visible, a full transmit buffer freeing a
//!   place while packets wait, and the `wake_at` the last poll returned, each
//!   after the node's main-loop latency. A node has at most one pending
//!   poll: each poll recomputes everything it waits for. A busy node's poll
//!   is put off to the end of its busy spell.
//! - **arrive**: a frame a node sent reaches the far end's gateway (when its
//!   last byte is in, or on a USB host when software sees it). The gateway is
//!   handed the bytes and the stamp of their first byte on its own clock.
//!
//! Metrics are sampled between events at a fixed period of true time.

use crate::busy::BusyState;
use crate::error::SimError;
use crate::hot_start;
use crate::link::SimLink;
use crate::medium::{Side, StampMode, Transit};
use crate::metrics::{Metrics, Parent};
use crate::network::{Gateway, Network};
use crate::node::{Node, NodeKind, NodeSpec, SimRuntime};
use crate::rng::Rng;
use crate::Nanos;
use osap_core::clock::TimeConfig;
use osap_core::netresponder::BuildKey;
use osap_core::Instant;
use std::cmp::Ordering;
use std::collections::{BinaryHeap, VecDeque};

/// Version reported by simulated runtimes.
const VERSION: [u8; 3] = [0, 1, 0];

/// Settings of one simulation run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimConfig {
    /// Seed of every random draw.
    pub seed: u64,
    /// Metrics sampling period, µs of true time (0: no sampling).
    pub sample_period_us: u64,
    /// Keep a [`FrameRecord`] of every frame (for tests; costs memory).
    pub trace_frames: bool,
    /// Nodes first poll at a random time in `[0, boot_window_us)`, so they
    /// do not all start in step.
    pub boot_window_us: f64,
}

impl Default for SimConfig {
    fn default() -> Self {
        SimConfig {
            seed: 1,
            sample_period_us: 10_000,
            trace_frames: false,
            boot_window_us: 1_000.0,
        }
    }
}

impl SimConfig {
    /// The default configuration with seed `seed`.
    pub fn seeded(seed: u64) -> Self {
        SimConfig {
            seed,
            ..SimConfig::default()
        }
    }
}

/// A link of the simulation: which gateway of which node each end is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LinkEnds {
    /// Type name of the link.
    pub type_name: &'static str,
    /// `[A, B]`: (node index, link index at that node).
    pub ends: [(usize, usize); 2],
}

/// One frame's journey, kept when [`SimConfig::trace_frames`] is set.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameRecord {
    /// The link's index in the simulation.
    pub link: usize,
    /// Sending node.
    pub from: usize,
    /// Receiving node.
    pub to: usize,
    /// Timing, bytes and fate.
    pub transit: Transit,
    /// The stamp the receiving gateway gave the frame (its local µs), if
    /// delivered and stamped.
    pub rx_stamp: Option<Instant>,
}

enum Event {
    Poll {
        node: usize,
        generation: u64,
    },
    Arrive {
        link: usize,
        to: Side,
        transit: Transit,
    },
}

struct Scheduled {
    at: Nanos,
    seq: u64,
    event: Event,
}

impl PartialEq for Scheduled {
    fn eq(&self, other: &Self) -> bool {
        (self.at, self.seq) == (other.at, other.seq)
    }
}

impl Eq for Scheduled {}

impl PartialOrd for Scheduled {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Scheduled {
    // Reversed: BinaryHeap is a max-heap, the earliest event must come first.
    fn cmp(&self, other: &Self) -> Ordering {
        (other.at, other.seq).cmp(&(self.at, self.seq))
    }
}

/// A running simulation.
pub struct Sim {
    config: SimConfig,
    name: String,
    nodes: Vec<Node>,
    links: Vec<LinkEnds>,
    queue: BinaryHeap<Scheduled>,
    seq: u64,
    now: Nanos,
    events: u64,
    next_sample: Nanos,
    metrics: Metrics,
    frames: Vec<FrameRecord>,
    system_buf: Vec<u64>,
    tier_buf: Vec<u8>,
}

impl std::fmt::Debug for Sim {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Its parts are tasks, locks and buffers: the name says enough.
        f.debug_struct("Sim").finish_non_exhaustive()
    }
}

impl Sim {
    /// Builds the network of `topology`: a runtime per node (the root
    /// configured as tier 0), a gateway per link end and per unconnected
    /// gateway, at the link indices [`Network::gateways`] gives them,
    /// oscillators and randomness drawn from `config.seed`.
    pub fn new(topology: &Network, config: SimConfig) -> Result<Sim, SimError> {
        topology.validate()?;
        if !(config.boot_window_us.is_finite() && config.boot_window_us >= 0.0) {
            return Err(SimError::config("boot_window_us must be finite and >= 0"));
        }
        let seed = config.seed;
        let mut nodes = Vec::with_capacity(topology.nodes.len());
        for (i, spec) in topology.nodes.iter().enumerate() {
            let i = i as u64;
            let clock = spec.clock.draw(&mut Rng::stream(seed, "clock", i));
            let busy = BusyState::new(spec.busy, Rng::stream(seed, "busy", i));
            let mut runtime = build_runtime(spec)?;
            // The runtime seeds its request dither from its name; draw it
            // from the simulation seed instead, so seeds vary it too.
            let dither_seed = Rng::stream(seed, "dither", i).next_u64() as u32;
            runtime.clock_mut().seed(dither_seed);
            nodes.push(Node::new(
                spec.clone(),
                runtime,
                clock,
                Rng::stream(seed, "loop", i),
                busy,
            ));
        }
        let gateways = topology.gateways()?;
        let mut links: Vec<LinkEnds> = topology
            .links
            .iter()
            .map(|spec| LinkEnds {
                type_name: spec.model.type_name(),
                ends: [(0, 0); 2],
            })
            .collect();
        for (n, node_gateways) in gateways.into_iter().enumerate() {
            for (index, g) in node_gateways.into_iter().enumerate() {
                let link = match g {
                    Gateway::Link { link: l, side } => {
                        let spec = &topology.links[l];
                        links[l].ends[side.index()] = (n, index);
                        let rng = Rng::stream(seed, "link", 2 * l as u64 + side.index() as u64);
                        SimLink::new(l, side, &spec.name, spec.model, rng)
                    }
                    Gateway::Unconnected(k) => SimLink::unconnected(topology.unconnected[k].model),
                };
                nodes[n].links.push(link);
            }
        }
        let root = topology.root().unwrap_or(0);
        let names = topology.nodes.iter().map(|n| n.name.clone()).collect();
        let parents = parents(topology.nodes.len(), root, &links);
        let mut sim = Sim {
            config,
            name: topology.name.clone(),
            metrics: Metrics::new(names, root, parents),
            nodes,
            links,
            queue: BinaryHeap::new(),
            seq: 0,
            now: 0,
            events: 0,
            next_sample: 0,
            frames: Vec::new(),
            system_buf: Vec::new(),
            tier_buf: Vec::new(),
        };
        let mut boot = Rng::stream(seed, "boot", 0);
        for n in 0..sim.nodes.len() {
            let at = crate::rng::us_to_ns(boot.uniform(0.0, config.boot_window_us));
            sim.schedule_poll(n, at);
        }
        Ok(sim)
    }

    /// The topology's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The configuration.
    pub fn config(&self) -> &SimConfig {
        &self.config
    }

    /// Current true time, ns.
    pub fn now(&self) -> Nanos {
        self.now
    }

    /// Events handled so far.
    pub fn events(&self) -> u64 {
        self.events
    }

    /// The nodes, by index (topology order).
    pub fn nodes(&self) -> &[Node] {
        &self.nodes
    }

    /// One node. Panics if `index` is not a node index.
    pub fn node(&self, index: usize) -> &Node {
        &self.nodes[index]
    }

    /// One node, mutably (ports, runtime configuration). Panics if `index`
    /// is not a node index.
    pub fn node_mut(&mut self, index: usize) -> &mut Node {
        &mut self.nodes[index]
    }

    /// The index of the node named `name`.
    pub fn node_index(&self, name: &str) -> Option<usize> {
        self.nodes.iter().position(|n| n.name() == name)
    }

    /// The links, by index (topology order).
    pub fn links(&self) -> &[LinkEnds] {
        &self.links
    }

    /// One end of a link. Panics if `link` is not a link index.
    pub fn link_end(&self, link: usize, side: Side) -> &SimLink {
        let (n, l) = self.links[link].ends[side.index()];
        &self.nodes[n].links[l]
    }

    /// Opens or closes both ends of a link. Panics if `link` is not a link
    /// index.
    pub fn set_link_open(&mut self, link: usize, open: bool) {
        for (n, l) in self.links[link].ends {
            self.nodes[n].links[l].set_open(open);
            self.schedule_poll(n, self.now);
        }
    }

    /// The metrics sampled so far.
    pub fn metrics(&self) -> &Metrics {
        &self.metrics
    }

    /// Ends the simulation, keeping its metrics.
    pub fn into_metrics(self) -> Metrics {
        self.metrics
    }

    /// Every frame so far, if [`SimConfig::trace_frames`] is set.
    pub fn frames(&self) -> &[FrameRecord] {
        &self.frames
    }

    /// Makes node `node` poll at true time `at` (or now, if `at` is past),
    /// for example after queueing a send on one of its ports. Panics if
    /// `node` is not a node index.
    pub fn wake(&mut self, node: usize, at: Nanos) {
        self.schedule_poll(node, at.max(self.now));
    }

    /// Changes the time configuration of every node: `f` gets each node's
    /// spec and a copy of its configuration to edit.
    pub fn configure_clocks(
        &mut self,
        mut f: impl FnMut(&NodeSpec, &mut TimeConfig),
    ) -> Result<(), SimError> {
        for node in &mut self.nodes {
            let mut cfg = *node.runtime.clock().config();
            f(&node.spec, &mut cfg);
            node.runtime.clock_mut().set_config(cfg).map_err(|e| {
                SimError::config(format!(
                    "node {}: time configuration: {e:?}",
                    node.spec.name
                ))
            })?;
        }
        Ok(())
    }

    /// Hot start: presets every non-root node's clock rate correction to
    /// the one that matches the root's rate now, as if persisted from an
    /// earlier run. Returns false if the runtime has no way to take it (see
    /// [`hot_start::apply_hot_start`]).
    pub fn apply_hot_start(&mut self) -> bool {
        let root = self.metrics.root;
        let now = self.now;
        let root_rate = self.nodes[root].clock.rate_ppm_at(now) * 1e-6;
        let mut applied = true;
        for (i, node) in self.nodes.iter_mut().enumerate() {
            if i == root {
                continue;
            }
            let rate = node.clock.rate_ppm_at(now) * 1e-6;
            // system = local · (1 + c) must advance like the root's clock.
            let correction = (1.0 + root_rate) / (1.0 + rate) - 1.0;
            let ppb = (correction * 1e9).round() as i32;
            let local = node.clock.local_us(now);
            applied &= hot_start::apply_hot_start(&mut node.runtime, local, ppb);
        }
        applied
    }

    /// Runs until true time `until` (ns).
    pub fn run_until(&mut self, until: Nanos) {
        let period = self.config.sample_period_us.saturating_mul(1000);
        loop {
            let next = self.queue.peek().map(|s| s.at).filter(|&at| at <= until);
            if period > 0 {
                let horizon = next.unwrap_or(until);
                while self.next_sample <= horizon {
                    self.sample(self.next_sample);
                    self.next_sample += period;
                }
            }
            if next.is_none() {
                break;
            }
            let Some(s) = self.queue.pop() else { break };
            self.now = s.at;
            self.events += 1;
            match s.event {
                Event::Poll { node, generation } => self.on_poll(node, generation),
                Event::Arrive { link, to, transit } => self.on_arrive(link, to, transit),
            }
        }
        self.now = self.now.max(until);
    }

    /// Runs for `duration` ns more.
    pub fn run_for(&mut self, duration: Nanos) {
        self.run_until(self.now.saturating_add(duration));
    }

    /// Runs for `seconds` more of true time.
    pub fn run_secs(&mut self, seconds: f64) {
        self.run_for((seconds.max(0.0) * 1e9) as Nanos);
    }

    fn push(&mut self, at: Nanos, event: Event) {
        self.seq += 1;
        self.queue.push(Scheduled {
            at,
            seq: self.seq,
            event,
        });
    }

    fn schedule_poll(&mut self, node: usize, at: Nanos) {
        let n = &mut self.nodes[node];
        if n.next_poll.is_some_and(|p| p <= at) {
            return;
        }
        n.poll_generation += 1;
        n.next_poll = Some(at);
        let generation = n.poll_generation;
        self.push(at, Event::Poll { node, generation });
    }

    fn on_poll(&mut self, n: usize, generation: u64) {
        let t = self.now;
        let node = &mut self.nodes[n];
        if generation != node.poll_generation {
            return; // superseded by an earlier poll
        }
        node.next_poll = None;
        if let Some(end) = node.busy.event(t) {
            self.schedule_poll(n, end);
            return;
        }
        let local = node.clock.local_us(t);
        for link in &mut node.links {
            link.set_now(t);
        }
        let result = node.runtime.poll(local, &mut node.ports, &mut node.links);
        node.polls += 1;

        let mut next: Option<Nanos> = None;
        let mut want = |at: Nanos| next = Some(next.map_or(at, |n: Nanos| n.min(at)));
        if result.more {
            // At least 1 ns on, so a zero latency cannot stall time.
            want(t + node.loop_latency().max(1));
        }
        if let Some(w) = result.wake_at {
            // The loop notices a due wake-up one loop latency after it.
            let due = if w <= local {
                t
            } else {
                node.clock.true_time_at(w)
            };
            want(due.max(t) + node.loop_latency().max(1));
        }
        if result.waiting > 0 {
            // A transmit-complete interrupt frees the buffer: poll then.
            let free = node.links.iter().filter_map(SimLink::next_tx_free).min();
            if let Some(free) = free {
                want(free + node.loop_latency());
            }
        }
        let mut sent = Vec::new();
        for link in &mut node.links {
            let (index, to) = (link.link_index(), link.side().other());
            sent.extend(link.take_outgoing().map(|tr| (index, to, tr)));
        }
        for (link, to, transit) in sent {
            if transit.lost {
                if self.config.trace_frames {
                    let peer = self.links[link].ends[to.index()].0;
                    self.frames.push(FrameRecord {
                        link,
                        from: n,
                        to: peer,
                        transit,
                        rx_stamp: None,
                    });
                }
                continue;
            }
            self.push(transit.visible_ns, Event::Arrive { link, to, transit });
        }
        if let Some(at) = next {
            self.schedule_poll(n, at);
        }
    }

    fn on_arrive(&mut self, link: usize, to: Side, transit: Transit) {
        let t = self.now;
        let (n, l) = self.links[link].ends[to.index()];
        let from = self.links[link].ends[to.other().index()].0;
        let node = &mut self.nodes[n];
        let late_stamps = node.busy.model().is_some_and(|m| m.late_stamps);
        // The frame's first byte is an event at the node (an interrupt), and
        // may find it busy or start a spell.
        let busy_at_first = node.busy.event(transit.first_byte_ns);
        let stamp = match node.links[l].stamp_mode() {
            StampMode::Wire => {
                let at = match busy_at_first {
                    Some(end) if late_stamps => end,
                    _ => transit.first_byte_ns,
                };
                Some(node.clock.local_us(at))
            }
            StampMode::Software => {
                // Software reads (and stamps) only when it runs.
                let at = node.busy.busy_until(t).unwrap_or(t);
                Some(node.clock.local_us(at))
            }
            StampMode::None => None,
        };
        let endpoint = &mut node.links[l];
        let before = endpoint.inbox_len();
        endpoint.deliver(&transit.bytes, stamp, transit.ns_per_byte / 1000.0);
        let arrived = endpoint.inbox_len() > before;
        if self.config.trace_frames {
            self.frames.push(FrameRecord {
                link,
                from,
                to: n,
                transit,
                rx_stamp: stamp,
            });
        }
        if arrived {
            let at = t + node.loop_latency();
            self.schedule_poll(n, at);
        }
    }

    fn sample(&mut self, t: Nanos) {
        self.system_buf.clear();
        self.tier_buf.clear();
        for node in &self.nodes {
            let local = node.clock.local_us(t);
            self.system_buf
                .push(node.runtime.system_time(local).as_micros());
            self.tier_buf.push(node.runtime.clock().tier());
        }
        self.metrics
            .push(t as f64 / 1e9, &self.system_buf, &self.tier_buf);
        // Each clock's rate correction against the one its oscillator
        // needs to run at the root's rate now (as `apply_hot_start` sets).
        let root_rate = self.nodes[self.metrics.root].clock.rate_ppm_at(t) * 1e-6;
        let rates: Vec<f64> = self
            .nodes
            .iter()
            .map(|node| {
                let needed = (1.0 + root_rate) / (1.0 + node.clock.rate_ppm_at(t) * 1e-6) - 1.0;
                f64::from(node.runtime.clock().rate_ppb()) * 1e-3 - needed * 1e6
            })
            .collect();
        self.metrics.push_rate_errors(&rates);
    }
}

/// Builds a node's runtime: its names, build key and, for the root, the
/// tier-0 time configuration.
fn build_runtime(spec: &NodeSpec) -> Result<SimRuntime, SimError> {
    let build = match spec.kind {
        NodeKind::Host => BuildKey::RustHost,
        NodeKind::Mcu => BuildKey::RustSimulated,
    };
    let mut runtime = SimRuntime::new(spec.kind.type_name(), &spec.name)
        .map_err(|_| SimError::config(format!("node name {:?} is too long", spec.name)))?
        .with_version(VERSION, build);
    if spec.root {
        let cfg = TimeConfig {
            root: true,
            ..TimeConfig::default()
        };
        runtime.clock_mut().set_config(cfg).map_err(|e| {
            SimError::config(format!(
                "node {}: root time configuration: {e:?}",
                spec.name
            ))
        })?;
    }
    Ok(runtime)
}

/// Each node's parent on a shortest path to `root` (breadth first, links in
/// the order they were added).
fn parents(count: usize, root: usize, links: &[LinkEnds]) -> Vec<Option<Parent>> {
    let mut adjacent: Vec<Vec<(usize, &'static str)>> = vec![Vec::new(); count];
    for l in links {
        let (a, b) = (l.ends[0].0, l.ends[1].0);
        adjacent[a].push((b, l.type_name));
        adjacent[b].push((a, l.type_name));
    }
    let mut parents: Vec<Option<Parent>> = vec![None; count];
    let mut seen = vec![false; count];
    let mut depth = vec![0usize; count];
    let mut queue = VecDeque::from([root]);
    seen[root] = true;
    while let Some(n) = queue.pop_front() {
        for &(m, link_type) in &adjacent[n] {
            if !seen[m] {
                seen[m] = true;
                depth[m] = depth[n] + 1;
                parents[m] = Some(Parent {
                    node: n,
                    link_type,
                    depth: depth[m],
                });
                queue.push_back(m);
            }
        }
    }
    parents
}
