//! Topology files: which simulated modules a machine has and how they are
//! linked. The format is described in the [module docs](super).

use super::board::bootloader::BootloaderSpec;
use super::board::{IoSpec, MotorSpec};
use super::module::{FIRMWARE_LINKS, MODULE_LINKS, MODULE_MTU};
use crate::clock::ClockSpec;
use crate::from_machine::{ClockSource, HostSpec};
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
    /// behaves the same from run to run. The discrete-event simulator's
    /// [`Scenario::from_machine`](crate::Scenario::from_machine) takes it
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
    /// the probe tip ([`BedContact`](super::bed::BedContact)); absent: at
    /// `at`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bed: Option<super::bed::BedContact>,
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
    /// its drive (see [`bootloader`](super::board::bootloader)); without,
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

/// One end of a link, as a node of the machine's graph.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(crate) enum Node {
    Host,
    Module(usize),
}

/// A link seen from one of its ends: the node at the other end, and the
/// link's index among this end's link gateways.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Hop {
    pub(crate) peer: Node,
    pub(crate) index: usize,
    /// Across a bus: the peer's drop address.
    pub(crate) drop: Option<u8>,
}

/// Which firmware link a link of `kind` is on a `stepper`.
pub(crate) fn firmware_link(kind: LinkKind) -> Option<usize> {
    match kind {
        LinkKind::Usb => Some(0),
        LinkKind::Uart | LinkKind::Rs485 => Some(1),
        LinkKind::Memory => None,
    }
}

/// What a topology check failed on.
#[derive(Debug, Clone, Copy)]
enum Item {
    Module(usize),
    Link(usize),
    Switch(usize),
}

struct CheckError {
    item: Option<Item>,
    message: String,
}

impl CheckError {
    fn file(message: String) -> Self {
        CheckError {
            item: None,
            message,
        }
    }

    fn at(item: Item, message: String) -> Self {
        CheckError {
            item: Some(item),
            message,
        }
    }
}

