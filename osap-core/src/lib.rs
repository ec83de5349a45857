//! # osap-core
//!
//! The sans-IO, `no_std`, allocation-free core of the OSAP network used by
//! osap-rs: a source-routed packet network that spans any mix of links.
//!
//! The pieces, bottom up:
//! - [`packet`]: the packet header and the four route instructions, read and
//!   written in place over a byte buffer.
//! - [`route`]: building routes, walking them, reversing them.
//! - [`framing`]: COBS + CRC-16 frames for byte-stream links.
//! - [`time`]: typed local instants, system instants and durations.
//! - [`stack`]: fixed packet slots kept in earliest-deadline order, with
//!   per-owner hold quotas.
//! - [`transport`]: the sequential request/reply transport.
//! - [`segment`]: datagrams larger than one packet, sent as segments and
//!   reassembled in bounded memory.
//! - [`runtime`]: the loop that serves the stack, forwards packets over link
//!   gateways, delivers them to ports and answers the netresponder (port 0).
//!
//! Nothing here allocates, blocks, or panics on input from the wire: malformed
//! data becomes an error value and a counter. The design follows the OSAP
//! chapter of Jake Read's thesis *Modular Machine Control*; the byte layout is
//! the project's `docs/protocol.md`.
#![no_std]
#![deny(missing_docs)]
// Lints as policy: every public type can be printed, and `pub` means
// reachable from outside the crate.
#![warn(missing_debug_implementations, unreachable_pub)]
#![forbid(unsafe_code)]

#[cfg(feature = "std")]
extern crate std;

pub mod bus;
pub mod clock;
pub mod codec;
pub mod counters;
pub mod framing;
pub mod link;
pub mod netresponder;
pub mod packet;
pub mod port;
pub mod route;
pub mod runtime;
pub mod segment;
pub mod stack;
pub mod time;
pub mod transport;
pub mod usb;

pub use packet::{Instruction, PacketError};
pub use route::Route;
pub use runtime::{Runtime, RuntimeConfig};
pub use time::{Duration, Instant, SystemInstant};
