//! The module's faults: what stopped, refused or disturbed its axis, kept
//! as one record that the `get_fault` function reports.
//!
//! `get_fault` returns `(time, code, detail, count)`: the latest fault's
//! synchronized time (µs), its kind ([`FaultKind`] code), a detail whose
//! meaning depends on the kind, and the faults counted since boot. Run as a
//! pipe source with the output mode "on change", it sends each new fault
//! once; when several happen between two runs, the count says how many.
//!
//! | code | kind | detail |
//! |---|---|---|
//! | 0 | none yet | 0 |
//! | 1 | [`FaultKind::Refused`]: a control point was refused | the refusal's [`StepperError`] code |
//! | 2 | [`FaultKind::Backstop`]: the stream ran dry mid-motion and the backstop braked the axis | µs since the module last accepted a point (the upstream's quiet time) |
//! | 3 | [`FaultKind::StepOverrun`]: steps went out late | the late steps since the step generator last started (a running count) |
//! | 4 | [`FaultKind::LimitHit`]: the limit switch was pressed | limit edges since boot |
//! | 5 | [`FaultKind::Halted`]: `halt` stopped the axis | 0 |
//! | 6 | [`FaultKind::OverLimit`]: a control point past the axis's limits (`set_limits`) was refused | which limits it went past, as bits: [`OVER_VELOCITY`] 1, [`OVER_ACCELERATION`] 2, [`OVER_JERK`] 4 |
//! | 7 | [`FaultKind::OutputWatchdog`]: upstream was quiet past `set_output_watchdog`'s timeout, and the module put its outputs in their safe state | µs since a call or pipe datagram last reached the module (held at `u32::MAX`) |
//! | 8 | [`FaultKind::HeaterRunaway`]: a heater cut itself off (see [`crate::heater`]) | the heater's index in the low byte, the [`RunawayReason`] code in the next: 1 not heating, 2 fell from target, 3 sensor open, 4 sensor short, 5 over max_temp ([`runaway_detail`]) |
//!
//! While the axis stands stopped by a backstop or a halt, the refusals that
//! follow (code `Faulted`) are counted but keep the record of their cause.
//! So do the `Gap` refusals right behind refused points: the points missing
//! are the ones the module refused, and the record keeps why it did.
//!
//! **Late steps.** A step that went out on a later tick than the one it
//! fell due at (more than one step tick, 10 µs, after the position crossed
//! its boundary: [`maxl::StepStats::late`]) is late: the axis was asked to
//! move faster than one step per tick, and the step generator caught up at
//! one step per tick, a burst a real motor may not follow. No step is
//! lost, but a late step is a fault: a [`FaultKind::StepOverrun`] is
//! recorded after each step word (16 ticks) that sent late steps, its
//! detail the running count of late steps since the step generator last
//! started (at boot, `set_enable`, `halt`, a scale or microstep change:
//! `get_steps`' `late` output), so a host compares the detail with its
//! bound (`[limits] max_late_steps`) and stops as soon as the count passes
//! it. A late-step record never replaces a record of another kind younger
//! than [`FAULT_HOLD`] (100 ms): it waits, and carries the count at the
//! first word after the hold, so a host's `get_fault` source, run every
//! few ms, reports both. A point refused
//! for being past a limit (`OverLimit`) is an [`FaultKind::OverLimit`]
//! fault, not a [`FaultKind::Refused`] one, so that its detail can say
//! which limit.
//!
//! [`StepperError`]: crate::stepper::StepperError
//! [`RunawayReason`]: crate::heater::RunawayReason
//! [`runaway_detail`]: crate::heater::runaway_detail

use crate::stepper::StepperError;
use maxl::Clamped;
use osap_core::{Duration, SystemInstant};

/// How long a record of another kind holds off a late-step record: the
/// late-step record, made after every step word that sent late steps,
/// would otherwise replace a fault 160 µs after it, before a host's
/// `get_fault` source (run every few ms) reported it. Held back, the
/// late-step record is made at the first word after the hold, with the
/// count then.
pub const FAULT_HOLD: Duration = Duration::from_millis(100);

/// [`FaultKind::OverLimit`]'s detail bit: past the velocity limit (the
/// limiter's velocity window looks ahead: the axis could not have ramped its
/// acceleration back to zero at the jerk limit without passing it).
pub const OVER_VELOCITY: u32 = 1;
/// [`FaultKind::OverLimit`]'s detail bit: past the acceleration limit.
pub const OVER_ACCELERATION: u32 = 2;
/// [`FaultKind::OverLimit`]'s detail bit: past the jerk limit.
pub const OVER_JERK: u32 = 4;

