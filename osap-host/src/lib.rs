//! # osap-host
//!
//! The OSAP runtime on a host operating system, driven by tokio.
//!
//! - [`Host`]: a task that owns an `osap_core::Runtime` and polls it when a
//!   link or a port has news or a deadline comes due, never on a timer tick.
//! - [`link`]: link gateways whose I/O runs in their own tasks: in-process
//!   queues, and (in submodules) serial, TCP, UDP and Unix sockets.
//! - [`port`]: async ports: send datagrams, make requests and await their
//!   replies with timeouts.
//! - [`driver`]: the loop that drives a runtime, shared with the simulated
//!   modules of `osap-sim`.
//!
//! The host is the clock root (tier 0) by default. Its clock reads tokio's
//! ([`clock`]), so a host on a runtime with paused time runs in virtual
//! time. This crate is a library only: the `osap` command line is
//! `osap-cli`, simulated machines are `osap-sim`.
#![deny(missing_docs)]
// Lints as policy: every public type can be printed, and `pub` means
// reachable from outside the crate.
#![warn(missing_debug_implementations, unreachable_pub)]

pub mod clock;
pub mod driver;
pub mod error;
pub mod link;
pub mod map;
pub mod netrunner;
pub mod port;
pub mod runtime;
pub mod som;

pub use clock::{HostClock, Pace};
pub use error::HostError;
pub use link::{LinkConfig, LinkIo};
pub use port::{Datagram, PortHandle};
pub use runtime::{Host, HostConfig};

/// The runtime a host runs: 64 packet slots of 1 KiB, 256 port indices and
/// 32 link gateways.
pub type HostRuntime = osap_core::Runtime<64, 1024, 256, 32>;
/// Largest packet a host handles.
pub const HOST_MTU: usize = 1024;
