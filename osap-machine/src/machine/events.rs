//! What a machine reports while it runs.

pub use osap_module::fault::FaultKind;

use super::error::StopReport;

/// What the machine is doing.
#[derive(Debug, Clone, PartialEq)]
pub enum MachineState {
    /// At rest, ready for moves.
    Idle,
    /// Moves are running or queued.
    Moving,
    /// Homing.
    Homing,
    /// Stopped on a fault: moves are refused until
    /// [`Machine::recover`](super::Machine::recover).
    Faulted(String),
    /// The machine has been stopped.
    Stopped,
}

/// Something that happened on the machine, as [`Machine::events`](super::Machine::events)
/// streams it. Times are synchronized system µs.
#[derive(Debug, Clone, PartialEq)]
pub enum MachineEvent {
    /// A module reported a fault through its `get_fault` source: a
    /// refused point, its backstop, late steps, a limit press (on a
    /// module whose switch homing does not watch) or a halt that the
    /// machine did not send itself. Every kind stops the machine, but late
    /// steps within `[limits] max_late_steps` and refusals for a motor the
    /// machine file leaves disabled.
    Fault {
        /// The module's key.
        module: String,
        /// What kind of fault.
        kind: FaultKind,
        /// The kind's detail: the refusal code, the backstop's quiet time
        /// (µs), the steps owed, the limit edges (see
        /// [`osap_module::fault`]).
        detail: u32,
        /// When the module saw it (its synchronized time stamp).
        time: u64,
        /// Why, in words (what follows "module NAME ").
        reason: String,
    },
    /// A limit switch changed.
    Limit {
        /// The module whose limit input changed.
        module: String,
        /// When (the module's time stamp of the edge).
        time: u64,
        /// Pressed (true) or released.
        pressed: bool,
        /// Whether homing or probing was expecting it: a press on the
        /// switch of the axis being homed, or on the probe being searched
        /// with. Any other press halts the machine.
        expected: bool,
    },
    /// A module stopped answering.
    LinkLost {
        /// The module's key.
        module: String,
    },
    /// A module refused control points.
    Refused {
        /// The module's key.
        module: String,
        /// Points refused since the machine started.
        count: u32,
        /// The latest refusal's reason.
        reason: String,
    },
    /// An axis was homed.
    Homed {
        /// The axis.
        axis: String,
    },
    /// The machine's state changed.
    State(MachineState),
    /// A stop ended: which modules confirmed their halt and their tools
    /// off, and which could not be reached.
    Stop(StopReport),
}
