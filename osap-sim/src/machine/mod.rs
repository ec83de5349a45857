//! Simulated modules: whole machines on the host, without hardware.
//!
//! A simulated module runs a real osap-core runtime ([`ModuleRuntime`]: the
//! firmware's 16 slots of 256 bytes, the firmware's port indices, up to 8 links; build key
//! `RustSimulated`), in its own tokio task, behind simulated links, on a
//! drifting clock ([`DriftClock`]). Unlike this crate's discrete-event
//! simulator ([`crate::Sim`]) a real [`Host`] (and the CLI, and any script)
//! talks to it exactly as to hardware: scans, requests and clock sync all go
//! over the network, in real time or in virtual time ([`TimeMode`]).
//!
//! Module types:
//!
//! - `stepper` is the module firmware itself: an [`osap_module::Module`]
//!   on a simulated board ([`board::SimBoard`]), with the same 32 PIPES
//!   functions, failure codes and step-word path as every board's firmware
//!   (a scan of it gives the firmware's `FUNCTION_SET_ID`, so proxies
//!   generated from it bind on hardware). Its step words are clocked out
//!   as the firmware's step generator clocks them; the board's motor keeps
//!   every step edge with its local time, moves a carriage, and presses a
//!   limit switch at a carriage position; its I/O pins read what the
//!   topology or a test sets and record what the module writes.
//!   [`SimModule::module`] reaches the instance.
//! - `hub` is host-only (no firmware build exists for it): a runtime that
//!   forwards between up to 8 links and has no functions, standing for a
//!   USB or RS-485 fan-out.
//!
//! No module logic lives here: what a `stepper` does is osap-module's.
//!
//! A machine is described by a [`SimSpec`], usually
//! read from a TOML file ([`SimSpec::load`](crate::topology::SimSpec::load)), and started against a host with [`SimMachine::start`]. The
//! repository ships eight in `osap-sim/topologies/`: `single-usb.toml` (one
//! module on USB), `small-machine.toml` (a hub on USB with four modules on
//! UARTs), `loop.toml` (a network with a loop), `corexy-plotter.toml`
//! (a hub with three steppers, one with a limit switch), and, written for
//! the clock-sync report, `uart-chain.toml` and `chain4-hub-root.toml`;
//! and `winch.toml`, a cable winch whose `[winch]`
//! ([`WinchSpec`](crate::topology::WinchSpec)) puts four motors' spools,
//! their cables and a hanging mass in one physical world ([`winch`];
//! `docs/winch.md`); and `bus32.toml`, 32 steppers on four RS-485 buses
//! behind hubs, the scale test. The discrete-event simulator runs the same
//! specs ([`crate::network::from_spec`]), those without a bus.
//!
//! ```no_run
//! # async fn demo() -> Result<(), osap_host::HostError> {
//! use osap_host::{Host, HostConfig};
//! use osap_sim::machine::SimMachine;
//! use osap_sim::SimSpec;
//! let host = Host::start(HostConfig::default())?;
//! let spec = SimSpec::load("osap-sim/topologies/small-machine.toml")?;
//! let machine = SimMachine::start(&host, &spec).await?;
//! let route = machine.route_to("x").unwrap(); // host → hub → x
//! let port = host.open_port("script").await?;
//! let name = port
//!     .request(&route, 0, &[osap_core::netresponder::key::NAME], std::time::Duration::from_millis(100))
//!     .await?;
//! # let _ = name; Ok(()) }
//! ```
//!
//! # Topology files (a spec in TOML)
//!
//! ```toml
//! name = "small-machine"     # optional
//! zero_latency = false       # optional: true makes every link deliver at once
//! sync = true                # optional: modules synchronise their clocks
//! seed = 0                   # optional: seeds the links' random latencies
//!
//! [host]                     # optional, DES only (see below)
//! kind = "host"              # "host" (a PC process) or "mcu"
//! clock = "fixed"            # "fixed": an ideal clock; "drawn": from the seed
//! busy = false               # busy spells
//!
//! [[module]]
//! name = "hub"               # unique, at most 31 bytes, not "host"
//! type = "hub"               # "hub" or "stepper" (its runtime's type name)
//!
//! [[module]]
//! name = "x"
//! type = "stepper"
//! rate_ppm = 40.0            # optional: clock rate error, ppm (default 0)
//! offset_us = 0.0            # optional: the clock's reading at boot, µs
//! wander_ppm = 0.0           # optional: slow sinusoidal rate wander, ppm
//! wander_period_s = 300.0    # optional: its period, s
//! root = false               # optional, DES only: the clock root, not the host
//! busy = false               # optional, DES only: busy spells
//! clock = "fixed"            # optional, DES only: "drawn" draws the clock
//! dangling_uart = false      # optional, "stepper" only: its UART (link 1),
//!                            # joined by no [[link]], is open with nothing
//!                            # wired to it (else it stays closed)
//! [module.motor]             # optional, for "stepper" only; defaults shown
//! full_steps_per_unit = 80.0 # full steps per unit of carriage travel
//! limit_min = -2.0           # optional: a limit switch pressed below this
//!                            # (or limit_max: pressed above); the input
//!                            # reads high released, low pressed
//! record = true              # keep every step edge
//! [module.io]                # optional, for "stepper" only
//! digital = [false, false]   # levels of pins 0..4 while nothing drives them
//! analog = [0.5, 0.0, 1.0]   # analog inputs 0..3, fractions of full scale
//! [module.io.contact]        # optional: a nozzle load cell pressing a bed
//! touch_at = -2.0            # carriage position where the tip touches
//! stiffness_n_per_unit = 40.0  # optional: the bed's push past the touch
//! data_pin = 2               # the HX711-kind converter's pins
//! clock_pin = 3
//! sample_hz = 320.0          # optional (default 320, an HX717)
//! [module.bootloader]        # optional, for "stepper" only: a UF2 bootloader
//! drive = "/tmp/x-drive"     # the directory its USB drive appears in
//! chip = "rp2040"            # optional: "rp2040" (default) or "samd51"
//! reboot_ms = 300            # optional: reboot into a new firmware, ms
//!
//! [[link]]
//! a = "host"                 # "host" is the Host the machine attaches to
//! b = "hub"
//! kind = "usb"               # usb | uart | rs485 | memory
//!
//! [[link]]
//! a = "hub"
//! b = "x"
//! kind = "uart"
//! baud = 2000000             # optional, uart and rs485 only (default 2 Mbaud)
//! mtu = 256                  # optional: 16..=256 (default 256)
//! name = ""                  # optional: instance name reported to scans
//! loss = 0.0                 # optional, DES only: frame loss (not memory)
//! jitter_us = 0.0            # optional, DES only, uart/rs485: U[0, x] µs
//! corrupt_per_byte = 0.0     # optional, DES only, uart/rs485: byte errors
//!
//! [[switch]]                 # optional: a limit switch over several motors
//! module = "a"               # the stepper whose limit input it is wired to
//! terms = [["a", 0.5], ["b", 0.5]]  # [stepper, coefficient]: its motor's
//!                            # carriage position (units) times the coefficient
//! offset = 100.0             # optional: added to the sum (default 0)
//! at = 0.0                   # where it closes
//! pressed_below = true       # pressed while sum + offset <= at (false: >= at)
//!
//! [winch]                    # optional: a cable winch over steppers' motors
//! mass_kg = 1.0              # (keys: osap_sim::topology::WinchSpec)
//! start = [0.5, 0.5]
//! [winch.model]              # maxl's StepperModel, SI units
//! # holding_torque_nm, rated_current_a, ...
//! [[winch.spool]]            # one per cable: its stepper and its anchor
//! module = "a"
//! anchor = [0.0, 1.0]
//! ```
//!
//! Unknown keys are errors. A module's link indices (what routes name)
//! follow the order its links are listed in the file, from 0 (a
//! `stepper`'s are the firmware's: its `usb` link 0, its `uart` or `rs485`
//! link 1, and one it lacks is there and never opens, unless
//! `dangling_uart` opens its UART onto nothing, as a real board's UART is
//! always open; a scan then finds no neighbour there); the host's
//! links are attached in file order after any it already has
//! ([`SimMachine::host_links`] tells their indices). Validation rejects, with
//! a message naming the module or link: duplicate or empty names, names or
//! types over 31 bytes, a module named `host`, a link end that names no
//! module, a link from a module to itself, `baud` on a link that is not a
//! UART, a baud rate or MTU out of range, more than 8 links on one module,
//! no link to the host, modules the host cannot reach, more than one
//! module with `root = true`, a `loss` or `corrupt_per_byte` outside
//! `[0, 1]`, `loss` on a `memory` link, `jitter_us` or
//! `corrupt_per_byte` on a link that is not a UART, `dangling_uart` on a
//! module that is not a `stepper` or whose UART a `[[link]]` joins, and a
//! `[[switch]]` (message naming the switch and its key) on or over a module
//! that is not a `stepper`, on a module whose motor has `limit_min` or
//! `limit_max` (one limit input), with no terms, a term named twice, a zero or
//! non-finite coefficient, or a non-finite `offset` or `at`.
//!
//! # Switches over several motors
//!
//! A `[[switch]]` ([`SwitchSpec`](crate::topology::SwitchSpec)) is pressed by a linear form of several
//! motors' carriage positions: a CoreXY machine's x endstop, wired to
//! module a's limit input, closes when x = (a + b) / 2 reaches it, however
//! a and b got there. Each watched motor publishes its steps with their
//! times; the switch's module merges them in time order and is handed each
//! edge (`limit_changed`) stamped with the tick of the step that made the
//! sum cross, to within 1 µs of converting between the two modules'
//! clocks, exactly as a switch on its own motor is. Motors clock their
//! words 2.28 ms ahead and a module watching a moving motor takes a turn
//! every 1 ms (a standing one is woken when a watched motor starts), so an
//! edge normally reaches the module at its time, and at worst at the first
//! turn after every watched motor clocked its words past it. Several
//! switches on one module are wired in parallel (low while any is
//! pressed). Only the simulated machines run them: the discrete-event
//! simulator has no motors and ignores them.
//!
//! A switch with a `bed` ([`BedContact`](crate::topology::BedContact)) is a bed levelling probe:
//! it closes at `at` plus the height of a tilted, warped bed
//! ([`BedSurface`](crate::topology::BedSurface)) under the probe tip, whose x and y are two more
//! forms of carriage positions.
//!
//! # Keys for the discrete-event simulator
//!
//! The same files describe networks for the discrete-event simulator
//! ([`crate::Network::load`]; how each key maps: [`crate::network::from_spec`]),
//! which needs a few things a machine does not: the `[host]` table (the
//! host as a PC process or a microcontroller, its clock, busy spells), a
//! module's `root`, `busy` and `clock`, and a link's `loss`, `jitter_us`
//! and `corrupt_per_byte`. The simulated machines check them and otherwise
//! ignore them: their host is a real [`Host`] and the time root, their
//! module clocks are always `rate_ppm`, `offset_us` and the wander, and
//! their links lose and corrupt nothing.
//!
//! # Virtual time
//!
//! [`SimMachine::start_with`]`(.., TimeMode::Virtual)` on a
//! [`virtual_runtime`] (tokio's current-thread runtime with time paused)
//! runs the machine, the host and the script on tokio's clock: time jumps
//! to the next thing due, so a long job takes a fraction of its duration
//! (a 60 s CoreXY job in about 2 s; `cargo bench -p osap-sim --bench
//! virtual_time`), and one seed gives the same step edges every run. Link
//! deliveries then fall on tokio's 1 ms timer ticks (their time stamps keep
//! the link model's µs), and nothing may block the runtime's thread.
//!
//! # Link timing
//!
//! With `zero_latency = false` each link kind takes the time the
//! discrete-event simulator's link models give it ([`crate::medium`]):
//!
//! | kind | timing |
//! |---|---|
//! | `uart`, `rs485` | `(len + 4) × 10 / baud` on the wire, a 2-frame transmit buffer, stamped at the first byte |
//! | `usb` | host → device: host software latency Exp(50 µs), then the next 1 ms frame's bulk slot; device → host: 0–20 µs poll delay, wire time at 12 Mbit/s, host receive latency Exp(75 µs) |
//! | `memory` | none |
//!
//! Delays are kept by a per-machine wire thread with µs precision (see
//! `wire.rs`), not tokio's 1 ms timers. With `zero_latency = true` (or
//! [`SimSpec::with_zero_latency`](crate::topology::SimSpec::with_zero_latency)) the two ends are joined directly, as
//! [`osap_host::link::memory`] joins two hosts: no timers, no
//! tasks in between.
//!
//! # Modules dying
//!
//! [`SimModule::kill`] stops a module's task as a power cut would. Its links
//! go down at both ends (the neighbours drop what is routed over them, as a
//! USB host sees a disconnect; a UART neighbour is modelled as detecting
//! the loss), so requests to the module, or through it, time out.
//! [`SimModule::restart`] boots it again: a fresh runtime, its clock
//! restarting from its boot value, the name it last had, its links back up.

