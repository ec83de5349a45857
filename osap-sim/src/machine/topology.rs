//! Topology files: which simulated modules a machine has and how they are
//! linked. The format is described in the [module docs](super).

use super::module::{MODULE_LINKS, MODULE_MTU};
use crate::clock::ClockSpec;
use osap_core::netresponder::NAME_MAX;
use osap_host::HostError;
use serde::{Deserialize, Serialize};
use std::collections::{HashMap, VecDeque};
use std::path::Path;

/// The name that stands for the host runtime a machine attaches to, in a
/// link's `a` or `b`.
pub const HOST: &str = "host";

/// Most links a topology may join to the host (the host runtime has 32
/// link gateways, and may have others of its own).
pub const MAX_HOST_LINKS: usize = 32;

fn yes() -> bool {
    true
}

fn default_wander_period() -> f64 {
    300.0
}

fn is_default<T: Default + PartialEq>(v: &T) -> bool {
    *v == T::default()
}

/// A simulated machine: modules and the links between them and the host.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Topology {
    /// The machine's name (for messages).
    #[serde(default)]
    pub name: String,
    /// Every link delivers at once, whatever its kind (no wire time, no
    /// timers): the fastest setting, for tests and benchmarks.
    #[serde(default)]
    pub zero_latency: bool,
    /// Modules synchronise their clocks to the host (as firmware does).
    #[serde(default = "yes")]
    pub sync: bool,
    /// Seed of the links' random latencies (USB scheduling), so a machine
    /// behaves the same from run to run.
    #[serde(default)]
    pub seed: u64,
    /// The modules, `[[module]]` in a file.
    #[serde(rename = "module", default)]
    pub modules: Vec<ModuleSpec>,
    /// The links, `[[link]]` in a file. A module's link indices follow the
    /// order its links are listed here.
    #[serde(rename = "link", default)]
    pub links: Vec<LinkSpec>,
}

/// One simulated module.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModuleSpec {
    /// Its runtime name (unique, at most 31 bytes, not `host`).
    pub name: String,
    /// Its runtime type name (at most 31 bytes): what firmware it stands for.
    #[serde(rename = "type")]
    pub type_name: String,
    /// Its oscillator's rate error, ppm (positive: its clock runs fast).
    #[serde(default, skip_serializing_if = "is_default")]
    pub rate_ppm: f64,
    /// Its local clock's reading when it boots, µs.
    #[serde(default, skip_serializing_if = "is_default")]
    pub offset_us: f64,
    /// Amplitude of a slow sinusoidal rate wander, ppm (temperature).
    #[serde(default, skip_serializing_if = "is_default")]
    pub wander_ppm: f64,
    /// Period of the wander, s.
    #[serde(default = "default_wander_period")]
    pub wander_period_s: f64,
    /// An `axis` module's hardware (defaults when absent); only `axis`
    /// modules may have it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub axis: Option<super::axis::AxisSpec>,
}

impl ModuleSpec {
    /// A module with an ideal clock.
    pub fn new(name: &str, type_name: &str) -> Self {
        ModuleSpec {
            name: name.to_string(),
            type_name: type_name.to_string(),
            rate_ppm: 0.0,
            offset_us: 0.0,
            wander_ppm: 0.0,
            wander_period_s: default_wander_period(),
            axis: None,
        }
    }

    /// The same module as an `axis` with hardware `axis`.
    pub fn with_axis(mut self, axis: super::axis::AxisSpec) -> Self {
        self.axis = Some(axis);
        self
    }

    /// The same module with a clock `rate_ppm` fast.
    pub fn with_rate_ppm(mut self, rate_ppm: f64) -> Self {
        self.rate_ppm = rate_ppm;
        self
    }

    /// The oscillator this spec describes (the wander starts at phase 0).
    pub fn clock_model(&self) -> crate::clock::ClockModel {
        crate::clock::ClockModel::new(self.offset_us, self.rate_ppm).with_wander(
            self.wander_ppm,
            self.wander_period_s,
            0.0,
        )
    }
}

