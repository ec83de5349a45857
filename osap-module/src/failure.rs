//! Failure codes by name: what a refusal of one of the module's functions
//! means, and how to fix it.
//!
//! A function that refuses answers `CallError::Failed(code)`; over the
//! network that is a bare byte, and its meaning depends on the function:
//! `add_point`'s code 2 is [`StepperError::Stale`], `pulse`'s code 2 is
//! [`IoError::BadValue`]. [`failure`] names a code for a function of this
//! crate's function set ([`crate::functions::SIGNATURES`]); it knows
//! nothing of other devices' functions, so a host must first tell that a
//! device runs osap-module (osap-host does so by its whole function set).
//!
//! The names come from the error enums themselves: each table below is an
//! exhaustive match, so a new variant does not compile until it is named
//! here, and the list of variants a code is looked up in is made by the
//! same macro from the same lines.
//!
//! Each function publishes its table with its signature
//! ([`FnId::failures`]: its family's codes, then [`NOT_INSTALLED`] and
//! [`INPUT_DECODE_FAILED`], the two generic codes a module function can
//! return), so a host names a refusal from what the module sent, knowing
//! nothing of osap-module ([`pipes_core::failure`]). The tables are in
//! every firmware image for that reason; the lookups by name below are
//! for hosts and the simulator.

use crate::boot::BootError;
use crate::functions::{FnId, ALL, NOT_INSTALLED, SIGNATURES};
use crate::heater::HeaterError;
use crate::io::IoError;
use crate::loadcell::LoadCellError;
use crate::sampler::SamplerError;
use crate::stepper::StepperError;
use pipes_core::export::{INPUT_DECODE_FAILED, NO_SUCH_MEMBER, STATE_BUSY};

/// One failure code, by name: pipes-core's, the same type a function
/// publishes with its signature (`QueueFull (code 8): ..` when printed).
pub use pipes_core::failure::Failure;

/// Which failure codes a function returns, besides the [`generic`] ones.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Family {
    /// [`StepperError`] codes.
    Stepper,
    /// [`IoError`] codes.
    Io,
    /// [`BootError`] codes (`enter_bootloader`).
    Boot,
    /// [`HeaterError`] codes (the `heater_` functions).
    Heater,
    /// [`LoadCellError`] codes (the `loadcell_` functions).
    LoadCell,
    /// [`SamplerError`] codes (`sample_block`).
    Sampler,
    /// None of its own: the function cannot refuse (beyond [`generic`]).
    None,
}

impl Family {
    /// The family of function `id`, as the table at the top of
    /// [`crate::functions`] has it.
    pub const fn of(id: FnId) -> Family {
        use FnId as F;
        // Exhaustive: a new function does not compile until its family is
        // chosen here. A function with an error enum of its own gets a new
        // `Family` variant, named by a new `failures!` table below and an
        // arm in `Family::failure`, as `enter_bootloader` does.
        match id {
            F::add_point
            | F::set_interval
            | F::set_scale
            | F::set_microsteps
            | F::set_limits
            | F::set_torque => Family::Stepper,
            F::digital_write
            | F::digital_read
            | F::pwm_write
            | F::pulse
            | F::pulse_at
            | F::analog_read
            | F::set_safe_pwm
            | F::set_safe_digital
            | F::tach_setup
            | F::tach_read
            | F::level_point
            | F::event_point
            | F::level_read => Family::Io,
            F::get_position
            | F::get_status
            | F::get_counters
            | F::get_steps
            | F::set_enable
            | F::read_limit
            | F::halt
            | F::get_fault
            | F::set_output_watchdog
            | F::torque_off => Family::None,
            F::enter_bootloader => Family::Boot,
            F::heater_sensor
            | F::heater_output
            | F::heater_limits
            | F::heater_gains
            | F::heater_runaway
            | F::heater_target
            | F::heater_power
            | F::heater_read
            | F::heater_clear => Family::Heater,
            F::loadcell_setup | F::loadcell_tare | F::loadcell_scale | F::loadcell_read => {
                Family::LoadCell
            }
            F::sample_block => Family::Sampler,
        }
    }

