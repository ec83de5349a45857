//! The boards' pins, and the board side of the module logic: the stepper
//! driver's control pins ([`StepperPins`]) and the general-purpose I/O
//! ([`IoPins`]), implementing osap-module's [`StepperHw`] and [`IoHw`].
//!
//! Pin map (Arduino header names; the README has the same table):
//!
//! | use | Metro M4 Express | Feather M4 Express |
//! |-----|------------------|--------------------|
//! | UART TX (to the RS-485 transceiver's DI) | D1 / PA22 (SERCOM3 PAD0) | TX / PB16 (SERCOM5 PAD0) |
//! | UART RX (from its RO) | D0 / PA23 (SERCOM3 PAD1) | RX / PB17 (SERCOM5 PAD1) |
//! | STEP | D2 / PB17 | D4 / PA14 |
//! | DIR | D3 / PB16 | D5 / PA16 |
//! | EN, active low | D4 / PB13 | D6 / PA18 |
//! | LIMIT, pull-up, both edges stamped | D5 / PB14 (EXTINT14) | D9 / PA19 (EXTINT3) |
//! | RS-485 driver enable (DE and /RE tied) | D6 / PB15 | D12 / PA22 |
//! | digital I/O 0-3, rising edges counted while inputs ([`crate::edges`]) | D7 / PB12 (EXTINT12), D10 / PA18 (EXTINT2), D11 / PA19 (EXTINT3), D12 / PA17 (EXTINT1) | MISO / PB22 (EXTINT6), MOSI / PB23 (EXTINT7), SCK / PA17 (EXTINT1), A4 / PA04 (EXTINT4) |
//! | PWM 0, 1 (TCC0 WO0, WO1) | D9 / PA20, D8 / PA21 | D10 / PA20, D11 / PA21 |
//! | analog 0-2 (ADC0) | A0 / PA02 (AIN0), A1 / PA05 (AIN5), A2 / PA06 (AIN6) | A0 / PA02 (AIN0), A1 / PA05 (AIN5), A2 / PB08 (AIN2) |
//! | LED (on while USB is configured) | D13 / PA16 | D13 / PA23 |
//!
//! No microstep pins: the boards' usual drivers (TMC2209 and the like) set
//! them by jumpers or UART, so only full steps (1) are accepted.

use atsamd_hal::gpio::{DynGroup, DynPin};
use atsamd_hal::pac;
use osap_core::Instant;
use osap_module::board::{IoHw, StepperHw};

/// A pin written and read through the PORT's set, clear and input
/// registers: no read-modify-write, so any priority may use it, and
/// cheap enough for the step interrupt.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FastPin {
    group: u8,
    num: u8,
}

impl FastPin {
    /// A packed "no pin": writes do nothing, reads give low.
    pub const NONE: u32 = u32::MAX;

    /// The pin `pin` (configured by the HAL beforehand).
    pub fn of(pin: &DynPin) -> Self {
        let id = pin.id();
        FastPin {
            group: match id.group {
                DynGroup::A => 0,
                DynGroup::B => 1,
            },
            num: id.num,
        }
    }

    /// The pin as one word, for an atomic.
    pub const fn pack(self) -> u32 {
        (self.group as u32) << 8 | self.num as u32
    }

    /// A pin from [`pack`](Self::pack)'s word.
    pub const fn unpack(word: u32) -> Self {
        if word == Self::NONE {
            // Bit 32 does not exist: a mask of 0.
            return FastPin { group: 0, num: 32 };
        }
        FastPin {
            group: (word >> 8) as u8,
            num: word as u8,
        }
    }

    fn mask(self) -> u32 {
        1u32.checked_shl(u32::from(self.num)).unwrap_or(0)
    }

    fn port(self) -> &'static pac::port::Group {
        // SAFETY: static MMIO; OUTSET, OUTCLR and IN are race-free.
        unsafe { (*pac::Port::ptr()).group(usize::from(self.group)) }
    }

    /// Drives the pin high or low.
    #[inline(always)]
    pub fn set(self, high: bool) {
        let mask = self.mask();
        // SAFETY: only this pin's bit.
        if high {
            self.port().outset().write(|w| unsafe { w.bits(mask) });
        } else {
            self.port().outclr().write(|w| unsafe { w.bits(mask) });
        }
    }

    /// The pin's level (its input buffer must be on).
    pub fn read(self) -> bool {
        self.port().in_().read().bits() & self.mask() != 0
    }

    /// Turns the pin's input buffer on, so [`read`](Self::read) sees its
    /// level while a peripheral (the EIC) has the pin.
    pub fn enable_input(self) {
        if self.num < 32 {
            self.port()
                .pincfg(usize::from(self.num))
                .modify(|_, w| w.inen().set_bit());
        }
    }
}