/// What kind of link, and so how long a packet takes on it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LinkKind {
    /// USB full-speed CDC: 1 ms frame scheduling host → device, a short
    /// poll delay device → host, host software latency. The end named
    /// `host` (else `a`) is the USB host. Type name `usb_cdc`.
    Usb,
    /// A UART: wire time `(len + 4) × 10 / baud`. Type name `uart`.
    Uart,
    /// RS-485, timed as a full-duplex UART. Type name `rs485`.
    Rs485,
    /// An in-process link: always delivers at once. Type name `memory`.
    Memory,
}

impl LinkKind {
    /// The link type name reported to scans.
    pub fn type_name(self) -> &'static str {
        match self {
            LinkKind::Usb => "usb_cdc",
            LinkKind::Uart => "uart",
            LinkKind::Rs485 => "rs485",
            LinkKind::Memory => "memory",
        }
    }

    /// Whether a `baud` applies.
    pub fn has_baud(self) -> bool {
        matches!(self, LinkKind::Uart | LinkKind::Rs485)
    }
}

/// Default baud rate of UART and RS-485 links.
pub const DEFAULT_BAUD: u32 = 2_000_000;

/// One link between two modules, or a module and the host.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LinkSpec {
    /// One end: a module's name or `host`.
    pub a: String,
    /// The other end.
    pub b: String,
    /// What kind of link.
    pub kind: LinkKind,
    /// Baud rate (UART and RS-485 only; default 2 000 000).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub baud: Option<u32>,
    /// Largest packet, bytes (16..=256; default 256, a module's packet size).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mtu: Option<u16>,
    /// Instance name both ends report to scans (default empty).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub name: String,
}

impl LinkSpec {
    /// A link of `kind` between `a` and `b` with default settings.
    pub fn new(a: &str, b: &str, kind: LinkKind) -> Self {
        LinkSpec {
            a: a.to_string(),
            b: b.to_string(),
            kind,
            baud: None,
            mtu: None,
            name: String::new(),
        }
    }

    /// The baud rate in effect (UART and RS-485).
    pub fn baud(&self) -> u32 {
        self.baud.unwrap_or(DEFAULT_BAUD)
    }

    /// The MTU in effect.
    pub fn mtu(&self) -> u16 {
        self.mtu.unwrap_or(MODULE_MTU as u16)
    }
}

/// One end of a link, as a node of the machine's graph.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(crate) enum Node {
    Host,
    Module(usize),
}

/// A link seen from one of its ends: the node at the other end.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Hop {
    pub(crate) peer: Node,
}

/// The error a bad topology gives: invalid data, with `context` saying
/// which topology.
pub(crate) fn invalid(context: String, message: String) -> HostError {
    HostError::Io {
        context,
        source: std::io::Error::new(std::io::ErrorKind::InvalidData, message),
    }
}

impl Topology {
    /// An empty topology.
    pub fn new(name: &str) -> Self {
        Topology {
            name: name.to_string(),
            zero_latency: false,
            sync: true,
            seed: 0,
            modules: Vec::new(),
            links: Vec::new(),
        }
    }

    /// Adds a module.
    pub fn with_module(mut self, module: ModuleSpec) -> Self {
        self.modules.push(module);
        self
    }

    /// Adds a link.
    pub fn with_link(mut self, link: LinkSpec) -> Self {
        self.links.push(link);
        self
    }

    /// The same topology with every link at zero latency (or not).
    pub fn with_zero_latency(mut self, zero: bool) -> Self {
        self.zero_latency = zero;
        self
    }

    /// Parses and validates a topology written in TOML.
    pub fn parse(text: &str) -> Result<Topology, HostError> {
        Self::parse_as(text, "topology")
    }

    fn parse_as(text: &str, context: &str) -> Result<Topology, HostError> {
        let topology: Topology = toml::from_str(text)
            .map_err(|e| invalid(context.to_string(), e.to_string().trim_end().to_string()))?;
        topology
            .check()
            .map_err(|m| invalid(context.to_string(), m))?;
        Ok(topology)
    }

