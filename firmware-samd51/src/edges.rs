//! Rising-edge counting on the digital I/O pins: the board side of
//! osap-module's tachometer ([`osap_module::tach`], through
//! [`crate::board::IoPins`]'s `edge_count`).
//!
//! Each digital pin is an EIC input (peripheral function A, pull-down)
//! sensing rising edges on its own EXTINT channel, with its own NVIC line,
//! as the limit switch is stamped ([`crate::steps::on_limit_interrupt`]).
//! The handler stamps the local time first thing, clears its flag, and
//! adds one to the pin's wrapping count and stores the time, both in one
//! critical section, so a reader never sees a count with another edge's
//! time.
//!
//! **Which pins count:** all four digital pins while they are inputs; every
//! one has an EXTINT channel of its own, apart from the limit switch's
//! (Metro M4: D7/PB12 EXTINT12, D10/PA18 EXTINT2, D11/PA19 EXTINT3,
//! D12/PA17 EXTINT1; Feather M4: MISO/PB22 EXTINT6, MOSI/PB23 EXTINT7,
//! SCK/PA17 EXTINT1, A4/PA04 EXTINT4). A pin a script has written is an
//! output, off the EIC's function: its channel's interrupt is switched off
//! and `edge_count` answers `None` for it.
//!
//! **Cost (estimated from the code path, not measured on silicon):** the
//! handler reads the time driver's counter (a READSYNC of TC2, under a
//! microsecond at its 16 MHz clock), clears the flag and takes a critical
//! section: about 2 µs at 120 MHz with entry and exit (the RP2040's
//! estimate came out 2.3 times low when measured in its emulator, so allow
//! 5 µs). At a spindle's worst case, 24 000 rpm × 2 pulses a turn = 800
//! Hz, that is at most 4 ms a second, 0.4 % of the core. It runs at [`EDGE_PRIORITY`] (0x20, the limit
//! switch's), below the step tick interrupt (0x00), which preempts it and
//! is never masked by its critical section (BASEPRI 0x20, [`crate::cs`]):
//! an edge adds no jitter to a step. The flag latches one edge while its
//! handler is pending or masked, so edges closer together than the
//! longest critical section or same-priority handler (the time driver,
//! the limit switch, the step task's refill) merge into one; sustained,
//! 10 kHz takes 2 to 5 % of the core, so a tachometer at or under 10 kHz
//! (12.5 times the 800 Hz above) leaves the step path and the links their
//! time. Each stamp is late by the same latency: under a µs when nothing
//! holds it off. A flash write (NVMCTRL, only while the axis stands and a
//! name, bus role or clock rate is saved) may hold it off for
//! milliseconds: the read across it comes out low.

use core::cell::Cell;
use core::sync::atomic::{AtomicBool, Ordering};

use atsamd_hal::pac::{self, NVIC};
use critical_section::Mutex;

use crate::board::{DIGITAL_CHANNELS, DIGITAL_IRQS};

/// Digital pins that count: all four.
pub(crate) const PINS: usize = 4;

/// NVIC priority of the digital pins' edge interrupts: the limit switch's.
pub(crate) const EDGE_PRIORITY: u8 = crate::steps::LIMIT_PRIORITY;

/// Per pin: rising edges since boot (wrapping) and the local µs of the
/// newest (0 before any), latched together.
static COUNTS: Mutex<[Cell<(u32, u64)>; PINS]> = Mutex::new([const { Cell::new((0, 0)) }; PINS]);

/// Set once a pin has been made an output: it counts no more.
static OUTPUT: [AtomicBool; PINS] = [const { AtomicBool::new(false) }; PINS];

fn eic() -> &'static pac::eic::RegisterBlock {
    // SAFETY: static MMIO; only write-one-to-set/clear registers are
    // written here, each with this module's channels' bits.
    unsafe { &*pac::Eic::ptr() }
}

/// Unmasks the digital pins' edge interrupts. The EIC must be clocked and
/// enabled with rising-edge sensing on [`DIGITAL_CHANNELS`] (`main`).
pub(crate) fn start(nvic: &mut NVIC) {
    for irq in DIGITAL_IRQS {
        // SAFETY: the handlers are ready (`on_edge`).
        unsafe {
            nvic.set_priority(irq, EDGE_PRIORITY);
            NVIC::unmask(irq);
        }
    }
}

/// Marks digital pin `pin` an output (from `write_digital`): its channel's
/// interrupt goes off and [`count`] answers `None`.
pub(crate) fn mark_output(pin: usize) {
    let (Some(o), Some(&channel)) = (OUTPUT.get(pin), DIGITAL_CHANNELS.get(pin)) else {
        return;
    };
    o.store(true, Ordering::Relaxed);
    // SAFETY: write-one-to-clear, this channel's bit.
    eic().intenclr().write(|w| unsafe { w.bits(1 << channel) });
}

/// Digital pin `pin`'s count and the local µs of its newest edge, or
/// `None` for a pin that does not count (none such, or an output).
pub(crate) fn count(pin: usize) -> Option<(u32, u64)> {
    if OUTPUT.get(pin)?.load(Ordering::Relaxed) {
        return None;
    }
    critical_section::with(|cs| COUNTS.borrow(cs).get(pin).map(Cell::get))
}

/// Digital pin `index`'s rising-edge interrupt, bound to its EXTINT line
/// in [`crate::board`].
pub(crate) fn on_edge(index: usize) {
    // Stamped first thing.
    let at = osap_firmware::local_now().as_micros();
    let Some(&channel) = DIGITAL_CHANNELS.get(index) else {
        return;
    };
    // SAFETY: INTFLAG is write-one-to-clear; only this channel's bit.
    eic().intflag().write(|w| unsafe { w.bits(1 << channel) });
    if OUTPUT.get(index).is_none_or(|o| o.load(Ordering::Relaxed)) {
        return;
    }
    critical_section::with(|cs| {
        if let Some(c) = COUNTS.borrow(cs).get(index) {
            let (n, _) = c.get();
            c.set((n.wrapping_add(1), at));
        }
    });
}