/// The [`FaultKind::OverLimit`] detail for the limits `c` says a point
/// went past.
pub fn over_limit_detail(c: Clamped) -> u32 {
    (if c.vel { OVER_VELOCITY } else { 0 })
        | (if c.acc { OVER_ACCELERATION } else { 0 })
        | (if c.jerk { OVER_JERK } else { 0 })
}

/// The names of the limits an [`FaultKind::OverLimit`] detail holds
/// ("velocity", "acceleration", "jerk"), in that order.
pub fn over_limit_names(detail: u32) -> impl Iterator<Item = &'static str> {
    [
        (OVER_VELOCITY, "velocity"),
        (OVER_ACCELERATION, "acceleration"),
        (OVER_JERK, "jerk"),
    ]
    .into_iter()
    .filter(move |(bit, _)| detail & bit != 0)
    .map(|(_, name)| name)
}

/// What kind of fault a module saw: the `code` output of `get_fault`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum FaultKind {
    /// No fault since boot.
    None = 0,
    /// A control point was refused; the detail is the refusal's
    /// [`StepperError`] code.
    Refused = 1,
    /// The stream ran dry mid-motion and the backstop braked the axis; the
    /// detail is how long (µs) the module had gone without accepting a point.
    Backstop = 2,
    /// Steps went out late: on a later tick than the one they fell due at
    /// (the axis was asked to move faster than the step rate); the detail is
    /// the running count of late steps since the step generator last
    /// started (`get_steps`' `late`).
    StepOverrun = 3,
    /// The limit switch was pressed; the detail is the edges seen since boot.
    LimitHit = 4,
    /// `halt` stopped the axis.
    Halted = 5,
    /// A control point past the axis's velocity, acceleration or jerk limit
    /// (`set_limits`) was refused; the detail says which, as bits
    /// ([`OVER_VELOCITY`], [`OVER_ACCELERATION`], [`OVER_JERK`]).
    OverLimit = 6,
    /// The output watchdog fired: no call or pipe datagram reached the
    /// module for `set_output_watchdog`'s timeout, and it put its outputs in
    /// their safe state (see [`crate::watchdog`]); the detail is how long
    /// upstream had been quiet, µs.
    OutputWatchdog = 7,
    /// A heater cut its output and latched off: its temperature ran away or
    /// its sensor failed (see [`crate::heater`]); the detail is the
    /// heater's index in the low byte and the
    /// [`RunawayReason`](crate::heater::RunawayReason) code in the next
    /// ([`runaway_detail`](crate::heater::runaway_detail)).
    HeaterRunaway = 8,
    /// A comparator block made with `halt` halted the axis: its input rose
    /// past its threshold (see [`crate::blocks`]); the detail is the
    /// block's slot.
    BlockHalt = 9,
}

impl FaultKind {
    /// Every kind, in code order.
    pub const ALL: [FaultKind; 10] = [
        FaultKind::None,
        FaultKind::Refused,
        FaultKind::Backstop,
        FaultKind::StepOverrun,
        FaultKind::LimitHit,
        FaultKind::Halted,
        FaultKind::OverLimit,
        FaultKind::OutputWatchdog,
        FaultKind::HeaterRunaway,
        FaultKind::BlockHalt,
    ];

    /// The kind's code.
    pub fn code(self) -> u8 {
        self as u8
    }

    /// The kind of code `code`, if it is one.
    pub fn from_code(code: u8) -> Option<FaultKind> {
        FaultKind::ALL.get(usize::from(code)).copied()
    }

    /// A short name.
    pub fn name(self) -> &'static str {
        match self {
            FaultKind::None => "none",
            FaultKind::Refused => "refused point",
            FaultKind::Backstop => "backstop",
            FaultKind::StepOverrun => "late steps",
            FaultKind::LimitHit => "limit hit",
            FaultKind::Halted => "halted",
            FaultKind::OverLimit => "point over limit",
            FaultKind::OutputWatchdog => "output watchdog",
            FaultKind::HeaterRunaway => "heater runaway",
            FaultKind::BlockHalt => "halted by a block",
        }
    }
}

/// The latest fault and the count since boot, as `get_fault` reports them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Fault {
    /// When (system time).
    pub time: SystemInstant,
    /// What.
    pub kind: FaultKind,
    /// The kind's detail (see the module docs).
    pub detail: u32,
    /// Faults since boot.
    pub count: u32,
}

impl Default for Fault {
    fn default() -> Self {
        Fault {
            time: SystemInstant::ZERO,
            kind: FaultKind::None,
            detail: 0,
            count: 0,
        }
    }
}

