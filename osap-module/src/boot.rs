//! Rebooting into the board's bootloader for a firmware update
//! (`enter_bootloader`, what `osap flash` calls).
//!
//! The function only arms the request: a module that rebooted inside the
//! call would never send its answer, and the caller could not tell a
//! module that obeyed from one that was lost. The runtime's loop performs
//! the reboot ([`crate::board::Board::reboot_to_bootloader`], from the pulse
//! timer port it polls) [`BOOTLOADER_DELAY`] after the call, by which
//! time the answer has left on its link. Before rebooting the driver is
//! disabled, as a reset would leave it.

use osap_core::{Duration, Instant};

/// How long after `enter_bootloader` answers the board reboots, on the
/// module's local clock: time for the answer to leave (a USB CDC reply
/// waits for the host's next poll, at most a 1 ms frame; a UART reply of
/// a few dozen bytes takes well under 1 ms at 1 Mbaud) with a wide margin.
pub const BOOTLOADER_DELAY: Duration = Duration::from_millis(100);

/// Why `enter_bootloader` was refused: the failure code a caller sees.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
#[non_exhaustive]
pub enum BootError {
    /// This board has no bootloader the firmware can reboot into (its
    /// [`crate::board::Board`] does not offer one): put it into its
    /// bootloader by hand (BOOTSEL held at power-up on a Pico, a double
    /// tap of reset on a SAMD51 board).
    Unsupported = 1,
    /// The axis has motion queued or running: a reboot would stop the motor
    /// mid-move. Let the motion finish, or halt it, first.
    Moving = 2,
}

impl BootError {
    /// Every boot error, in code order.
    pub const ALL: [BootError; 2] = [BootError::Unsupported, BootError::Moving];

    /// The failure code.
    pub const fn code(self) -> u8 {
        self as u8
    }

    /// The error with failure code `code`; `None` for a code that is not a
    /// boot error (see [`crate::failure::Refusal`]).
    pub fn from_code(code: u8) -> Option<BootError> {
        Self::ALL.into_iter().find(|e| e.code() == code)
    }
}

impl core::fmt::Display for BootError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            BootError::Unsupported => "this board cannot reboot into a bootloader",
            BootError::Moving => "the axis has motion queued or running",
        })
    }
}

impl core::error::Error for BootError {}

impl From<BootError> for pipes_core::FailureCode {
    fn from(e: BootError) -> Self {
        pipes_core::FailureCode::Other(e.code())
    }
}

impl From<BootError> for pipes_core::function::CallError {
    fn from(e: BootError) -> Self {
        pipes_core::function::CallError::Failed(e.into())
    }
}

/// A reboot request: armed by `enter_bootloader`, performed by the
/// runtime's loop once due.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BootRequest {
    at: Option<Instant>,
}

impl BootRequest {
    /// Arms the request for [`BOOTLOADER_DELAY`] after local time `now`
    /// (a second call keeps the first time: the answer to the first call
    /// has been sent already).
    pub fn arm(&mut self, now: Instant) {
        if self.at.is_none() {
            self.at = Some(now + BOOTLOADER_DELAY);
        }
    }

    /// When the reboot is due, local µs (`None`: not armed).
    pub fn due_at(&self) -> Option<Instant> {
        self.at
    }

    /// Whether the reboot is due at local time `now`; if so, disarms it
    /// (the board is told once).
    pub fn take_due(&mut self, now: Instant) -> bool {
        match self.at {
            Some(at) if now >= at => {
                self.at = None;
                true
            }
            _ => false,
        }
    }
}
