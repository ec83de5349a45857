//! Simulated nodes: a real `osap_core` runtime with its simulated links,
//! its ports, its oscillator and its main-loop behaviour.

use crate::busy::{BusyModel, BusyState};
use crate::clock::{ClockModel, ClockSpec};
use crate::error::SimError;
use crate::link::SimLink;
use crate::rng::{Dist, Rng};
use crate::Nanos;
use osap_core::port::Port;
use osap_core::Instant;
use osap_core::Runtime;
use std::any::Any;

/// Packet slots of a simulated runtime.
pub const SLOTS: usize = 32;
/// Packet size of a simulated runtime, bytes.
pub const PACKET_SIZE: usize = 256;
/// Port quota entries of a simulated runtime (port 0 included).
pub const PORTS: usize = 8;
/// Most links one simulated node can have.
pub const MAX_LINKS: usize = 16;

/// The runtime every simulated node runs.
pub type SimRuntime = Runtime<SLOTS, PACKET_SIZE, PORTS, MAX_LINKS>;

/// What a node is: it sets the defaults of its main-loop latency and clock.
/// In a TOML topology's `[host]` table (`kind`), `"host"` or `"mcu"`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum NodeKind {
    /// A host process (an operating system schedules its loop).
    Host,
    /// A microcontroller module.
    Mcu,
}

impl NodeKind {
    /// The runtime type name reported to scans.
    pub fn type_name(self) -> &'static str {
        match self {
            NodeKind::Host => "sim_host",
            NodeKind::Mcu => "sim_module",
        }
    }
}

/// How one node is built.
#[derive(Debug, Clone, PartialEq)]
pub struct NodeSpec {
    /// Its name (unique in the topology; at most 31 bytes).
    pub name: String,
    /// Host or microcontroller.
    pub kind: NodeKind,
    /// Whether it is the clock root (tier 0).
    pub root: bool,
    /// Its oscillator.
    pub clock: ClockSpec,
    /// Time from an event (a frame arriving, a transmit buffer freeing, a
    /// due wake-up) until the main loop polls the runtime, µs.
    pub poll_latency: Dist,
    /// Busy spells, if any.
    pub busy: Option<BusyModel>,
}

impl NodeSpec {
    /// A microcontroller: loop latency U[2, 20] µs, a ±100 ppm crystal.
    pub fn mcu(name: &str) -> Self {
        NodeSpec {
            name: name.to_string(),
            kind: NodeKind::Mcu,
            root: false,
            clock: ClockSpec::MCU,
            poll_latency: Dist::uniform(2.0, 20.0),
            busy: None,
        }
    }

    /// A host process, the clock root: loop latency 10 µs + Exp(40 µs), a
    /// ±50 ppm clock.
    pub fn host(name: &str) -> Self {
        NodeSpec {
            name: name.to_string(),
            kind: NodeKind::Host,
            root: true,
            clock: ClockSpec::HOST,
            poll_latency: Dist::exp(10.0, 40.0),
            busy: None,
        }
    }

    /// The same node with `root` set as given.
    pub fn with_root(mut self, root: bool) -> Self {
        self.root = root;
        self
    }

    /// The same node with another oscillator.
    pub fn with_clock(mut self, clock: ClockSpec) -> Self {
        self.clock = clock;
        self
    }

    /// The same node with busy spells.
    pub fn with_busy(mut self, busy: Option<BusyModel>) -> Self {
        self.busy = busy;
        self
    }

    /// Checks the parameters.
    pub fn validate(&self) -> Result<(), SimError> {
        if self.name.is_empty() || self.name.len() > osap_core::netresponder::NAME_MAX {
            return Err(SimError::config(format!(
                "node name {:?} must be 1..={} bytes",
                self.name,
                osap_core::netresponder::NAME_MAX
            )));
        }
        if self.name.chars().any(char::is_whitespace) {
            return Err(SimError::config(format!(
                "node name {:?} must not contain whitespace",
                self.name
            )));
        }
        self.clock.validate(&self.name)?;
        self.poll_latency
            .validate(&format!("node {}: poll_latency", self.name))?;
        if let Some(b) = &self.busy {
            b.validate(&self.name)?;
        }
        Ok(())
    }
}

