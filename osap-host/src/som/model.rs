//! The system object model: every runtime, link, function and pipe a
//! [`Manager`](super::Manager) found, serializable to JSON.
//!
//! The layout is the serde form of these types and is documented in
//! `docs/som.md`; [`SOM_VERSION`] changes whenever it does. It extends the
//! network map (`docs/network-map.md`): runtimes and links are the map's,
//! each runtime carries the PIPES functions found on its ports, and the
//! pipes are listed both per function (as configured) and flattened, source
//! → destination, at the top level.

use crate::error::JsonError;
use crate::map::{LinkEdge, NetworkMap, RuntimeRecord};
use osap_core::packet::Instruction;
use osap_core::route::Route;
use pipes_core::control::{InputMode, OutputMode};
use pipes_core::pipe::{PipeConfig, PipeDelivery};
use pipes_core::Type;
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;

/// Layout version of [`Som`].
pub const SOM_VERSION: u32 = 1;

/// Why [`Som::runtime_index`] found no one runtime by its name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum RuntimeLookupError {
    /// No runtime has the name.
    #[error("no runtime has this name")]
    NotFound,
    /// Several runtimes have the name.
    #[error("{count} runtimes have this name")]
    Ambiguous {
        /// How many have it (at least 2).
        count: usize,
    },
}

/// The system object model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Som {
    /// Layout version ([`SOM_VERSION`]).
    pub version: u32,
    /// The runtimes; index 0 is the host that built the model.
    pub runtimes: Vec<SomRuntime>,
    /// The links between runtimes, each once (as in the network map).
    pub links: Vec<LinkEdge>,
    /// Every configured pipe, source → destination.
    pub pipes: Vec<SomPipe>,
    /// The PIPES classes found (a port of type `pipes_class` each), by
    /// runtime then port. Their members are also listed among their
    /// runtime's functions.
    pub classes: Vec<SomClass>,
}

/// One runtime, as the network map has it, with its functions.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SomRuntime {
    /// What the scan found (JSON: the record's fields, inline).
    #[serde(flatten)]
    pub record: RuntimeRecord,
    /// The PIPES functions among its ports, by port index: the blocks made
    /// at run time too (they are functions like any other).
    pub functions: Vec<SomFunction>,
    /// The blocks made on it at run time, by slot (see
    /// [`pipes_core::manager`]); empty when it has no block manager.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub blocks: Vec<SomBlock>,
}

/// A block made on a runtime at run time: a function among its runtime's,
/// whose class its block manager knows.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct SomBlock {
    /// Its name (also its function's).
    pub name: String,
    /// Its class (`comparator`, `lowpass`, ...).
    pub class: String,
    /// Its slot in the manager's pool.
    pub slot: u8,
    /// Its control port's index.
    pub port: u16,
    /// The constructor's arguments it was made with, in order.
    #[serde(default)]
    pub arguments: Vec<SomBlockArgument>,
}

/// One constructor argument of a [`SomBlock`].
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct SomBlockArgument {
    /// The argument's name.
    pub name: String,
    /// Its type's name (`f32`, `bool`, ...).
    #[serde(rename = "type")]
    pub type_name: String,
    /// Its value as a person types it (`0.5`, `true`).
    pub value: String,
}

impl SomRuntime {
    /// Whether `function` is a block made at run time.
    pub fn is_block(&self, function: &SomFunction) -> bool {
        self.blocks.iter().any(|b| b.port == function.port)
    }

    /// The functions the runtime was built with: every function but its
    /// blocks (what a function-set id covers).
    pub fn built_functions(&self) -> impl Iterator<Item = &SomFunction> {
        self.functions.iter().filter(|f| !self.is_block(f))
    }

    /// The block manager's port, if the runtime has one.
    pub fn block_manager_port(&self) -> Option<u16> {
        self.record
            .ports
            .iter()
            .find(|p| p.type_name == pipes_core::manager::MANAGER_PORT_TYPE)
            .map(|p| p.index)
    }
}

/// A named, typed input or output.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct SomArg {
    /// Its name.
    pub name: String,
    /// Its type's name (`f32`, `arry_u8`, `utf8`, ..; see `docs/pipes.md`).
    #[serde(rename = "type")]
    pub type_name: String,
}

