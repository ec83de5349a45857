//! Rising-edge counting on the digital I/O pins (GP10..GP13): the board
//! side of osap-module's tachometer ([`osap_module::tach`], through
//! [`crate::board::IoPins`]'s `edge_count`).
//!
//! Each pin has a watcher task awaiting its rising edge with embassy-rp's
//! IO_BANK0 edge interrupt, the mechanism the limit switch is stamped with
//! ([`crate::steps::limit_task`]). The tasks run on their own interrupt
//! executor (`SWI_IRQ_2`, priority P0, in `main`), above the step executor,
//! so an edge is stamped and the interrupt re-armed right after the GPIO
//! interrupt, never behind a step-word refill. Each edge adds one to the
//! pin's wrapping count and stores its local time, both in one critical
//! section, so a reader never sees a count with another edge's time.
//!
//! **Which pins count:** all four digital pins while they are inputs. A
//! pin a script has written is an output: its edges are its own, so its
//! watcher stops for good (the interface has no way back to input) and
//! `edge_count` answers `None` for it.
//!
//! **Cost:** per edge, embassy-rp's IO_IRQ_BANK0 handler scans the 30
//! pins' status registers and wakes the task; the executor's tail-chained
//! interrupt polls it: a timer read, a critical section, clearing the
//! pin's edge latch and re-enabling its interrupt. Measured on the emulated
//! chip (`emulator/edge-cost.mjs`, rp2040js's cycle counts, not silicon):
//! 1 840 cycles a rising edge, 14.7 µs at 125 MHz (an estimate from the
//! code paths had said 800). At a spindle's worst case, 24 000 rpm × 2
//! pulses a turn = 800 Hz, that is 11.8 ms a second, 1.2 % of the core.
//! The step path is not starved by it: the PIO's FIFO holds 1.28 ms of
//! ticks and is refilled with 640 µs to spare, and an edge delays a refill
//! by at most 14.7 µs (59 µs if all four pins' edges land together), so
//! the tick timing, clocked by the PIO, is untouched.
//!
//! **Highest rate and stamp error:** re-arming clears the pin's edge
//! latch, and the latch holds one edge, so edges closer together than the
//! re-arm's latency merge into one. That latency is the ~15 µs above plus
//! whatever holds the interrupt off: another P0 interrupt (USB, UART, PIO,
//! timer; a few µs each) or a critical section (interrupts off; tens of
//! µs, up to 50 µs while the step machine is restarted). So rising edges
//! 70 µs or more apart count without loss. Sustained, the rate is bounded
//! by what the step path can spare: 10 kHz on one pin takes 15 % of the
//! core, and a streaming axis's refills need about a third of it, so keep
//! a tachometer at or under 10 kHz (12.5 times the 800 Hz above). Each
//! edge's stamp is late by the same latency: on the emulated chip, most
//! reads over 10 ms were exact, some 0.4 to 0.8 % off (a stamp 40 to 80 µs
//! late). A
//! flash erase (~45 ms with interrupts off, only while the axis stands and
//! a name, bus role or clock rate is saved) merges the edges within it:
//! the read across it comes out low.

use core::cell::Cell;
use core::sync::atomic::{AtomicBool, Ordering};

use critical_section::Mutex;
use embassy_rp::gpio::Flex;

/// Digital pins that count: all four.
pub(crate) const PINS: usize = 4;

/// Per pin: rising edges since boot (wrapping) and the local µs of the
/// newest (0 before any), latched together.
static COUNTS: Mutex<[Cell<(u32, u64)>; PINS]> = Mutex::new([const { Cell::new((0, 0)) }; PINS]);

/// Set once a pin has been made an output: it counts no more.
static OUTPUT: [AtomicBool; PINS] = [const { AtomicBool::new(false) }; PINS];

/// Marks digital pin `pin` an output (from `write_digital`): its watcher
/// stops at its next edge and `count` answers `None`.
pub(crate) fn mark_output(pin: usize) {
    if let Some(o) = OUTPUT.get(pin) {
        o.store(true, Ordering::Relaxed);
    }
}

/// Digital pin `pin`'s count and the local µs of its newest edge, or
/// `None` for a pin that does not count (none such, or an output).
pub(crate) fn count(pin: usize) -> Option<(u32, u64)> {
    if OUTPUT.get(pin)?.load(Ordering::Relaxed) {
        return None;
    }
    critical_section::with(|cs| COUNTS.borrow(cs).get(pin).map(Cell::get))
}

/// Counts digital pin `index`'s rising edges, forever. `watch` is a second
/// handle on the pin, used only to await edges: it never changes the
/// pin's direction or pull, and is never dropped (a dropped `Flex`
/// disconnects its pin).
#[embassy_executor::task(pool_size = 4)]
pub(crate) async fn edge_task(index: usize, mut watch: Flex<'static>) {
    let Some(output) = OUTPUT.get(index) else {
        return core::future::pending().await;
    };
    loop {
        watch.wait_for_rising_edge().await;
        // Stamped first thing: only the P0 interrupts run ahead of this.
        let at = osap_firmware::local_now().as_micros();
        if output.load(Ordering::Relaxed) {
            // An output's edges are its own: stop watching (and leave the
            // edge interrupt off, which the handler cleared).
            return core::future::pending().await;
        }
        critical_section::with(|cs| {
            if let Some(c) = COUNTS.borrow(cs).get(index) {
                let (n, _) = c.get();
                c.set((n.wrapping_add(1), at));
            }
        });
    }
}