/// A port the simulator can hold and hand back by type: any [`Port`] that
/// is `'static` and `Send` is one.
pub trait SimPort: Port + Any + Send {
    /// As `Any`, to get the concrete port back.
    fn as_any(&self) -> &dyn Any;
    /// As `Any`, mutably.
    fn as_any_mut(&mut self) -> &mut dyn Any;
}

impl<T: Port + Any + Send> SimPort for T {
    fn as_any(&self) -> &dyn Any {
        self
    }
    fn as_any_mut(&mut self) -> &mut dyn Any {
        self
    }
}

/// One simulated node.
pub struct Node {
    pub(crate) spec: NodeSpec,
    pub(crate) runtime: SimRuntime,
    pub(crate) links: Vec<SimLink>,
    pub(crate) ports: Vec<Box<dyn SimPort>>,
    pub(crate) clock: ClockModel,
    pub(crate) busy: BusyState,
    /// Main-loop latency draws.
    pub(crate) rng: Rng,
    /// Identifies the one pending poll event; older ones are stale.
    pub(crate) poll_generation: u64,
    pub(crate) next_poll: Option<Nanos>,
    pub(crate) polls: u64,
}

impl std::fmt::Debug for Node {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Its parts are tasks, locks and buffers: the name says enough.
        f.debug_struct("Node").finish_non_exhaustive()
    }
}

impl Node {
    pub(crate) fn new(
        spec: NodeSpec,
        runtime: SimRuntime,
        clock: ClockModel,
        rng: Rng,
        busy: BusyState,
    ) -> Self {
        Node {
            spec,
            runtime,
            links: Vec::new(),
            ports: Vec::new(),
            clock,
            busy,
            rng,
            poll_generation: 0,
            next_poll: None,
            polls: 0,
        }
    }

    /// Its name.
    pub fn name(&self) -> &str {
        &self.spec.name
    }

    /// How it was built.
    pub fn spec(&self) -> &NodeSpec {
        &self.spec
    }

    /// Its runtime.
    pub fn runtime(&self) -> &SimRuntime {
        &self.runtime
    }

    /// Its runtime, mutably (configuration, hot start, sending from a port
    /// object outside a poll).
    pub fn runtime_mut(&mut self) -> &mut SimRuntime {
        &mut self.runtime
    }

    /// Its oscillator.
    pub fn clock(&self) -> &ClockModel {
        &self.clock
    }

    /// Its local µs counter at true time `t`.
    pub fn local_us(&self, t: Nanos) -> Instant {
        self.clock.local_us(t)
    }

    /// Its link gateways, in runtime link order.
    pub fn links(&self) -> &[SimLink] {
        &self.links
    }

    /// One of its link gateways, mutably (to open or close it).
    pub fn link_mut(&mut self, index: usize) -> Option<&mut SimLink> {
        self.links.get_mut(index)
    }

    /// Attaches a port; returns its runtime port index (ports number from 1
    /// in the order they are attached, port 0 being the netresponder).
    pub fn add_port(&mut self, port: Box<dyn SimPort>) -> u16 {
        let index = 1 + self.ports.iter().map(|p| p.port_count()).sum::<u16>();
        self.ports.push(port);
        index
    }

    /// The `k`-th attached port object, if it is a `T`.
    pub fn port<T: SimPort>(&self, k: usize) -> Option<&T> {
        // Deref the box first: `Box<dyn SimPort>` is itself a `SimPort`.
        let port: &dyn SimPort = self.ports.get(k)?.as_ref();
        port.as_any().downcast_ref()
    }

    /// The `k`-th attached port object, mutably, if it is a `T`.
    pub fn port_mut<T: SimPort>(&mut self, k: usize) -> Option<&mut T> {
        let port: &mut dyn SimPort = self.ports.get_mut(k)?.as_mut();
        port.as_any_mut().downcast_mut()
    }

    /// How many times its runtime has been polled.
    pub fn polls(&self) -> u64 {
        self.polls
    }

    /// Busy spells started so far.
    pub fn busy_spells(&self) -> u64 {
        self.busy.spells_started()
    }

    /// Draws one main-loop latency, ns.
    pub(crate) fn loop_latency(&mut self) -> Nanos {
        self.spec.poll_latency.sample_ns(&mut self.rng)
    }
}