impl SomArg {
    /// The type, if the name is one this build knows.
    pub fn ty(&self) -> Option<Type> {
        Type::from_name(&self.type_name)
    }
}

/// When a function runs on dataflow (JSON: `{"mode": "on_any_fresh"}`,
/// `{"mode": "on_all_fresh"}`, `{"mode": "on_timer", "interval_us": 1000}`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "mode", rename_all = "snake_case")]
pub enum SomInputMode {
    /// Runs when a fresh value arrives and every input holds one.
    OnAnyFresh,
    /// Runs when every input is fresh.
    OnAllFresh,
    /// Runs every `interval_us` µs once every input holds a value.
    OnTimer {
        /// The interval, µs.
        interval_us: u32,
    },
}

impl From<InputMode> for SomInputMode {
    fn from(m: InputMode) -> Self {
        match m {
            InputMode::OnAnyFresh => SomInputMode::OnAnyFresh,
            InputMode::OnAllFresh => SomInputMode::OnAllFresh,
            InputMode::OnTimer(interval_us) => SomInputMode::OnTimer { interval_us },
        }
    }
}

impl From<SomInputMode> for InputMode {
    fn from(m: SomInputMode) -> Self {
        match m {
            SomInputMode::OnAnyFresh => InputMode::OnAnyFresh,
            SomInputMode::OnAllFresh => InputMode::OnAllFresh,
            SomInputMode::OnTimer { interval_us } => InputMode::OnTimer(interval_us),
        }
    }
}

/// When a function sends its outputs (JSON: `"always"` or `"on_change"`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SomOutputMode {
    /// After every run.
    Always,
    /// Only when the outputs changed.
    OnChange,
}

impl From<OutputMode> for SomOutputMode {
    fn from(m: OutputMode) -> Self {
        match m {
            OutputMode::Always => SomOutputMode::Always,
            OutputMode::OnChange => SomOutputMode::OnChange,
        }
    }
}

impl From<SomOutputMode> for OutputMode {
    fn from(m: SomOutputMode) -> Self {
        match m {
            SomOutputMode::Always => OutputMode::Always,
            SomOutputMode::OnChange => OutputMode::OnChange,
        }
    }
}

/// How a pipe delivers (JSON: `"best_effort"` or `"acked"`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SomDelivery {
    /// Send and forget.
    #[default]
    BestEffort,
    /// Acknowledged: each datagram is retransmitted until the destination
    /// replies or the retries run out (at least once; `docs/pipes.md` §5).
    Acked,
}

impl From<PipeDelivery> for SomDelivery {
    fn from(d: PipeDelivery) -> Self {
        match d {
            PipeDelivery::BestEffort => SomDelivery::BestEffort,
            PipeDelivery::Acked => SomDelivery::Acked,
        }
    }
}

impl From<SomDelivery> for PipeDelivery {
    fn from(d: SomDelivery) -> Self {
        match d {
            SomDelivery::BestEffort => PipeDelivery::BestEffort,
            SomDelivery::Acked => PipeDelivery::Acked,
        }
    }
}

/// One argmap pair: source output `output` → destination input `input`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct SomArgPair {
    /// The source function's output index.
    pub output: u8,
    /// The destination function's input index.
    pub input: u8,
}

/// Where a pipe ends: a runtime and a port in it, with the function found
/// there if there is one.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct SomEndpoint {
    /// The runtime's index in [`Som::runtimes`].
    pub runtime: usize,
    /// The runtime's name.
    pub runtime_name: String,
    /// The port index in that runtime.
    pub port: u16,
    /// The function whose control port that is (`None`: not a function).
    pub function: Option<String>,
}

/// A pipe as a function's slot holds it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct SomFunctionPipe {
    /// The slot.
    pub slot: u8,
    /// Link indices from the source runtime to the destination runtime.
    pub route: Vec<u8>,
    /// The route's MTU as configured.
    pub route_mtu: u16,
    /// The destination port.
    pub port: u16,
    /// Time-to-live of each datagram, µs.
    pub ttl_us: u16,
    /// How it delivers.
    pub delivery: SomDelivery,
    /// Which outputs go to which inputs.
    pub argmap: Vec<SomArgPair>,
    /// The destination, if the route leads to a runtime in the model
    /// (`None`: it leads off the map, or through a hop that is not a link).
    pub destination: Option<SomEndpoint>,
}

