//! What a board does for the module logic: the hardware traits.
//!
//! The logic in this crate never touches a peripheral. A firmware crate
//! implements these traits over its HAL (embassy-rp, atsamd-hal) and hands
//! them to its [`crate::ModuleCell`]; the simulator implements them over
//! simulated pins and clocks, host tests over plain memory. Every method is
//! quick and non-blocking: they run inside critical sections, where an
//! interrupt waits for them.

use osap_core::Instant;

/// A stepper driver's control pins (step and direction are driven by the
/// board's step generator from the words [`crate::Module::fill_step_word`]
/// returns, not through this trait).
pub trait StepperHw {
    /// Powers the driver's outputs (`true`) or lets the motor go limp.
    fn set_enable(&mut self, on: bool);

    /// Sets the driver's microstep mode pins, if the board has them.
    /// Returns `false` when this board cannot set `microsteps` (no mode pins,
    /// or a value its driver does not offer); the logic then refuses the
    /// call and keeps the old setting.
    fn set_microsteps(&mut self, microsteps: u16) -> bool;

    /// The shaft's angle from the motor's encoder, in Q16.16 full steps
    /// (65 536 per full step, counting whole turns), zero where the
    /// coils' electrical angle is zero (the board aligns its encoder to
    /// the coils); `None` on a board without an encoder (the default). The
    /// torque mode ([`crate::torque`]) commutes from it and reports it.
    fn read_shaft(&mut self) -> Option<i64> {
        None
    }

    /// Drives the coils' currents directly, in Q15 fractions of the
    /// driver's set current (±32 768: [`maxl::phase::Coils`]), instead of
    /// from the step and direction inputs; `None` hands them back to the
    /// step input, which holds the shaft where it stands (the driver's
    /// microstep position re-aligned to the shaft). Returns `false` if this
    /// driver cannot (the default): the torque mode is then refused.
    fn drive_coils(&mut self, coils: Option<maxl::phase::Coils>) -> bool {
        let _ = coils;
        false
    }
}

/// A general-purpose I/O board: digital pins, PWM outputs and analog inputs,
/// each numbered from 0 in the board's own order (its README maps numbers to
/// header pins).
pub trait IoHw {
    /// How many digital pins there are.
    fn digital_pins(&self) -> u8;
    /// Drives digital pin `pin` (`pin < digital_pins()`) high or low, making
    /// it an output if it was not.
    fn write_digital(&mut self, pin: u8, level: bool);
    /// Reads digital pin `pin`'s level (an output reads back what it drives).
    fn read_digital(&mut self, pin: u8) -> bool;

    /// How many PWM outputs there are.
    fn pwm_outputs(&self) -> u8;
    /// Sets PWM output `channel`'s duty cycle, `duty` of 65 535 (0: always
    /// low, 65 535: always high).
    fn write_pwm(&mut self, channel: u8, duty: u16);
    /// The duty cycle PWM output `channel` drives now, of 65 535 (what
    /// [`write_pwm`](Self::write_pwm) last set; 0 before any write and for
    /// an output the board lacks): how tests and a simulator's control see
    /// that a tool went off.
    fn read_pwm(&self, channel: u8) -> u16;

    /// How many analog inputs there are.
    fn analog_inputs(&self) -> u8;
    /// Samples analog input `channel`; the result is a fraction of full
    /// scale in `0..=65535` (a 12-bit converter's reading shifted left by 4),
    /// so scripts see the same range on every board.
    fn read_analog(&mut self, channel: u8) -> u16;

    /// Pulse counting on digital pin `pin` (a tachometer's input, see
    /// [`crate::tach`]): the rising edges counted since boot (wrapping)
    /// and the local time of the newest (0 before any), latched together
    /// by the counting hardware or its edge interrupt. `None` for a pin
    /// the board cannot count on; the default counts on none.
    fn edge_count(&mut self, pin: u8) -> Option<(u32, Instant)> {
        let _ = pin;
        None
    }

    /// Waits at least 0.25 µs: how long a bit-banged clock level is held
    /// (an HX711 wants 0.2 µs high and low). A board whose pin writes
    /// already take that long, or a simulated one, leaves it empty.
    fn hold_pulse(&mut self) {}
}

impl<T: StepperHw + ?Sized> StepperHw for &mut T {
    fn set_enable(&mut self, on: bool) {
        (**self).set_enable(on)
    }
    fn set_microsteps(&mut self, microsteps: u16) -> bool {
        (**self).set_microsteps(microsteps)
    }
    fn read_shaft(&mut self) -> Option<i64> {
        (**self).read_shaft()
    }
    fn drive_coils(&mut self, coils: Option<maxl::phase::Coils>) -> bool {
        (**self).drive_coils(coils)
    }
}