    /// The table a function of this family publishes: its own codes, then
    /// [`NOT_INSTALLED`] and [`INPUT_DECODE_FAILED`].
    pub const fn failures(self) -> &'static [Failure] {
        match self {
            Family::Stepper => &STEPPER_FAILURES,
            Family::Io => &IO_FAILURES,
            Family::Boot => &BOOT_FAILURES,
            Family::Heater => &HEATER_FAILURES,
            Family::LoadCell => &LOADCELL_FAILURES,
            Family::Sampler => &SAMPLER_FAILURES,
            Family::None => &GENERIC_FAILURES,
        }
    }

    /// What `code` means for a function of this family (its own codes
    /// only; see [`failure`] for the generic ones too).
    pub fn failure(self, code: u8) -> Option<Failure> {
        match self {
            Family::Stepper => find(STEPPER.iter().map(|&e| stepper(e)), code),
            Family::Io => find(IO.iter().map(|&e| io(e)), code),
            Family::Boot => find(BOOT.iter().map(|&e| boot(e)), code),
            Family::Heater => find(HEATER.iter().map(|&e| heater(e)), code),
            Family::LoadCell => find(LOADCELL.iter().map(|&e| loadcell(e)), code),
            Family::Sampler => find(SAMPLER.iter().map(|&e| sampler(e)), code),
            Family::None => None,
        }
    }
}

/// What failure `code` of the module function named `function` means:
/// its family's code, or a [`generic`] one; `None` for a code the function
/// does not return, or a name that is not one of the module's functions.
pub fn failure(function: &str, code: u8) -> Option<Failure> {
    let id = function_id(function)?;
    Family::of(id).failure(code).or_else(|| generic(code))
}

impl FnId {
    /// The failure table function `id` publishes with its signature
    /// ([`Family::failures`] of its family).
    pub const fn failures(self) -> &'static [Failure] {
        Family::of(self).failures()
    }
}

/// [`NOT_INSTALLED`] by name.
const NOT_INSTALLED_FAILURE: Failure = Failure {
    code: NOT_INSTALLED,
    name: "NotInstalled",
    reason: "the firmware never installed its board (a firmware bug): flash a released firmware",
};

/// [`INPUT_DECODE_FAILED`] by name.
const INPUT_DECODE_FAILURE: Failure = Failure {
    code: INPUT_DECODE_FAILED,
    name: "InputDecodeFailed",
    reason: "an input was missing or not of its declared type (inputs are converted before \
             the call, so this is a bug): report it with the call that caused it",
};

/// What a function without codes of its own publishes: the generic codes
/// a module function can return. (`StateBusy` and `NoSuchMember` are class
/// members' codes; no module function returns them.)
pub static GENERIC_FAILURES: [Failure; 2] = [NOT_INSTALLED_FAILURE, INPUT_DECODE_FAILURE];

/// The module function named `function`.
pub fn function_id(function: &str) -> Option<FnId> {
    ALL.iter()
        .copied()
        .find(|&id| SIGNATURES[id as usize].name == function)
}

/// The codes every module function may return whatever its family:
/// [`NOT_INSTALLED`] and pipes-core's generated wrappers' codes
/// ([`pipes_core::export`]).
pub fn generic(code: u8) -> Option<Failure> {
    let (name, reason) = match code {
        NOT_INSTALLED => return Some(NOT_INSTALLED_FAILURE),
        INPUT_DECODE_FAILED => return Some(INPUT_DECODE_FAILURE),
        STATE_BUSY => (
            "StateBusy",
            "a class member ran while the class's state was in use elsewhere: call it again",
        ),
        NO_SUCH_MEMBER => (
            "NoSuchMember",
            "the class has no such member: scan again (the firmware may have changed)",
        ),
        _ => return None,
    };
    Some(Failure { code, name, reason })
}

