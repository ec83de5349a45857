//! Network descriptions: which nodes, joined by which links.
//!
//! A [`Topology`] is plain data: node specs and link specs that name their
//! two ends. A node's link gateways are numbered in the order the links
//! naming it were added, from 0, which is the order a runtime's
//! `link_forward` indices refer to.
//!
//! Built-in shapes (hosts are clock roots; hubs and modules are MCUs; every
//! host–hub link is USB CDC and every other link a 2 Mbaud UART):
//!
//! - [`Topology::chain`]`(n)`: `n` runtimes in a line, `n - 1` link hops:
//!   `host –USB– hub1 –UART– hub2 … –UART– m1`. [`Topology::chain4`] is
//!   host → USB → hub1 → UART → hub2 → UART → m1: four runtimes, three hops
//!   (four hops if the module's own port is counted as the last).
//! - [`Topology::star`]`(n)`: `host –USB– hub`, and `n` modules each on its
//!   own UART to the hub ([`Topology::star8`]: the hub has 9 links).
//! - [`Topology::tree`]`(depth, fanout)`: `host –USB– t0`, each hub with
//!   `fanout` children over UART, `depth` levels below `t0`.
//! - [`Topology::loop3`] (`loop`): `host –USB– a`, a UART cycle `a – b – c
//!   – a`, and a module `m1` off `c`.
//!
//! The same can be written as text ([`Topology::parse`]):
//!
//! ```text
//! # chain4
//! name chain4
//! node host host root
//! node hub1 mcu
//! node hub2 mcu
//! node m1 mcu
//! link host hub1 usb_cdc
//! link hub1 hub2 uart baud=2000000
//! link hub2 m1 uart baud=2000000
//! ```
//!
//! `node NAME host|mcu [root] [busy] [rate_ppm=X] [offset_us=X]`;
//! `link A B TYPE [key=value…]` with TYPE one of `uart`, `rs485`,
//! `usb_cdc` (A is the USB host), `tcp`, `udp`. Keys: `mtu`, `loss`; for
//! UARTs `baud`, `bits`, `prop_us`, `asym_us`, `jitter_us` (uniform
//! `[0, x]`), `corrupt` (per byte), `fifo` (frames); for USB
//! `sof_phase_us`, `tx_latency_us`, `rx_latency_us` (exponential means),
//! `host_stamps`, `out_frame_aligned`, `in_frame_aligned`; for sockets `preset` (`loopback`, `lan`), `min_latency_us`,
//! `jitter_us` (exponential mean), `asym_us`, `stamps`.

use crate::busy::BusyModel;
use crate::clock::Param;
use crate::error::SimError;
use crate::medium::{IpParams, LinkModel, UartParams, UsbParams};
use crate::node::{NodeKind, NodeSpec, MAX_LINKS};
use crate::rng::Dist;
use std::collections::HashSet;

/// One link: its two ends (node names) and its kind.
#[derive(Debug, Clone, PartialEq)]
pub struct LinkSpec {
    /// End A (on a USB link, the host).
    pub a: String,
    /// End B (on a USB link, the device).
    pub b: String,
    /// Instance name reported to scans (may be empty).
    pub name: String,
    /// Kind and parameters.
    pub model: LinkModel,
}

/// A network description.
#[derive(Debug, Clone, PartialEq)]
pub struct Topology {
    /// Its name (used in reports and file names).
    pub name: String,
    /// The nodes.
    pub nodes: Vec<NodeSpec>,
    /// The links, in the order they were added.
    pub links: Vec<LinkSpec>,
}

/// The default UART of the built-in shapes: 2 Mbaud.
fn uart() -> LinkModel {
    LinkModel::uart(2_000_000)
}

impl Topology {
    /// An empty topology.
    pub fn new(name: &str) -> Self {
        Topology {
            name: name.to_string(),
            nodes: Vec::new(),
            links: Vec::new(),
        }
    }

    /// Adds a node.
    pub fn add_node(&mut self, spec: NodeSpec) -> &mut Self {
        self.nodes.push(spec);
        self
    }