impl SomFunctionPipe {
    /// The pipe's wire configuration. `None` if the route is not valid.
    pub fn config(&self) -> Option<PipeConfig> {
        let route = Route::through_links(&self.route).ok()?;
        let mut p = PipeConfig::new(route.with_mtu(self.route_mtu), self.port, self.ttl_us)
            .with_delivery(self.delivery.into());
        for a in &self.argmap {
            p.map(a.output, a.input).ok()?;
        }
        Some(p)
    }
}

/// A PIPES function found on a runtime.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SomFunction {
    /// Its name (from its signature).
    pub name: String,
    /// The first sentence of its documentation, as it sent it
    /// (`pipes_core::docs`); empty if it has none or predates the docs.
    /// The whole text is read on demand
    /// ([`Manager::describe`](super::Manager::describe)).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub summary: String,
    /// Its control port's index.
    pub port: u16,
    /// The sending ports of its pipe slots, by slot (the `pipes_pipe`
    /// ports that follow the control port).
    pub pipe_ports: Vec<u16>,
    /// Its inputs, by index.
    pub inputs: Vec<SomArg>,
    /// Its outputs, by index.
    pub outputs: Vec<SomArg>,
    /// When it runs on dataflow.
    pub input_mode: SomInputMode,
    /// When it sends its outputs.
    pub output_mode: SomOutputMode,
    /// How many pipe slots it has.
    pub pipe_slots: u8,
    /// Its pipes, by slot (used slots only).
    pub pipes: Vec<SomFunctionPipe>,
}

/// A pipe in the flattened list: from a function's slot to a destination.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct SomPipe {
    /// The source function.
    pub source: SomEndpoint,
    /// Its slot.
    pub slot: u8,
    /// The destination, if resolved (see [`SomFunctionPipe::destination`]).
    pub destination: Option<SomEndpoint>,
    /// Link indices from the source runtime.
    pub route: Vec<u8>,
    /// Which outputs go to which inputs.
    pub argmap: Vec<SomArgPair>,
    /// Time-to-live, µs.
    pub ttl_us: u16,
    /// How it delivers.
    pub delivery: SomDelivery,
}

/// A PIPES class found on a runtime: its class port (which answers the
/// function protocol with the constructor) and its members, the functions
/// of the same runtime named `"<name>.<member>"`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct SomClass {
    /// The runtime's index in [`Som::runtimes`].
    pub runtime: usize,
    /// The class's name (its port's name and its constructor's).
    pub name: String,
    /// Its member functions' names (`"<name>.<member>"`, as in the
    /// runtime's [`functions`](SomRuntime::functions)), in port order.
    pub members: Vec<String>,
    /// The class port's index in its runtime. Absent from layouts written
    /// before classes were found (read as 0).
    #[serde(default)]
    pub port: u16,
    /// The constructor's inputs, by index (it has no outputs). Absent from
    /// layouts written before classes were found (read as empty).
    #[serde(default)]
    pub constructor: Vec<SomArg>,
}

/// A path between two runtimes: link indices walked from the first, and
/// the largest packet that may travel it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Path {
    /// Link indices, each as seen from the runtime it leaves.
    pub links: Vec<u8>,
    /// Runtimes visited, first and last included.
    pub runtimes: Vec<usize>,
    /// Smallest of the link MTUs crossed and the packet sizes of the
    /// runtimes visited.
    pub mtu: u16,
}

impl Path {
    /// As a route with its MTU. `None` if it is longer than a route can be.
    pub fn route(&self) -> Option<Route> {
        Route::through_links(&self.links)
            .ok()
            .map(|r| r.with_mtu(self.mtu))
    }
}

impl Som {
    /// A model of the runtimes and links of `map`, without functions.
    pub fn from_map(map: &NetworkMap) -> Som {
        Som {
            version: SOM_VERSION,
            runtimes: map
                .runtimes
                .iter()
                .map(|r| SomRuntime {
                    record: r.clone(),
                    functions: Vec::new(),
                    blocks: Vec::new(),
                })
                .collect(),
            links: map.links.clone(),
            pipes: Vec::new(),
            classes: Vec::new(),
        }
    }