pub mod board;
mod bus;
mod clock;
pub mod faults;
pub mod mode;
mod module;
mod switch;
pub mod winch;
mod wire;

pub use bus::BusStats;
pub use clock::DriftClock;
pub use faults::{CorruptionStats, Fault, FaultError, FaultParseError};
pub use module::{
    ModuleRuntime, SharedModule, FIRMWARE_LINKS, MODULE_LINKS, MODULE_MTU, MODULE_PORTS,
    MODULE_SLOTS,
};

/// How a simulated machine keeps time.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum TimeMode {
    /// On the system's clock: a host, the CLI and other processes talk to
    /// it as to hardware. Link delays are kept to a few µs by a wire thread.
    #[default]
    RealTime,
    /// On tokio's clock, paused ([`virtual_runtime`]): time jumps to the
    /// next thing due, so a long job runs in a fraction of its duration and
    /// the same seed gives the same run. Everything must run on that one
    /// current-thread runtime; link delays fall on tokio's 1 ms timer ticks
    /// (time stamps keep the model's µs).
    Virtual,
}

/// A current-thread tokio runtime with time paused: where a host and a
/// machine started with [`TimeMode::Virtual`] run in virtual time.
pub fn virtual_runtime() -> std::io::Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .start_paused(true)
        .build()
}

