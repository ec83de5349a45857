//! The I/O module: digital pins, PWM outputs, analog inputs and timed
//! pulses (a solenoid striking a xylophone bar), over [`IoHw`].
//!
//! Reads are stamped in synchronized time, so a script can line a sample
//! up with motion. Pulses end from the runtime's loop ([`Io::poll`], woken
//! at [`Io::wake_at`]), so their length is exact to the runtime's wake-up
//! latency (tens of µs on a module), not to the cycle; a pulse can also be
//! scheduled ahead at a synchronized time so a script can play several
//! modules together.
//!
//! **Safe values.** Each output has a safe value ([`Io::set_safe_pwm`],
//! [`Io::set_safe_digital`]; 0 duty and low until set) that
//! [`Io::apply_safe`] drives it to: the module does so on every stop
//! (`halt`, a backstop) and when its output watchdog fires (see
//! [`crate::watchdog`]). It applies them to the outputs the module has
//! driven or been given a safe value for since boot (a pin never written
//! may be an input, and stays one), ends every running pulse and drops
//! every scheduled one. An output stays at its safe value until a call
//! writes it again.

use crate::board::IoHw;
use osap_core::{Duration, Instant, SystemInstant};

/// Digital pins the logic can time pulses on (boards with more pins pulse
/// only the first ones).
pub const MAX_PULSE_PINS: usize = 32;
/// Pulses that can wait for their start time at once.
pub const SCHEDULED_PULSES: usize = 16;
/// The longest pulse, µs (10 s): a solenoid held longer burns.
pub const MAX_PULSE_US: u32 = 10_000_000;
/// How far ahead a pulse may be scheduled (60 s).
pub const MAX_PULSE_LEAD: Duration = Duration::from_secs(60);
/// Digital pins that can have a safe level (boards with more leave the
/// rest alone at a stop).
pub const MAX_SAFE_PINS: usize = 32;
/// PWM outputs that can have a safe duty (boards with more leave the rest
/// alone at a stop).
pub const MAX_SAFE_PWM: usize = 16;

/// Why an I/O call was refused: the failure code a caller sees.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
#[non_exhaustive]
pub enum IoError {
    /// No such pin, PWM output or analog input on this board.
    NoSuchPin = 1,
    /// A value out of range: a duty cycle outside `0..=1` or NaN, a pulse
    /// longer than 10 s, or a start (or a track point) more than 60 s
    /// ahead.
    BadValue = 2,
    /// Every slot for scheduled pulses is taken, or a level or event
    /// track's queue is full (see [`crate::levels`]).
    Full = 3,
    /// The I/O hardware was never installed (a firmware without it).
    NoHardware = 4,
    /// A heater drives that PWM output (see [`crate::heater`]): only the
    /// heater sets its duty, and its safe duty is 0.
    HeaterOutput = 5,
    /// The board cannot count pulses on that pin, or no tachometer is set
    /// up (`tach_setup`; see [`crate::tach`]).
    NoCounter = 6,
    /// A level or event point stamped before now: it would take effect
    /// late (see [`crate::levels`]).
    Late = 7,
    /// A level or event point stamped before one already queued for its
    /// output (or at the same time as a level point): send points in time
    /// order.
    OutOfOrder = 8,
}

impl IoError {
    /// Every I/O error, in code order.
    pub const ALL: [IoError; 8] = [
        IoError::NoSuchPin,
        IoError::BadValue,
        IoError::Full,
        IoError::NoHardware,
        IoError::HeaterOutput,
        IoError::NoCounter,
        IoError::Late,
        IoError::OutOfOrder,
    ];

    /// The failure code.
    pub const fn code(self) -> u8 {
        self as u8
    }

    /// The error with failure code `code`; `None` for a code that is not an
    /// I/O error (see [`crate::failure::Refusal`]).
    pub fn from_code(code: u8) -> Option<IoError> {
        Self::ALL.into_iter().find(|e| e.code() == code)
    }
}