    /// An empty model (nothing scanned yet).
    pub fn empty() -> Som {
        Som {
            version: SOM_VERSION,
            runtimes: Vec::new(),
            links: Vec::new(),
            pipes: Vec::new(),
            classes: Vec::new(),
        }
    }

    /// As pretty JSON.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).unwrap_or_default()
    }

    /// From JSON, checking the layout version.
    ///
    /// Errors: [`JsonError::Json`] for text that is not a model's JSON,
    /// [`JsonError::Version`] for a model of another layout version.
    pub fn from_json(text: &str) -> Result<Som, JsonError> {
        let som: Som = serde_json::from_str(text)?;
        if som.version != SOM_VERSION {
            return Err(JsonError::Version {
                what: "system object model",
                found: som.version,
                supported: SOM_VERSION,
            });
        }
        Ok(som)
    }

    /// The index of the runtime named `name`.
    ///
    /// Errors: [`RuntimeLookupError::NotFound`] when no runtime has the
    /// name, [`RuntimeLookupError::Ambiguous`] when several do.
    pub fn runtime_index(&self, name: &str) -> Result<usize, RuntimeLookupError> {
        let mut found = self
            .runtimes
            .iter()
            .enumerate()
            .filter(|(_, r)| r.record.name == name);
        match (found.next(), found.next()) {
            (Some((i, _)), None) => Ok(i),
            (None, _) => Err(RuntimeLookupError::NotFound),
            (Some(_), Some(_)) => Err(RuntimeLookupError::Ambiguous {
                count: 2 + found.count(),
            }),
        }
    }

    /// The class named `class` on runtime `runtime`.
    pub fn class(&self, runtime: usize, class: &str) -> Option<&SomClass> {
        self.classes
            .iter()
            .find(|c| c.runtime == runtime && c.name == class)
    }

    /// The function named `function` on runtime `runtime`.
    pub fn function(&self, runtime: usize, function: &str) -> Option<&SomFunction> {
        self.runtimes
            .get(runtime)?
            .functions
            .iter()
            .find(|f| f.name == function)
    }

    /// The runtime one link away from `runtime` through its link `link`.
    pub fn neighbour(&self, runtime: usize, link: u8) -> Option<(usize, u8)> {
        self.links.iter().find_map(|e| {
            if e.a.runtime == runtime && e.a.link == link {
                Some((e.b.runtime, e.b.link))
            } else if e.b.runtime == runtime && e.b.link == link {
                Some((e.a.runtime, e.a.link))
            } else {
                None
            }
        })
    }

    fn link_mtu(&self, runtime: usize, link: u8) -> u16 {
        self.runtimes
            .get(runtime)
            .and_then(|r| r.record.links.iter().find(|l| l.index == link))
            .map_or(u16::MAX, |l| l.mtu)
    }

    fn link_open(&self, runtime: usize, link: u8) -> bool {
        self.runtimes
            .get(runtime)
            .and_then(|r| r.record.links.iter().find(|l| l.index == link))
            .is_none_or(|l| l.open)
    }

    /// The shortest path (in hops) from runtime `from` to runtime `to` over
    /// the model's open links, walked from `from` (so link indices are as
    /// `from` and each runtime after it see them). Among paths of equal
    /// length the first found in link order wins. `None` if `to` cannot be
    /// reached.
    pub fn path(&self, from: usize, to: usize) -> Option<Path> {
        let n = self.runtimes.len();
        if from >= n || to >= n {
            return None;
        }
        // prev[r] = (runtime before r, link taken from it, link arrived on).
        let mut prev: Vec<Option<(usize, u8, u8)>> = vec![None; n];
        let mut seen = vec![false; n];
        seen[from] = true;
        let mut queue = VecDeque::from([from]);
        while let Some(r) = queue.pop_front() {
            if r == to {
                break;
            }
            let mut out: Vec<(u8, usize, u8)> = self
                .links
                .iter()
                .filter_map(|e| {
                    if e.a.runtime == r {
                        Some((e.a.link, e.b.runtime, e.b.link))
                    } else if e.b.runtime == r {
                        Some((e.b.link, e.a.runtime, e.a.link))
                    } else {
                        None
                    }
                })
                .filter(|(l, next, back)| self.link_open(r, *l) && self.link_open(*next, *back))
                .collect();
            out.sort_unstable();
            for (l, next, back) in out {
                if next < n && !seen[next] {
                    seen[next] = true;
                    prev[next] = Some((r, l, back));
                    queue.push_back(next);
                }
            }
        }
        if !seen[to] {
            return None;
        }
        let mut links = Vec::new();
        let mut runtimes = vec![to];
        let mut mtu = self.runtimes[to].record.packet_size;
        let mut at = to;
        while at != from {
            let (p, l, back) = prev[at]?;
            links.push(l);
            runtimes.push(p);
            mtu = mtu
                .min(self.link_mtu(p, l))
                .min(self.link_mtu(at, back))
                .min(self.runtimes[p].record.packet_size);
            at = p;
        }
        links.reverse();
        runtimes.reverse();
        Some(Path {
            links,
            runtimes,
            mtu,
        })
    }

    /// Where `route` leads when walked from runtime `from`: the runtime
    /// reached, or `None` if a hop is not a link in the model.
    pub fn walk(&self, from: usize, route: &[u8]) -> Option<usize> {
        let mut at = from;
        for &l in route {
            at = self.neighbour(at, l)?.0;
        }
        Some(at)
    }

    /// The endpoint at port `port` of runtime `runtime`.
    pub fn endpoint(&self, runtime: usize, port: u16) -> Option<SomEndpoint> {
        let r = self.runtimes.get(runtime)?;
        Some(SomEndpoint {
            runtime,
            runtime_name: r.record.name.clone(),
            port,
            function: r
                .functions
                .iter()
                .find(|f| f.port == port)
                .map(|f| f.name.clone()),
        })
    }

    /// Resolves every pipe's destination from its route and rebuilds the
    /// flattened [`pipes`](Som::pipes) list from the functions' slots.
    pub fn resolve_pipes(&mut self) {
        let mut flat = Vec::new();
        let mut resolved = Vec::new();
        for (ri, r) in self.runtimes.iter().enumerate() {
            for (fi, f) in r.functions.iter().enumerate() {
                for (pi, p) in f.pipes.iter().enumerate() {
                    let dest = self
                        .walk(ri, &p.route)
                        .and_then(|d| self.endpoint(d, p.port));
                    resolved.push((ri, fi, pi, dest.clone()));
                    flat.push(SomPipe {
                        source: SomEndpoint {
                            runtime: ri,
                            runtime_name: r.record.name.clone(),
                            port: f.port,
                            function: Some(f.name.clone()),
                        },
                        slot: p.slot,
                        destination: dest,
                        route: p.route.clone(),
                        argmap: p.argmap.clone(),
                        ttl_us: p.ttl_us,
                        delivery: p.delivery,
                    });
                }
            }
        }
        for (ri, fi, pi, dest) in resolved {
            if let Some(p) = self
                .runtimes
                .get_mut(ri)
                .and_then(|r| r.functions.get_mut(fi))
                .and_then(|f| f.pipes.get_mut(pi))
            {
                p.destination = dest;
            }
        }
        self.pipes = flat;
    }
}

/// A pipe's route as link indices; `None` if a hop is not a link.
pub(crate) fn route_links(route: &Route) -> Option<Vec<u8>> {
    route
        .hops()
        .map(|h| match h {
            Instruction::LinkForward(l) => Some(l),
            _ => None,
        })
        .collect()
}

/// The model's record of a pipe read from slot `slot`.
pub(crate) fn pipe_record(slot: u8, config: &PipeConfig) -> Option<SomFunctionPipe> {
    Some(SomFunctionPipe {
        slot,
        route: route_links(&config.route)?,
        route_mtu: config.route.mtu(),
        port: config.port,
        ttl_us: config.ttl,
        delivery: config.delivery.into(),
        argmap: config
            .argmap()
            .iter()
            .map(|a| SomArgPair {
                output: a.output,
                input: a.input,
            })
            .collect(),
        destination: None,
    })
}
