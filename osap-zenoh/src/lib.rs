//! A machine served on [zenoh](https://zenoh.io), so that a lab or a fleet
//! reaches it from anywhere, from Rust, Python, C, JavaScript or anything
//! else zenoh has a client for.
//!
//! A [`Bridge`] serves one [`osap_machine::Machine`] under `osap/NAME/…`
//! ([`keys`]): its info, state (published at 20 Hz) and events, any module
//! function as a query, homing, halting, and jobs. [`ZenohOptions`] builds
//! the session's configuration and refuses one that would expose the
//! machine off loopback without TLS and authentication. [`fleet`] finds
//! every machine a session can reach. `osap bridge` and `osap fleet` are
//! this crate on the command line; docs/fleet.md has the whole protocol.

pub mod bridge;
pub mod config;
pub mod fleet;
pub mod json;
pub mod keys;

pub use bridge::{Bridge, BridgeError, BridgeOptions};
pub use config::{ConfigError, ZenohOptions};
pub use keys::MachineKeys;
/// The zenoh this crate is built on (its version and transports), for
/// clients and the CLI.
pub use zenoh;