use crate::medium::{LinkModel, Side, Transmitter, UartParams, UsbParams};
use crate::rng::Rng;
use crate::topology::graph::{firmware_link, Node};
use crate::topology::{LinkKind, LinkSpec, ModuleKind, ModuleSpec, SimSpec, HOST};
use board::bootloader::{Arrival, BootHook, BootStats, Drive};
use board::SimBoard;
use module::{ModuleCommand, ModuleLink, ModuleTask, Parked, StepClock};
use osap_core::clock::TimeConfig;
use osap_core::link::LinkGateway;
use osap_core::netresponder::BuildKey;
use osap_core::route::Route;
use osap_core::Instant as LocalInstant;
use osap_core::Instruction;
use osap_host::error::ConfigError;
use osap_host::link::{self, ChannelLink, LinkConfig, LinkIo, LinkStats};
use osap_host::{Host, HostError};
use osap_module::{Module, ModulePort, ModulePorts};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Instant;
use switch::{Input, Positions, Publisher};
use tokio::sync::{mpsc, oneshot, Notify};
use tokio::task::JoinHandle;
use wire::{Carrier, Wire, WireHandle};

/// Packets each link end buffers each way.
const LINK_DEPTH: usize = 32;

/// A simulated machine attached to a host. Dropping it (and every
/// [`SimModule`] handle) stops its modules and takes its links down.
pub struct SimMachine {
    machine: Arc<Machine>,
    modules: Vec<SimModule>,
    host_links: Vec<u8>,
}

/// A handle to one simulated module. Cheap to clone.
#[derive(Clone)]
pub struct SimModule {
    inner: Arc<ModuleShared>,
}

struct Machine {
    topology: SimSpec,
    /// True time zero of the link models.
    epoch: Instant,
    host_clock: osap_host::HostClock,
    links: Mutex<Vec<LinkState>>,
    /// Whether each module's task is running.
    running: Vec<AtomicBool>,
    /// How deliveries are scheduled (`None`: no link has latency).
    wire: Option<WireHandle>,
    /// Where watched motors' carriages are (`None`: no switch over motors).
    positions: Option<Arc<Positions>>,
    /// The cable robot's world, if the topology has a `[winch]`.
    winch: Option<winch::SharedPlant>,
    /// The I/O sides of dangling UARTs, closed on drop (ending their
    /// drains).
    dangling: Mutex<Vec<LinkIo>>,
    /// Per module: its bus stations (link index, bus configuration).
    bus_roles: Vec<Vec<(usize, osap_core::bus::BusConfig)>>,
    /// Per `[[bus]]`: what its pair carried.
    bus_stats: Vec<Arc<BusStats>>,
    // Last: dropped after the links are down.
    _wire_thread: Option<Wire>,
}

struct LinkState {
    /// The link's position in the topology.
    index: usize,
    /// Side A (on USB, the USB host) and side B.
    ends: [End; 2],
    /// `None`: the ends are joined (no latency).
    model: Option<LinkModel>,
    up: bool,
    carriers: Vec<JoinHandle<()>>,
    generation: Arc<AtomicU64>,
    /// Injected faults (cut, corruption) and their counts.
    faults: Arc<faults::LinkFaults>,
}

struct End {
    node: Node,
    io: LinkIo,
}

struct ModuleShared {
    index: usize,
    spec: ModuleSpec,
    machine: Arc<Machine>,
    /// The runtime's wake-up, shared by its link ends for good.
    wake: Arc<Notify>,
    state: tokio::sync::Mutex<ModuleState>,
    live: Mutex<Live>,
    /// The main loop is frozen (fault injection): the runtime is not polled.
    frozen: Arc<AtomicBool>,
    /// In its UF2 bootloader (off the network, its drive shown).
    in_bootloader: Arc<AtomicBool>,
    /// What its bootloader has done.
    boot_stats: Mutex<BootStats>,
}

struct Live {
    commands: Option<mpsc::UnboundedSender<ModuleCommand>>,
    clock: DriftClock,
    /// A `stepper`'s osap-module instance, replaced at each boot.
    module: Option<SharedModule>,
}

