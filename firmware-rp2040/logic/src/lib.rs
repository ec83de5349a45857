//! The board-independent logic of firmware-rp2040, kept apart so it builds
//! and is tested on the host: the name record in flash ([`name_store`])
//! and the receive framer that splits a link's byte stream into packets
//! and time-stamps them ([`framer`]), with the serial line's timing
//! ([`serial`]). Nothing here touches a peripheral.
#![no_std]
#![deny(missing_docs)]
#![forbid(unsafe_code)]

pub mod framer;
pub mod name_store;
pub mod serial;
