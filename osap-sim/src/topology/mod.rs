//! The one description of a simulated network and machine, read by both
//! simulators: a [`SimSpec`] says which modules there are, how they are
//! linked to each other and to the host, what their boards carry (motor,
//! I/O, bootloader), which switches and bed a machine has, and how the
//! discrete-event simulator runs the host. The real-time simulated machines
//! ([`crate::machine::SimMachine`]) start from one; the discrete-event
//! simulator lowers one into its [`Network`](crate::network::Network)
//! ([`Network::from_spec`](crate::network::Network::from_spec),
//! [`Scenario::from_spec`](crate::Scenario::from_spec)). A machine file's
//! simulation (osap-machine's `sim` module) derives one, and topology files
//! (`osap-sim/topologies/*.toml`) are one written in TOML; the format is
//! described in the [`machine`](crate::machine) module docs.
//!
//! The spec is plain data with its checks; it imports neither simulator.

mod bed;
mod board;
mod bus_tree;
mod check;
mod error;
pub(crate) mod graph;
mod host;
mod spindle;
mod winch;

pub use bed::{BedContact, BedSurface};
pub use board::{
    AccelSpec, BoardError, BootloaderSpec, Chip, ContactSpec, HeaterSpec, IoSpec, MeltSpec,
    MotorSpec, RotorSpec, ANALOG_INPUTS, DIGITAL_PINS, DRIVER_MICROSTEPS, PWM_OUTPUTS,
};
pub use bus_tree::bus_tree;
pub use error::SpecError;
pub use host::{ClockSource, HostSpec};
pub use spindle::SpindleSpec;
pub use winch::{SpoolSpec, WinchSpec};

use check::{invalid, item_line};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Packet slots of a simulated module's runtime: the firmware's
/// ([`osap_module::sizes::SLOTS`]).
pub const MODULE_SLOTS: usize = osap_module::sizes::SLOTS;
/// Packet size of a simulated module: the firmware's
/// ([`osap_module::sizes::MTU`]).
pub const MODULE_MTU: usize = osap_module::sizes::MTU;
/// Port indices of a simulated module (port 0 included): every index the
/// module firmware's ports take ([`osap_module::sizes::PORTS`]).
pub const MODULE_PORTS: usize = osap_module::sizes::PORTS;
/// Link gateways of a simulated module: room for a simulated hub's; a
/// `stepper` uses the firmware's [`FIRMWARE_LINKS`]. (Quotas are per link
/// and per port, not per gateway, so the unused room changes nothing.)
pub const MODULE_LINKS: usize = 8;
/// Link gateways of the module firmware: USB CDC (link 0) and a UART
/// (link 1) ([`osap_module::sizes::LINKS`]).
pub const FIRMWARE_LINKS: usize = osap_module::sizes::LINKS;

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

/// A simulated machine or network: modules and the links between them
/// and the host (see the [module docs](self)).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimSpec {
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
    /// behaves the same from run to run. The discrete-event simulator's
    /// [`Scenario::from_spec`](crate::Scenario::from_spec) takes it
    /// as the run's seed.
    #[serde(default)]
    pub seed: u64,
    /// DES only: how the discrete-event simulator runs the host (`[host]`).
    #[serde(default, skip_serializing_if = "is_default")]
    pub host: HostSpec,
    /// The modules, `[[module]]` in a file.
    #[serde(rename = "module", default)]
    pub modules: Vec<ModuleSpec>,
    /// The links, `[[link]]` in a file. A module's link indices follow the
    /// order its links are listed here.
    #[serde(rename = "link", default)]
    pub links: Vec<LinkSpec>,
    /// Limit switches over several motors, `[[switch]]` in a file: each on
    /// a `stepper`'s limit input, pressed by a linear form of carriage
    /// positions.
    #[serde(rename = "switch", default, skip_serializing_if = "Vec::is_empty")]
    pub switches: Vec<SwitchSpec>,
    /// RS-485 buses, `[[bus]]` in a file: one head module and its drops on
    /// one shared pair (see `osap_core::bus`).
    #[serde(rename = "bus", default, skip_serializing_if = "Vec::is_empty")]
    pub buses: Vec<BusSpec>,
    /// A cable robot's world, `[winch]` in a file: a point mass on cables
    /// wound on steppers' spools (see [`WinchSpec`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub winch: Option<WinchSpec>,
}

fn default_bus_baud() -> u32 {
    1_000_000
}

/// An RS-485 bus, `[[bus]]` in a topology file: the `head` module polls
/// the `drops`, which get drop addresses 1, 2, ... in list order. The bus
/// is a link of each of them, numbered after the module's `[[link]]`s (a
/// `stepper` has it as its UART, link 1).
///
/// ```toml
/// [[bus]]
/// head = "hub"
/// drops = ["a", "b", "c"]
/// baud = 1000000
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BusSpec {
    /// Instance name reported to scans.
    #[serde(default)]
    pub name: String,
    /// The module that polls the bus (drop 0).
    pub head: String,
    /// The drop modules, drop addresses 1.. in order.
    pub drops: Vec<String>,
    /// Bits per second on the pair (10 bits per byte).
    #[serde(default = "default_bus_baud")]
    pub baud: u32,
}