/// A refusal of one of the module's functions, decoded from its failure
/// code ([`pipes_core::FailureCode`]'s byte): by name where this version
/// knows the code for the function's [`Family`], [`Refusal::Other`] for a
/// code it does not know (a newer firmware's). Decoding never fails, and
/// [`Refusal::code`] gives the wire byte back.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum Refusal {
    /// A stepper function's refusal.
    Stepper(StepperError),
    /// An I/O function's refusal.
    Io(IoError),
    /// `enter_bootloader`'s refusal.
    Boot(BootError),
    /// A heater function's refusal.
    Heater(HeaterError),
    /// A load-cell function's refusal.
    LoadCell(LoadCellError),
    /// `sample_block`'s refusal.
    Sampler(SamplerError),
    /// [`NOT_INSTALLED`]: the firmware never installed its board.
    NotInstalled,
    /// One of pipes-core's generated wrappers' codes
    /// ([`pipes_core::FailureCode::InputDecodeFailed`],
    /// [`pipes_core::FailureCode::StateBusy`],
    /// [`pipes_core::FailureCode::NoSuchMember`]).
    Wrapper(pipes_core::FailureCode),
    /// A code this version does not know for the function's family.
    Other(u8),
}

impl Refusal {
    /// The refusal that failure code `code` of a function of `family`
    /// means.
    pub fn from_code(family: Family, code: u8) -> Refusal {
        let own = match family {
            Family::Stepper => StepperError::from_code(code).map(Refusal::Stepper),
            Family::Io => IoError::from_code(code).map(Refusal::Io),
            Family::Boot => BootError::from_code(code).map(Refusal::Boot),
            Family::Heater => HeaterError::from_code(code).map(Refusal::Heater),
            Family::LoadCell => LoadCellError::from_code(code).map(Refusal::LoadCell),
            Family::Sampler => SamplerError::from_code(code).map(Refusal::Sampler),
            Family::None => None,
        };
        own.unwrap_or(match pipes_core::FailureCode::from_code(code) {
            pipes_core::FailureCode::Other(NOT_INSTALLED) => Refusal::NotInstalled,
            pipes_core::FailureCode::Other(c) => Refusal::Other(c),
            named => Refusal::Wrapper(named),
        })
    }

    /// The refusal of the module function `id` with failure code `code`.
    pub fn of(id: FnId, code: u8) -> Refusal {
        Refusal::from_code(Family::of(id), code)
    }

    /// The wire byte.
    pub fn code(self) -> u8 {
        match self {
            Refusal::Stepper(e) => e.code(),
            Refusal::Io(e) => e.code(),
            Refusal::Boot(e) => e.code(),
            Refusal::Heater(e) => e.code(),
            Refusal::LoadCell(e) => e.code(),
            Refusal::Sampler(e) => e.code(),
            Refusal::NotInstalled => NOT_INSTALLED,
            Refusal::Wrapper(c) => c.code(),
            Refusal::Other(c) => c,
        }
    }

    /// The refusal by name, with what it means; `None` for
    /// [`Refusal::Other`].
    pub fn failure(self) -> Option<Failure> {
        match self {
            Refusal::Stepper(e) => Some(stepper(e)),
            Refusal::Io(e) => Some(io(e)),
            Refusal::Boot(e) => Some(boot(e)),
            Refusal::Heater(e) => Some(heater(e)),
            Refusal::LoadCell(e) => Some(loadcell(e)),
            Refusal::Sampler(e) => Some(sampler(e)),
            Refusal::NotInstalled | Refusal::Wrapper(_) => generic(self.code()),
            Refusal::Other(_) => None,
        }
    }
}

impl From<Refusal> for pipes_core::FailureCode {
    fn from(r: Refusal) -> Self {
        pipes_core::FailureCode::from_code(r.code())
    }
}

impl core::fmt::Display for Refusal {
    /// Like [`Failure`]'s; `unknown failure code 42` for [`Refusal::Other`].
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self.failure() {
            Some(failure) => failure.fmt(f),
            None => write!(f, "unknown failure code {}", self.code()),
        }
    }
}

impl core::error::Error for Refusal {}

fn find(mut all: impl Iterator<Item = Failure>, code: u8) -> Option<Failure> {
    all.find(|f| f.code == code)
}

