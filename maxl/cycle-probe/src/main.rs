//! Cycle probe: calls maxl's fixed-point hot paths between `bkpt`
//! instructions; `scripts/maxl-cycles.js` runs it on an emulated RP2040
//! core and prints the cycles between each pair of markers.
//!
//! Marker pairs (`bkpt 2k` before, `bkpt 2k+1` after) are listed in
//! `scripts/maxl-cycles.js`. Each measured function is `#[inline(never)]`
//! and `extern "C"`, so a measurement includes the call and return, as an
//! interrupt handler calling it would pay. State lives on the stack and
//! passes through `black_box` so nothing is folded at compile time.

#![no_std]
#![no_main]

use core::arch::asm;
use core::hint::black_box;
use maxl::eval::{Fx, KinFx, Point, TickEval};
use maxl::limit::{AxisLimits, Limiter};
use maxl::phase::{Coils, PhaseOut};
use maxl::step::{Dir, Rounding, StepGen};
use maxl::Interval;

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

/// One tick of the fast evaluator (the per-tick cost).
#[no_mangle]
#[inline(never)]
pub extern "C" fn probe_tick(e: &mut TickEval) -> i32 {
    match e.next() {
        Some(p) => p.0,
        None => i32::MIN,
    }
}

/// Per-segment setup of the fast evaluator.
#[no_mangle]
#[inline(never)]
pub extern "C" fn probe_load(e: &mut TickEval, p: &[Fx; 4], du0: u32) -> bool {
    e.load(p, du0).is_ok()
}

/// The direct `i64` evaluator, position only.
#[no_mangle]
#[inline(never)]
pub extern "C" fn probe_eval_pos(p: &[Fx; 4], du: u32, iv: &Interval) -> i32 {
    Fx::eval(p, du, *iv).pos.0
}

/// The direct `i64` evaluator, full kinematics.
#[no_mangle]
#[inline(never)]
pub extern "C" fn probe_eval_full(p: &[Fx; 4], du: u32, iv: &Interval, out: &mut KinFx) {
    *out = Fx::eval(p, du, *iv);
}

/// One tick of the step generator.
#[no_mangle]
#[inline(never)]
pub extern "C" fn probe_step(g: &mut StepGen, p: i32) -> i32 {
    match g.tick(Fx(p)) {
        Some(Dir::Up) => 1,
        Some(Dir::Down) => -1,
        None => 0,
    }
}

/// Coil amplitudes from a position.
#[no_mangle]
#[inline(never)]
pub extern "C" fn probe_phase(o: &PhaseOut, p: i32, out: &mut Coils) {
    *out = o.coils(Fx(p));
}

/// A 100 kHz interrupt's work: next position, then its step.
#[no_mangle]
#[inline(never)]
pub extern "C" fn probe_isr(e: &mut TickEval, g: &mut StepGen) -> i32 {
    match e.next() {
        Some(p) => match g.tick(p) {
            Some(Dir::Up) => 1,
            Some(Dir::Down) => -1,
            None => 0,
        },
        None => i32::MIN,
    }
}

/// One point through the `Fx` limiter.
#[no_mangle]
#[inline(never)]
pub extern "C" fn probe_limit(l: &mut Limiter<Fx>, p: i32) -> i32 {
    l.push(Fx(p)).point.0
}

#[no_mangle]
pub extern "C" fn _start() -> ! {
    let iv = black_box(Interval::from_micros(1024).unwrap());
    let seg = black_box([Fx(1_234_567), Fx(2_345_678), Fx(5_432_100), Fx(9_876_543)]);
    let mut e = black_box(TickEval::new(iv, 10).unwrap());

    // 0/1: marker overhead (subtracted by the harness).
    bkpt::<0>();
    bkpt::<1>();

    // 2/3: per-segment setup.
    bkpt::<2>();
    let ok = probe_load(&mut e, &seg, 3);
    bkpt::<3>();
    black_box(ok);

    // 4/5: one tick.
    bkpt::<4>();
    let x = probe_tick(&mut e);
    bkpt::<5>();
    black_box(x);

    // 6/7: the rest of the segment (loop included); the harness divides by
    // the tick count it reads from r0 at marker 7.
    let mut n = 0u32;
    bkpt::<6>();
    while probe_tick(&mut e) != i32::MIN {
        n += 1;
    }
    let n = black_box(n);
    // SAFETY: hands `n` to the harness in r0 at the marker.
    unsafe { asm!("bkpt #7", in("r0") n, options(nomem, nostack)) };

    // 8/9 and 10/11: the direct i64 evaluator.
    let mut k = KinFx::default();
    bkpt::<8>();
    let y = probe_eval_pos(&seg, 517, &iv);
    bkpt::<9>();
    black_box(y);
    bkpt::<10>();
    probe_eval_full(&seg, 517, &iv, &mut k);
    bkpt::<11>();
    black_box(&k);

    // 12/13: step generator tick (with a step).
    let mut g = black_box(StepGen::new(Fx(0), Rounding::Nearest));
    bkpt::<12>();
    let s = probe_step(&mut g, 40_000);
    bkpt::<13>();
    black_box(s);

    // 14/15: phase output.
    let o = black_box(PhaseOut::new(1000));
    let mut c = Coils::default();
    bkpt::<14>();
    probe_phase(&o, 123_457, &mut c);
    bkpt::<15>();
    black_box(&c);

    // 16/17: interrupt body, evaluator + step generator.
    probe_load(&mut e, &seg, 0);
    bkpt::<16>();
    let s = probe_isr(&mut e, &mut g);
    bkpt::<17>();
    black_box(s);

    // 18/19: limiter, one clamped point.
    let lim = AxisLimits {
        max_vel: 5000.0,
        max_acc: 100_000.0,
        max_jerk: 10_000_000.0,
    };
    let mut l = black_box(Limiter::<Fx>::new(lim, iv).unwrap());
    probe_limit(&mut l, 0);
    bkpt::<18>();
    let q = probe_limit(&mut l, 100 << 16);
    bkpt::<19>();
    black_box(q);
    // 20/21: limiter, a point within the limits (same velocity again: the
    // jerk back to zero acceleration equals the limit, not beyond).
    let q2 = black_box(2 * q);
    bkpt::<20>();
    let q = probe_limit(&mut l, q2);
    bkpt::<21>();
    black_box(q);

    // 22/23: setup at Δt = 16384 µs (the other rounding branch).
    let iv14 = black_box(Interval::from_micros(16384).unwrap());
    let mut e14 = black_box(TickEval::new(iv14, 10).unwrap());
    bkpt::<22>();
    let ok = probe_load(&mut e14, &seg, 7);
    bkpt::<23>();
    black_box(ok);

    // 24/25: setup for differences of 2^27 raw or more (the i128 path).
    let wide = black_box([Fx(-2_000_000_000), Fx(0), Fx(2_000_000_000), Fx(0)]);
    bkpt::<24>();
    let ok = probe_load(&mut e, &wide, 3);
    bkpt::<25>();
    black_box(ok);

    loop {
        bkpt::<0xFF>();
    }
}