enum ModuleState {
    Running(JoinHandle<Parked>),
    Stopped(Parked),
    /// The task panicked; its links went with it.
    Lost,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// This crate's version as three bytes.
fn version() -> [u8; 3] {
    let part = |s: &str| s.parse::<u8>().unwrap_or(0);
    [
        part(env!("CARGO_PKG_VERSION_MAJOR")),
        part(env!("CARGO_PKG_VERSION_MINOR")),
        part(env!("CARGO_PKG_VERSION_PATCH")),
    ]
}

fn link_model(spec: &LinkSpec) -> Option<LinkModel> {
    let uart = UartParams {
        baud: spec.baud(),
        mtu: spec.mtu(),
        ..UartParams::default()
    };
    match spec.kind {
        LinkKind::Uart => Some(LinkModel::Uart(uart)),
        LinkKind::Rs485 => Some(LinkModel::Rs485(uart)),
        LinkKind::Usb => Some(LinkModel::UsbCdc(UsbParams {
            mtu: spec.mtu(),
            ..UsbParams::default()
        })),
        LinkKind::Memory => None,
    }
}

fn link_config(spec: &LinkSpec, timed: bool) -> LinkConfig {
    let (bits_per_second, bits_per_byte) = match (timed, spec.kind) {
        (false, _) | (true, LinkKind::Memory) => (0, 8),
        (true, LinkKind::Usb) => (12_000_000, 8),
        (true, LinkKind::Uart | LinkKind::Rs485) => (spec.baud(), 10),
    };
    LinkConfig {
        type_name: spec.kind.type_name().to_string(),
        name: spec.name.clone(),
        mtu: spec.mtu(),
        depth: LINK_DEPTH,
        bits_per_second,
        bits_per_byte,
    }
}

impl SimMachine {
    /// Starts the machine `topology` describes, attached to `host`: one task
    /// per module, its links attached to the host in file order, every
    /// link up. The topology is validated first.
    pub async fn start(host: &Host, topology: &SimSpec) -> Result<SimMachine, HostError> {
        Self::start_with(host, topology, TimeMode::RealTime).await
    }

    /// [`start`](Self::start) in the given [`TimeMode`].
    pub async fn start_with(
        host: &Host,
        topology: &SimSpec,
        mode: TimeMode,
    ) -> Result<SimMachine, HostError> {
        topology.validate()?;
        let epoch = osap_host::clock::now();
        let host_clock = host.clock();
        let timed = !topology.zero_latency;
        let (wire, wire_thread) = if (timed
            && topology.links.iter().any(|l| l.kind != LinkKind::Memory))
            || !topology.buses.is_empty()
        {
            match mode {
                TimeMode::RealTime => {
                    let thread = Wire::start().map_err(|source| HostError::Io {
                        context: "starting the simulated wire thread".into(),
                        source,
                    })?;
                    (Some(thread.handle()), Some(thread))
                }
                TimeMode::Virtual => {
                    let task = Wire::start_virtual();
                    (Some(task.handle()), Some(task))
                }
            }
        } else {
            (None, None)
        };
        let wakes: Vec<Arc<Notify>> = topology
            .modules
            .iter()
            .map(|_| Arc::new(Notify::new()))
            .collect();
        // Each module's link gateways by index (a stepper's at the
        // firmware's indices, the rest in file order).
        let mut module_links: Vec<Vec<Option<ChannelLink>>> =
            topology.modules.iter().map(|_| Vec::new()).collect();
        let mut links = Vec::new();
        let mut host_links = Vec::new();
        for (index, spec) in topology.links.iter().enumerate() {
            let model = if timed { link_model(spec) } else { None };
            let config = link_config(spec, model.is_some());
            let (Some(a), Some(b)) = (topology.node(&spec.a), topology.node(&spec.b)) else {
                unreachable!("validated");
            };
            let (a, b) = if spec.kind == LinkKind::Usb && b == Node::Host {
                (b, a)
            } else {
                (a, b)
            };
            let half = |n: Node| match n {
                Node::Host => host.make_link(config.clone()),
                Node::Module(m) => link::channel(config.clone(), wakes[m].clone(), host_clock),
            };
            let (mut link_a, io_a) = half(a);
            let (mut link_b, io_b) = half(b);
            if model.is_none() {
                ChannelLink::join(&mut link_a, &mut link_b);
            }
            // Links are attached in file order, so each end's link indices
            // follow it (a link never has the same runtime at both ends).
            for (node, link) in [(a, link_a), (b, link_b)] {
                match node {
                    Node::Host => host_links.push(host.attach_link(link).await?),
                    Node::Module(m) => {
                        let slots = &mut module_links[m];
                        let at = match topology.modules[m].kind() {
                            Some(ModuleKind::Stepper) => {
                                firmware_link(spec.kind).unwrap_or(slots.len())
                            }
                            _ => slots.len(),
                        };
                        if slots.len() <= at {
                            slots.resize_with(at + 1, || None);
                        }
                        slots[at] = Some(link);
                    }
                }
            }
            links.push(LinkState {
                index,
                ends: [End { node: a, io: io_a }, End { node: b, io: io_b }],
                model,
                up: false,
                carriers: Vec::new(),
                generation: Arc::new(AtomicU64::new(0)),
                faults: Arc::default(),
            });
        }
        // Buses: one station link per member, after its [[link]]s.
        let mut bus_roles: Vec<Vec<(usize, osap_core::bus::BusConfig)>> =
            topology.modules.iter().map(|_| Vec::new()).collect();
        let mut bus_ios: Vec<(Vec<LinkIo>, u32)> = Vec::new();
        for bus in &topology.buses {
            let config = LinkConfig {
                type_name: "rs485_bus".into(),
                name: bus.name.clone(),
                mtu: 256,
                depth: LINK_DEPTH,
                bits_per_second: bus.baud,
                bits_per_byte: 10,
            };
            let mut ios = Vec::new();
            for (name, drop) in bus.stations() {
                let Some(Node::Module(m)) = topology.node(name) else {
                    unreachable!("validated");
                };
                let (link, io) = link::channel(config.clone(), wakes[m].clone(), host_clock);
                let slots = &mut module_links[m];
                let at = match topology.modules[m].kind() {
                    Some(ModuleKind::Stepper) => {
                        firmware_link(LinkKind::Rs485).unwrap_or(slots.len())
                    }
                    _ => slots.len(),
                };
                if slots.len() <= at {
                    slots.resize_with(at + 1, || None);
                }
                slots[at] = Some(link);
                let role = if drop == osap_core::bus::HEAD {
                    // A simulated module answers as late as its task is
                    // scheduled (hundreds of µs on a busy host): a firmware
                    // head's 500 µs would time drops out.
                    osap_core::bus::BusConfig {
                        reply_timeout: osap_core::Duration::from_millis(5),
                        absent_every: 4,
                        ..osap_core::bus::BusConfig::head(bus.drops.len().min(254) as u8)
                    }
                } else {
                    osap_core::bus::BusConfig::drop(drop)
                };
                bus_roles[m].push((at, role));
                ios.push(io);
            }
            bus_ios.push((ios, bus.baud));
        }
        let bus_stats: Vec<Arc<BusStats>> = bus_ios.iter().map(|_| Arc::default()).collect();
        let positions = Positions::new(topology, &wakes, epoch);
        let machine = Arc::new(Machine {
            dangling: Mutex::new(Vec::new()),
            positions,
            winch: topology
                .winch
                .as_ref()
                .map(|w| winch::SharedPlant::new(winch::Plant::new(w))),
            topology: topology.clone(),
            epoch,
            host_clock,
            links: Mutex::new(links),
            running: topology
                .modules
                .iter()
                .map(|_| AtomicBool::new(false))
                .collect(),
            wire,
            bus_roles,
            bus_stats: bus_stats.clone(),
            _wire_thread: wire_thread,
        });
        // A stepper always has the firmware's two links; one the topology
        // leaves out is there, and never opens (but a dangling UART is open
        // onto nothing).
        let mut dangling = Vec::new();
        let module_links: Vec<Vec<ChannelLink>> = module_links
            .into_iter()
            .zip(&topology.modules)
            .zip(&wakes)
            .map(|((mut slots, m), wake)| {
                if m.kind() == Some(ModuleKind::Stepper) && slots.len() < FIRMWARE_LINKS {
                    slots.resize_with(FIRMWARE_LINKS, || None);
                }
                slots
                    .into_iter()
                    .enumerate()
                    .map(|(i, l)| {
                        l.unwrap_or_else(|| {
                            let kind = if i == 0 {
                                LinkKind::Usb
                            } else {
                                LinkKind::Uart
                            };
                            let spec = LinkSpec::new(HOST, HOST, kind);
                            let (link, io) =
                                link::channel(link_config(&spec, false), wake.clone(), host_clock);
                            if m.dangling_uart && kind == LinkKind::Uart {
                                io.set_open(true);
                                dangling.push(io);
                            }
                            link
                        })
                    })
                    .collect()
            })
            .collect();
        // What a dangling UART sends goes nowhere: drain it until the
        // machine closes it.
        for io in &dangling {
            let io = io.clone();
            tokio::spawn(async move { while io.next_tx().await.is_some() {} });
        }
        *lock(&machine.dangling) = dangling;
        let mut modules = Vec::new();
        for ((index, spec), (wake, links)) in topology
            .modules
            .iter()
            .enumerate()
            .zip(wakes.into_iter().zip(module_links))
        {
            let shared = Arc::new(ModuleShared {
                index,
                spec: spec.clone(),
                machine: machine.clone(),
                wake,
                state: tokio::sync::Mutex::new(ModuleState::Lost),
                live: Mutex::new(Live {
                    commands: None,
                    clock: DriftClock::new(epoch, spec.clock_model()),
                    module: None,
                }),
                frozen: Arc::default(),
                in_bootloader: Arc::default(),
                boot_stats: Mutex::default(),
            });
            let module = SimModule { inner: shared };
            let parked = Parked {
                links,
                name: spec.name.clone(),
                carriage: 0,
            };
            *module.inner.state.lock().await = ModuleState::Running(module.spawn(parked)?);
            machine.running[index].store(true, Ordering::SeqCst);
            modules.push(module);
        }
        {
            let mut links = lock(&machine.links);
            for l in links.iter_mut() {
                machine.open(l);
            }
        }
        for ((stations, baud), stats) in bus_ios.into_iter().zip(bus_stats) {
            let Some(wire) = machine.wire.clone() else {
                unreachable!("a machine with a bus has a wire");
            };
            bus::SimBus {
                stations,
                baud,
                wire,
                epoch,
                host_clock,
                stats,
            }
            .start();
        }
        Ok(SimMachine {
            machine,
            modules,
            host_links,
        })
    }

