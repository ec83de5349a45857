//! The embassy time driver: TC2+TC3 as one 32-bit counter at 1 MHz,
//! extended to 64 bits by half-period counting, with the alarm on CC0.
//!
//! The arithmetic (joining the period count and the counter, deciding
//! whether and when to arm the compare) is osap-firmware's
//! [`timebase`](osap_firmware::timebase), tested on the host; this module
//! only moves it to and from the registers:
//!
//! - CC1 = `0x8000_0000`: the TC2 interrupt bumps `period` on `MC1` and on
//!   `OVF`, twice per wrap;
//! - reading COUNT takes `CTRLBSET.CMD = READSYNC` and a wait for the
//!   synchronisation, inside a critical section so the period read with it
//!   belongs to it;
//! - an alarm is written to CC0, its stale `MC0` flag cleared, and `MC0`
//!   enabled only if it is less than `ARM_LIMIT` ticks ahead (a period bump
//!   re-checks the others); a time that has passed by the moment it is armed
//!   is reported as not set, so the queue runs at once.
//!
//! The counter runs from GCLK3 (16 MHz from the crystal through DPLL1, see
//! [`crate::clocks`]) divided by 16.

use core::cell::{Cell, RefCell};
use core::sync::atomic::{AtomicU32, Ordering};

use atsamd_hal::clock::ClockId;
use atsamd_hal::pac::{self, interrupt, Interrupt, NVIC};
use critical_section::{CriticalSection, Mutex};
use embassy_time_driver::Driver;
use embassy_time_queue_utils::Queue;
use osap_firmware::timebase::{self, AlarmAction};

use crate::clocks;

/// NVIC priority of the TC2 interrupt (0x20: below only the step tick).
pub(crate) const PRIORITY: u8 = 0x20;

/// The driver's state.
struct TcDriver {
    /// Half periods of the counter since start.
    period: AtomicU32,
    /// The armed alarm, `u64::MAX` for none.
    alarm: Mutex<Cell<u64>>,
    /// embassy's timer queue.
    queue: Mutex<RefCell<Queue>>,
}

embassy_time_driver::time_driver_impl!(static DRIVER: TcDriver = TcDriver {
    period: AtomicU32::new(0),
    alarm: Mutex::new(Cell::new(u64::MAX)),
    queue: Mutex::new(RefCell::new(Queue::new())),
});

/// TC2's registers in 32-bit mode.
fn tc() -> &'static pac::tc0::Count32 {
    // SAFETY: TC2 belongs to this driver after `init`; the register block
    // is static MMIO.
    unsafe { (*pac::Tc2::ptr()).count32() }
}

/// Starts the counter and its interrupt. Call once, before anything reads
/// the time.
pub(crate) fn init(mclk: &mut pac::Mclk, nvic: &mut NVIC) {
    mclk.apbbmask()
        .modify(|_, w| w.tc2_().set_bit().tc3_().set_bit());
    clocks::route_timebase(ClockId::TC2_TC3);
    let c = tc();
    c.ctrla().write(|w| w.swrst().set_bit());
    while c.syncbusy().read().swrst().bit_is_set() {}
    c.ctrla().write(|w| {
        w.mode().count32();
        w.prescsync().presc();
        w.prescaler().div16()
    });
    // SAFETY: any value is a valid compare.
    c.cc(1).write(|w| unsafe { w.cc().bits(timebase::HALF) });
    while c.syncbusy().read().cc1().bit_is_set() {}
    c.intflag()
        .write(|w| w.ovf().set_bit().mc0().set_bit().mc1().set_bit());
    c.intenset().write(|w| w.ovf().set_bit().mc1().set_bit());
    c.ctrla().modify(|_, w| w.enable().set_bit());
    while c.syncbusy().read().enable().bit_is_set() {}
    // SAFETY: the handler below is ready; priorities are set before unmasking.
    unsafe {
        nvic.set_priority(Interrupt::TC2, PRIORITY);
        NVIC::unmask(Interrupt::TC2);
    }
}

