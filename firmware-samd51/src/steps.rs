//! Step generation and the limit switch: the time-critical work.
//!
//! TC0 interrupts twice per 10 µs tick at the top NVIC priority (0x00),
//! which no critical section masks (see [`crate::cs`]):
//!
//! - at the tick's overflow, 3 µs before the tick's time, it ends the
//!   previous step pulse (STEP low) and sets DIR for this tick;
//! - at CC1, at the tick's time, it raises STEP if the tick has a step.
//!
//! So DIR is set 3 µs before STEP rises, a pulse is 7 µs high and at least
//! 3 µs low (A4988: 1 µs each and 200 ns of DIR setup; DRV8825: 1.9 µs and
//! 650 ns). A tick is two bits of a 32-bit word (bit 0 STEP, bit 1 DIR, LSB
//! first, 16 ticks a word): the format of `maxl::step::PioPacker` that
//! [`osap_module::ModuleCell::fill_step_word`] (on [`crate::MODULE`]) returns.
//!
//! Words come from a lock-free ring of eight (1.28 ms of ticks), topped up
//! by the step task on the step executor (priority 0x20) with
//! `fill_step_word`, four words at a time. Each word's start time comes
//! from a running tick count anchored to the time base when the timer was
//! started, not from when the task ran: TC0 and the time base run off the
//! same 16 MHz generator, so the count stays exact however late the task
//! gets to the ring. If the ring runs dry (the task was held off for over a
//! millisecond) the interrupt stops the timer; the task starts it afresh
//! on a new anchor, as the RP2040 firmware restarts its stalled PIO.

use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use atsamd_hal::clock::ClockId;
use atsamd_hal::pac::{self, interrupt, Interrupt, NVIC};
use embassy_time::{Instant, Timer};
use osap_module::{STEP_TICK_US, TICKS_PER_WORD};
// The module takes typed local instants; the step schedule here counts
// embassy-time µs, the same counter.
use osap_core::Instant as LocalInstant;

use crate::board::FastPin;
use crate::clocks;

/// Local µs covered by one word.
const WORD_US: u64 = (STEP_TICK_US * TICKS_PER_WORD) as u64;
/// Words in the ring.
const RING_WORDS: u32 = 8;
/// Words left when the step task refills the ring.
const REFILL_MARGIN_WORDS: u64 = 4;
/// How far ahead of starting the timer its first words are computed.
const START_LEAD_US: u64 = 2_000;
/// The last part of the wait before starting is spun, not slept.
const START_SPIN_US: u64 = 50;
/// Time-base ticks (16 MHz) per step tick.
const TIMER_TICKS: u32 = clocks::TIMEBASE_HZ / 1_000_000 * STEP_TICK_US;
/// DIR is set, and the previous pulse ended, this long before a tick's
/// STEP edge, µs.
const DIR_LEAD_US: u32 = 3;
/// NVIC priority of the tick interrupt: the top one.
pub(crate) const TICK_PRIORITY: u8 = 0x00;

/// A single-producer (step task), single-consumer (tick interrupt) ring
/// of step words.
struct WordRing {
    words: [AtomicU32; RING_WORDS as usize],
    /// Words pushed, wrapping.
    head: AtomicU32,
    /// Words taken, wrapping.
    tail: AtomicU32,
}

impl WordRing {
    const fn new() -> Self {
        WordRing {
            words: [const { AtomicU32::new(0) }; RING_WORDS as usize],
            head: AtomicU32::new(0),
            tail: AtomicU32::new(0),
        }
    }

    fn len(&self) -> u32 {
        self.head
            .load(Ordering::Acquire)
            .wrapping_sub(self.tail.load(Ordering::Acquire))
    }

    /// Adds a word; the caller checked there is room.
    fn push(&self, word: u32) {
        let h = self.head.load(Ordering::Relaxed);
        self.words[(h % RING_WORDS) as usize].store(word, Ordering::Relaxed);
        self.head.store(h.wrapping_add(1), Ordering::Release);
    }

    fn pop(&self) -> Option<u32> {
        let t = self.tail.load(Ordering::Relaxed);
        if self.head.load(Ordering::Acquire) == t {
            return None;
        }
        let w = self.words[(t % RING_WORDS) as usize].load(Ordering::Relaxed);
        self.tail.store(t.wrapping_add(1), Ordering::Release);
        Some(w)
    }

    /// Empties the ring (only while the timer is stopped).
    fn clear(&self) {
        self.tail
            .store(self.head.load(Ordering::Acquire), Ordering::Release);
    }
}