impl core::fmt::Display for IoError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            IoError::NoSuchPin => "no such pin, PWM output or analog input on this board",
            IoError::BadValue => "a value out of range",
            IoError::Full => "every slot for scheduled pulses or track points is taken",
            IoError::NoHardware => "the I/O hardware was never installed",
            IoError::HeaterOutput => "a heater drives that PWM output",
            IoError::NoCounter => "no pulse counter on that pin, or no tachometer set up",
            IoError::Late => "the point's time has already passed",
            IoError::OutOfOrder => "the point is stamped before one already queued",
        })
    }
}

impl core::error::Error for IoError {}

impl From<IoError> for pipes_core::FailureCode {
    fn from(e: IoError) -> Self {
        pipes_core::FailureCode::Other(e.code())
    }
}

impl From<IoError> for pipes_core::function::CallError {
    fn from(e: IoError) -> Self {
        pipes_core::function::CallError::Failed(e.into())
    }
}

#[derive(Debug, Clone, Copy)]
struct Scheduled {
    start: SystemInstant,
    pin: u8,
    duration_us: u32,
}

/// The I/O logic's state (the hardware is passed in to each call).
#[derive(Debug, Clone)]
pub struct Io {
    /// When each pin's running pulse ends, local time.
    ends: [Option<Instant>; MAX_PULSE_PINS],
    /// Pulses waiting for their synchronized start time.
    scheduled: [Option<Scheduled>; SCHEDULED_PULSES],
    pulses: u32,
    /// Each PWM output's safe duty, of 65 535.
    safe_pwm: [u16; MAX_SAFE_PWM],
    /// Each digital pin's safe level, as bits.
    safe_digital: u32,
    /// The PWM outputs a stop drives to their safe duty, as bits: those
    /// written or given a safe duty since boot.
    pwm_outputs: u32,
    /// The digital pins a stop drives to their safe level, as bits: those
    /// driven (written, pulsed) or given a safe level since boot.
    digital_outputs: u32,
    /// Times the safe values were applied since boot.
    safe_applied: u32,
}

impl Default for Io {
    fn default() -> Self {
        Io::new()
    }
}

fn check_pin(hw: &dyn IoHw, pin: u8) -> Result<(), IoError> {
    if pin < hw.digital_pins() {
        Ok(())
    } else {
        Err(IoError::NoSuchPin)
    }
}

/// `duty` (a fraction, `0..=1`) of 65 535, for PWM output `channel`.
fn pwm_duty(hw: &dyn IoHw, channel: u8, duty: f32) -> Result<u16, IoError> {
    if channel >= hw.pwm_outputs() {
        return Err(IoError::NoSuchPin);
    }
    if !(0.0..=1.0).contains(&duty) {
        return Err(IoError::BadValue);
    }
    Ok((duty * 65_535.0 + 0.5) as u16)
}

/// The bit of `index` in a mask of `max` outputs (`0` past it: such an
/// output is never tracked).
fn bit(index: u8, max: usize) -> u32 {
    if usize::from(index) < max {
        1 << index
    } else {
        0
    }
}

impl Io {
    /// No pulses running or waiting.
    pub const fn new() -> Self {
        Io {
            ends: [None; MAX_PULSE_PINS],
            scheduled: [None; SCHEDULED_PULSES],
            pulses: 0,
            safe_pwm: [0; MAX_SAFE_PWM],
            safe_digital: 0,
            pwm_outputs: 0,
            digital_outputs: 0,
            safe_applied: 0,
        }
    }

    /// Drives `pin` high or low; a pulse running on it ends here.
    pub fn digital_write(
        &mut self,
        hw: &mut dyn IoHw,
        pin: u8,
        level: bool,
    ) -> Result<(), IoError> {
        check_pin(hw, pin)?;
        if let Some(end) = self.ends.get_mut(usize::from(pin)) {
            *end = None;
        }
        self.digital_outputs |= bit(pin, MAX_SAFE_PINS);
        hw.write_digital(pin, level);
        Ok(())
    }

    /// Notes that `pin` is driven (an event track switches it), so a stop
    /// drives it to its safe level.
    pub fn mark_digital_output(&mut self, pin: u8) {
        self.digital_outputs |= bit(pin, MAX_SAFE_PINS);
    }

