//! Cycle probe: calls osap-module's step-word path
//! (`ModuleCell::fill_step_word` on a `static` cell, what a firmware's step
//! interrupt calls for each word of 16 ticks) between `bkpt` instructions;
//! `scripts/module-cycles.js` runs it on an emulated RP2040 core and prints
//! the cycles between each pair of markers.
//!
//! Markers (`bkpt 2k` before, `bkpt 2k+1` after; the harness collects every
//! span of a pair, so a pair inside a loop measures each call):
//! - 0/1: marker overhead (subtracted by the harness);
//! - 2/3: one word of an enabled axis with no stream (idle), 64 in a row;
//! - 8/9: the stream's first words (warm-up, not reported);
//! - 4/5: one word of an axis tracking a stream of control points
//!   (1024 µs interval, 0.78 steps per 10 µs tick), 640 in a row: 100
//!   segments;
//! - 6: `r0` steps up, `r1` late steps, `r2` mode (checks, not spans);
//! - 10/11: one heater's control period (`Module::poll_heater` in its own
//!   critical section, as the pulse timer port runs it) of a module with
//!   two heaters holding their targets, 50 periods of both (on a second module
//!   whose board has I/O, so the step-word numbers above are unchanged);
//! - 12: `r0` the two heaters' states (first in the low byte), `r1` heater
//!   0's duty, of 65 535 (a check).
//!
//! At each opening marker `r0` holds the word's local start time and `r1`
//! its synchronized one (low 32 bits), so the harness can tell which words
//! re-read the time map and which start a segment.
//!
//! The measured call is `probe_fill`, `#[inline(never)]` and `extern "C"`:
//! a measurement includes the call and return, as the step interrupt pays.
//! The module runs under a real single-core critical section (PRIMASK).

#![no_std]
#![no_main]

use core::arch::asm;
use core::hint::black_box;
use osap_core::clock::{Clock, TimeMap};
use osap_core::Instant;
use osap_module::board::{IoHw, NoIo, Parts, StepperHw};
use osap_module::{Module, ModuleCell, ModuleHandle};

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    loop {
        bkpt::<0xEE>();
    }
}

#[inline(always)]
fn bkpt<const N: u8>() {
    // SAFETY: a breakpoint; the harness records the cycle counter and resumes.
    unsafe { asm!("bkpt #{n}", n = const N, options(nomem, nostack)) }
}

/// A single-core critical section, as `cortex-m`'s
/// `critical-section-single-core` does it: PRIMASK read, interrupts masked,
/// unmasked on release only if they were on before.
struct SingleCore;
critical_section::set_impl!(SingleCore);

// SAFETY: one core; masking interrupts excludes every other context.
unsafe impl critical_section::Impl for SingleCore {
    unsafe fn acquire() -> bool {
        let primask: u32;
        // SAFETY: reads PRIMASK, then masks interrupts; no `nomem`, so the
        // compiler keeps memory accesses inside the section.
        unsafe {
            asm!("mrs {}, PRIMASK", out(reg) primask, options(nostack, preserves_flags));
            asm!("cpsid i", options(nostack, preserves_flags));
        }
        primask & 1 == 0
    }

    unsafe fn release(was_active: bool) {
        if was_active {
            // SAFETY: interrupts were on when the section was entered.
            unsafe { asm!("cpsie i", options(nostack, preserves_flags)) };
        }
    }
}

/// The board's stepper driver: keeps the enable flag, nothing else.
struct Driver {
    on: bool,
}

impl StepperHw for Driver {
    fn set_enable(&mut self, on: bool) {
        self.on = on;
    }
    fn set_microsteps(&mut self, microsteps: u16) -> bool {
        microsteps == 1
    }
}

static NOW: u64 = 1_000_000;

fn clock() -> Instant {
    // SAFETY: a plain read of a static.
    Instant::from_micros(unsafe { core::ptr::read_volatile(&raw const NOW) })
}

