//! The discrete-event simulator's network: which nodes, joined by which
//! links with which link models. It is what a [`SimSpec`](crate::SimSpec)
//! lowers into ([`Network::from_spec`]), and what experiments on link
//! models build directly (every [`LinkModel`] and its parameters).
//!
//! A [`Network`] is plain data: node specs and link specs that name their
//! two ends. A node's link gateways are numbered from 0 in the order the
//! links naming it were added, which is the order a runtime's
//! `link_forward` indices refer to, unless a link end asks for an index of
//! its own ([`NetLink::at`]); a gateway that joins nothing
//! ([`Unconnected`]) can hold an index no link takes, as the module
//! firmware's USB link does on a module that is reached over its UART.
//!
//! Specs are written as the TOML files the simulated machines read
//! (`osap-sim/topologies/*.toml`): [`Network::load`] reads one and
//! [`Network::from_spec`] lowers one (see [`from_spec`] for how each key
//! maps).
//!
//! Built-in shapes (hosts are clock roots; hubs and modules are MCUs; every
//! host–hub link is USB CDC and every other link a 2 Mbaud UART):
//!
//! - [`Network::chain`]`(n)`: `n` runtimes in a line, `n - 1` link hops:
//!   `host –USB– hub1 –UART– hub2 … –UART– m1`. [`Network::chain4`] is
//!   host → USB → hub1 → UART → hub2 → UART → m1: four runtimes, three hops
//!   (four hops if the module's own port is counted as the last).
//! - [`Network::star`]`(n)`: `host –USB– hub`, and `n` modules each on its
//!   own UART to the hub ([`Network::star8`]: the hub has 9 links).
//! - [`Network::tree`]`(depth, fanout)`: `host –USB– t0`, each hub with
//!   `fanout` children over UART, `depth` levels below `t0`.
//! - [`Network::loop3`] (`loop`): `host –USB– a`, a UART cycle `a – b – c
//!   – a`, and a module `m1` off `c`.
//!
//! Link kinds and parameters the TOML format has no keys for (TCP and UDP
//! links, USB latencies, UART bits per byte, propagation delay, asymmetry,
//! transmit buffers) are set with the builders: [`Network::with_link`],
//! [`Network::map_links`].

pub mod from_spec;

use crate::busy::BusyModel;
use crate::error::SimError;
use crate::medium::{LinkModel, Side};
use crate::node::{NodeKind, NodeSpec, MAX_LINKS};
use std::collections::HashSet;

/// One link: its two ends (node names) and its kind.
#[derive(Debug, Clone, PartialEq)]
pub struct NetLink {
    /// End A (on a USB link, the host).
    pub a: String,
    /// End B (on a USB link, the device).
    pub b: String,
    /// Instance name reported to scans (may be empty).
    pub name: String,
    /// Kind and parameters.
    pub model: LinkModel,
    /// The link index of end A and of end B at their nodes; `None` (the
    /// default): the lowest index that end's node has free, taking the
    /// links in order after every index asked for is reserved.
    pub at: [Option<usize>; 2],
}

impl NetLink {
    /// A link of `model` between `a` and `b` (on USB, `a` is the host),
    /// unnamed, at the next free link index of each end.
    pub fn new(a: &str, b: &str, model: LinkModel) -> Self {
        NetLink {
            a: a.to_string(),
            b: b.to_string(),
            name: String::new(),
            model,
            at: [None, None],
        }
    }

    /// The same link with instance name `name`.
    pub fn named(mut self, name: &str) -> Self {
        self.name = name.to_string();
        self
    }

    /// The same link at link index `index` of end `side`'s node.
    pub fn at(mut self, side: Side, index: usize) -> Self {
        self.at[side.index()] = Some(index);
        self
    }
}

/// A link gateway that joins nothing: it is there, at its index, and never
/// opens (as the module firmware's USB link on a module reached over its
/// UART).
#[derive(Debug, Clone, PartialEq)]
pub struct Unconnected {
    /// Its node.
    pub node: String,
    /// Its link index at the node.
    pub index: usize,
    /// Its kind (for its type name, MTU and, on USB, as the device end).
    pub model: LinkModel,
}