/// The line (from 1) of `item`'s `[[module]]` or `[[link]]` header in a
/// topology file's `text`.
fn item_line(text: &str, item: Item) -> Option<usize> {
    let (header, n) = match item {
        Item::Module(i) => ("[[module]]", i),
        Item::Link(i) => ("[[link]]", i),
        Item::Switch(i) => ("[[switch]]", i),
    };
    text.lines()
        .enumerate()
        .filter(|(_, l)| l.split('#').next().unwrap_or("").trim() == header)
        .nth(n)
        .map(|(line, _)| line + 1)
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
            host: HostSpec::default(),
            modules: Vec::new(),
            links: Vec::new(),
            switches: Vec::new(),
            buses: Vec::new(),
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
    pub fn parse(text: &str) -> Result<Topology, HostError> {
        Self::parse_as(text, "topology")
    }

    fn parse_as(text: &str, context: &str) -> Result<Topology, HostError> {
        let topology: Topology = toml::from_str(text)
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
    /// to the host and every module reachable from it, and switches over
    /// motors on and over `stepper` modules, with finite numbers.
    pub fn validate(&self) -> Result<(), HostError> {
        self.check()
            .map_err(|e| invalid(format!("topology {:?}", self.name), e.message))
    }

    fn check(&self) -> Result<(), CheckError> {
        self.check_modules()?;
        self.check_links()?;
        self.check_switches()?;
        self.check_graph().map_err(CheckError::file)
    }

    fn check_switches(&self) -> Result<(), CheckError> {
        for (i, s) in self.switches.iter().enumerate() {
            let at = |message: String| CheckError::at(Item::Switch(i), message);
            let what = format!("switch {} (on {:?})", i + 1, s.module);
            let stepper = |key: &str, name: &str| -> Result<(), CheckError> {
                match self.module_index(name).map(|m| &self.modules[m]) {
                    None => Err(at(format!(
                        "{what}: {key}: no module is named {name:?}; name one of: {}",
                        self.known_stepper_names()
                    ))),
                    Some(m) if m.kind() != Some(ModuleKind::Stepper) => Err(at(format!(
                        "{what}: {key}: module {name:?} is a {:?}; a switch is on, and over, modules of type \"stepper\" (with a limit input and a motor)",
                        m.type_name
                    ))),
                    Some(_) => Ok(()),
                }
            };
            stepper("module", &s.module)?;
            if let Some(motor) = self
                .module_index(&s.module)
                .and_then(|m| self.modules[m].motor.as_ref())
            {
                let own = match (motor.limit_min, motor.limit_max) {
                    (Some(_), _) => Some("limit_min"),
                    (None, Some(_)) => Some("limit_max"),
                    _ => None,
                };
                if let Some(key) = own {
                    return Err(at(format!(
                        "{what}: module: {:?} already has a switch on its own motor ({key} in its [module.motor]) and a module has one limit input; remove {key} and give that switch as a [[switch]] with terms = [[{:?}, 1.0]]",
                        s.module, s.module
                    )));
                }
            }
            if s.terms.is_empty() {
                return Err(at(format!(
                    "{what}: terms is empty; list [module, coefficient] pairs, e.g. terms = [[\"a\", 0.5], [\"b\", 0.5]]"
                )));
            }
            for (k, (module, coef)) in s.terms.iter().enumerate() {
                let key = format!("terms[{k}]");
                stepper(&key, module)?;
                if !(coef.is_finite() && *coef != 0.0) {
                    return Err(at(format!(
                        "{what}: {key}: coefficient {coef} must be finite and not zero; drop the term or give its weight"
                    )));
                }
                if let Some(first) = s.terms[..k].iter().position(|(m, _)| m == module) {
                    return Err(at(format!(
                        "{what}: {key}: module {module:?} is already terms[{first}]; add the coefficients into one term"
                    )));
                }
            }
            for (key, v) in [("offset", s.offset), ("at", s.at)] {
                if !v.is_finite() {
                    return Err(at(format!("{what}: {key} {v} must be finite")));
                }
            }
            if let Some(bed) = &s.bed {
                for module in bed.modules() {
                    stepper("bed", module)?;
                }
                bed.check().map_err(|e| at(format!("{what}: {e}")))?;
            }
        }
        Ok(())
    }

    fn known_stepper_names(&self) -> String {
        let names: Vec<String> = self
            .modules
            .iter()
            .filter(|m| m.kind() == Some(ModuleKind::Stepper))
            .map(|m| format!("{:?}", m.name))
            .collect();
        if names.is_empty() {
            "(no stepper modules)".into()
        } else {
            names.join(", ")
        }
    }

    fn check_modules(&self) -> Result<(), CheckError> {
        if self.modules.is_empty() {
            return Err(CheckError::file(
                "no modules: add at least one [[module]]".into(),
            ));
        }
        let mut names: HashMap<&str, usize> = HashMap::new();
        let mut root: Option<usize> = None;
        for (i, m) in self.modules.iter().enumerate() {
            let at = |message: String| CheckError::at(Item::Module(i), message);
            let what = format!("module {} ({:?})", i + 1, m.name);
            check_name(&what, "name", &m.name).map_err(at)?;
            check_name(&what, "type", &m.type_name).map_err(at)?;
            if m.name == HOST {
                return Err(at(format!(
                    "{what}: the name {HOST:?} is reserved for the host runtime; rename the module"
                )));
            }
            if let Some(first) = names.insert(&m.name, i) {
                return Err(at(format!(
                    "{what}: module {} is also named {:?}; give each module its own name",
                    first + 1,
                    m.name
                )));
            }
            let Some(kind) = m.kind() else {
                let hint = if m.type_name == "axis" {
                    " (an \"axis\" is now a \"stepper\": its [module.axis] table becomes [module.motor])"
                } else {
                    ""
                };
                return Err(at(format!(
                    "{what}: unknown type {:?}; a simulated module is \"stepper\" (the module firmware) or \"hub\" (a router without functions){hint}",
                    m.type_name
                )));
            };
            ClockSpec::fixed(m.offset_us, m.rate_ppm)
                .validate(&m.name)
                .map_err(|e| at(e.to_string()))?;
            if !(m.wander_ppm.is_finite() && (0.0..=10_000.0).contains(&m.wander_ppm)) {
                return Err(at(format!("{what}: wander_ppm must be within [0, 10000]")));
            }
            if !(m.wander_period_s.is_finite() && m.wander_period_s > 0.0) {
                return Err(at(format!("{what}: wander_period_s must be positive")));
            }
            if kind != ModuleKind::Stepper && m.dangling_uart {
                return Err(at(format!(
                    "{what}: dangling_uart is for modules of type \"stepper\" (the firmware's UART), not {:?}",
                    m.type_name
                )));
            }
            if kind != ModuleKind::Stepper && (m.motor.is_some() || m.io.is_some()) {
                return Err(at(format!(
                    "{what}: [module.motor] and [module.io] are for modules of type \"stepper\", not {:?}",
                    m.type_name
                )));
            }
            if let Some(motor) = &m.motor {
                motor.check().map_err(|e| at(format!("{what}: {e}")))?;
            }
            if let Some(io) = &m.io {
                io.check().map_err(|e| at(format!("{what}: {e}")))?;
            }
            if let Some(boot) = &m.bootloader {
                if kind != ModuleKind::Stepper {
                    return Err(at(format!(
                        "{what}: [module.bootloader] is for modules of type \"stepper\" (the module firmware), not {:?}",
                        m.type_name
                    )));
                }
                boot.check().map_err(|e| at(format!("{what}: {e}")))?;
                let shared = self.modules[..i]
                    .iter()
                    .position(|o| o.bootloader.as_ref().is_some_and(|b| b.drive == boot.drive));
                if let Some(first) = shared {
                    return Err(at(format!(
                        "{what}: [module.bootloader] drive {} is module {}'s too; give each module its own drive directory",
                        boot.drive.display(),
                        first + 1
                    )));
                }
            }
            if m.root {
                if let Some(first) = root {
                    return Err(at(format!(
                        "{what}: module {} ({:?}) is already the clock root; set root = true on one module at most",
                        first + 1,
                        self.modules[first].name
                    )));
                }
                root = Some(i);
            }
        }
        Ok(())
    }

    fn check_links(&self) -> Result<(), CheckError> {
        for (i, l) in self.links.iter().enumerate() {
            let at = |message: String| CheckError::at(Item::Link(i), message);
            let what = format!("link {} ({} – {})", i + 1, l.a, l.b);
            for end in [&l.a, &l.b] {
                if self.node(end).is_none() {
                    return Err(at(format!(
                        "{what}: no module is named {end:?}; add a [[module]] named so, or name one of: {}",
                        self.known_names()
                    )));
                }
            }
            if l.a == l.b {
                return Err(at(format!(
                    "{what}: a link must join two different runtimes"
                )));
            }
            if let Some(baud) = l.baud {
                if !l.kind.has_baud() {
                    return Err(at(format!(
                        "{what}: baud applies to uart and rs485 links, not {:?}; remove it",
                        l.kind.type_name()
                    )));
                }
                if !(1_200..=50_000_000).contains(&baud) {
                    return Err(at(format!(
                        "{what}: baud {baud} must be within 1200..=50000000"
                    )));
                }
            }
            if let Some(mtu) = l.mtu {
                if !(16..=MODULE_MTU as u16).contains(&mtu) {
                    return Err(at(format!(
                        "{what}: mtu {mtu} must be within 16..={MODULE_MTU} (a module's packet size)"
                    )));
                }
            }
            let probability = |key: &str, p: Option<f64>| match p {
                Some(p) if !(0.0..=1.0).contains(&p) => Err(at(format!(
                    "{what}: {key} {p} must be a probability within [0, 1]"
                ))),
                _ => Ok(()),
            };
            probability("loss", l.loss)?;
            probability("corrupt_per_byte", l.corrupt_per_byte)?;
            if l.loss.is_some() && l.kind == LinkKind::Memory {
                return Err(at(format!(
                    "{what}: a memory link loses nothing; remove loss"
                )));
            }
            for (key, set) in [
                ("jitter_us", l.jitter_us.is_some()),
                ("corrupt_per_byte", l.corrupt_per_byte.is_some()),
            ] {
                if set && !l.kind.has_baud() {
                    return Err(at(format!(
                        "{what}: {key} applies to uart and rs485 links, not {:?}; remove it",
                        l.kind.type_name()
                    )));
                }
            }
            if let Some(j) = l.jitter_us {
                if !(j.is_finite() && (0.0..=1e9).contains(&j)) {
                    return Err(at(format!(
                        "{what}: jitter_us {j} must be within [0, 1e9] µs"
                    )));
                }
            }
            if l.name.len() > NAME_MAX {
                return Err(at(format!(
                    "{what}: its name is {} bytes long; names are at most {NAME_MAX} bytes",
                    l.name.len()
                )));
            }
        }
        // A stepper has the firmware's two links: USB (0) and a UART (1).
        for spec in &self.modules {
            if spec.kind() != Some(ModuleKind::Stepper) {
                continue;
            }
            let mut taken: [Option<usize>; FIRMWARE_LINKS] = [None; FIRMWARE_LINKS];
            for (i, l) in self.links.iter().enumerate() {
                if l.a != spec.name && l.b != spec.name {
                    continue;
                }
                let Some(index) = firmware_link(l.kind) else {
                    return Err(CheckError::at(
                        Item::Link(i),
                        format!(
                            "link {} ({} – {}): a {:?} link cannot reach stepper {:?}: the module firmware has a usb link (its link 0) and a uart/rs485 link (its link 1)",
                            i + 1,
                            l.a,
                            l.b,
                            l.kind.type_name(),
                            spec.name
                        ),
                    ));
                };
                if let Some(first) = taken[index] {
                    return Err(CheckError::at(
                        Item::Link(i),
                        format!(
                            "link {} ({} – {}): stepper {:?} already has its {} link (link {}): the module firmware has {FIRMWARE_LINKS} links, one usb and one uart/rs485; join further modules through a hub",
                            i + 1,
                            l.a,
                            l.b,
                            spec.name,
                            if index == 0 { "usb" } else { "uart/rs485" },
                            first + 1
                        ),
                    ));
                }
                taken[index] = Some(i);
            }
            if let (true, Some(i)) = (spec.dangling_uart, taken[1]) {
                return Err(CheckError::at(
                    Item::Link(i),
                    format!(
                        "link {} ({} – {}): stepper {:?} has dangling_uart = true, so nothing may join its uart/rs485 link; remove one or the other",
                        i + 1,
                        self.links[i].a,
                        self.links[i].b,
                        spec.name
                    ),
                ));
            }
        }
        Ok(())
    }

    fn check_graph(&self) -> Result<(), String> {
        let adjacency = self.adjacency();
        for (i, m) in self.modules.iter().enumerate() {
            let indices: std::collections::BTreeSet<usize> =
                adjacency[i + 1].iter().map(|h| h.index).collect();
            let n = indices.len();
            if n > MODULE_LINKS {
                return Err(format!(
                    "module {:?} has {n} links; a simulated module has at most {MODULE_LINKS}",
                    m.name
                ));
            }
        }
        for bus in &self.buses {
            let what = format!("[[bus]] with head {:?}", bus.head);
            if bus.drops.is_empty() || bus.drops.len() > 254 {
                return Err(format!("{what}: list 1 to 254 drops"));
            }
            if bus.baud == 0 {
                return Err(format!("{what}: baud must be above 0"));
            }
            for (name, _) in bus.stations() {
                match self.node(name) {
                    Some(Node::Module(_)) => {}
                    Some(Node::Host) => {
                        return Err(format!(
                            "{what}: the host cannot be on a bus; put a hub module at its head"
                        ))
                    }
                    None => {
                        return Err(format!(
                            "{what}: no module is named {name:?}; name one of: {}",
                            self.known_names()
                        ))
                    }
                }
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

    fn known_names(&self) -> String {
        std::iter::once(HOST)
            .chain(self.modules.iter().map(|m| m.name.as_str()))
            .map(|n| format!("{n:?}"))
            .collect::<Vec<_>>()
            .join(", ")
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
        let mut adj: Vec<Vec<Hop>> = vec![Vec::new(); self.modules.len() + 1];
        let index_at = |n: Node, adj: &Vec<Vec<Hop>>, kind: LinkKind| match n {
            Node::Module(m) if self.modules[m].kind() == Some(ModuleKind::Stepper) => {
                firmware_link(kind).unwrap_or(adj[slot(n)].len())
            }
            _ => adj[slot(n)].len(),
        };
        for l in &self.links {
            let (Some(a), Some(b)) = (self.node(&l.a), self.node(&l.b)) else {
                continue;
            };
            let index = index_at(a, &adj, l.kind);
            adj[slot(a)].push(Hop {
                peer: b,
                index,
                drop: None,
            });
            if a != b {
                let index = index_at(b, &adj, l.kind);
                adj[slot(b)].push(Hop {
                    peer: a,
                    index,
                    drop: None,
                });
            }
        }
        // A bus is one link index at each station, with a hop to every
        // other station on it.
        for bus in &self.buses {
            let stations: Vec<(Node, u8, usize)> = bus
                .stations()
                .filter_map(|(name, drop)| {
                    let n = self.node(name)?;
                    Some((n, drop, index_at(n, &adj, LinkKind::Rs485)))
                })
                .collect();
            for &(n, _, index) in &stations {
                for &(peer, drop, _) in &stations {
                    if peer != n {
                        adj[slot(n)].push(Hop {
                            peer,
                            index,
                            drop: Some(drop),
                        });
                    }
                }
            }
        }
        adj
    }

    /// For each module, the shortest way there from the host (fewest hops;
    /// among equals, the one through earlier-listed links): at each node on
    /// the way, the [`PathHop`] taken. `None` for modules the host cannot
    /// reach.
    pub(crate) fn paths(&self) -> Vec<Option<Vec<PathHop>>> {
        let adj = self.adjacency();
        // For each node: the node before it and the hop taken from there.
        let mut from: Vec<Option<(usize, PathHop)>> = vec![None; adj.len()];
        let mut seen = vec![false; adj.len()];
        seen[0] = true;
        let mut queue = VecDeque::from([0usize]);
        while let Some(n) = queue.pop_front() {
            for hop in &adj[n] {
                let Node::Module(m) = hop.peer else { continue };
                if !seen[m + 1] {
                    seen[m + 1] = true;
                    from[m + 1] = Some((n, (hop.index, hop.drop)));
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

/// One hop of a path from the host: the index of the link taken among
/// that node's link gateways (for the host, its position among the host's
/// links), and the drop addressed if that link is a bus.
pub(crate) type PathHop = (usize, Option<u8>);

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
