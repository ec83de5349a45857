//! Step generation and the limit switch: the time-critical work, run on the
//! step executor (an interrupt executor on `SWI_IRQ_1`, above the link
//! executor and the runtime), so no amount of network traffic delays it.
//!
//! A PIO state machine clocks STEP (GP2) and DIR (GP3) out at 100 kHz, one
//! 10 µs tick per two bits of a 32-bit word (bit 0 STEP, bit 1 DIR, LSB
//! first; 16 ticks a word), the format of `maxl::step::PioPacker`. Its
//! joined 8-word TX FIFO holds 1.28 ms of ticks. The step task tops it up
//! with [`osap_module::ModuleCell::fill_step_word`] (on [`crate::MODULE`]) on a timer alarm every 640 µs,
//! when half of it has run out.
//!
//! Each word's start time comes from a running tick count anchored to the
//! timer when the state machine was started, not from when the interrupt
//! ran: the PIO and the timer run off the same crystal, so the count stays
//! exact however late the task gets to the FIFO. If the FIFO ever runs dry
//! (the state machine stalls, e.g. while a flash erase held interrupts off)
//! the anchor is lost; the task stops the machine and starts it afresh.

use embassy_rp::gpio::{Input, Level};
use embassy_rp::peripherals::PIO0;
use embassy_rp::pio::{
    Common, Config, Direction, FifoJoin, Pin, ShiftConfig, ShiftDirection, StateMachine,
};
use embassy_time::{Instant, Timer};
use fixed::types::U24F8;
use osap_module::{STEP_TICK_US, TICKS_PER_WORD};
// The module takes typed local instants; the step schedule here counts
// embassy-time µs, the same counter.
use osap_core::Instant as LocalInstant;

/// Local µs covered by one FIFO word.
const WORD_US: u64 = (STEP_TICK_US * TICKS_PER_WORD) as u64;
/// Words in the joined TX FIFO.
const FIFO_WORDS: u64 = 8;
/// How far ahead of starting the state machine its first words are
/// computed: enough for eight `fill_step_word` calls with room to spare.
const START_LEAD_US: u64 = 2_000;
/// The last part of the wait before starting is spun, not slept, so the
/// start lands on the anchor within a microsecond.
const START_SPIN_US: u64 = 50;
/// Words left in the FIFO when the step task refills it: 640 µs of ticks,
/// the most the task may be held up without the machine running dry.
const REFILL_MARGIN_WORDS: u64 = 4;
/// PIO instruction clock: 1 MHz, 10 instructions per 10 µs tick.
const PIO_HZ: u32 = 1_000_000;

/// The step state machine: PIO0, state machine 0.
pub(crate) type StepSm = StateMachine<'static, PIO0, 0>;

/// Loads the step program into PIO0 and configures state machine 0 to run
/// it on `step` (set pin) and `dir` (out pin). The machine is left stopped.
pub(crate) fn configure(
    common: &mut Common<'static, PIO0>,
    sm: &mut StepSm,
    step: Pin<'static, PIO0>,
    dir: Pin<'static, PIO0>,
) {
    // Ten cycles of 1 µs per tick on both paths. DIR is set 2 µs before
    // STEP rises; STEP stays high 4 µs (A4988 needs 1 µs and 200 ns of DIR
    // setup, DRV8825 1.9 µs and 650 ns). An empty FIFO stalls the machine
    // at the first `out`, with STEP low and DIR held.
    let program = pio::pio_asm!(
        ".wrap_target",
        "top:",
        "    out x, 1",    // STEP bit of this tick (autopull)
        "    out pins, 1", // DIR
        "    jmp !x idle",
        "    set pins, 1 [3]", // STEP high for 4 µs
        "    set pins, 0 [1]",
        "    jmp top",
        "idle:",
        "    nop [6]",
        ".wrap",
    );
    let loaded = common.load_program(&program.program);

    let mut cfg = Config::default();
    cfg.use_program(&loaded, &[]);
    cfg.set_set_pins(&[&step]);
    cfg.set_out_pins(&[&dir]);
    cfg.shift_out = ShiftConfig {
        threshold: 32,
        direction: ShiftDirection::Right,
        auto_fill: true,
    };
    cfg.fifo_join = FifoJoin::TxOnly;
    // 125 MHz / 125 = 1 MHz: an integer divider, so no fractional jitter.
    cfg.clock_divider = U24F8::from_num(embassy_rp::clocks::clk_sys_freq() / PIO_HZ);
    sm.set_config(&cfg);
    sm.set_pins(Level::Low, &[&step, &dir]);
    sm.set_pin_dirs(Direction::Out, &[&step, &dir]);
}