/// What one of a node's link indices holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Gateway {
    /// End `side` of `links[link]`.
    Link {
        /// The link's position in [`Network::links`].
        link: usize,
        /// Which end.
        side: Side,
    },
    /// [`Network::unconnected`]`[k]`.
    Unconnected(usize),
}

/// A network description.
#[derive(Debug, Clone, PartialEq)]
pub struct Network {
    /// Its name (used in reports and file names).
    pub name: String,
    /// The nodes.
    pub nodes: Vec<NodeSpec>,
    /// The links, in the order they were added.
    pub links: Vec<NetLink>,
    /// Gateways that join nothing.
    pub unconnected: Vec<Unconnected>,
}

/// The default UART of the built-in shapes: 2 Mbaud.
fn uart() -> LinkModel {
    LinkModel::uart(2_000_000)
}

impl Network {
    /// An empty topology.
    pub fn new(name: &str) -> Self {
        Network {
            name: name.to_string(),
            nodes: Vec::new(),
            links: Vec::new(),
            unconnected: Vec::new(),
        }
    }

    /// Adds a node.
    pub fn add_node(&mut self, spec: NodeSpec) -> &mut Self {
        self.nodes.push(spec);
        self
    }

    /// Adds a link between nodes `a` and `b` (on USB, `a` is the host).
    pub fn add_link(&mut self, a: &str, b: &str, model: LinkModel) -> &mut Self {
        self.links.push(NetLink::new(a, b, model));
        self
    }

    /// Adds a link described in full (a name, link indices of its own).
    pub fn add_link_spec(&mut self, link: NetLink) -> &mut Self {
        self.links.push(link);
        self
    }

    /// Adds a gateway of `model` at link index `index` of `node` that joins
    /// nothing and never opens.
    pub fn add_unconnected(&mut self, node: &str, index: usize, model: LinkModel) -> &mut Self {
        self.unconnected.push(Unconnected {
            node: node.to_string(),
            index,
            model,
        });
        self
    }

    /// [`add_node`](Self::add_node), by value.
    pub fn with_node(mut self, spec: NodeSpec) -> Self {
        self.add_node(spec);
        self
    }

    /// [`add_link`](Self::add_link), by value.
    pub fn with_link(mut self, a: &str, b: &str, model: LinkModel) -> Self {
        self.add_link(a, b, model);
        self
    }

    /// Changes every node with `f`.
    pub fn map_nodes(mut self, f: impl FnMut(&mut NodeSpec)) -> Self {
        self.nodes.iter_mut().for_each(f);
        self
    }

    /// Changes every link with `f`.
    pub fn map_links(mut self, f: impl FnMut(&mut NetLink)) -> Self {
        self.links.iter_mut().for_each(f);
        self
    }

    /// Gives every microcontroller node the busy model.
    pub fn with_busy_modules(self, model: BusyModel) -> Self {
        self.map_nodes(|n| {
            if n.kind == NodeKind::Mcu {
                n.busy = Some(model);
            }
        })
    }

    /// The index of the node named `name`.
    pub fn node_index(&self, name: &str) -> Option<usize> {
        self.nodes.iter().position(|n| n.name == name)
    }

    /// The first clock root.
    pub fn root(&self) -> Option<usize> {
        self.nodes.iter().position(|n| n.root)
    }

    /// `n` runtimes in a line: host, `n - 2` hubs, one module (`n >= 2`).
    pub fn chain(n: usize) -> Self {
        let mut t = Network::new(&format!("chain{n}"));
        t.add_node(NodeSpec::host("host"));
        let mut prev = "host".to_string();
        for i in 1..n.max(2) {
            let name = if i == n.max(2) - 1 {
                "m1".to_string()
            } else {
                format!("hub{i}")
            };
            t.add_node(NodeSpec::mcu(&name));
            let model = if i == 1 { LinkModel::usb_cdc() } else { uart() };
            t.add_link(&prev, &name, model);
            prev = name;
        }
        t
    }

    /// host –USB– hub1 –UART– hub2 –UART– m1.
    pub fn chain4() -> Self {
        Network::chain(4)
    }