    /// Adds a link between nodes `a` and `b` (on USB, `a` is the host).
    pub fn add_link(&mut self, a: &str, b: &str, model: LinkModel) -> &mut Self {
        self.links.push(LinkSpec {
            a: a.to_string(),
            b: b.to_string(),
            name: String::new(),
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
    pub fn map_links(mut self, f: impl FnMut(&mut LinkSpec)) -> Self {
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
        let mut t = Topology::new(&format!("chain{n}"));
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
        Topology::chain(4)
    }

    /// host –USB– hub, and `n` modules on their own UARTs to the hub.
    pub fn star(n: usize) -> Self {
        let mut t = Topology::new(&format!("star{n}"));
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
        Topology::star(8)
    }

    /// host –USB– t0, then `depth` levels of `fanout` children per hub over
    /// UART. Nodes are named `t<level>_<index>` (`t0` for the top hub).
    pub fn tree(depth: usize, fanout: usize) -> Self {
        let mut t = Topology::new(&format!("tree{depth}x{fanout}"));
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
        let mut t = Topology::new("loop");
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
            return Ok(Topology::loop3());
        }
        if let Some(n) = name.strip_prefix("chain").and_then(num) {
            if n >= 2 {
                return Ok(Topology::chain(n));
            }
        }
        if let Some(n) = name.strip_prefix("star").and_then(num) {
            if n < MAX_LINKS {
                return Ok(Topology::star(n));
            }
        }
        if let Some((d, f)) = name.strip_prefix("tree").and_then(|s| s.split_once('x')) {
            if let (Some(d), Some(f)) = (num(d), num(f)) {
                if f < MAX_LINKS && f.pow(d as u32) <= 256 {
                    return Ok(Topology::tree(d, f));
                }
            }
        }
        Err(SimError::config(format!(
            "unknown topology {name:?}: expected loop, chain<2..64>, star<1..15> or \
             tree<depth>x<fanout> (at most 256 leaves)"
        )))
    }

    /// Checks the description: unique names, links between distinct
    /// existing nodes, at most [`MAX_LINKS`] links per node, a clock root,
    /// and every parameter in range.
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
        let mut degree = vec![0usize; self.nodes.len()];
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
            for n in [a, b] {
                degree[n] += 1;
                if degree[n] > MAX_LINKS {
                    return Err(SimError::config(format!(
                        "node {} has more than {MAX_LINKS} links",
                        self.nodes[n].name
                    )));
                }
            }
        }
        Ok(())
    }

    /// For each link, its two ends as (node index, link index at that
    /// node). Call after [`validate`](Self::validate).
    pub fn endpoints(&self) -> Vec<[(usize, usize); 2]> {
        let mut degree = vec![0usize; self.nodes.len()];
        let mut out = Vec::with_capacity(self.links.len());
        for l in &self.links {
            let mut ends = [(0, 0); 2];
            for (k, name) in [&l.a, &l.b].into_iter().enumerate() {
                let n = self.node_index(name).unwrap_or(0);
                ends[k] = (n, degree[n]);
                degree[n] += 1;
            }
            out.push(ends);
        }
        out
    }

    /// Reads the text form described in the module documentation.
    pub fn parse(text: &str) -> Result<Self, SimError> {
        let mut t = Topology::new("custom");
        for (i, raw) in text.lines().enumerate() {
            let line = raw.split('#').next().unwrap_or("").trim();
            if line.is_empty() {
                continue;
            }
            let err = |message: String| SimError::Parse {
                line: i + 1,
                message,
            };
            let words: Vec<&str> = line.split_whitespace().collect();
            match words[0] {
                "name" => match words.as_slice() {
                    [_, name] => t.name = (*name).to_string(),
                    _ => return Err(err("expected `name NAME`".into())),
                },
                "node" => t.nodes.push(parse_node(&words[1..]).map_err(err)?),
                "link" => t.links.push(parse_link(&words[1..]).map_err(err)?),
                other => {
                    return Err(err(format!(
                        "unknown statement {other:?}: expected name, node or link"
                    )))
                }
            }
        }
        t.validate()?;
        Ok(t)
    }
}

fn value<T: std::str::FromStr>(key: &str, v: &str) -> Result<T, String> {
    v.parse()
        .map_err(|_| format!("{key}={v}: not a valid value for {key}"))
}

fn parse_node(words: &[&str]) -> Result<NodeSpec, String> {
    let (name, kind, rest) = match words {
        [name, kind, rest @ ..] => (*name, *kind, rest),
        _ => return Err("expected `node NAME host|mcu [options]`".into()),
    };
    let mut spec = match kind {
        "host" => NodeSpec::host(name).with_root(false),
        "mcu" => NodeSpec::mcu(name),
        _ => return Err(format!("node kind {kind:?}: expected host or mcu")),
    };
    for w in rest {
        match w.split_once('=') {
            None if *w == "root" => spec.root = true,
            None if *w == "busy" => spec.busy = Some(BusyModel::MOTOR),
            Some(("rate_ppm", v)) => spec.clock.rate_ppm = Param::Fixed(value("rate_ppm", v)?),
            Some(("offset_us", v)) => spec.clock.offset_us = Param::Fixed(value("offset_us", v)?),
            _ => return Err(format!("unknown node option {w:?}")),
        }
    }
    Ok(spec)
}