/// Two PWM outputs and two thermistors that read about 200 °C and 60 °C
/// (100 kΩ, β 3950, 4.7 kΩ pullup): a hotend and a bed holding their
/// targets.
struct Heated {
    pwm: [u16; 2],
}

impl IoHw for Heated {
    fn digital_pins(&self) -> u8 {
        0
    }
    fn write_digital(&mut self, _pin: u8, _level: bool) {}
    fn read_digital(&mut self, _pin: u8) -> bool {
        false
    }
    fn pwm_outputs(&self) -> u8 {
        2
    }
    fn write_pwm(&mut self, channel: u8, duty: u16) {
        if let Some(p) = self.pwm.get_mut(usize::from(channel)) {
            *p = duty;
        }
    }
    fn read_pwm(&self, channel: u8) -> u16 {
        self.pwm.get(usize::from(channel)).copied().unwrap_or(0)
    }
    fn analog_inputs(&self) -> u8 {
        2
    }
    fn read_analog(&mut self, channel: u8) -> u16 {
        // 12-bit readings as a board's converter gives them.
        black_box(if channel == 0 { 577 << 4 } else { 3_337 << 4 })
    }
}

/// A module with two heaters, for the heater period's measurement.
static HEATED: ModuleCell<Parts<Driver, Heated>> = ModuleCell::new();

/// One heater's control period, as the pulse timer port runs it: in a
/// critical section of its own.
#[no_mangle]
#[inline(never)]
pub extern "C" fn probe_heater(local: u64, index: u8) {
    HEATED.with(|m| m.poll_heater(Instant::from_micros(local), index));
}

/// Heater periods measured.
const HEATER_PERIODS: u32 = 50;

/// The module, as a firmware keeps it: a trivial board in a `static` cell.
static MODULE: ModuleCell<Parts<Driver, NoIo>> = ModuleCell::new();

/// The step interrupt's call for one word.
#[no_mangle]
#[inline(never)]
pub extern "C" fn probe_fill(local: u64) -> u32 {
    MODULE.fill_step_word(Instant::from_micros(local))
}

/// A module function call, as the runtime makes it: on the cell, in its
/// critical section.
fn call<R>(f: impl FnOnce(&mut Module<Parts<Driver, NoIo>>) -> R) -> R {
    match MODULE.with(f) {
        Some(r) => r,
        None => panic!("not installed"),
    }
}

/// One word between markers `OPEN` and `CLOSE`, with the word's local and
/// synchronized start times (low 32 bits) in `r0`/`r1` at `OPEN`.
#[inline(always)]
fn word<const OPEN: u8, const CLOSE: u8>(map: &TimeMap, local: u64) -> u32 {
    let sys = map.system_time(Instant::from_micros(local)).as_micros();
    // SAFETY: a breakpoint; the harness reads r0/r1 and resumes.
    unsafe {
        asm!("bkpt #{n}", n = const OPEN, in("r0") local as u32, in("r1") sys as u32,
             options(nomem, nostack))
    };
    let w = probe_fill(local);
    bkpt::<CLOSE>();
    black_box(w)
}

/// Local µs per word (16 ticks of 10 µs).
const WORD_US: u64 = 160;
/// Control-point interval, µs.
const IV: u64 = 1024;
/// Step of the ramp per interval, user units (80 steps a unit: 80 steps
/// per 102.4 ticks, 0.78 a tick, leaving room for the step-word anchor's
/// catch-up at this map's rate without a tick owing two steps).
const RAMP: f32 = 1.0;
/// Control points kept queued ahead of the word being filled.
const LEAD: u64 = 40;
/// Words run before the tracking measurement (past the stream's start).
const WARMUP_WORDS: u32 = 128;
/// Words measured while tracking: 100 segments of 1024 µs.
const TRACK_WORDS: u32 = 640;
/// Words measured while idle.
const IDLE_WORDS: u32 = 64;