/// The counter's value, synchronised.
fn read_counter() -> u32 {
    let c = tc();
    c.ctrlbset().write(|w| w.cmd().readsync());
    while c.ctrlbset().read().cmd().bits() != 0 {}
    while {
        let s = c.syncbusy().read();
        s.ctrlb().bit_is_set() || s.count().bit_is_set()
    } {}
    c.count().read().bits()
}

impl TcDriver {
    fn now_in(&self, _cs: CriticalSection) -> u64 {
        timebase::now(self.period.load(Ordering::Relaxed), read_counter())
    }

    /// Arms (or defers) the alarm for `at`; `false` if `at` has passed.
    fn set_alarm(&self, cs: CriticalSection, at: u64) -> bool {
        let c = tc();
        self.alarm.borrow(cs).set(at);
        match timebase::alarm_action(self.now_in(cs), at) {
            AlarmAction::Past => {
                c.intenclr().write(|w| w.mc0().set_bit());
                self.alarm.borrow(cs).set(u64::MAX);
                false
            }
            AlarmAction::Arm(compare) => {
                // SAFETY: any value is a valid compare.
                c.cc(0).write(|w| unsafe { w.cc().bits(compare) });
                while c.syncbusy().read().cc0().bit_is_set() {}
                // A match 2³² ticks ago may have left the flag set.
                c.intflag().write(|w| w.mc0().set_bit());
                c.intenset().write(|w| w.mc0().set_bit());
                if timebase::is_due(self.now_in(cs), at) {
                    // Passed while arming: the match may have been missed.
                    c.intenclr().write(|w| w.mc0().set_bit());
                    self.alarm.borrow(cs).set(u64::MAX);
                    false
                } else {
                    true
                }
            }
            AlarmAction::Defer => {
                c.intenclr().write(|w| w.mc0().set_bit());
                true
            }
        }
    }

    /// Wakes what is due and arms the next alarm.
    fn run_queue(&self, cs: CriticalSection) {
        let mut queue = self.queue.borrow(cs).borrow_mut();
        let mut next = queue.next_expiration(self.now_in(cs));
        while !self.set_alarm(cs, next) {
            next = queue.next_expiration(self.now_in(cs));
        }
    }

    fn on_interrupt(&self) {
        let c = tc();
        critical_section::with(|cs| {
            let flags = c.intflag().read();
            if flags.ovf().bit_is_set() {
                c.intflag().write(|w| w.ovf().set_bit());
                self.period.fetch_add(1, Ordering::Relaxed);
            }
            if flags.mc1().bit_is_set() {
                c.intflag().write(|w| w.mc1().set_bit());
                self.period.fetch_add(1, Ordering::Relaxed);
            }
            if flags.mc0().bit_is_set() {
                c.intflag().write(|w| w.mc0().set_bit());
            }
            let at = self.alarm.borrow(cs).get();
            if timebase::is_due(self.now_in(cs), at) {
                self.alarm.borrow(cs).set(u64::MAX);
                self.run_queue(cs);
            } else if at != u64::MAX && !self.set_alarm(cs, at) {
                // A deferred alarm re-checked after a period bump, which
                // turned out due.
                self.run_queue(cs);
            }
        });
    }
}

impl Driver for TcDriver {
    fn now(&self) -> u64 {
        critical_section::with(|cs| self.now_in(cs))
    }

    fn schedule_wake(&self, at: u64, waker: &core::task::Waker) {
        critical_section::with(|cs| {
            let mut queue = self.queue.borrow(cs).borrow_mut();
            if queue.schedule_wake(at, waker) {
                let mut next = queue.next_expiration(self.now_in(cs));
                while !self.set_alarm(cs, next) {
                    next = queue.next_expiration(self.now_in(cs));
                }
            }
        });
    }
}

#[interrupt]
fn TC2() {
    DRIVER.on_interrupt();
}
