//! A copy of a clock's local-to-system mapping.
//!
//! Motion and sensor interrupts need synchronized time at a precise local
//! instant, but must not touch the runtime (it belongs to another task).
//! The runtime task publishes a [`TimeMap`] after each poll; an interrupt
//! keeps the latest copy and converts its own counter readings with it. The
//! map holds the rate and any slew in progress, so it stays exact between
//! publications, not just at the moment it was taken.

use crate::Micros;

/// The linear map from a runtime's local counter to system time, as its
/// clock held it when the copy was made. `Copy` and small, for passing to
/// an interrupt.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct TimeMap {
    pub(crate) base_local: Micros,
    pub(crate) base_system: i64,
    pub(crate) base_frac: u32,
    pub(crate) rate_q32: i64,
    pub(crate) slew_q32: i64,
    pub(crate) slew_len: i64,
}

impl TimeMap {
    /// The identity map: system time equals the local counter (a runtime
    /// that has not synchronised yet).
    pub const IDENTITY: TimeMap = TimeMap {
        base_local: 0,
        base_system: 0,
        base_frac: 0,
        rate_q32: 0,
        slew_q32: 0,
        slew_len: 0,
    };

    /// System time at local time `local` (never below 0).
    pub fn system_time(&self, local: Micros) -> u64 {
        self.system_time_q32(local).0.max(0) as u64
    }

    /// Signed system time at `local` as whole µs and a Q32 fraction.
    pub(crate) fn system_time_q32(&self, local: Micros) -> (i64, u32) {
        let delta = local.wrapping_sub(self.base_local) as i64;
        let slewed = delta.min(self.slew_len);
        let adjust = i128::from(delta) * i128::from(self.rate_q32)
            + i128::from(slewed) * i128::from(self.slew_q32)
            + i128::from(self.base_frac);
        let whole = i128::from(self.base_system) + i128::from(delta) + (adjust >> 32);
        let whole = whole.clamp(i128::from(i64::MIN), i128::from(i64::MAX)) as i64;
        (whole, adjust as u32)
    }
}