/// `fn $name(e) -> Failure`, an exhaustive match naming each variant of
/// `$enum` with its reason, `$all`, every variant, and `$table`, the table
/// the family's functions publish, all from the same lines.
macro_rules! failures {
    (
        $(#[$doc:meta])*
        $vis:vis fn $name:ident, $all:ident, $table:ident: $enum:ident {
            $($variant:ident => $reason:expr,)*
        }
    ) => {
        $(#[$doc])*
        $vis const fn $name(e: $enum) -> Failure {
            match e {
                $($enum::$variant => Failure {
                    code: $enum::$variant as u8,
                    name: stringify!($variant),
                    reason: $reason,
                },)*
            }
        }

        #[doc = concat!("Every [`", stringify!($enum), "`].")]
        pub const $all: &[$enum] = &[$($enum::$variant),*];

        #[doc = concat!(
            "The table a function refusing with [`", stringify!($enum),
            "`] publishes: every variant, then the generic codes."
        )]
        pub static $table: [Failure; $all.len() + GENERIC_FAILURES.len()] = [
            $($name($enum::$variant),)*
            NOT_INSTALLED_FAILURE,
            INPUT_DECODE_FAILURE,
        ];
    };
}

failures! {
    /// A stepper function's refusal ([`StepperError`]), by name.
    pub fn stepper, STEPPER, STEPPER_FAILURES: StepperError {
        Misaligned => "time not a multiple of the interval: stamp points on the interval's \
                       grid (set_interval sets it)",
        Stale => "point not after the newest queued one (arrived late): send points in time \
                  order, further ahead of their time",
        Gap => "two or more points missing before this one: send every interval's point \
                (a lossy link drops them: check its counters)",
        Faulted => "the axis is faulted or halted: cycle the motor's enable (set_enable \
                    false, then true)",
        OutOfRange => "position not finite or beyond 2^46 microsteps: send finite \
                       positions in the motor's units (set_scale sets them)",
        Disabled => "the motor is disabled: enable it first (set_enable true)",
        Discontinuous => "a new stream must start where the axis stands: start it at \
                          get_position's position",
        QueueFull => "the module's queue is full (stream too far ahead): send points closer \
                      to their time",
        Busy => "the setting can only change while no stream is queued: let the stream run \
                 out (or halt) first",
        BadValue => "the value is not allowed: an interval is a power of two from 256 to \
                     16 384 µs, a scale finite and positive, microsteps a mode the driver \
                     has, limits finite, not negative and not rounding to nothing, a torque \
                     within -1..=1",
        OverLimit => "the point is past the axis's velocity, acceleration or jerk limit \
                      (set_limits; get_fault says which): plan the motion within the limits, \
                      or raise them",
        Unsupported => "no shaft encoder or coil drive on this board: use position mode",
        WrongMode => "the motor is a torque device: torque_off first",
    }
}

failures! {
    /// An I/O function's refusal ([`IoError`]), by name.
    pub fn io, IO, IO_FAILURES: IoError {
        NoSuchPin => "no such pin, PWM output or analog input on this board: check the \
                      board's pin numbers",
        BadValue => "a value out of range: a duty cycle is within 0..=1, a pulse at most \
                     10 s long, a scheduled start at most 60 s ahead",
        Full => "every slot for scheduled pulses (16) or track points is taken: wait for \
                 some to run, or schedule less far ahead",
        NoHardware => "this firmware has no I/O hardware: use a board build with I/O",
        HeaterOutput => "a heater drives that PWM output: set it through heater_target or \
                         heater_power, or move the heater to another output (heater_output)",
        NoCounter => "no pulse counter on that pin, or no tachometer set up: tach_setup on a \
                      pin the board counts pulses on first",
        Late => "the point's time had passed: send points further ahead",
        OutOfOrder => "stamped before one queued for its output: send points in time order",
    }
}