    /// What the pair of `[[bus]]` number `index` (file order) carried.
    pub fn bus_stats(&self, index: usize) -> Option<&BusStats> {
        self.machine.bus_stats.get(index).map(|s| &**s)
    }

    /// The cable robot's world (`[winch]`), if the topology has one: where
    /// the mass truly is, for a script's check.
    pub fn winch(&self) -> Option<&winch::SharedPlant> {
        self.machine.winch.as_ref()
    }

    /// The topology it was started from.
    pub fn topology(&self) -> &SimSpec {
        &self.machine.topology
    }

    /// Its modules, in file order.
    pub fn modules(&self) -> &[SimModule] {
        &self.modules
    }

    /// The module named `name` (its name in the file).
    pub fn module(&self, name: &str) -> Option<&SimModule> {
        self.modules.iter().find(|m| m.name() == name)
    }

    /// The host's link index of each link to the host, in file order.
    pub fn host_links(&self) -> &[u8] {
        &self.host_links
    }

    /// The shortest route from the host to module `name` (fewest hops;
    /// among equals, through the links listed first), from the topology.
    pub fn route_to(&self, name: &str) -> Option<Route> {
        let topology = &self.machine.topology;
        let index = topology.module_index(name)?;
        let path = topology.paths().into_iter().nth(index)??;
        let ((first, _), rest) = path.split_first()?;
        let mut route = Route::local()
            .with_hop(Instruction::LinkForward(*self.host_links.get(*first)?))
            .ok()?;
        for &(k, drop) in rest {
            let hop = match drop {
                Some(drop) => Instruction::BusForward { bus: k as u8, drop },
                None => Instruction::LinkForward(k as u8),
            };
            route = route.with_hop(hop).ok()?;
        }
        Some(route)
    }

    /// Whether link `index` (its position in the topology) is up: both its
    /// ends are running.
    pub fn link_is_up(&self, index: usize) -> Option<bool> {
        lock(&self.machine.links)
            .iter()
            .find(|l| l.index == index)
            .map(|l| l.up)
    }

    /// A handle that injects faults into this machine (see [`Fault`]).
    /// It holds the modules, so keep it no longer than the machine.
    pub fn injector(&self) -> FaultInjector {
        FaultInjector {
            machine: self.machine.clone(),
            modules: self.modules.clone(),
        }
    }

    /// Injects `fault` (see [`FaultInjector::inject`]).
    pub async fn inject(&self, fault: &Fault) -> Result<(), FaultError> {
        self.injector().inject(fault).await
    }