fn parse_link(words: &[&str]) -> Result<LinkSpec, String> {
    let (a, b, kind, rest) = match words {
        [a, b, kind, rest @ ..] => (*a, *b, *kind, rest),
        _ => return Err("expected `link A B TYPE [key=value...]`".into()),
    };
    let mut model = match kind {
        "uart" => LinkModel::Uart(UartParams::default()),
        "rs485" => LinkModel::Rs485(UartParams::default()),
        "usb_cdc" => LinkModel::UsbCdc(UsbParams::default()),
        "tcp" => LinkModel::Tcp(IpParams::LOOPBACK),
        "udp" => LinkModel::Udp(IpParams::LOOPBACK),
        _ => {
            return Err(format!(
                "link type {kind:?}: expected uart, rs485, usb_cdc, tcp or udp"
            ))
        }
    };
    for w in rest {
        let Some((k, v)) = w.split_once('=') else {
            return Err(format!("link option {w:?}: expected key=value"));
        };
        set_link_option(&mut model, k, v)?;
    }
    Ok(LinkSpec {
        a: a.to_string(),
        b: b.to_string(),
        name: String::new(),
        model,
    })
}

fn set_link_option(model: &mut LinkModel, k: &str, v: &str) -> Result<(), String> {
    let unknown = |kind: &str| format!("unknown option {k:?} for a {kind} link");
    let kind = model.type_name();
    match model {
        LinkModel::Uart(p) | LinkModel::Rs485(p) => match k {
            "mtu" => p.mtu = value(k, v)?,
            "loss" => p.loss = value(k, v)?,
            "baud" => p.baud = value(k, v)?,
            "bits" => p.bits_per_byte = value(k, v)?,
            "prop_us" => p.propagation_us = value(k, v)?,
            "asym_us" => p.asymmetry_us = value(k, v)?,
            "jitter_us" => p.jitter = Dist::uniform(0.0, value(k, v)?),
            "corrupt" => p.corrupt_per_byte = value(k, v)?,
            "fifo" => p.tx_buffer_frames = value(k, v)?,
            _ => return Err(unknown(kind)),
        },
        LinkModel::UsbCdc(p) => match k {
            "mtu" => p.mtu = value(k, v)?,
            "loss" => p.loss = value(k, v)?,
            "sof_phase_us" => p.sof_phase_us = value(k, v)?,
            "tx_latency_us" => p.host_tx_latency = Dist::exp(0.0, value(k, v)?),
            "rx_latency_us" => p.host_rx_latency = Dist::exp(0.0, value(k, v)?),
            "host_stamps" => p.host_stamps = value(k, v)?,
            "out_frame_aligned" => p.out_frame_aligned = value(k, v)?,
            "in_frame_aligned" => p.in_frame_aligned = value(k, v)?,
            _ => return Err(unknown(kind)),
        },
        LinkModel::Tcp(p) | LinkModel::Udp(p) => match k {
            "mtu" => p.mtu = value(k, v)?,
            "loss" => p.loss = value(k, v)?,
            "preset" => {
                let keep = (p.mtu, p.loss);
                *p = match v {
                    "loopback" => IpParams::LOOPBACK,
                    "lan" => IpParams::LAN,
                    _ => return Err(format!("preset {v:?}: expected loopback or lan")),
                };
                (p.mtu, p.loss) = keep;
            }
            "min_latency_us" | "jitter_us" => {
                let (min, mean) = match p.latency {
                    Dist::Exp { min, mean } => (min, mean),
                    d => (d.mean_us(), 0.0),
                };
                let x: f64 = value(k, v)?;
                p.latency = if k == "min_latency_us" {
                    Dist::exp(x, mean)
                } else {
                    Dist::exp(min, x)
                };
            }
            "asym_us" => p.asymmetry_us = value(k, v)?,
            "stamps" => p.stamps = value(k, v)?,
            _ => return Err(unknown(kind)),
        },
    }
    Ok(())
}
