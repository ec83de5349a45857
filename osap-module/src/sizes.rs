//! The module runtime's sizes: one set, which every firmware and every
//! simulated module builds its runtime with, so a simulated module queues,
//! refuses and drops packets as a board does.
//!
//! `osap_core::Runtime<SLOTS, MTU, PORTS, LINKS>` is a module's runtime.

/// Packet slots: enough for two links' quotas, the ports' and replies.
pub const SLOTS: usize = 16;

/// Largest packet a module takes, bytes (a slot's size; as on an RP2040
/// or SAMD51).
pub const MTU: usize = 256;

/// Port indices with quotas (port 0 included): every index the module's
/// ports take, or the functions past the last would never reply.
pub const PORTS: usize = crate::PORT_INDICES;

/// Link gateways of a module board: USB CDC (link 0) and a UART (link 1).
pub const LINKS: usize = 2;