    /// Stops every module and takes every link down.
    pub async fn stop(self) -> Result<(), HostError> {
        for m in &self.modules {
            m.kill().await?;
        }
        Ok(())
    }
}

/// Injects faults into a running [`SimMachine`]. Cheap to clone.
#[derive(Clone)]
pub struct FaultInjector {
    machine: Arc<Machine>,
    modules: Vec<SimModule>,
}

impl FaultInjector {
    /// Applies `fault`:
    /// - `Cut` takes the link down at both ends (each end sees it closed, as
    ///   after a pulled cable) until `Restore`;
    /// - `Corrupt` flips bytes of every frame on the link from now on, in
    ///   both directions, through the real framing (a rate of 0 stops it);
    /// - `Reset` power-cycles the module: its links drop, it boots afresh;
    /// - `Freeze` stops the module's main loop (its steps run on from what
    ///   is queued) until `Thaw`.
    pub async fn inject(&self, fault: &Fault) -> Result<(), FaultError> {
        match fault {
            Fault::Cut(link) | Fault::Restore(link) => {
                let cut = matches!(fault, Fault::Cut(_));
                let index = self.link_index(link)?;
                let mut links = lock(&self.machine.links);
                let l = &mut links[index];
                l.faults.cut.store(cut, Ordering::SeqCst);
                let up = !cut && l.ends.iter().all(|e| self.machine.alive(e.node));
                if up && !l.up {
                    self.machine.open(l);
                } else if !up && l.up {
                    Machine::close(l);
                }
                Ok(())
            }
            Fault::Corrupt { link, per_byte } => {
                let index = self.link_index(link)?;
                let links = lock(&self.machine.links);
                if links[index].model.is_none() || self.machine.wire.is_none() {
                    return Err(FaultError::NoWire(link.clone()));
                }
                links[index].faults.set_corruption(*per_byte);
                Ok(())
            }
            Fault::Reset(module) => {
                let m = self.module(module)?;
                m.inner.frozen.store(false, Ordering::Release);
                m.kill().await?;
                m.restart().await?;
                Ok(())
            }
            Fault::Freeze(module) | Fault::Thaw(module) => {
                let m = self.module(module)?;
                m.inner
                    .frozen
                    .store(matches!(fault, Fault::Freeze(_)), Ordering::Release);
                m.inner.wake.notify_one();
                Ok(())
            }
        }
    }

    /// The topology position of a link named by its index, its name, or its
    /// two ends (`hub-a` or `a-hub`).
    pub fn link_index(&self, link: &str) -> Result<usize, FaultError> {
        let specs = &self.machine.topology.links;
        if let Ok(i) = link.parse::<usize>() {
            if i < specs.len() {
                return Ok(i);
            }
        }
        let matches: Vec<usize> = specs
            .iter()
            .enumerate()
            .filter(|(_, l)| {
                (!l.name.is_empty() && l.name == link)
                    || link == format!("{}-{}", l.a, l.b)
                    || link == format!("{}-{}", l.b, l.a)
            })
            .map(|(i, _)| i)
            .collect();
        match matches.as_slice() {
            [i] => Ok(*i),
            [] => Err(FaultError::UnknownLink {
                link: link.to_string(),
                known: specs
                    .iter()
                    .enumerate()
                    .map(|(i, l)| format!("{i}: {}-{}", l.a, l.b))
                    .collect(),
            }),
            _ => Err(FaultError::AmbiguousLink(link.to_string())),
        }
    }

    fn module(&self, name: &str) -> Result<&SimModule, FaultError> {
        self.modules
            .iter()
            .find(|m| m.name() == name)
            .ok_or_else(|| FaultError::UnknownModule {
                module: name.to_string(),
                known: self.modules.iter().map(|m| m.name().to_string()).collect(),
            })
    }

    /// What module `name`'s outputs drive now, read back through its
    /// board ([`board::Outputs`]).
    pub fn outputs(&self, name: &str) -> Result<board::Outputs, FaultError> {
        let shared = self
            .module(name)?
            .module()
            .ok_or_else(|| FaultError::NoOutputs(name.to_string()))?;
        shared
            .lock(|m| osap_module::board::Board::io(m.board_mut()).map(board::Outputs::read))
            .ok_or_else(|| FaultError::NoOutputs(name.to_string()))
    }

    /// What injected corruption has done on a link so far.
    pub fn corruption(&self, link: &str) -> Result<CorruptionStats, FaultError> {
        let index = self.link_index(link)?;
        Ok(lock(&self.machine.links)[index].faults.stats())
    }

    /// Each end's link counters (side A, then side B; on USB, A is the
    /// host), as the runtimes at the ends keep them.
    pub fn link_stats(&self, link: &str) -> Result<[LinkStats; 2], FaultError> {
        let index = self.link_index(link)?;
        let links = lock(&self.machine.links);
        let l = &links[index];
        Ok([l.ends[0].io.stats(), l.ends[1].io.stats()])
    }

    /// Every link's position and its ends, as `index: a-b`.
    pub fn links(&self) -> Vec<String> {
        self.machine
            .topology
            .links
            .iter()
            .enumerate()
            .map(|(i, l)| format!("{i}: {}-{}", l.a, l.b))
            .collect()
    }
}

impl std::fmt::Debug for FaultInjector {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FaultInjector")
            .field("topology", &self.machine.topology.name)
            .finish()
    }
}

impl Machine {
    fn alive(&self, node: Node) -> bool {
        match node {
            Node::Host => true,
            Node::Module(m) => self.running[m].load(Ordering::SeqCst),
        }
    }

    /// Brings each link of module `m` up or down to match whether both its
    /// ends are running.
    fn refresh(&self, m: usize) {
        let mut links = lock(&self.links);
        for l in links.iter_mut() {
            if !l.ends.iter().any(|e| e.node == Node::Module(m)) {
                continue;
            }
            let up =
                !l.faults.cut.load(Ordering::SeqCst) && l.ends.iter().all(|e| self.alive(e.node));
            if up && !l.up {
                self.open(l);
            } else if !up && l.up {
                Self::close(l);
            }
        }
    }

    fn open(&self, l: &mut LinkState) {
        for e in &l.ends {
            e.io.set_open(true);
        }
        l.up = true;
        let (Some(model), Some(wire)) = (l.model, &self.wire) else {
            return;
        };
        let started = l.generation.load(Ordering::Acquire);
        for (from, side) in [(0, Side::A), (1, Side::B)] {
            let stream = ((l.index as u64) << 32) | (started << 1) | from as u64;
            let carrier = Carrier {
                from: l.ends[from].io.clone(),
                to: l.ends[1 - from].io.clone(),
                transmitter: Transmitter::new(
                    model,
                    side,
                    Rng::stream(self.topology.seed, "osap-host-sim-link", stream),
                ),
                stamp: model.stamp_mode(side.other()),
                wire: wire.clone(),
                epoch: self.epoch,
                host_clock: self.host_clock,
                generation: l.generation.clone(),
                started,
                faults: l.faults.clone(),
                fault_rng: Rng::stream(self.topology.seed, "osap-sim-fault", stream),
                flow_controlled: model.is_flow_controlled(),
            };
            l.carriers.push(tokio::spawn(carrier.run()));
        }
    }