/// The stepper driver's enable pin.
pub struct StepperPins {
    /// EN, active low: high lets the motor go limp.
    pub enable_n: FastPin,
}

impl core::fmt::Debug for StepperPins {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("StepperPins").finish_non_exhaustive()
    }
}

impl StepperHw for StepperPins {
    fn set_enable(&mut self, on: bool) {
        self.enable_n.set(!on);
    }

    fn set_microsteps(&mut self, microsteps: u16) -> bool {
        // No mode pins on these boards: only full steps.
        microsteps == 1
    }
}

/// Digital pins, PWM outputs and analog inputs.
pub struct IoPins {
    /// Digital I/O 0..3; inputs with pull-down until written.
    pub digital: [DynPin; 4],
    /// ADC0 input numbers of analog inputs 0..2.
    pub analog: [u8; 3],
}

impl core::fmt::Debug for IoPins {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("IoPins").finish_non_exhaustive()
    }
}

/// TCC0's period: a 16-bit duty maps 1:1 to the compare value, and 65 535
/// (compare above the period) is always high. 120 MHz / 65 535 ≈ 1.8 kHz.
pub(crate) const PWM_TOP: u32 = 65_534;

/// TCC0's registers.
fn tcc0() -> &'static pac::tcc0::RegisterBlock {
    // SAFETY: TCC0 belongs to the I/O set after `start_pwm`; static MMIO.
    unsafe { &*pac::Tcc0::ptr() }
}

/// Starts TCC0 in normal PWM with both outputs low. The pins must be on
/// their TCC0 function already (peripheral function G).
pub(crate) fn start_pwm(mclk: &mut pac::Mclk) {
    mclk.apbbmask().modify(|_, w| w.tcc0_().set_bit());
    let t = tcc0();
    t.ctrla().write(|w| w.swrst().set_bit());
    while t.syncbusy().read().swrst().bit_is_set() {}
    t.wave().write(|w| w.wavegen().npwm());
    // SAFETY: values fit the 24-bit registers.
    t.per().write(|w| unsafe { w.per().bits(PWM_TOP) });
    t.cc(0).write(|w| unsafe { w.cc().bits(0) });
    t.cc(1).write(|w| unsafe { w.cc().bits(0) });
    while t.syncbusy().read().bits() != 0 {}
    t.ctrla().modify(|_, w| w.enable().set_bit());
    while t.syncbusy().read().enable().bit_is_set() {}
}

/// ADC0's registers.
fn adc0() -> &'static pac::adc0::RegisterBlock {
    // SAFETY: ADC0 belongs to the I/O set after `start_adc`; static MMIO.
    unsafe { &*pac::Adc0::ptr() }
}

fn adc_sync() {
    while adc0().syncbusy().read().bits() != 0 {}
}

/// Starts ADC0: 12 bits, single-ended against ground, VDDANA (3.3 V) as
/// reference, factory calibration loaded. Its generic clock (at most
/// 16 MHz) must be routed already; the prescaler halves it.
pub(crate) fn start_adc(mclk: &mut pac::Mclk) {
    mclk.apbdmask().modify(|_, w| w.adc0_().set_bit());
    let a = adc0();
    a.ctrla().write(|w| w.swrst().set_bit());
    while a.syncbusy().read().swrst().bit_is_set() {}
    // SAFETY: factory calibration values for their own fields.
    a.calib().write(|w| unsafe {
        w.biascomp()
            .bits(atsamd_hal::calibration::adc0_biascomp_scale_cal());
        w.biasrefbuf()
            .bits(atsamd_hal::calibration::adc0_biasref_scale_cal());
        w.biasr2r()
            .bits(atsamd_hal::calibration::adc0_biasr2r_scale_cal())
    });
    a.ctrla().modify(|_, w| w.prescaler().div2());
    a.ctrlb().modify(|_, w| w.ressel()._12bit());
    adc_sync();
    a.refctrl().modify(|_, w| w.refsel().intvcc1());
    adc_sync();
    // SAFETY: 8 ADC clocks of sampling: a valid length.
    a.sampctrl().modify(|_, w| unsafe { w.samplen().bits(7) });
    adc_sync();
    a.inputctrl().modify(|_, w| w.muxneg().gnd());
    adc_sync();
    a.ctrla().modify(|_, w| w.enable().set_bit());
    adc_sync();
}