impl BusSpec {
    /// The stations (head first) with their drop addresses.
    pub fn stations(&self) -> impl Iterator<Item = (&str, u8)> {
        std::iter::once((self.head.as_str(), 0)).chain(
            self.drops
                .iter()
                .enumerate()
                .map(|(i, d)| (d.as_str(), (i + 1).min(254) as u8)),
        )
    }
}

/// A limit switch over several motors, `[[switch]]` in a topology file: on
/// module `module`'s limit input, pressed while
///
/// ```text
/// Σ coef·(carriage position of that module's motor) + offset ≤ at
/// ```
///
/// (`pressed_below`; else `≥ at`). A CoreXY machine's x endstop, wired to
/// module a's input, with x = (a + b) / 2 and the carriage at x = 100 when
/// both carriages read 0: `terms = [["a", 0.5], ["b", 0.5]]`,
/// `offset = 100`, `at = 0`, `pressed_below = true`.
///
/// Like a switch on the module's own motor ([`MotorSpec::limit_min`]) the
/// input reads high released and low pressed, the module reads the level
/// at boot (`limit_initial`) and is handed each edge with its time on its
/// own clock (`limit_changed`), stamped with the tick of the step that
/// made the form cross. Several switches on one module are wired in
/// parallel: the input is low while any is pressed. A module with a
/// `[[switch]]` has no `limit_min`/`limit_max` on its motor.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SwitchSpec {
    /// The `stepper` whose limit input the switch is wired to.
    pub module: String,
    /// The form's terms: a `stepper` module (its motor's carriage position,
    /// units) and its coefficient, e.g. `[["a", 0.5], ["b", 0.5]]`.
    pub terms: Vec<(String, f64)>,
    /// Added to the form (default 0).
    #[serde(default, skip_serializing_if = "is_default")]
    pub offset: f64,
    /// Where the switch closes.
    pub at: f64,
    /// Pressed while the form is at or below `at` (a minimum endstop);
    /// `false`: at or above it.
    pub pressed_below: bool,
    /// A bed probe: the switch closes at `at` plus the bed's height under
    /// the probe tip ([`BedContact`]); absent: at
    /// `at`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bed: Option<BedContact>,
}

impl SwitchSpec {
    /// A switch on `module`'s input pressed while `Σ coef·position + offset`
    /// is at or below `at` (`pressed_below`) or at or above it.
    pub fn new(
        module: &str,
        terms: &[(&str, f64)],
        offset: f64,
        at: f64,
        pressed_below: bool,
    ) -> Self {
        SwitchSpec {
            module: module.to_string(),
            terms: terms.iter().map(|(m, c)| (m.to_string(), *c)).collect(),
            offset,
            at,
            pressed_below,
            bed: None,
        }
    }

    /// The form's value with carriages at `position(module)`.
    pub fn value(&self, mut position: impl FnMut(&str) -> f64) -> f64 {
        self.offset + self.terms.iter().map(|(m, c)| c * position(m)).sum::<f64>()
    }

    /// Whether the switch is pressed with carriages at `position(module)`.
    pub fn pressed(&self, mut position: impl FnMut(&str) -> f64) -> bool {
        let v = self.value(&mut position);
        let at = self.at + self.bed.as_ref().map_or(0.0, |b| b.height(&mut position));
        if self.pressed_below {
            v <= at
        } else {
            v >= at
        }
    }
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
    /// A `stepper` module's motor and what it drives (defaults when
    /// absent).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub motor: Option<MotorSpec>,
    /// What a `stepper` module's I/O pins read at boot (defaults when
    /// absent).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub io: Option<IoSpec>,
    /// A `stepper` module's UF2 bootloader (`[module.bootloader]`): with
    /// one, `enter_bootloader` takes the module off the network and shows
    /// its drive (see [`bootloader`](crate::machine::board::bootloader)); without,
    /// `enter_bootloader` refuses, as on a board that has none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bootloader: Option<BootloaderSpec>,
    /// DES only: this module is the clock root (tier 0) instead of the host;
    /// at most one module may be.
    #[serde(default, skip_serializing_if = "is_default")]
    pub root: bool,
    /// DES only: busy spells ([`crate::busy::BusyModel::MOTOR`]: motor
    /// control that holds off the main loop and delays receive stamps).
    #[serde(default, skip_serializing_if = "is_default")]
    pub busy: bool,
    /// DES only: where its oscillator comes from (default `"fixed"`: the
    /// values above).
    #[serde(default, skip_serializing_if = "is_default")]
    pub clock: ClockSource,
    /// Simulated machines only, `stepper` only: its UART (link 1), which
    /// no `[[link]]` joins, is open with nothing at the other end, as on a
    /// board whose UART is not wired (a UART cannot tell); what it sends
    /// is lost. Default false: a firmware link nothing joins stays closed.
    #[serde(default, skip_serializing_if = "is_default")]
    pub dangling_uart: bool,
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
            motor: None,
            io: None,
            bootloader: None,
            root: false,
            busy: false,
            clock: ClockSource::Fixed,
            dangling_uart: false,
        }
    }

    /// The same module with motor `motor` (a `stepper`).
    pub fn with_motor(mut self, motor: MotorSpec) -> Self {
        self.motor = Some(motor);
        self
    }

    /// The same module with I/O pins reading `io` at boot (a `stepper`).
    pub fn with_io(mut self, io: IoSpec) -> Self {
        self.io = Some(io);
        self
    }

    /// The same module with a UF2 bootloader (a `stepper`).
    pub fn with_bootloader(mut self, bootloader: BootloaderSpec) -> Self {
        self.bootloader = Some(bootloader);
        self
    }

    /// What kind of module it is, if its type is one the simulator has.
    pub fn kind(&self) -> Option<ModuleKind> {
        ModuleKind::of(&self.type_name)
    }

    /// The same `stepper` with its UART open and joined to nothing
    /// ([`dangling_uart`](Self::dangling_uart)).
    pub fn with_dangling_uart(mut self) -> Self {
        self.dangling_uart = true;
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

/// The module types a topology may use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ModuleKind {
    /// `stepper`: the osap-rs module firmware (osap-module's logic, the 19
    /// functions a scan finds on every board) on a simulated board. Its
    /// links follow the firmware's: a `usb` link is its link 0, a `uart` or
    /// `rs485` link its link 1.
    Stepper,
    /// `hub`: a router with up to 8 links and no functions. Host-only: no
    /// firmware build exists for it (any module forwards between its
    /// links; a hub stands for a USB or RS-485 fan-out).
    Hub,
}

