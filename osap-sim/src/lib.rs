//! # osap-sim
//!
//! A deterministic discrete-event simulator of OSAP networks. Every node
//! runs a real [`osap_core::Runtime`]; what is simulated is everything
//! around it: oscillators that drift, main loops that take time to come
//! around and are sometimes busy, and links with wire time, framing,
//! quantised USB frames, latency jitter, loss and byte corruption. True
//! time is a `u64` of nanoseconds; the same topology and seed always give
//! the same run, and a run goes many times faster than real time.
//!
//! The pieces, each in its own module:
//! - [`rng`]: the seeded generator and delay distributions;
//! - [`clock`]: each node's local µs counter as a function of true time;
//! - [`medium`]: link kinds and their timing (UART, RS-485, USB CDC, TCP,
//!   UDP);
//! - [`link`]: the simulated [`LinkGateway`](osap_core::link::LinkGateway);
//! - [`busy`]: busy spells of a node;
//! - [`node`]: a node (runtime, links, ports, clock, main-loop model);
//! - [`topology`]: the one description both simulators read ([`SimSpec`]:
//!   modules, links, boards, switches, bed; `osap-sim/topologies/*.toml`
//!   are specs in TOML, and osap-machine derives one from a machine file);
//! - [`network`]: the discrete-event simulator's network, lowered from a
//!   spec ([`network::from_spec`]) or built directly with any link model;
//! - [`sim`]: the event loop;
//! - [`metrics`]: errors of every node's synchronised time against the
//!   root's, and their statistics;
//! - [`scenario`]: one-call runs;
//! - [`probe`]: a port that sends and records packets, for tests;
//! - `plot` (with the feature `plot`): SVG plots of error over time.
//!
//! Beside it, [`machine`]: simulated machines a real [`osap_host::Host`]
//! (and the `osap` CLI, and any script) talks to as to hardware, in real
//! time or in virtual time (deterministic per seed, many times faster than
//! real time). Their `stepper` modules are the module firmware's own logic
//! (osap-module instances on simulated boards), so what a script does
//! against them it does against hardware. Both simulators take the same
//! [`SimSpec`]; neither imports the other.
//!
//! Run a topology in one call and look at the result:
//!
//! ```
//! use osap_sim::{Scenario, Network};
//! let outcome = Scenario::new(Network::chain4()).seed(7).seconds(0.5).run().unwrap();
//! let m = &outcome.metrics;
//! assert_eq!(m.node_count(), 4);
//! let _worst_now = m.worst_abs().last().copied();
//! let _settled = m.worst_convergence_time(10.0);
//! ```
//!
//! or just `osap_sim::run(&Network::star8(), seed, seconds)?` for the
//! [`Metrics`], and `.summary()` on them for the benchmark's figures
//! ([`SyncSummary`]: convergence to 50 and 10 µs, steady-state |error|
//! p50/p99/max, per UART and per USB hop). For finer control build a [`Sim`], attach ports
//! ([`node::Node::add_port`]), change time configurations
//! ([`Sim::configure_clocks`]) and call [`Sim::run_secs`] as often as
//! needed.
//!
//! ## Default models
//!
//! | what | default |
//! |---|---|
//! | MCU node | main-loop latency U[2, 20] µs; oscillator booted U[0, 10] s before true 0, rate error U[−100, 100] ppm, wander U[0.5, 1.5] ppm over a period of U[120, 600] s |
//! | host node | clock root; loop latency 10 µs + Exp(40 µs); rate error U[−50, 50] ppm, same wander |
//! | busy module ([`busy::BusyModel::MOTOR`]) | 5 % of events start a spell of U[20, 200] µs; receive stamps pre-empted |
//! | UART | 2 Mbaud, 10 bits per byte, no propagation delay, jitter, asymmetry, loss or corruption; TX buffer of 2 frames |
//! | USB CDC | 12 Mbit/s, 1 ms frames, transfers U[10, 20] µs after SOF, 13 bytes overhead per 64-byte packet, host TX latency Exp(50 µs), host RX latency Exp(75 µs), OUT and IN both wait for the next frame |
//! | TCP / UDP | loopback: 10 Gbit/s, latency 15 µs + Exp(25 µs) ([`medium::IpParams::LAN`]: 80 µs + Exp(60 µs)) |
//! | runtime | [`SimRuntime`]: 32 slots of 256 bytes, 8 ports, 16 links |
//! | metrics | every 10 ms of true time |
//!
//! ## Modelling choices
//!
//! - Receive stamps: UARTs and USB devices stamp the first byte on the wire
//!   on the receiver's clock (late by the rest of a busy spell if the
//!   receive interrupt is pre-empted); USB hosts and sockets stamp when
//!   their software sees the data.
//! - `queue_delay` and `transmit_time` are computed in true time and
//!   rounded to µs: the ≤ 100 ppm rate error over a wait of a few ms is
//!   below the counter's resolution.
//! - RS-485 is a full-duplex point-to-point UART (no turnaround, no
//!   multi-drop); USB IN and OUT do not compete for the bus.
//! - A busy spell that a frame's first byte starts is placed at that byte's
//!   arrival, which can be up to one frame time before the simulator
//!   handles the frame; polls already made in between are not undone.
//! - A poll is instantaneous in true time; main-loop latency is modelled
//!   before it, not inside it.

#![deny(missing_docs)]
#![forbid(unsafe_code)]

pub mod busy;
pub mod clock;
pub mod error;
pub mod hot_start;
pub mod link;
pub mod machine;
pub mod medium;
pub mod metrics;
pub mod network;
pub mod node;
#[cfg(feature = "plot")]
pub mod plot;
pub mod probe;
pub mod rng;
pub mod scenario;
pub mod sim;
pub mod topology;

pub use error::SimError;
pub use medium::LinkModel;
pub use metrics::{Metrics, Stats, SyncSummary};
pub use network::Network;
pub use node::{NodeKind, NodeSpec, SimRuntime};
pub use scenario::{run, Outcome, Scenario};
pub use sim::{Sim, SimConfig};
pub use topology::{SimSpec, SpecError};

/// True time in nanoseconds.
pub type Nanos = u64;