    /// host –USB– hub, and `n` modules on their own UARTs to the hub.
    pub fn star(n: usize) -> Self {
        let mut t = Network::new(&format!("star{n}"));
        t.add_node(NodeSpec::host("host"));
        t.add_node(NodeSpec::mcu("hub"));
        t.add_link("host", "hub", LinkModel::usb_cdc());
        for i in 1..=n {
            let name = format!("m{i}");
            t.add_node(NodeSpec::mcu(&name));
            t.add_link("hub", &name, uart());
        }
        t
    }

    /// A star of 8 modules.
    pub fn star8() -> Self {
        Network::star(8)
    }

    /// host –USB– t0, then `depth` levels of `fanout` children per hub over
    /// UART. Nodes are named `t<level>_<index>` (`t0` for the top hub).
    pub fn tree(depth: usize, fanout: usize) -> Self {
        let mut t = Network::new(&format!("tree{depth}x{fanout}"));
        t.add_node(NodeSpec::host("host"));
        t.add_node(NodeSpec::mcu("t0"));
        t.add_link("host", "t0", LinkModel::usb_cdc());
        let mut level = vec!["t0".to_string()];
        for d in 1..=depth {
            let mut next = Vec::new();
            for parent in &level {
                for _ in 0..fanout {
                    let name = format!("t{d}_{}", next.len());
                    t.add_node(NodeSpec::mcu(&name));
                    t.add_link(parent, &name, uart());
                    next.push(name);
                }
            }
            level = next;
        }
        t
    }

    /// host –USB– a; a UART cycle a – b – c – a; module m1 off c.
    pub fn loop3() -> Self {
        let mut t = Network::new("loop");
        t.add_node(NodeSpec::host("host"));
        for n in ["a", "b", "c", "m1"] {
            t.add_node(NodeSpec::mcu(n));
        }
        t.add_link("host", "a", LinkModel::usb_cdc());
        t.add_link("a", "b", uart());
        t.add_link("b", "c", uart());
        t.add_link("c", "a", uart());
        t.add_link("c", "m1", uart());
        t
    }

    /// A built-in topology by name: `chain<N>`, `star<N>`, `tree<D>x<F>`,
    /// `loop`.
    pub fn named(name: &str) -> Result<Self, SimError> {
        let num = |s: &str| s.parse::<usize>().ok().filter(|&n| (1..=64).contains(&n));
        if name == "loop" {
            return Ok(Network::loop3());
        }
        if let Some(n) = name.strip_prefix("chain").and_then(num) {
            if n >= 2 {
                return Ok(Network::chain(n));
            }
        }
        if let Some(n) = name.strip_prefix("star").and_then(num) {
            if n < MAX_LINKS {
                return Ok(Network::star(n));
            }
        }
        if let Some((d, f)) = name.strip_prefix("tree").and_then(|s| s.split_once('x')) {
            if let (Some(d), Some(f)) = (num(d), num(f)) {
                if f < MAX_LINKS && f.pow(d as u32) <= 256 {
                    return Ok(Network::tree(d, f));
                }
            }
        }
        Err(SimError::config(format!(
            "unknown topology {name:?}: expected loop, chain<2..64>, star<1..15> or \
             tree<depth>x<fanout> (at most 256 leaves)"
        )))
    }

    /// Checks the description: unique names, links between distinct
    /// existing nodes, a clock root, every parameter in range, and link
    /// indices that leave no gap and give no node more than [`MAX_LINKS`]
    /// ([`gateways`](Self::gateways)).
    pub fn validate(&self) -> Result<(), SimError> {
        if self.nodes.is_empty() {
            return Err(SimError::config(format!(
                "topology {} has no nodes",
                self.name
            )));
        }
        let mut names = HashSet::new();
        for n in &self.nodes {
            n.validate()?;
            if !names.insert(n.name.as_str()) {
                return Err(SimError::config(format!(
                    "node name {:?} is used twice",
                    n.name
                )));
            }
        }
        if self.root().is_none() {
            return Err(SimError::config(format!(
                "topology {} has no clock root (set root on one node)",
                self.name
            )));
        }
        for (i, l) in self.links.iter().enumerate() {
            let label = format!("#{i} ({} - {})", l.a, l.b);
            let end = |name: &str| {
                self.node_index(name).ok_or_else(|| {
                    SimError::config(format!("link {label}: no node named {name:?}"))
                })
            };
            let (a, b) = (end(&l.a)?, end(&l.b)?);
            if a == b {
                return Err(SimError::config(format!(
                    "link {label} joins a node to itself"
                )));
            }
            l.model.validate(&label)?;
        }
        for (k, u) in self.unconnected.iter().enumerate() {
            let label = format!("unconnected gateway #{k} ({} link {})", u.node, u.index);
            if self.node_index(&u.node).is_none() {
                return Err(SimError::config(format!(
                    "{label}: no node named {:?}",
                    u.node
                )));
            }
            u.model.validate(&label)?;
        }
        self.gateways().map(|_| ())
    }