failures! {
    /// A heater function's refusal ([`HeaterError`]), by name.
    pub fn heater, HEATER, HEATER_FAILURES: HeaterError {
        NoSuchHeater => "no such heater: a module has heaters 0 and 1",
        NoSuchPin => "no such PWM output or analog input on this board: check the board's \
                      pin numbers",
        BadValue => "a value out of range: a thermistor's curve falls as it warms, a pullup \
                     or max_power (at most 1) is positive, min_temp below max_temp, gains and \
                     runaway settings not negative, a target in [min_temp, max_temp), a duty \
                     in 0..=1",
        NotConfigured => "the heater is not configured: give it heater_sensor, heater_output \
                          and heater_limits (and heater_gains for a target) first",
        Faulted => "the heater is latched off by a runaway fault (get_fault says why): fix \
                    the cause, then heater_clear",
        SensorFault => "the heater's sensor reads open, shorted or out of its limits: check \
                        the thermistor and its wiring, then heater_clear again",
        Busy => "the setting can only change while the heater is off: heater_target 0 first",
        NoHardware => "this firmware has no I/O hardware: use a board build with I/O",
        InUse => "another heater drives that PWM output: give each heater its own output",
    }
}

failures! {
    /// A load-cell function's refusal ([`LoadCellError`]), by name.
    pub fn loadcell, LOADCELL, LOADCELL_FAILURES: LoadCellError {
        NoSuchPin => "no such digital pin on this board, or data and clock on one pin: give \
                      the converter's two pins",
        BadValue => "a value out of range: a scale finite and not 0, a tare of 1 to 1000 \
                     samples",
        NotConfigured => "the load cell is not set up: loadcell_setup with its pins first",
        NoHardware => "this firmware has no I/O hardware: use a board build with I/O",
        NoConverter => "data line low after a read, so no converter drives it: check its \
                        wiring, then loadcell_setup",
        Silent => "no sample for 0.5 s: check the converter's power and data line",
    }
}

failures! {
    /// `sample_block`'s refusal ([`SamplerError`]), by name.
    pub fn sampler, SAMPLER, SAMPLER_FAILURES: SamplerError {
        BadSource => "a source is not one of the module's read functions (outputs, and no \
                      input or one u8 input; not sample_block): name read functions such as \
                      get_position or analog_read",
        TooLarge => "one sample of the sources does not fit a block: sample fewer sources at \
                     once",
    }
}