    /// Notes that PWM output `channel` is driven (a level track drives
    /// it), so a stop drives it to its safe duty.
    pub fn mark_pwm_output(&mut self, channel: u8) {
        self.pwm_outputs |= bit(channel, MAX_SAFE_PWM);
    }

    /// Reads `pin`'s level.
    pub fn digital_read(&mut self, hw: &mut dyn IoHw, pin: u8) -> Result<bool, IoError> {
        check_pin(hw, pin)?;
        Ok(hw.read_digital(pin))
    }

    /// Sets PWM output `channel` to `duty` (a fraction, `0..=1`).
    pub fn pwm_write(&mut self, hw: &mut dyn IoHw, channel: u8, duty: f32) -> Result<(), IoError> {
        let raw = pwm_duty(hw, channel, duty)?;
        self.pwm_outputs |= bit(channel, MAX_SAFE_PWM);
        hw.write_pwm(channel, raw);
        Ok(())
    }

    /// Sets the duty (a fraction, `0..=1`) PWM output `channel` takes on
    /// every stop ([`apply_safe`](Self::apply_safe)); the output keeps its
    /// duty until then. Refused as [`pwm_write`](Self::pwm_write) refuses,
    /// and `NoSuchPin` past [`MAX_SAFE_PWM`].
    pub fn set_safe_pwm(&mut self, hw: &dyn IoHw, channel: u8, duty: f32) -> Result<(), IoError> {
        let raw = pwm_duty(hw, channel, duty)?;
        let safe = self
            .safe_pwm
            .get_mut(usize::from(channel))
            .ok_or(IoError::NoSuchPin)?;
        *safe = raw;
        self.pwm_outputs |= bit(channel, MAX_SAFE_PWM);
        Ok(())
    }

    /// Sets the level digital pin `pin` takes on every stop
    /// ([`apply_safe`](Self::apply_safe)); the pin keeps its level until
    /// then. `NoSuchPin` for a pin the board lacks or past
    /// [`MAX_SAFE_PINS`].
    pub fn set_safe_digital(&mut self, hw: &dyn IoHw, pin: u8, level: bool) -> Result<(), IoError> {
        check_pin(hw, pin)?;
        let b = bit(pin, MAX_SAFE_PINS);
        if b == 0 {
            return Err(IoError::NoSuchPin);
        }
        if level {
            self.safe_digital |= b;
        } else {
            self.safe_digital &= !b;
        }
        self.digital_outputs |= b;
        Ok(())
    }

    /// The safe duty of PWM output `channel`, of 65 535 (0 until set).
    pub fn safe_pwm(&self, channel: u8) -> u16 {
        self.safe_pwm
            .get(usize::from(channel))
            .copied()
            .unwrap_or(0)
    }

    /// The safe level of digital pin `pin` (low until set).
    pub fn safe_digital(&self, pin: u8) -> bool {
        self.safe_digital & bit(pin, MAX_SAFE_PINS) != 0
    }

    /// Drives every output to its safe value: the PWM outputs and digital
    /// pins written or given a safe value since boot (others are left
    /// alone: a pin never driven may be an input). Running pulses end and
    /// scheduled ones are dropped. Quick: a write per output.
    pub fn apply_safe(&mut self, hw: &mut dyn IoHw) {
        self.scheduled = [None; SCHEDULED_PULSES];
        self.ends = [None; MAX_PULSE_PINS];
        for channel in 0..hw.pwm_outputs() {
            if self.pwm_outputs & bit(channel, MAX_SAFE_PWM) != 0 {
                hw.write_pwm(channel, self.safe_pwm(channel));
            }
        }
        for pin in 0..hw.digital_pins() {
            if self.digital_outputs & bit(pin, MAX_SAFE_PINS) != 0 {
                hw.write_digital(pin, self.safe_digital(pin));
            }
        }
        self.safe_applied = self.safe_applied.wrapping_add(1);
    }