    /// Each node's link gateways in link-index order: indices asked for
    /// ([`NetLink::at`], [`Unconnected::index`]) first, then every other
    /// link end, in link order, at the lowest index its node has free.
    /// Fails if two ask for one index, an index is left without a gateway,
    /// or a node has more than [`MAX_LINKS`].
    pub fn gateways(&self) -> Result<Vec<Vec<Gateway>>, SimError> {
        let mut slots: Vec<Vec<Option<Gateway>>> = vec![Vec::new(); self.nodes.len()];
        let node = |name: &str| {
            self.node_index(name)
                .ok_or_else(|| SimError::config(format!("no node named {name:?}")))
        };
        let too_many = |n: usize| {
            SimError::config(format!(
                "node {} has more than {MAX_LINKS} links",
                self.nodes[n].name
            ))
        };
        let mut place = |n: usize, index: usize, g: Gateway| {
            if index >= MAX_LINKS {
                return Err(too_many(n));
            }
            let s = &mut slots[n];
            if s.len() <= index {
                s.resize(index + 1, None);
            }
            if let Some(taken) = s[index] {
                return Err(SimError::config(format!(
                    "node {}: link index {index} is asked for twice ({}, {})",
                    self.nodes[n].name,
                    self.describe(taken),
                    self.describe(g)
                )));
            }
            s[index] = Some(g);
            Ok(())
        };
        for (link, l) in self.links.iter().enumerate() {
            for side in [Side::A, Side::B] {
                if let Some(index) = l.at[side.index()] {
                    let n = node([&l.a, &l.b][side.index()])?;
                    place(n, index, Gateway::Link { link, side })?;
                }
            }
        }
        for (k, u) in self.unconnected.iter().enumerate() {
            place(node(&u.node)?, u.index, Gateway::Unconnected(k))?;
        }
        for (link, l) in self.links.iter().enumerate() {
            for side in [Side::A, Side::B] {
                if l.at[side.index()].is_some() {
                    continue;
                }
                let n = node([&l.a, &l.b][side.index()])?;
                let s = &mut slots[n];
                let index = s.iter().position(Option::is_none).unwrap_or(s.len());
                if index >= MAX_LINKS {
                    return Err(too_many(n));
                }
                if index == s.len() {
                    s.push(None);
                }
                s[index] = Some(Gateway::Link { link, side });
            }
        }
        slots
            .into_iter()
            .enumerate()
            .map(|(n, s)| {
                s.into_iter()
                    .enumerate()
                    .map(|(index, g)| {
                        g.ok_or_else(|| {
                            SimError::config(format!(
                                "node {}: no link or unconnected gateway is at link index {index}, below one that is",
                                self.nodes[n].name
                            ))
                        })
                    })
                    .collect()
            })
            .collect()
    }

    fn describe(&self, g: Gateway) -> String {
        match g {
            Gateway::Link { link, side } => {
                let l = &self.links[link];
                format!("link #{link} ({} - {}) end {side:?}", l.a, l.b)
            }
            Gateway::Unconnected(k) => format!("unconnected gateway #{k}"),
        }
    }

    /// For each link, its two ends as (node index, link index at that
    /// node). Call after [`validate`](Self::validate) (empty if invalid).
    pub fn endpoints(&self) -> Vec<[(usize, usize); 2]> {
        let Ok(gateways) = self.gateways() else {
            return Vec::new();
        };
        let mut out = vec![[(0, 0); 2]; self.links.len()];
        for (n, node) in gateways.iter().enumerate() {
            for (index, g) in node.iter().enumerate() {
                if let Gateway::Link { link, side } = *g {
                    out[link][side.index()] = (n, index);
                }
            }
        }
        out
    }
}