/// Fills the FIFO for a start a little ahead, starts the state machine at
/// exactly that time and returns the local time of the next word's first
/// tick.
///
/// If the start time has already passed when the task gets to it
/// (interrupts were held off across it, as by a flash erase right after
/// the previous stall), the queued words are for ticks that are gone: it
/// tries again on a fresh anchor. Starting anyway would anchor the count
/// in the past, so every later refill would be due at once and the task,
/// above the runtime in priority, would spin on it for good.
async fn start(sm: &mut StepSm) -> u64 {
    loop {
        sm.set_enable(false);
        sm.clear_fifos();
        sm.restart();
        let anchor = Instant::now().as_micros() + START_LEAD_US;
        for k in 0..FIFO_WORDS {
            sm.tx()
                .push(crate::MODULE.fill_step_word(LocalInstant::from_micros(anchor + k * WORD_US)));
        }
        Timer::at(Instant::from_micros(anchor - START_SPIN_US)).await;
        // With interrupts off, so nothing lands between reaching the anchor
        // and starting the machine.
        let started = critical_section::with(|_| {
            if Instant::now().as_micros() > anchor {
                return false;
            }
            while Instant::now().as_micros() < anchor {}
            sm.clkdiv_restart();
            sm.set_enable(true);
            true
        });
        if started {
            // The FIFO just went empty-flagged before the start: clear the flag.
            let _ = sm.tx().stalled();
            return anchor + FIFO_WORDS * WORD_US;
        }
    }
}

/// Keeps the step state machine's FIFO topped up, forever.
///
/// It wakes when the FIFO is down to [`REFILL_MARGIN_WORDS`] words and
/// fills it again, rather than on every free slot: a wake-up costs about as
/// much as computing a word, so this halves the step path's idle load.
#[embassy_executor::task]
pub async fn step_task(mut sm: StepSm) {
    let mut next = start(&mut sm).await;
    loop {
        // Words already queued run until `next`; wake when only the
        // margin is left.
        let refill_at = next - REFILL_MARGIN_WORDS * WORD_US;
        Timer::at(Instant::from_micros(refill_at)).await;
        // Only this task pushes, so a slot seen free stays free.
        while !sm.tx().full() {
            sm.tx()
                .push(crate::MODULE.fill_step_word(LocalInstant::from_micros(next)));
            next += WORD_US;
        }
        if sm.tx().stalled() {
            // Ticks ran out before the refill (interrupts were held off
            // for over a millisecond): the queued words' tick times are
            // unknown. Start over on a fresh anchor.
            next = start(&mut sm).await;
        }
    }
}

/// Reports every change of the limit switch's level (GP5, pull-up) with
/// the time of the edge. The level at start is reported too, so the module
/// knows it before the first edge.
#[embassy_executor::task]
pub async fn limit_task(mut pin: Input<'static>) {
    let mut level = pin.is_high();
    crate::MODULE.limit_initial(level);
    loop {
        pin.wait_for_any_edge().await;
        // Stamped first thing: only the GPIO interrupt and the step task
        // run ahead of this.
        let at = osap_firmware::local_now();
        let now_level = pin.is_high();
        // A bounce that settled back before we looked is no change.
        if now_level != level {
            level = now_level;
            crate::MODULE.limit_changed(at, level);
        }
    }
}
