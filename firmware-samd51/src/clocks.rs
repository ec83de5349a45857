//! Clocks: the HAL's 120 MHz tree on the 32.768 kHz crystal, plus a
//! crystal-locked 16 MHz generator for the time base and the step timer.
//!
//! `GenericClockController::with_external_32kosc` starts XOSC32K (GCLK1),
//! runs the DFLL in USB clock-recovery mode (locked to the host's 1 kHz
//! start-of-frame packets, as USB needs) and DPLL0 at 120 MHz from it for
//! the CPU. The DFLL is accurate only while SOFs arrive; unplugged it runs
//! open loop. So the time base does not use it: DPLL1 multiplies the
//! crystal to 96 MHz (32 768 Hz × 2929.6875, an exact fractional ratio) and
//! GCLK3 divides that by 6 to 16 MHz, which clocks TC2+TC3 (the 1 MHz time
//! base) and TC0 (the 100 kHz step tick). Both then run at the crystal's
//! rate, so step ticks and time stamps stay in step with each other.

use atsamd_hal::clock::{ClockId, GenericClockController};
use atsamd_hal::pac;

/// The generator that feeds the time base and the step timer.
pub(crate) const TIMEBASE_GCLK: u8 = 3;
/// Its frequency.
pub(crate) const TIMEBASE_HZ: u32 = 16_000_000;
/// DPLL1's output: 96 MHz, the lowest the DPLL allows.
const DPLL1_HZ: u32 = 96_000_000;
/// The crystal.
const XOSC32K_HZ: u32 = 32_768;
/// DPLL1 ratio: output = reference × (LDR + 1 + LDRFRAC / 32).
const LDR_TIMES_32: u32 = DPLL1_HZ * 32 / XOSC32K_HZ - 32;
const _: () = assert!(
    (LDR_TIMES_32 + 32) as u64 * XOSC32K_HZ as u64 == DPLL1_HZ as u64 * 32,
    "the DPLL1 ratio must be exact"
);

/// Sets up the clock tree; returns the HAL's controller for the
/// peripherals it clocks (USB, SERCOM, EIC, ADC, TCC).
pub(crate) fn init(
    gclk: pac::Gclk,
    mclk: &mut pac::Mclk,
    osc32kctrl: &mut pac::Osc32kctrl,
    oscctrl: &mut pac::Oscctrl,
    nvmctrl: &mut pac::Nvmctrl,
) -> GenericClockController {
    let clocks =
        GenericClockController::with_external_32kosc(gclk, mclk, osc32kctrl, oscctrl, nvmctrl);

    let dpll = oscctrl.dpll(1);
    // SAFETY: LDR and LDRFRAC fit their fields (checked by the constants).
    dpll.dpllratio().write(|w| unsafe {
        w.ldr().bits((LDR_TIMES_32 / 32) as u16);
        w.ldrfrac().bits((LDR_TIMES_32 % 32) as u8)
    });
    while dpll.dpllsyncbusy().read().dpllratio().bit_is_set() {}
    dpll.dpllctrlb().write(|w| w.refclk().xosc32());
    dpll.dpllctrla().write(|w| w.enable().set_bit());
    while dpll.dpllsyncbusy().read().enable().bit_is_set() {}
    while {
        let s = dpll.dpllstatus().read();
        s.lock().bit_is_clear() || s.clkrdy().bit_is_clear()
    } {}

    // SAFETY: GCLK3 is not used by the HAL's controller (its table shows
    // it unconfigured), and only this module touches it.
    let gclk = unsafe { pac::Gclk::steal() };
    gclk.genctrl(usize::from(TIMEBASE_GCLK)).write(|w| unsafe {
        w.src().dpll1();
        w.div().bits((DPLL1_HZ / TIMEBASE_HZ) as u16);
        w.genen().set_bit()
    });
    while gclk.syncbusy().read().bits() != 0 {}
    clocks
}

/// Connects peripheral channel `id` to the time-base generator.
pub(crate) fn route_timebase(id: ClockId) {
    // SAFETY: one PCHCTRL register, owned by the peripheral `id` names.
    let gclk = unsafe { pac::Gclk::steal() };
    let ch = gclk.pchctrl(id as usize);
    ch.write(|w| unsafe {
        w.r#gen().bits(TIMEBASE_GCLK);
        w.chen().set_bit()
    });
    while ch.read().chen().bit_is_clear() {}
}