    /// Reads, parses and validates a topology file.
    pub fn load(path: impl AsRef<Path>) -> Result<Topology, HostError> {
        let path = path.as_ref();
        let context = format!("topology file {}", path.display());
        let text = std::fs::read_to_string(path).map_err(|source| HostError::Io {
            context: context.clone(),
            source,
        })?;
        Self::parse_as(&text, &context)
    }

    /// Checks the topology: unique module names of at most 31 bytes (and
    /// not `host`), links between known, distinct ends, valid link
    /// settings and clocks, at most 8 links on a module, at least one link
    /// to the host and every module reachable from it.
    pub fn validate(&self) -> Result<(), HostError> {
        self.check()
            .map_err(|m| invalid(format!("topology {:?}", self.name), m))
    }

    fn check(&self) -> Result<(), String> {
        if self.modules.is_empty() {
            return Err("no modules: add at least one [[module]]".into());
        }
        let mut names: HashMap<&str, usize> = HashMap::new();
        for (i, m) in self.modules.iter().enumerate() {
            let what = format!("module {} ({:?})", i + 1, m.name);
            check_name(&what, "name", &m.name)?;
            check_name(&what, "type", &m.type_name)?;
            if m.name == HOST {
                return Err(format!(
                    "{what}: the name {HOST:?} is reserved for the host runtime"
                ));
            }
            if names.insert(&m.name, i).is_some() {
                return Err(format!("{what}: another module is also named {:?}", m.name));
            }
            ClockSpec::fixed(m.offset_us, m.rate_ppm)
                .validate(&m.name)
                .map_err(|e| e.to_string())?;
            if !(m.wander_ppm.is_finite() && (0.0..=10_000.0).contains(&m.wander_ppm)) {
                return Err(format!("{what}: wander_ppm must be within [0, 10000]"));
            }
            if !(m.wander_period_s.is_finite() && m.wander_period_s > 0.0) {
                return Err(format!("{what}: wander_period_s must be positive"));
            }
            if let Some(axis) = &m.axis {
                if m.type_name != "axis" {
                    return Err(format!(
                        "{what}: an [module.axis] table is for modules of type \"axis\", not {:?}",
                        m.type_name
                    ));
                }
                axis.check().map_err(|e| format!("{what}: {e}"))?;
            }
        }
        let node = |name: &str| -> Option<Node> {
            if name == HOST {
                Some(Node::Host)
            } else {
                names.get(name).map(|&i| Node::Module(i))
            }
        };
        for (i, l) in self.links.iter().enumerate() {
            let what = format!("link {} ({} – {})", i + 1, l.a, l.b);
            for end in [&l.a, &l.b] {
                if node(end).is_none() {
                    return Err(format!("{what}: no module is named {end:?}"));
                }
            }
            if l.a == l.b {
                return Err(format!("{what}: a link must join two different runtimes"));
            }
            if let Some(baud) = l.baud {
                if !l.kind.has_baud() {
                    return Err(format!(
                        "{what}: baud applies to uart and rs485 links, not {:?}",
                        l.kind.type_name()
                    ));
                }
                if !(1_200..=50_000_000).contains(&baud) {
                    return Err(format!(
                        "{what}: baud {baud} must be within 1200..=50000000"
                    ));
                }
            }
            if let Some(mtu) = l.mtu {
                if !(16..=MODULE_MTU as u16).contains(&mtu) {
                    return Err(format!(
                        "{what}: mtu {mtu} must be within 16..={MODULE_MTU} (a module's packet size)"
                    ));
                }
            }
            if l.name.len() > NAME_MAX {
                return Err(format!(
                    "{what}: its name is {} bytes long; names are at most {NAME_MAX} bytes",
                    l.name.len()
                ));
            }
        }
        let adjacency = self.adjacency();
        for (i, m) in self.modules.iter().enumerate() {
            let n = adjacency[i + 1].len();
            if n > MODULE_LINKS {
                return Err(format!(
                    "module {:?} has {n} links; a simulated module has at most {MODULE_LINKS}",
                    m.name
                ));
            }
        }
        let host_links = adjacency[0].len();
        if host_links == 0 {
            return Err(format!(
                "no link joins a module to the host: add a [[link]] with a = {HOST:?}"
            ));
        }
        if host_links > MAX_HOST_LINKS {
            return Err(format!(
                "{host_links} links join the host; at most {MAX_HOST_LINKS} can"
            ));
        }
        let paths = self.paths();
        for (i, m) in self.modules.iter().enumerate() {
            if paths[i].is_none() {
                return Err(format!(
                    "module {:?} is not connected to the host through any links",
                    m.name
                ));
            }
        }
        Ok(())
    }