/// Where Adafruit's UF2 bootloader looks for its double-tap magic: the
/// last word of the SAMD51J19's 192 KiB SRAM (`HSRAM_ADDR + HSRAM_SIZE -
/// 4`). memory.x leaves it (and the word below it, for the stack's 8-byte
/// alignment) out of RAM, so nothing of the program lives there.
const DOUBLE_TAP_WORD: *mut u32 = 0x2002_FFFC as *mut u32;

/// The value that makes the bootloader stay in its UF2 drive instead of
/// starting the program (what a double tap of reset writes).
const DOUBLE_TAP_MAGIC: u32 = 0xF016_69EF;

/// Reboots into the UF2 bootloader (its drive appears for a firmware
/// update): the double-tap magic in its word, then a system reset. The
/// reset returns every pin to an input, so the driver's EN pull-up lets the
/// motor go limp.
pub(crate) fn reboot_to_uf2() -> ! {
    // SAFETY: a word outside the program's RAM (memory.x), aligned, that
    // the bootloader reads after the reset; SRAM keeps it through one.
    unsafe { core::ptr::write_volatile(DOUBLE_TAP_WORD, DOUBLE_TAP_MAGIC) };
    cortex_m::peripheral::SCB::sys_reset()
}

impl IoHw for IoPins {
    fn digital_pins(&self) -> u8 {
        self.digital.len() as u8
    }

    fn write_digital(&mut self, pin: u8, level: bool) {
        if let Some(p) = self.digital.get_mut(usize::from(pin)) {
            let fast = FastPin::of(p);
            fast.set(level);
            // Readable: the input buffer stays on, so a read gives back
            // what the pin drives.
            p.into_readable_output();
            fast.set(level);
            // Off the EIC now: it counts no more.
            crate::edges::mark_output(usize::from(pin));
        }
    }

    fn read_digital(&mut self, pin: u8) -> bool {
        self.digital
            .get(usize::from(pin))
            .is_some_and(|p| FastPin::of(p).read())
    }

    fn pwm_outputs(&self) -> u8 {
        2
    }

    fn write_pwm(&mut self, channel: u8, duty: u16) {
        if channel > 1 {
            return;
        }
        let t = tcc0();
        // Through the buffer: the new duty starts with the next period.
        // SAFETY: a 16-bit value in a 24-bit register.
        t.ccbuf(usize::from(channel))
            .write(|w| unsafe { w.ccbuf().bits(u32::from(duty)) });
    }

    fn read_pwm(&self, channel: u8) -> u16 {
        if channel > 1 {
            return 0;
        }
        // The buffered value: what the output drives from its next period
        // on (a 16-bit duty, as written).
        tcc0().ccbuf(usize::from(channel)).read().ccbuf().bits() as u16
    }

    fn analog_inputs(&self) -> u8 {
        self.analog.len() as u8
    }

    fn read_analog(&mut self, channel: u8) -> u16 {
        let Some(&ain) = self.analog.get(usize::from(channel)) else {
            return 0;
        };
        let a = adc0();
        // SAFETY: an AIN number of this board's pins.
        a.inputctrl().modify(|_, w| unsafe { w.muxpos().bits(ain) });
        adc_sync();
        // A conversion takes about 2 µs at 8 MHz.
        a.intflag().write(|w| w.resrdy().set_bit());
        a.swtrig().write(|w| w.start().set_bit());
        while a.intflag().read().resrdy().bit_is_clear() {}
        // 12-bit result, scaled to the trait's 0..=65535 range.
        (a.result().read().result().bits() & 0x0FFF) << 4
    }