#[no_mangle]
pub extern "C" fn _start() -> ! {
    // 0/1: marker overhead.
    bkpt::<0>();
    bkpt::<1>();

    MODULE.install(Parts {
        stepper: Driver { on: false },
        io: None,
        clock,
        bootloader: None,
    });
    // A non-identity map: +400 ppm since local 0.
    let mut c: Clock<1> = Clock::new(Default::default());
    c.set_rate_ppb(Instant::ZERO, 400_000);
    let map: TimeMap = black_box(c.time_map());
    (&MODULE).publish_time(map);
    call(|m| m.set_enable(true)).unwrap();

    // 2/3: idle words.
    let mut local = black_box(clock()).as_micros();
    for _ in 0..IDLE_WORDS {
        word::<2, 3>(&map, local);
        local += WORD_US;
    }

    // A stream: three points where the axis stands, then a ramp.
    call(|m| m.set_interval(IV as u32)).unwrap();
    let first = (map.system_time(Instant::from_micros(local)).as_micros() / IV + 2) * IV;
    let mut k = 0u64;
    let mut top_up = |local: u64| {
        let now = map.system_time(Instant::from_micros(local)).as_micros();
        while first + k * IV <= now + LEAD * IV {
            let pos = k.saturating_sub(2) as f32 * RAMP;
            call(|m| m.add_point(first + k * IV, pos)).unwrap();
            k += 1;
        }
    };
    for _ in 0..WARMUP_WORDS {
        top_up(local);
        word::<8, 9>(&map, local);
        local += WORD_US;
    }
    if call(|m| m.get_status()).unwrap().0 != 2 {
        panic!("not tracking");
    }

    // 4/5: tracking words.
    for _ in 0..TRACK_WORDS {
        top_up(local);
        word::<4, 5>(&map, local);
        local += WORD_US;
    }

    // 6: checks.
    let (_, up, _, late) = call(|m| m.get_steps()).unwrap();
    let mode = call(|m| m.get_status()).unwrap().0;
    // SAFETY: hands the checks to the harness at the marker.
    unsafe {
        asm!("bkpt #6", in("r0") up as u32, in("r1") late as u32,
             in("r2") u32::from(mode), options(nomem, nostack))
    };

    // 10/11: heater periods.
    HEATED.install(Parts {
        stepper: Driver { on: false },
        io: Some(Heated { pwm: [0; 2] }),
        clock,
        bootloader: None,
    });
    HEATED.with(|m| {
        for (i, target) in [(0u8, 200.0f32), (1, 60.0)] {
            let t = osap_module::heater::Thermistor::from_beta(3950.0, 100_000.0, 4_700.0);
            m.heater_sensor(i, i, t.a, t.b, t.c, t.pullup_ohms).unwrap();
            m.heater_output(i, i, 1.0).unwrap();
            m.heater_limits(i, 0.0, 280.0).unwrap();
            m.heater_gains(i, 22.2, 1.08, 114.0).unwrap();
            m.heater_target(i, target).unwrap();
        }
    });
    let mut local = black_box(clock()).as_micros();
    for _ in 0..HEATER_PERIODS {
        for index in 0..2 {
            bkpt::<10>();
            probe_heater(local, black_box(index));
            bkpt::<11>();
        }
        local += 100_000;
    }
    let mut check = (0u32, 0u32);
    HEATED.with(|m| {
        let (_, _, _, _, s0) = m.heater_read(0).unwrap();
        let (_, _, _, _, s1) = m.heater_read(1).unwrap();
        let duty = m.board().io.as_ref().map_or(0, |io| io.read_pwm(0));
        check = (u32::from(s0) | u32::from(s1) << 8, u32::from(duty));
    });
    // SAFETY: hands the check to the harness at the marker.
    unsafe { asm!("bkpt #12", in("r0") check.0, in("r1") check.1, options(nomem, nostack)) };

    loop {
        bkpt::<0xFF>();
    }
}