    fn close(l: &mut LinkState) {
        l.generation.fetch_add(1, Ordering::AcqRel);
        for c in l.carriers.drain(..) {
            c.abort();
        }
        for e in &l.ends {
            e.io.set_open(false);
        }
        l.up = false;
    }
}

impl Drop for Machine {
    fn drop(&mut self) {
        let mut links = lock(&self.links);
        for l in links.iter_mut() {
            Self::close(l);
        }
        for io in lock(&self.dangling).iter() {
            io.set_open(false);
        }
    }
}

impl SimModule {
    /// Its name in the topology (the runtime's name at boot).
    pub fn name(&self) -> &str {
        &self.inner.spec.name
    }

    /// Its runtime type name.
    pub fn type_name(&self) -> &str {
        &self.inner.spec.type_name
    }

    /// Its position among the topology's modules.
    pub fn index(&self) -> usize {
        self.inner.index
    }

    /// Its description.
    pub fn spec(&self) -> &ModuleSpec {
        &self.inner.spec
    }

    /// Its local clock since it last booted.
    pub fn clock(&self) -> DriftClock {
        lock(&self.inner.live).clock
    }

    /// A `stepper`'s osap-module instance on its simulated board (from its
    /// current boot): its logic state, the motor's step edges, the limit
    /// switch and the I/O pins. `None` for a hub.
    pub fn module(&self) -> Option<SharedModule> {
        lock(&self.inner.live).module.clone()
    }

    /// The host clock's reading (the machine's true time: the host is the
    /// time root) when this module's local clock read `local`, in its
    /// current boot. Comparing it with what the module believed
    /// (a step edge's local time, say) gives the sync error.
    pub fn host_time_at(&self, local: LocalInstant) -> LocalInstant {
        self.inner
            .machine
            .host_clock
            .at(self.clock().instant_at(local))
    }

    /// Its local clock's reading now.
    pub fn local_now(&self) -> LocalInstant {
        self.clock().now()
    }

    /// Whether its task is running.
    pub fn is_running(&self) -> bool {
        self.inner.machine.running[self.inner.index].load(Ordering::SeqCst)
    }