impl<T: IoHw + ?Sized> IoHw for &mut T {
    fn digital_pins(&self) -> u8 {
        (**self).digital_pins()
    }
    fn write_digital(&mut self, pin: u8, level: bool) {
        (**self).write_digital(pin, level)
    }
    fn read_digital(&mut self, pin: u8) -> bool {
        (**self).read_digital(pin)
    }
    fn pwm_outputs(&self) -> u8 {
        (**self).pwm_outputs()
    }
    fn write_pwm(&mut self, channel: u8, duty: u16) {
        (**self).write_pwm(channel, duty)
    }
    fn read_pwm(&self, channel: u8) -> u16 {
        (**self).read_pwm(channel)
    }
    fn analog_inputs(&self) -> u8 {
        (**self).analog_inputs()
    }
    fn read_analog(&mut self, channel: u8) -> u16 {
        (**self).read_analog(channel)
    }
    fn edge_count(&mut self, pin: u8) -> Option<(u32, Instant)> {
        (**self).edge_count(pin)
    }
    fn hold_pulse(&mut self) {
        (**self).hold_pulse()
    }
}

/// Everything a module needs from its board: the stepper driver, the I/O
/// hardware if there is any, and the local microsecond clock (the one the
/// runtime is polled with).
///
/// A firmware implements it over its peripherals (or uses [`Parts`]); a
/// simulator implements it over simulated pins and a drifting clock.
pub trait Board {
    /// The stepper driver's control pins.
    fn stepper(&mut self) -> &mut dyn StepperHw;
    /// The I/O hardware, or `None` on a board without it (the I/O functions
    /// then fail with [`crate::io::IoError::NoHardware`]).
    fn io(&mut self) -> Option<&mut dyn IoHw>;
    /// Local time, µs.
    fn now(&self) -> Instant;

    /// Whether this board can reboot into its bootloader
    /// ([`reboot_to_bootloader`](Self::reboot_to_bootloader)). The default
    /// cannot: `enter_bootloader` then refuses with
    /// [`BootError::Unsupported`](crate::boot::BootError::Unsupported).
    fn has_bootloader(&self) -> bool {
        false
    }

    /// Reboots into the bootloader (a UF2 drive for a firmware update).
    /// Called from the runtime's loop once an armed `enter_bootloader` is
    /// due (see [`crate::boot`]), never from inside the call, and only if
    /// [`has_bootloader`](Self::has_bootloader). On hardware it does not
    /// return; a simulated board takes its module off the network. The
    /// default does nothing.
    fn reboot_to_bootloader(&mut self) {}
}

/// A board assembled from a stepper driver, optional I/O hardware, a
/// clock function and a bootloader entry: what a firmware usually hands to
/// [`crate::ModuleCell::install`].
pub struct Parts<S, I> {
    /// The stepper driver.
    pub stepper: S,
    /// The I/O hardware, if any.
    pub io: Option<I>,
    /// The local clock, µs.
    pub clock: fn() -> Instant,
    /// Reboots the chip into its bootloader, if the board has one
    /// ([`Board::reboot_to_bootloader`]); `None`: `enter_bootloader`
    /// refuses.
    pub bootloader: Option<fn() -> !>,
}

impl<S, I> core::fmt::Debug for Parts<S, I> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Parts").finish_non_exhaustive()
    }
}

impl<S: StepperHw, I: IoHw> Board for Parts<S, I> {
    fn stepper(&mut self) -> &mut dyn StepperHw {
        &mut self.stepper
    }
    fn io(&mut self) -> Option<&mut dyn IoHw> {
        self.io.as_mut().map(|io| io as &mut dyn IoHw)
    }
    fn now(&self) -> Instant {
        (self.clock)()
    }
    fn has_bootloader(&self) -> bool {
        self.bootloader.is_some()
    }
    fn reboot_to_bootloader(&mut self) {
        if let Some(reboot) = self.bootloader {
            reboot()
        }
    }
}

/// An I/O board with nothing on it: the `I` of a [`Parts`] without I/O.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoIo;

impl IoHw for NoIo {
    fn digital_pins(&self) -> u8 {
        0
    }
    fn write_digital(&mut self, _pin: u8, _level: bool) {}
    fn read_digital(&mut self, _pin: u8) -> bool {
        false
    }
    fn pwm_outputs(&self) -> u8 {
        0
    }
    fn write_pwm(&mut self, _channel: u8, _duty: u16) {}
    fn read_pwm(&self, _channel: u8) -> u16 {
        0
    }
    fn analog_inputs(&self) -> u8 {
        0
    }
    fn read_analog(&mut self, _channel: u8) -> u16 {
        0
    }
}