    /// The index of the module named `name`.
    pub fn module_index(&self, name: &str) -> Option<usize> {
        self.modules.iter().position(|m| m.name == name)
    }

    /// The positions in [`links`](Self::links) of the links of module
    /// `name` (or of `host`), in the order of its link indices.
    pub fn links_of(&self, name: &str) -> Vec<usize> {
        self.links
            .iter()
            .enumerate()
            .filter(|(_, l)| l.a == name || l.b == name)
            .map(|(i, _)| i)
            .collect()
    }

    pub(crate) fn node(&self, name: &str) -> Option<Node> {
        if name == HOST {
            Some(Node::Host)
        } else {
            self.module_index(name).map(Node::Module)
        }
    }

    /// Each node's links in order: index 0 is the host, module `i` is
    /// `i + 1`. Links naming an unknown end are left out.
    pub(crate) fn adjacency(&self) -> Vec<Vec<Hop>> {
        let slot = |n: Node| match n {
            Node::Host => 0,
            Node::Module(i) => i + 1,
        };
        let mut adj = vec![Vec::new(); self.modules.len() + 1];
        for l in &self.links {
            let (Some(a), Some(b)) = (self.node(&l.a), self.node(&l.b)) else {
                continue;
            };
            adj[slot(a)].push(Hop { peer: b });
            if a != b {
                adj[slot(b)].push(Hop { peer: a });
            }
        }
        adj
    }

    /// For each module, the shortest way there from the host (fewest hops;
    /// among equals, the one through earlier-listed links): at each node on
    /// the way, the position of the link taken in that node's own link
    /// list. `None` for modules the host cannot reach.
    pub(crate) fn paths(&self) -> Vec<Option<Vec<usize>>> {
        let adj = self.adjacency();
        let mut from: Vec<Option<(usize, usize)>> = vec![None; adj.len()];
        let mut seen = vec![false; adj.len()];
        seen[0] = true;
        let mut queue = VecDeque::from([0usize]);
        while let Some(n) = queue.pop_front() {
            for (k, hop) in adj[n].iter().enumerate() {
                let Node::Module(m) = hop.peer else { continue };
                if !seen[m + 1] {
                    seen[m + 1] = true;
                    from[m + 1] = Some((n, k));
                    queue.push_back(m + 1);
                }
            }
        }
        (1..adj.len())
            .map(|target| {
                if !seen[target] {
                    return None;
                }
                let mut hops = Vec::new();
                let mut n = target;
                while let Some((prev, k)) = from[n] {
                    hops.push(k);
                    n = prev;
                }
                hops.reverse();
                Some(hops)
            })
            .collect()
    }
}

fn check_name(what: &str, field: &str, value: &str) -> Result<(), String> {
    if value.is_empty() {
        return Err(format!("{what}: its {field} is empty"));
    }
    if value.len() > NAME_MAX {
        return Err(format!(
            "{what}: its {field} {value:?} is {} bytes long; names are at most {NAME_MAX} bytes",
            value.len()
        ));
    }
    Ok(())
}

/// Reads, parses and validates a topology file ([`Topology::load`]).
pub fn load(path: impl AsRef<Path>) -> Result<Topology, HostError> {
    Topology::load(path)
}
