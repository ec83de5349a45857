//! What a board does for the module logic: the hardware traits.
//!
//! The logic in this crate never touches a peripheral. A firmware crate
//! implements these traits over its HAL (embassy-rp, atsamd-hal) and hands
//! them to [`crate::install`]; host tests implement them over plain memory.
//! Every method is quick and non-blocking: they run inside critical
//! sections, where an interrupt waits for them.

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

    /// How many analog inputs there are.
    fn analog_inputs(&self) -> u8;
    /// Samples analog input `channel`; the result is a fraction of full
    /// scale in `0..=65535` (a 12-bit converter's reading shifted left by 4),
    /// so scripts see the same range on every board.
    fn read_analog(&mut self, channel: u8) -> u16;
}