static RING: WordRing = WordRing::new();
/// Set by the interrupt when the ring ran dry and it stopped the timer.
static STALLED: AtomicBool = AtomicBool::new(false);
/// Set by the task after a restart: the interrupt drops its partial word.
static FRESH: AtomicBool = AtomicBool::new(false);
/// The STEP and DIR pins (packed [`FastPin`]s), set once by [`configure`]
/// before the interrupt is unmasked.
static STEP_PIN: AtomicU32 = AtomicU32::new(FastPin::NONE);
static DIR_PIN: AtomicU32 = AtomicU32::new(FastPin::NONE);

/// TC0's registers in 16-bit mode.
fn tc() -> &'static pac::tc0::Count16 {
    // SAFETY: TC0 belongs to the step generator; static MMIO.
    unsafe { (*pac::Tc0::ptr()).count16() }
}

/// Sets up TC0 as the tick timer on `step` and `dir` (outputs, low), its
/// interrupt at the top priority; the timer is left stopped.
pub(crate) fn configure(mclk: &mut pac::Mclk, nvic: &mut NVIC, step: FastPin, dir: FastPin) {
    step.set(false);
    dir.set(false);
    STEP_PIN.store(step.pack(), Ordering::Release);
    DIR_PIN.store(dir.pack(), Ordering::Release);
    mclk.apbamask().modify(|_, w| w.tc0_().set_bit());
    clocks::route_timebase(ClockId::TC0_TC1);
    let c = tc();
    c.ctrla().write(|w| w.swrst().set_bit());
    while c.syncbusy().read().swrst().bit_is_set() {}
    c.ctrla().write(|w| {
        w.mode().count16();
        w.prescsync().presc();
        w.prescaler().div1()
    });
    // The counter runs 0..=CC0 (one tick) and wraps.
    c.wave().write(|w| w.wavegen().mfrq());
    // SAFETY: both values fit 16 bits.
    c.cc(0)
        .write(|w| unsafe { w.cc().bits((TIMER_TICKS - 1) as u16) });
    c.cc(1).write(|w| unsafe {
        w.cc()
            .bits((clocks::TIMEBASE_HZ / 1_000_000 * DIR_LEAD_US) as u16)
    });
    while c.syncbusy().read().bits() != 0 {}
    c.intflag()
        .write(|w| w.ovf().set_bit().mc0().set_bit().mc1().set_bit());
    c.intenset().write(|w| w.ovf().set_bit().mc1().set_bit());
    // SAFETY: the pins are set; the handler below is ready.
    unsafe {
        nvic.set_priority(Interrupt::TC0, TICK_PRIORITY);
        NVIC::unmask(Interrupt::TC0);
    }
}

fn stop_timer() {
    let c = tc();
    c.ctrla().modify(|_, w| w.enable().clear_bit());
    while c.syncbusy().read().enable().bit_is_set() {}
}

/// Fills the ring for a start a little ahead, starts the timer so the
/// first tick's STEP edge lands on that time, and returns the local time
/// of the next word's first tick.
async fn start() -> u64 {
    stop_timer();
    let c = tc();
    // SAFETY: zero is a valid count.
    c.count().write(|w| unsafe { w.count().bits(0) });
    while c.syncbusy().read().count().bit_is_set() {}
    c.intflag()
        .write(|w| w.ovf().set_bit().mc0().set_bit().mc1().set_bit());
    RING.clear();
    FRESH.store(true, Ordering::Release);
    STALLED.store(false, Ordering::Release);
    let anchor = Instant::now().as_micros() + START_LEAD_US;
    for k in 0..u64::from(RING_WORDS) {
        RING.push(crate::MODULE.fill_step_word(LocalInstant::from_micros(anchor + k * WORD_US)));
    }
    // The first overflow comes one tick after the start and leads the
    // first STEP edge by DIR_LEAD_US.
    let start_at = anchor - u64::from(STEP_TICK_US) - u64::from(DIR_LEAD_US);
    Timer::at(Instant::from_micros(start_at - START_SPIN_US)).await;
    // Nothing but the (stopped) tick interrupt runs between reaching the
    // time and starting the timer.
    critical_section::with(|_| {
        while Instant::now().as_micros() < start_at {}
        c.ctrla().modify(|_, w| w.enable().set_bit());
    });
    anchor + u64::from(RING_WORDS) * WORD_US
}

