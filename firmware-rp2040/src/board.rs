//! The Pico's pins, and the board side of the module logic: the stepper
//! driver's control pins ([`StepperPins`]) and the general-purpose I/O
//! ([`IoPins`]), implementing osap-module's [`StepperHw`] and [`IoHw`].
//!
//! Pin map (GP numbers; the README has the same table):
//!
//! | pin   | use                                                        |
//! |-------|------------------------------------------------------------|
//! | GP0   | UART0 TX (to the RS-485 transceiver's DI)                  |
//! | GP1   | UART0 RX (from its RO)                                     |
//! | GP2   | STEP (PIO0, state machine 0)                               |
//! | GP3   | DIR (PIO0, state machine 0)                                |
//! | GP4   | EN, active low (A4988 / DRV8825 / TMC2209 `EN`)            |
//! | GP5   | LIMIT switch input, pull-up, both edges time-stamped       |
//! | GP6   | RS-485 driver enable (DE and /RE tied), high while sending |
//! | GP7   | MS1 microstep select                                       |
//! | GP8   | MS2 microstep select                                       |
//! | GP9   | MS3 microstep select                                       |
//! | GP10-13 | digital I/O 0-3; rising edges counted while inputs ([`crate::edges`]) |
//! | GP14  | PWM output 0 (slice 7 A)                                   |
//! | GP15  | PWM output 1 (slice 7 B)                                   |
//! | GP26-28 | analog inputs 0-2 (ADC0-2)                               |

use embassy_rp::adc::{self, Adc, Channel};
use embassy_rp::gpio::{Flex, Level, Output, Pull};
use embassy_rp::pwm::{self, Pwm};
use osap_core::Instant;
use osap_module::board::{IoHw, StepperHw};

/// The stepper driver's enable and microstep pins.
pub struct StepperPins {
    /// EN, active low: high lets the motor go limp.
    pub enable_n: Output<'static>,
    /// MS1, MS2, MS3.
    pub ms: [Output<'static>; 3],
}

impl core::fmt::Debug for StepperPins {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("StepperPins").finish_non_exhaustive()
    }
}

/// MS1..MS3 levels for each microstep setting of an A4988 (the common
/// Pico carrier boards' driver). A DRV8825 or TMC2209 board has another
/// table; change this one for it.
const A4988_MODES: [(u16, [bool; 3]); 5] = [
    (1, [false, false, false]),
    (2, [true, false, false]),
    (4, [false, true, false]),
    (8, [true, true, false]),
    (16, [true, true, true]),
];

impl StepperHw for StepperPins {
    fn set_enable(&mut self, on: bool) {
        self.enable_n.set_level(Level::from(!on));
    }

    fn set_microsteps(&mut self, microsteps: u16) -> bool {
        let Some((_, levels)) = A4988_MODES.iter().find(|(m, _)| *m == microsteps) else {
            return false;
        };
        for (pin, &high) in self.ms.iter_mut().zip(levels) {
            pin.set_level(Level::from(high));
        }
        true
    }
}

/// Digital pins, PWM outputs and analog inputs.
pub struct IoPins {
    /// Digital I/O 0..3 (GP10..GP13); inputs with pull-down until written.
    pub digital: [Flex<'static>; 4],
    /// PWM slice 7, outputs A (GP14) and B (GP15).
    pub pwm: Pwm<'static>,
    /// The ADC in blocking mode: one conversion takes 2 µs.
    pub adc: Adc<'static, adc::Blocking>,
    /// Analog inputs 0..2 (GP26..GP28).
    pub analog: [Channel<'static>; 3],
    /// The PWM configuration, kept to change one compare value at a time.
    pub pwm_config: pwm::Config,
}

impl core::fmt::Debug for IoPins {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("IoPins").finish_non_exhaustive()
    }
}

/// PWM counter top: a 16-bit duty maps 1:1 to the compare value, and 65 535
/// (compare above top) is always high. 125 MHz / 65 535 ≈ 1.9 kHz.
pub(crate) const PWM_TOP: u16 = 65_534;

impl IoPins {
    /// The PWM configuration at start: both outputs low.
    pub fn pwm_start_config() -> pwm::Config {
        let mut c = pwm::Config::default();
        c.top = PWM_TOP;
        c.compare_a = 0;
        c.compare_b = 0;
        c
    }
}

impl IoHw for IoPins {
    fn digital_pins(&self) -> u8 {
        self.digital.len() as u8
    }

    fn write_digital(&mut self, pin: u8, level: bool) {
        if let Some(p) = self.digital.get_mut(usize::from(pin)) {
            p.set_level(Level::from(level));
            p.set_as_output();
            // Its edges are its own from now on: it counts no more.
            crate::edges::mark_output(usize::from(pin));
        }
    }

    fn read_digital(&mut self, pin: u8) -> bool {
        // An output's input buffer stays on, so this reads back what it drives.
        self.digital
            .get(usize::from(pin))
            .is_some_and(|p| p.is_high())
    }

    fn pwm_outputs(&self) -> u8 {
        2
    }

    fn write_pwm(&mut self, channel: u8, duty: u16) {
        match channel {
            0 => self.pwm_config.compare_a = duty,
            1 => self.pwm_config.compare_b = duty,
            _ => return,
        }
        self.pwm.set_config(&self.pwm_config);
    }

    fn read_pwm(&self, channel: u8) -> u16 {
        match channel {
            0 => self.pwm_config.compare_a,
            1 => self.pwm_config.compare_b,
            _ => 0,
        }
    }

    fn analog_inputs(&self) -> u8 {
        self.analog.len() as u8
    }

    fn read_analog(&mut self, channel: u8) -> u16 {
        let Some(ch) = self.analog.get_mut(usize::from(channel)) else {
            return 0;
        };
        // 12-bit result, scaled to the trait's 0..=65535 range.
        self.adc.blocking_read(ch).map_or(0, |v| v << 4)
    }

    fn edge_count(&mut self, pin: u8) -> Option<(u32, Instant)> {
        // Counted by the pin's edge interrupt (crate::edges): every
        // digital pin while it is an input.
        crate::edges::count(usize::from(pin)).map(|(n, at)| (n, Instant::from_micros(at)))
    }

    fn hold_pulse(&mut self) {
        // 40 cycles at 125 MHz: 0.32 µs.
        cortex_m::asm::delay(40);
    }
}

/// Reboots into the boot ROM's USB mass-storage bootloader (the
/// `RPI-RP2` drive, as a power-up with BOOTSEL held gives) for a firmware
/// update. The ROM resets the chip through the watchdog, which returns
/// every pin to an input, so the driver's EN pull-up lets the motor go limp.
pub(crate) fn reboot_to_usb_boot() -> ! {
    // No activity LED pin (the Pico's LED, GP25, is not ours to drive);
    // both the mass-storage and the PICOBOOT interfaces, as on a cold boot.
    embassy_rp::rom_data::reset_to_usb_boot(0, 0);
    // The ROM does not return; should it ever, wait for the reset.
    loop {
        cortex_m::asm::wfi();
    }
}

/// Digital I/O pins start as inputs with pull-downs, so nothing connected
/// is driven until a script writes it.
pub(crate) fn digital_input(mut pin: Flex<'static>) -> Flex<'static> {
    pin.set_pull(Pull::Down);
    pin.set_as_input();
    pin
}