    fn edge_count(&mut self, pin: u8) -> Option<(u32, Instant)> {
        // Counted by the pin's EXTINT interrupt (crate::edges): every
        // digital pin while it is an input.
        crate::edges::count(usize::from(pin)).map(|(n, at)| (n, Instant::from_micros(at)))
    }

    fn hold_pulse(&mut self) {
        // 40 cycles at 120 MHz: 0.32 µs.
        cortex_m::asm::delay(40);
    }
}

/// The board's pins, sorted by use.
pub(crate) struct BoardPins {
    /// STEP.
    pub step: DynPin,
    /// DIR.
    pub dir: DynPin,
    /// EN, active low.
    pub enable_n: DynPin,
    /// LIMIT switch input.
    pub limit: DynPin,
    /// Its EXTINT channel.
    pub limit_channel: u8,
    /// RS-485 driver enable.
    pub driver_enable: DynPin,
    /// The LED.
    pub led: DynPin,
    /// Digital I/O 0..3.
    pub digital: [DynPin; 4],
    /// PWM 0 and 1 (TCC0 WO0, WO1).
    pub pwm: [DynPin; 2],
    /// Analog inputs 0..2 and their ADC0 input numbers.
    pub analog: [(DynPin, u8); 3],
    /// The UART's pads.
    pub uart: UartPads,
    /// USB D- and D+.
    pub usb: (
        atsamd_hal::gpio::Pin<atsamd_hal::gpio::PA24, atsamd_hal::gpio::Reset>,
        atsamd_hal::gpio::Pin<atsamd_hal::gpio::PA25, atsamd_hal::gpio::Reset>,
    ),
}

#[cfg(feature = "metro-m4")]
mod map {
    use atsamd_hal::gpio::{Pins, PA22, PA23};
    use atsamd_hal::pac::{self, interrupt, Interrupt};
    use atsamd_hal::sercom::uart;

    /// The UART's SERCOM.
    pub(crate) type UartSercom = pac::Sercom3;
    /// Its pads: RX on PAD1, TX on PAD0.
    pub(crate) type UartPads = uart::PadsFromIds<UartSercom, PA23, PA22>;
    /// Its four interrupt lines.
    pub(crate) const UART_IRQS: [Interrupt; 4] = [
        Interrupt::SERCOM3_0,
        Interrupt::SERCOM3_1,
        Interrupt::SERCOM3_2,
        Interrupt::SERCOM3_OTHER,
    ];
    /// The limit switch's EXTINT line.
    pub(crate) const LIMIT_IRQ: Interrupt = Interrupt::EIC_EXTINT_14;
    /// Digital I/O 0..3's EXTINT channels (PB12, PA18, PA19, PA17).
    pub(crate) const DIGITAL_CHANNELS: [u8; 4] = [12, 2, 3, 1];
    /// Their interrupt lines.
    pub(crate) const DIGITAL_IRQS: [Interrupt; 4] = [
        Interrupt::EIC_EXTINT_12,
        Interrupt::EIC_EXTINT_2,
        Interrupt::EIC_EXTINT_3,
        Interrupt::EIC_EXTINT_1,
    ];

    /// The Metro M4's pins by use.
    pub(crate) fn take(p: Pins) -> super::BoardPins {
        super::BoardPins {
            step: p.pb17.into(),
            dir: p.pb16.into(),
            enable_n: p.pb13.into(),
            limit: p.pb14.into(),
            limit_channel: 14,
            driver_enable: p.pb15.into(),
            led: p.pa16.into(),
            digital: [p.pb12.into(), p.pa18.into(), p.pa19.into(), p.pa17.into()],
            pwm: [p.pa20.into(), p.pa21.into()],
            analog: [(p.pa02.into(), 0), (p.pa05.into(), 5), (p.pa06.into(), 6)],
            uart: uart::Pads::default().rx(p.pa23).tx(p.pa22),
            usb: (p.pa24, p.pa25),
        }
    }