/// Keeps the ring topped up, forever.
#[embassy_executor::task]
pub async fn step_task() {
    let mut next = start().await;
    loop {
        let refill_at = next - REFILL_MARGIN_WORDS * WORD_US;
        Timer::at(Instant::from_micros(refill_at)).await;
        // Only this task pushes, so room seen stays.
        while RING.len() < RING_WORDS {
            RING.push(crate::MODULE.fill_step_word(LocalInstant::from_micros(next)));
            next += WORD_US;
        }
        if STALLED.load(Ordering::Acquire) {
            // The ring ran dry before the refill: the words' tick times are
            // unknown. Start over on a fresh anchor.
            next = start().await;
        }
    }
}

/// The tick interrupt.
#[interrupt]
fn TC0() {
    static mut WORD: u32 = 0;
    static mut LEFT: u32 = 0;
    static mut STEP_DUE: bool = false;

    let step = FastPin::unpack(STEP_PIN.load(Ordering::Relaxed));
    let dir = FastPin::unpack(DIR_PIN.load(Ordering::Relaxed));
    let c = tc();
    let flags = c.intflag().read();
    // The STEP edge of the current tick first, if both are pending.
    if flags.mc1().bit_is_set() {
        c.intflag().write(|w| w.mc1().set_bit());
        if *STEP_DUE {
            step.set(true);
            *STEP_DUE = false;
        }
    }
    if flags.ovf().bit_is_set() {
        c.intflag().write(|w| w.ovf().set_bit());
        step.set(false);
        if FRESH.swap(false, Ordering::AcqRel) {
            *LEFT = 0;
        }
        if *LEFT == 0 {
            match RING.pop() {
                Some(w) => {
                    *WORD = w;
                    *LEFT = TICKS_PER_WORD;
                }
                None => {
                    // Out of words: stop; the step task restarts.
                    c.ctrla().modify(|_, w| w.enable().clear_bit());
                    *STEP_DUE = false;
                    STALLED.store(true, Ordering::Release);
                    return;
                }
            }
        }
        let bits = *WORD & 0b11;
        *WORD >>= 2;
        *LEFT -= 1;
        dir.set(bits & 0b10 != 0);
        *STEP_DUE = bits & 0b01 != 0;
    }
}

/// The limit switch's EIC channel and pin.
pub(crate) struct Limit {
    /// EXTINT channel.
    pub channel: u8,
    /// The pin, for its level.
    pub pin: FastPin,
}

/// The limit switch's channel and packed pin, set by [`start_limit`]
/// before its interrupt is unmasked.
static LIMIT_CHANNEL: AtomicU32 = AtomicU32::new(0);
static LIMIT_PIN: AtomicU32 = AtomicU32::new(FastPin::NONE);
static LIMIT_LEVEL: AtomicBool = AtomicBool::new(false);

/// NVIC priority of the limit switch's interrupt.
pub(crate) const LIMIT_PRIORITY: u8 = 0x20;

/// Starts reporting the limit switch: both edges on its EIC channel, the
/// level at start reported at once.
///
/// The pin must already be an EIC input with its pull-up, and the EIC
/// clocked and enabled with both-edge sensing on `limit.channel`.
pub(crate) fn start_limit(nvic: &mut NVIC, limit: Limit, irq: Interrupt) {
    let level = limit.pin.read();
    LIMIT_LEVEL.store(level, Ordering::Relaxed);
    crate::MODULE.limit_initial(level);
    LIMIT_CHANNEL.store(u32::from(limit.channel), Ordering::Release);
    LIMIT_PIN.store(limit.pin.pack(), Ordering::Release);
    // SAFETY: the handler is ready.
    unsafe {
        nvic.set_priority(irq, LIMIT_PRIORITY);
        NVIC::unmask(irq);
    }
}

/// The limit switch's edge interrupt (both edges), bound to its EXTINT
/// line in `main`.
pub(crate) fn on_limit_interrupt() {
    // Stamped first thing.
    let at = osap_firmware::local_now();
    let channel = LIMIT_CHANNEL.load(Ordering::Acquire);
    let pin = FastPin::unpack(LIMIT_PIN.load(Ordering::Acquire));
    // SAFETY: INTFLAG is write-one-to-clear; only this channel's bit.
    let eic = unsafe { &*pac::Eic::ptr() };
    eic.intflag().write(|w| unsafe { w.bits(1 << channel) });
    let level = pin.read();
    // A bounce that settled back before we looked is no change.
    if level != LIMIT_LEVEL.swap(level, Ordering::Relaxed) {
        crate::MODULE.limit_changed(at, level);
    }
}