    /// Runs `f` on its runtime, inside its task, with the module's local
    /// time; `HostError::Stopped` if it is not running.
    pub async fn with_runtime<R: Send + 'static>(
        &self,
        f: impl FnOnce(&mut ModuleRuntime, LocalInstant) -> R + Send + 'static,
    ) -> Result<R, HostError> {
        let (tx, rx) = oneshot::channel();
        let command = ModuleCommand::With(Box::new(move |rt, now| {
            let _ = tx.send(f(rt, now));
        }));
        lock(&self.inner.live)
            .commands
            .as_ref()
            .ok_or(HostError::Stopped)?
            .send(command)
            .map_err(|_| HostError::Stopped)?;
        rx.await.map_err(|_| HostError::Stopped)
    }

    /// Stops the module as a power cut would: its links go down at both
    /// ends, then its task ends. Does nothing if it is not running.
    pub async fn kill(&self) -> Result<(), HostError> {
        let mut state = self.inner.state.lock().await;
        let ModuleState::Running(_) = &*state else {
            return Ok(());
        };
        let machine = &self.inner.machine;
        machine.running[self.inner.index].store(false, Ordering::SeqCst);
        machine.refresh(self.inner.index);
        if let Some(commands) = lock(&self.inner.live).commands.take() {
            let _ = commands.send(ModuleCommand::Stop);
        }
        let ModuleState::Running(task) = std::mem::replace(&mut *state, ModuleState::Lost) else {
            unreachable!("checked above");
        };
        let parked = task.await.map_err(|_| HostError::Stopped)?;
        if let Some(positions) = &machine.positions {
            positions.stopped(self.inner.index);
        }
        *state = ModuleState::Stopped(parked);
        Ok(())
    }

    /// Boots a stopped module again: a fresh runtime with the name it last
    /// had, its clock restarting from its boot value, and its links up
    /// wherever the other end is running. Does nothing if it is running.
    pub async fn restart(&self) -> Result<(), HostError> {
        let mut state = self.inner.state.lock().await;
        match std::mem::replace(&mut *state, ModuleState::Lost) {
            ModuleState::Running(task) => {
                *state = ModuleState::Running(task);
                Ok(())
            }
            ModuleState::Lost => Err(HostError::Stopped),
            ModuleState::Stopped(parked) => {
                *state = ModuleState::Running(self.spawn(parked)?);
                let machine = &self.inner.machine;
                machine.running[self.inner.index].store(true, Ordering::SeqCst);
                machine.refresh(self.inner.index);
                Ok(())
            }
        }
    }

    /// Whether it is in its UF2 bootloader (off the network, its drive
    /// shown; see [`board::bootloader`]).
    pub fn in_bootloader(&self) -> bool {
        self.inner.in_bootloader.load(Ordering::SeqCst)
    }

    /// What its UF2 bootloader has done since the machine started.
    pub fn boot_stats(&self) -> BootStats {
        lock(&self.inner.boot_stats).clone()
    }

    /// What the board does when osap-module's `enter_bootloader` comes
    /// due: the chip stops at once (the runtime is no longer polled), then
    /// a task takes the module off the network and runs its bootloader.
    fn boot_hook(&self) -> BootHook {
        let weak = Arc::downgrade(&self.inner);
        let runtime = tokio::runtime::Handle::current();
        BootHook::new(move || {
            let Some(inner) = weak.upgrade() else {
                return;
            };
            inner.frozen.store(true, Ordering::Release);
            inner.in_bootloader.store(true, Ordering::SeqCst);
            runtime.spawn(SimModule { inner }.run_bootloader());
        })
    }

    /// The module in its bootloader: off the network, its drive mounted
    /// until a UF2 of its family lands (then it reboots into it, the name
    /// kept) or it is restarted, or the machine is gone.
    async fn run_bootloader(self) {
        let Some(spec) = self.inner.spec.bootloader.clone() else {
            return;
        };
        let name = self.name().to_string();
        let left = self.kill().await;
        let drive = left
            .map_err(|e| e.to_string())
            .and_then(|()| Drive::mount(&spec).map_err(|e| format!("cannot mount its drive: {e}")));
        let mut drive = match drive {
            Ok(d) => d,
            Err(e) => {
                tracing::error!("simulated module {name}: bootloader failed: {e}");
                self.inner.in_bootloader.store(false, Ordering::SeqCst);
                return;
            }
        };
        lock(&self.inner.boot_stats).entered += 1;
        tracing::info!(
            "simulated module {name}: in its UF2 bootloader ({}), drive at {}",
            spec.chip.name(),
            drive.dir().display()
        );
        // Held weakly from here: a machine dropped meanwhile powers off.
        let weak = Arc::downgrade(&self.inner);
        drop(self);
        loop {
            tokio::time::sleep(std::time::Duration::from_millis(20)).await;
            let Some(inner) = weak.upgrade() else {
                drive.unmount();
                return;
            };
            let module = SimModule { inner };
            if module.is_running() {
                // Restarted from outside: a reset leaves the bootloader.
                drive.unmount();
                module.inner.in_bootloader.store(false, Ordering::SeqCst);
                return;
            }
            match drive.poll() {
                None => {}
                Some(Arrival::Rejected(why)) => {
                    tracing::warn!(
                        "simulated module {name}: its bootloader refused {why}; it stays in its bootloader"
                    );
                    let mut stats = lock(&module.inner.boot_stats);
                    stats.rejected += 1;
                    stats.last_rejection = Some(why);
                }
                Some(Arrival::Flashed(info)) => {
                    drive.unmount();
                    lock(&module.inner.boot_stats).flashed += 1;
                    tracing::info!("simulated module {name}: flashed {info}; rebooting into it");
                    tokio::time::sleep(std::time::Duration::from_millis(spec.reboot_ms)).await;
                    module.inner.frozen.store(false, Ordering::Release);
                    module.inner.in_bootloader.store(false, Ordering::SeqCst);
                    if let Err(e) = module.restart().await {
                        tracing::error!("simulated module {name}: did not come back: {e}");
                    }
                    return;
                }
            }
        }
    }

    /// Boots the module's runtime on `parked`'s links.
    fn spawn(&self, parked: Parked) -> Result<JoinHandle<Parked>, HostError> {
        let spec = &self.inner.spec;
        let machine = &self.inner.machine;
        let time = TimeConfig {
            enabled: machine.topology.sync,
            ..TimeConfig::default()
        };
        // A stepper runs the module firmware's functions; a hub has none.
        let function_set = if spec.kind() == Some(ModuleKind::Stepper) {
            osap_module::FUNCTION_SET_ID
        } else {
            0
        };
        let runtime = ModuleRuntime::new(&spec.type_name, &parked.name)
            .map_err(ConfigError::from)?
            .with_version(version(), BuildKey::RustSimulated)
            .with_function_set(function_set)
            .with_time_config(time)
            .map_err(ConfigError::from)?;
        let clock = DriftClock::new(osap_host::clock::now(), spec.clock_model());
        let links = parked
            .links
            .into_iter()
            .enumerate()
            .map(|(i, mut link)| {
                // Whatever arrived while it was down is gone with the power.
                while link.receive(&mut []).is_some() {}
                let role = machine.bus_roles[self.inner.index]
                    .iter()
                    .find(|(at, _)| *at == i)
                    .map(|(_, role)| *role);
                ModuleLink::new(link, clock, machine.host_clock).on_bus(role)
            })
            .collect();
        let (commands, rx) = mpsc::unbounded_channel();
        let mut ports: Vec<Box<dyn osap_core::port::Port + Send>> = Vec::new();
        let mut stepper = None;
        if spec.kind() == Some(ModuleKind::Stepper) {
            let mut board = SimBoard::new(
                clock,
                spec.motor.clone().unwrap_or_default(),
                &spec.io.clone().unwrap_or_default(),
            );
            board.motor_mut().place(parked.carriage);
            let spool = machine
                .topology
                .winch
                .as_ref()
                .and_then(|w| w.spools.iter().position(|s| s.module == spec.name));
            if let (Some(plant), Some(index)) = (&machine.winch, spool) {
                board.set_winch(winch::WinchMotor {
                    plant: plant.clone(),
                    index,
                });
            }
            if spec.bootloader.is_some() {
                board.set_bootloader(self.boot_hook());
            }
            let carriage = board.motor().position();
            let module = SharedModule::new(Module::new(board));
            let (publisher, input) = match &machine.positions {
                Some(board) => (
                    Publisher::new(board, self.inner.index, clock, carriage),
                    Input::new(board, &machine.topology, self.inner.index, clock),
                ),
                None => (None, None),
            };
            let steps = StepClock::new(module.clone(), clock.now(), publisher, input);
            let level = steps.initial_level();
            module.lock(|m| m.limit_initial(level));
            let module_ports = ModulePorts::new(module.clone()).map_err(ConfigError::from)?;
            // The functions, then the pulse timer (it takes no port index),
            // then the block manager and its pools.
            // sample_block's port stands where its slot is.
            let (functions, sampler, blocks) = module_ports.into_parts();
            let mut sampler = Some(sampler);
            for port in functions {
                match (port, sampler.take()) {
                    (ModulePort::Sampler(_), Some(s)) => ports.push(Box::new(s)),
                    (port, s) => {
                        sampler = s;
                        ports.push(Box::new(port));
                    }
                }
            }
            ports.push(Box::new(blocks));
            stepper = Some((module, steps));
        }
        let task = ModuleTask {
            runtime: Box::new(runtime),
            ports,
            links,
            commands: rx,
            wake: self.inner.wake.clone(),
            clock,
            stepper: stepper.as_ref().map(|(_, steps)| steps.clone()),
            frozen: self.inner.frozen.clone(),
        };
        *lock(&self.inner.live) = Live {
            commands: Some(commands),
            clock,
            module: stepper.map(|(m, _)| m),
        };
        Ok(tokio::spawn(task.run()))
    }
}

impl std::fmt::Debug for SimModule {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimModule")
            .field("name", &self.name())
            .field("type", &self.type_name())
            .field("running", &self.is_running())
            .finish()
    }
}

impl std::fmt::Debug for SimMachine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimMachine")
            .field("topology", &self.machine.topology.name)
            .field("modules", &self.modules)
            .field("host_links", &self.host_links)
            .finish()
    }
}