impl Fault {
    /// Counts a fault of `kind` at synchronized `time` and makes it the
    /// record, unless it is a consequence of the recorded one (a `Faulted`
    /// refusal behind a backstop or halt that still holds the axis,
    /// `stopped`).
    pub fn record(&mut self, time: SystemInstant, kind: FaultKind, detail: u32, stopped: bool) {
        self.count = self.count.wrapping_add(1);
        // Late steps drained while the axis stopped keep the stop as the
        // record too.
        let consequence = stopped
            && kind == FaultKind::Refused
            && detail == u32::from(StepperError::Faulted.code())
            && matches!(
                self.kind,
                FaultKind::Backstop | FaultKind::Halted | FaultKind::StepOverrun
            );
        if !consequence {
            self.time = time;
            self.kind = kind;
            self.detail = detail;
        }
    }

    /// Counts a fault that follows from the recorded one (a point refused
    /// for a gap the module's own refusals opened), keeping the record.
    pub fn count_consequence(&mut self) {
        self.count = self.count.wrapping_add(1);
    }

    /// Whether a late-step record may replace the record at synchronized
    /// `now`: it is none, a late-step record, or at least [`FAULT_HOLD`]
    /// old.
    pub fn takes_late_steps(&self, now: SystemInstant) -> bool {
        matches!(self.kind, FaultKind::None | FaultKind::StepOverrun)
            || now - self.time >= FAULT_HOLD
    }

    /// The `get_fault` outputs (the time as system µs, its wire form).
    pub fn outputs(&self) -> (u64, u8, u32, u32) {
        (
            self.time.as_micros(),
            self.kind.code(),
            self.detail,
            self.count,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_round_trip() {
        for k in FaultKind::ALL {
            assert_eq!(FaultKind::from_code(k.code()), Some(k));
        }
        assert_eq!(FaultKind::from_code(8), Some(FaultKind::HeaterRunaway));
        assert_eq!(FaultKind::from_code(9), Some(FaultKind::BlockHalt));
        assert_eq!(FaultKind::from_code(10), None);
        assert_eq!(FaultKind::from_code(255), None);
    }

    #[test]
    fn a_refusal_behind_a_backstop_keeps_its_cause() {
        let mut f = Fault::default();
        f.record(
            SystemInstant::from_micros(10),
            FaultKind::Backstop,
            5_000,
            true,
        );
        f.record(SystemInstant::from_micros(20), FaultKind::Refused, 4, true);
        assert_eq!(f.outputs(), (10, 2, 5_000, 2));
        // Once the axis runs again, a refusal is the record.
        f.record(SystemInstant::from_micros(30), FaultKind::Refused, 4, false);
        assert_eq!(f.outputs(), (30, 1, 4, 3));
        f.record(SystemInstant::from_micros(40), FaultKind::Refused, 2, true);
        assert_eq!(f.outputs(), (40, 1, 2, 4));
    }

    #[test]
    fn late_steps_wait_behind_a_younger_fault_of_another_kind() {
        let at = SystemInstant::from_micros;
        let mut f = Fault::default();
        assert!(f.takes_late_steps(at(0)));
        f.record(at(1_000), FaultKind::StepOverrun, 3, false);
        assert!(f.takes_late_steps(at(1_160)), "updates its own kind");
        f.record(at(2_000), FaultKind::LimitHit, 1, false);
        assert!(!f.takes_late_steps(at(2_160)));
        assert!(!f.takes_late_steps(at(101_999)));
        assert!(f.takes_late_steps(at(102_000)));
        // A refusal behind a stop that late steps followed keeps them.
        f.record(at(200_000), FaultKind::Backstop, 5_000, true);
        f.record(at(400_000), FaultKind::StepOverrun, 9, true);
        f.record(at(400_100), FaultKind::Refused, 4, true);
        assert_eq!(f.outputs(), (400_000, 3, 9, 5));
    }

    #[test]
    fn over_limit_details_name_their_limits() {
        use std::vec::Vec;
        let all = Clamped {
            jerk: true,
            acc: true,
            vel: true,
        };
        assert_eq!(over_limit_detail(Clamped::default()), 0);
        assert_eq!(over_limit_detail(all), 7);
        let acc = Clamped {
            acc: true,
            ..Clamped::default()
        };
        assert_eq!(over_limit_detail(acc), OVER_ACCELERATION);
        assert_eq!(
            over_limit_names(7).collect::<Vec<_>>(),
            ["velocity", "acceleration", "jerk"]
        );
        assert_eq!(over_limit_names(OVER_JERK).collect::<Vec<_>>(), ["jerk"]);
        assert_eq!(over_limit_names(0).count(), 0);
    }
}