    /// Times the safe values were applied since boot.
    pub fn safe_applied(&self) -> u32 {
        self.safe_applied
    }

    /// Samples analog input `channel`, as a fraction of full scale.
    pub fn analog_read(&mut self, hw: &mut dyn IoHw, channel: u8) -> Result<f32, IoError> {
        if channel >= hw.analog_inputs() {
            return Err(IoError::NoSuchPin);
        }
        Ok(f32::from(hw.read_analog(channel)) / 65_535.0)
    }

    /// Drives `pin` high now (local time `now`) and low `duration_us` later;
    /// a pulse already running on the pin restarts.
    pub fn pulse(
        &mut self,
        hw: &mut dyn IoHw,
        now: Instant,
        pin: u8,
        duration_us: u32,
    ) -> Result<(), IoError> {
        check_pin(hw, pin)?;
        if duration_us > MAX_PULSE_US {
            return Err(IoError::BadValue);
        }
        let end = self
            .ends
            .get_mut(usize::from(pin))
            .ok_or(IoError::NoSuchPin)?;
        *end = Some(now + Duration::from_micros(duration_us.into()));
        self.digital_outputs |= bit(pin, MAX_SAFE_PINS);
        hw.write_digital(pin, true);
        self.pulses = self.pulses.wrapping_add(1);
        Ok(())
    }

    /// Schedules a pulse on `pin` starting at synchronized time `start`
    /// (`system_now` is the synchronized time now). A start already past
    /// pulses at the next poll.
    pub fn pulse_at(
        &mut self,
        hw: &dyn IoHw,
        system_now: SystemInstant,
        start: SystemInstant,
        pin: u8,
        duration_us: u32,
    ) -> Result<(), IoError> {
        check_pin(hw, pin)?;
        if usize::from(pin) >= MAX_PULSE_PINS
            || duration_us > MAX_PULSE_US
            || start > system_now + MAX_PULSE_LEAD
        {
            return Err(if usize::from(pin) >= MAX_PULSE_PINS {
                IoError::NoSuchPin
            } else {
                IoError::BadValue
            });
        }
        let slot = self
            .scheduled
            .iter_mut()
            .find(|s| s.is_none())
            .ok_or(IoError::Full)?;
        *slot = Some(Scheduled {
            start,
            pin,
            duration_us,
        });
        self.digital_outputs |= bit(pin, MAX_SAFE_PINS);
        Ok(())
    }

    /// Starts scheduled pulses whose time has come and ends pulses whose
    /// time is up, at local time `now` (synchronized `system_now`).
    pub fn poll(&mut self, hw: &mut dyn IoHw, now: Instant, system_now: SystemInstant) {
        for slot in self.scheduled.iter_mut() {
            if let Some(s) = *slot {
                if s.start <= system_now {
                    *slot = None;
                    // Start late by as much as the loop was late, but keep
                    // the end where the schedule put it.
                    let late = (system_now - s.start)
                        .as_micros()
                        .min(u64::from(s.duration_us));
                    let left = s.duration_us - late as u32;
                    if let Some(end) = self.ends.get_mut(usize::from(s.pin)) {
                        *end = Some(now + Duration::from_micros(left.into()));
                        hw.write_digital(s.pin, true);
                        self.pulses = self.pulses.wrapping_add(1);
                    }
                }
            }
        }
        for (pin, end) in self.ends.iter_mut().enumerate() {
            if end.is_some_and(|e| e <= now) {
                *end = None;
                hw.write_digital(pin as u8, false);
            }
        }
    }

    /// When [`poll`](Self::poll) next has work, local time, given the local
    /// time `now` and synchronized `system_now` (to place scheduled starts
    /// on the local clock).
    pub fn wake_at(&self, now: Instant, system_now: SystemInstant) -> Option<Instant> {
        let ends = self.ends.iter().flatten().copied();
        let starts = self
            .scheduled
            .iter()
            .flatten()
            .map(|s| now + (s.start - system_now));
        ends.chain(starts).min()
    }

    /// Pulses started since boot.
    pub fn pulses(&self) -> u32 {
        self.pulses
    }
}