    #[interrupt]
    fn SERCOM3_0() {
        crate::uart_link::on_interrupt();
    }
    #[interrupt]
    fn SERCOM3_1() {
        crate::uart_link::on_interrupt();
    }
    #[interrupt]
    fn SERCOM3_2() {
        crate::uart_link::on_interrupt();
    }
    #[interrupt]
    fn SERCOM3_OTHER() {
        crate::uart_link::on_interrupt();
    }
    #[interrupt]
    fn EIC_EXTINT_14() {
        crate::steps::on_limit_interrupt();
    }
    #[interrupt]
    fn EIC_EXTINT_12() {
        crate::edges::on_edge(0);
    }
    #[interrupt]
    fn EIC_EXTINT_2() {
        crate::edges::on_edge(1);
    }
    #[interrupt]
    fn EIC_EXTINT_3() {
        crate::edges::on_edge(2);
    }
    #[interrupt]
    fn EIC_EXTINT_1() {
        crate::edges::on_edge(3);
    }
}

#[cfg(feature = "feather-m4")]
mod map {
    use atsamd_hal::gpio::{Pins, PB16, PB17};
    use atsamd_hal::pac::{self, interrupt, Interrupt};
    use atsamd_hal::sercom::uart;

    /// The UART's SERCOM.
    pub(crate) type UartSercom = pac::Sercom5;
    /// Its pads: RX on PAD1, TX on PAD0.
    pub(crate) type UartPads = uart::PadsFromIds<UartSercom, PB17, PB16>;
    /// Its four interrupt lines.
    pub(crate) const UART_IRQS: [Interrupt; 4] = [
        Interrupt::SERCOM5_0,
        Interrupt::SERCOM5_1,
        Interrupt::SERCOM5_2,
        Interrupt::SERCOM5_OTHER,
    ];
    /// The limit switch's EXTINT line.
    pub(crate) const LIMIT_IRQ: Interrupt = Interrupt::EIC_EXTINT_3;
    /// Digital I/O 0..3's EXTINT channels (PB22, PB23, PA17, PA04).
    pub(crate) const DIGITAL_CHANNELS: [u8; 4] = [6, 7, 1, 4];
    /// Their interrupt lines.
    pub(crate) const DIGITAL_IRQS: [Interrupt; 4] = [
        Interrupt::EIC_EXTINT_6,
        Interrupt::EIC_EXTINT_7,
        Interrupt::EIC_EXTINT_1,
        Interrupt::EIC_EXTINT_4,
    ];

    /// The Feather M4's pins by use.
    pub(crate) fn take(p: Pins) -> super::BoardPins {
        super::BoardPins {
            step: p.pa14.into(),
            dir: p.pa16.into(),
            enable_n: p.pa18.into(),
            limit: p.pa19.into(),
            limit_channel: 3,
            driver_enable: p.pa22.into(),
            led: p.pa23.into(),
            digital: [p.pb22.into(), p.pb23.into(), p.pa17.into(), p.pa04.into()],
            pwm: [p.pa20.into(), p.pa21.into()],
            analog: [(p.pa02.into(), 0), (p.pa05.into(), 5), (p.pb08.into(), 2)],
            uart: uart::Pads::default().rx(p.pb17).tx(p.pb16),
            usb: (p.pa24, p.pa25),
        }
    }

    #[interrupt]
    fn SERCOM5_0() {
        crate::uart_link::on_interrupt();
    }
    #[interrupt]
    fn SERCOM5_1() {
        crate::uart_link::on_interrupt();
    }
    #[interrupt]
    fn SERCOM5_2() {
        crate::uart_link::on_interrupt();
    }
    #[interrupt]
    fn SERCOM5_OTHER() {
        crate::uart_link::on_interrupt();
    }
    #[interrupt]
    fn EIC_EXTINT_3() {
        crate::steps::on_limit_interrupt();
    }
    #[interrupt]
    fn EIC_EXTINT_6() {
        crate::edges::on_edge(0);
    }
    #[interrupt]
    fn EIC_EXTINT_7() {
        crate::edges::on_edge(1);
    }
    #[interrupt]
    fn EIC_EXTINT_1() {
        crate::edges::on_edge(2);
    }
    #[interrupt]
    fn EIC_EXTINT_4() {
        crate::edges::on_edge(3);
    }
}

pub(crate) use map::{
    take, UartPads, UartSercom, DIGITAL_CHANNELS, DIGITAL_IRQS, LIMIT_IRQ, UART_IRQS,
};

/// The UART, configured.
pub(crate) type BoardUart = atsamd_hal::sercom::uart::Uart<
    atsamd_hal::sercom::uart::Config<UartPads>,
    atsamd_hal::sercom::uart::Duplex,
>;