failures! {
    /// `enter_bootloader`'s refusal ([`BootError`]), by name.
    pub fn boot, BOOT, BOOT_FAILURES: BootError {
        Unsupported => "this board cannot reboot into a bootloader from its firmware: put it \
                        into its bootloader by hand (hold BOOTSEL while plugging a Pico in, \
                        double-tap reset on a SAMD51 board)",
        Moving => "the axis has motion queued or running: let it finish, or halt it, then \
                   ask again",
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeSet;
    use std::string::ToString;

    #[test]
    fn every_stepper_error_is_named_by_its_variant() {
        let mut codes = BTreeSet::new();
        for &e in STEPPER {
            let f = stepper(e);
            assert_eq!(f.code, e.code());
            assert_eq!(std::format!("{e:?}"), f.name);
            assert!(codes.insert(f.code), "{} twice", f.code);
            assert!(f.reason.contains(": "), "{f}: name the fix");
            assert_eq!(failure("add_point", f.code), Some(f));
            assert_eq!(failure("set_microsteps", f.code), Some(f));
        }
        assert_eq!(
            failure("add_point", 8).unwrap().to_string(),
            "QueueFull (code 8): the module's queue is full (stream too far ahead): \
             send points closer to their time"
        );
    }

    #[test]
    fn refusals_decode_by_family_and_unknown_codes_are_other() {
        for byte in 0..=u8::MAX {
            for family in [
                Family::Stepper,
                Family::Io,
                Family::Boot,
                Family::Heater,
                Family::LoadCell,
                Family::Sampler,
                Family::None,
            ] {
                assert_eq!(Refusal::from_code(family, byte).code(), byte);
            }
        }
        assert_eq!(
            Refusal::from_code(Family::Stepper, 11),
            Refusal::Stepper(StepperError::OverLimit)
        );
        assert_eq!(
            Refusal::from_code(Family::Io, 2),
            Refusal::Io(IoError::BadValue)
        );
        assert_eq!(
            Refusal::of(FnId::enter_bootloader, 2),
            Refusal::Boot(BootError::Moving)
        );
        assert_eq!(
            Refusal::from_code(Family::Stepper, 100),
            Refusal::NotInstalled
        );
        assert_eq!(
            Refusal::from_code(Family::None, 254),
            Refusal::Wrapper(pipes_core::FailureCode::StateBusy)
        );
        // A code from a newer firmware, or of another family.
        assert_eq!(Refusal::from_code(Family::Stepper, 42), Refusal::Other(42));
        assert_eq!(Refusal::from_code(Family::Boot, 11), Refusal::Other(11));
        assert_eq!(StepperError::from_code(0), None);
        assert_eq!(StepperError::from_code(14), None);
        assert_eq!(IoError::from_code(7), Some(IoError::Late));
        assert_eq!(IoError::from_code(9), None);
        assert_eq!(HeaterError::from_code(0), None);
        assert_eq!(HeaterError::from_code(10), None);
        assert_eq!(
            Refusal::of(FnId::heater_target, 5),
            Refusal::Heater(HeaterError::Faulted)
        );
        assert_eq!(BootError::from_code(3), None);
        assert_eq!(Refusal::Other(42).to_string(), "unknown failure code 42");
        assert!(Refusal::Stepper(StepperError::QueueFull)
            .to_string()
            .starts_with("QueueFull (code 8): "));
        assert_eq!(
            StepperError::OverLimit.to_string(),
            "the point is past the axis's limits"
        );
        assert_eq!(
            IoError::Full.to_string(),
            "every slot for scheduled pulses or track points is taken"
        );
        assert_eq!(
            BootError::Moving.to_string(),
            "the axis has motion queued or running"
        );
        for e in StepperError::ALL {
            assert_eq!(StepperError::from_code(e.code()), Some(e));
        }
    }

    #[test]
    fn every_io_error_is_named_by_its_variant() {
        let mut codes = BTreeSet::new();
        for &e in IO {
            let f = io(e);
            assert_eq!(f.code, e.code());
            assert_eq!(std::format!("{e:?}"), f.name);
            assert!(codes.insert(f.code), "{} twice", f.code);
            assert!(f.reason.contains(": "), "{f}: name the fix");
            assert_eq!(failure("pulse_at", f.code), Some(f));
        }
        // The same code means different things in different families.
        assert_eq!(failure("pulse", 2).unwrap().name, "BadValue");
        assert_eq!(failure("add_point", 2).unwrap().name, "Stale");
    }

    #[test]
    fn every_boot_error_is_named_by_its_variant() {
        for &e in BOOT {
            let f = boot(e);
            assert_eq!((f.code, std::format!("{e:?}")), (e.code(), f.name.into()));
            assert!(f.reason.contains(": "), "{f}: name the fix");
            assert_eq!(failure("enter_bootloader", f.code), Some(f));
            assert_eq!(generic(f.code), None);
        }
    }

    #[test]
    fn every_function_has_a_family_and_the_generic_codes() {
        for &id in &ALL {
            let name = SIGNATURES[id as usize].name;
            assert_eq!(function_id(name), Some(id));
            let f = failure(name, NOT_INSTALLED).unwrap();
            assert_eq!(f.name, "NotInstalled");
            assert_eq!(failure(name, INPUT_DECODE_FAILED).unwrap().code, 255);
        }
        assert_eq!(Family::of(FnId::halt), Family::None);
        assert_eq!(failure("halt", 1), None);
        assert_eq!(failure("get_status", StepperError::QueueFull.code()), None);
        for code in [STATE_BUSY, NO_SUCH_MEMBER] {
            assert!(generic(code).is_some());
        }
    }

    #[test]
    fn every_function_publishes_its_codes_by_the_same_names() {
        use pipes_core::failure::{check_failures, tail_len, SignatureParts};
        let mut total = 0;
        for &id in &ALL {
            let sig = SIGNATURES[id as usize];
            let table = id.failures();
            assert_eq!(check_failures(table), Ok(()), "{}", sig.name);
            for f in table {
                assert_eq!(failure(sig.name, f.code), Some(*f), "{}", sig.name);
                assert!(f.reason.contains(": "), "{f}: name the fix");
            }
            // Every code the function can return is in its table.
            for code in 0..=u8::MAX {
                let own = Family::of(id).failure(code).is_some();
                let reachable = own || code == NOT_INSTALLED || code == INPUT_DECODE_FAILED;
                assert_eq!(
                    table.iter().any(|f| f.code == code),
                    reachable,
                    "{} {code}",
                    sig.name
                );
            }
            let reply = 2 + sig.encoded_len() + tail_len(SignatureParts::FAILURES, table, "");
            // A host reassembles replies of up to 8 KiB; a stepper function's
            // is about 2, 3 with its docs.
            let all = SignatureParts::FAILURES
                .with(SignatureParts::SUMMARY)
                .with(SignatureParts::DOCS);
            let described = 2 + sig.encoded_len() + tail_len(all, table, id.docs());
            assert!(described < 4096, "{}: {described} bytes", sig.name);
            total += reply;
        }
        // A scan reads every signature with its failure table (33 390 bytes
        // with the load cell's wiring checks; more with the tachometer's
        // functions and NoCounter, the torque functions (`set_torque`
        // carries the stepper table), and the level and event tracks'
        // functions with the I/O family's two codes for them: 43 756): a
        // budget, so a table that grows by much is noticed.
        assert!(
            total < 44 * 1024,
            "a scan reads {total} bytes of signatures"
        );
    }

    #[test]
    fn family_and_generic_codes_do_not_overlap() {
        for &e in STEPPER {
            assert_eq!(generic(e.code()), None);
        }
        for &e in IO {
            assert_eq!(generic(e.code()), None);
        }
        for &e in HEATER {
            assert_eq!(generic(e.code()), None);
        }
    }

    #[test]
    fn every_heater_error_is_named_by_its_variant() {
        let mut codes = BTreeSet::new();
        for &e in HEATER {
            let f = heater(e);
            assert_eq!((f.code, std::format!("{e:?}")), (e.code(), f.name.into()));
            assert!(codes.insert(f.code), "{} twice", f.code);
            assert!(f.reason.contains(": "), "{f}: name the fix");
            assert_eq!(failure("heater_target", f.code), Some(f));
            assert_eq!(failure("heater_read", f.code), Some(f));
        }
        assert_eq!(codes.len(), HeaterError::ALL.len());
        assert_eq!(failure("heater_clear", 6).unwrap().name, "SensorFault");
    }

    #[test]
    fn every_loadcell_error_is_named_by_its_variant() {
        let mut codes = BTreeSet::new();
        for &e in LOADCELL {
            let f = loadcell(e);
            assert_eq!((f.code, std::format!("{e:?}")), (e.code(), f.name.into()));
            assert!(codes.insert(f.code), "{} twice", f.code);
            assert!(f.reason.contains(": "), "{f}: name the fix");
            assert_eq!(failure("loadcell_read", f.code), Some(f));
        }
        assert_eq!(codes.len(), LoadCellError::ALL.len());
        assert_eq!(
            Refusal::of(FnId::loadcell_tare, 2),
            Refusal::LoadCell(LoadCellError::BadValue)
        );
    }

    #[test]
    fn every_sampler_error_is_named_by_its_variant() {
        let mut codes = BTreeSet::new();
        for &e in SAMPLER {
            let f = sampler(e);
            assert_eq!((f.code, std::format!("{e:?}")), (e.code(), f.name.into()));
            assert!(codes.insert(f.code), "{} twice", f.code);
            assert!(f.reason.contains(": "), "{f}: name the fix");
            assert_eq!(failure("sample_block", f.code), Some(f));
            assert_eq!(generic(e.code()), None);
        }
        assert_eq!(codes.len(), SamplerError::ALL.len());
    }

    #[test]
    fn unknown_codes_and_other_functions_have_no_name() {
        assert_eq!(failure("add_point", 0), None);
        assert_eq!(failure("add_point", 14), None);
        assert_eq!(failure("add_point", 99), None);
        assert_eq!(failure("pulse", 9), None);
        // Not one of the module's functions: its codes are its own.
        assert_eq!(failure("add_pointx", 8), None);
        assert_eq!(failure("move_to", 8), None);
        assert_eq!(failure("move_to", NOT_INSTALLED), None);
    }
}
