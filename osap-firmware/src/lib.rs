//! The board-independent part of osap-rs module firmware, shared by every
//! board crate (firmware-rp2040, firmware-samd51), which adds only its
//! peripherals:
//!
//! - [`link`]: the hand-over between a byte-stream link's I/O tasks and the
//!   runtime, and the gateway the runtime polls;
//! - [`framer`]: the receive framer that splits a link's byte stream into
//!   packets and time-stamps them, with a serial line's timing in
//!   [`serial`] and USB's in [`usb`];
//! - [`runtime`]: the runtime's loop;
//! - [`name_store`]: the name record in flash, and [`flash_writes`]: a name
//!   or bus role the network sets, held for the flash until the axis
//!   stands;
//! - [`rate_store`]: the learned clock rate, logged in its own flash
//!   sector, and [`hot_start`]: when to preset the clock from it and when
//!   to save it (osap-module's, re-exported: the logic is hardware-free and
//!   the simulator runs it too; each board crate implements
//!   [`rate_store::RateFlash`] over its flash);
//! - [`timebase`]: a 64-bit time base on a 32-bit hardware counter, for
//!   boards that bring their own embassy time driver.
//!
//! It needs an embassy time driver and executor only where a board runs
//! [`runtime::run`]; everything else is tested on the host.
#![no_std]
#![deny(missing_docs)]
// Lints as policy: every public type can be printed, and `pub` means
// reachable from outside the crate.
#![warn(missing_debug_implementations, unreachable_pub)]
#![forbid(unsafe_code)]

pub mod flash_writes;
pub mod framer;
pub mod link;
pub mod name_store;
pub mod runtime;
pub mod serial;
pub mod timebase;
pub mod usb;

pub use osap_module::{hot_start, rate_store};

/// This device's local clock now: embassy-time's µs counter as the
/// runtime's [`osap_core::Instant`].
pub fn local_now() -> osap_core::Instant {
    osap_core::Instant::from_micros(embassy_time::Instant::now().as_micros())
}