impl ModuleKind {
    /// The kind a type name stands for.
    pub fn of(type_name: &str) -> Option<ModuleKind> {
        match type_name {
            "stepper" => Some(ModuleKind::Stepper),
            "hub" => Some(ModuleKind::Hub),
            _ => None,
        }
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
    /// DES only: probability that a frame is lost, `[0, 1]` (not on
    /// `memory` links).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub loss: Option<f64>,
    /// DES only, UART and RS-485: random extra latency of each frame,
    /// uniform in `[0, jitter_us]` µs (frames never overtake).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub jitter_us: Option<f64>,
    /// DES only, UART and RS-485: probability that a byte is corrupted (one
    /// bit flipped), `[0, 1]`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub corrupt_per_byte: Option<f64>,
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
            loss: None,
            jitter_us: None,
            corrupt_per_byte: None,
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

impl SimSpec {
    /// An empty topology.
    pub fn new(name: &str) -> Self {
        SimSpec {
            name: name.to_string(),
            zero_latency: false,
            sync: true,
            seed: 0,
            host: HostSpec::default(),
            modules: Vec::new(),
            links: Vec::new(),
            switches: Vec::new(),
            buses: Vec::new(),
            winch: None,
        }
    }

    /// Adds a bus.
    pub fn with_bus(mut self, bus: BusSpec) -> Self {
        self.buses.push(bus);
        self
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

    /// Adds a limit switch over several motors.
    pub fn with_switch(mut self, switch: SwitchSpec) -> Self {
        self.switches.push(switch);
        self
    }

    /// The same topology with every link at zero latency (or not).
    pub fn with_zero_latency(mut self, zero: bool) -> Self {
        self.zero_latency = zero;
        self
    }

    /// Parses and validates a topology written in TOML.
    pub fn parse(text: &str) -> Result<SimSpec, SpecError> {
        Self::parse_as(text, "topology")
    }

    fn parse_as(text: &str, context: &str) -> Result<SimSpec, SpecError> {
        let topology: SimSpec = toml::from_str(text)
            .map_err(|e| invalid(context.to_string(), e.to_string().trim_end().to_string()))?;
        topology.check().map_err(|e| {
            let at = e
                .item
                .and_then(|item| item_line(text, item))
                .map(|line| format!(", line {line}"))
                .unwrap_or_default();
            invalid(format!("{context}{at}"), e.message)
        })?;
        Ok(topology)
    }

    /// Reads, parses and validates a topology file.
    pub fn load(path: impl AsRef<Path>) -> Result<SimSpec, SpecError> {
        let path = path.as_ref();
        let context = format!("topology file {}", path.display());
        let text = std::fs::read_to_string(path).map_err(|source| SpecError::Read {
            context: context.clone(),
            source,
        })?;
        Self::parse_as(&text, &context)
    }

    /// Checks the topology: unique module names of at most 31 bytes (and
    /// not `host`), links between known, distinct ends, valid link
    /// settings and clocks, at most 8 links on a module, at least one link
    /// to the host and every module reachable from it, and switches over
    /// motors on and over `stepper` modules, with finite numbers.
    pub fn validate(&self) -> Result<(), SpecError> {
        self.check()
            .map_err(|e| invalid(format!("topology {:?}", self.name), e.message))
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
}

/// Reads, parses and validates a topology file ([`SimSpec::load`]).
pub fn load(path: impl AsRef<Path>) -> Result<SimSpec, SpecError> {
    SimSpec::load(path)
}
