//! Step/direction output from a fixed-point position, integer only.
//!
//! [`StepGen`] is fed one [`Fx`] position per tick (e.g. from
//! [`crate::eval::TickEval`] at 100 kHz) and emits at most one step per tick.
//!
//! **Rounding rule.** The motor's step index for a position `p` (Q16.16
//! steps) is `count(p) = floor((p.0 + offset) / 65536)` with `offset` from
//! [`Rounding`]: `Nearest` (`offset = 32768`, boundaries at half steps, so the
//! step index is `p` rounded half up) or `Floor` (`offset = 0`, boundaries at
//! whole steps). Computed with arithmetic shifts: exact, no hysteresis.
//!
//! **Accounting.** The generator keeps `emitted` (net steps sent) and the
//! `target = count(p)` of the last position. Each tick it moves `emitted` one
//! step toward the target when they differ. So at every tick
//! `emitted + backlog = target`, exactly, and the net step count over any run
//! equals `count(p_end) − count(p_start)` once the backlog has drained.
//!
//! **Overrun.** When a position moves the target by more than one step in a
//! tick (or a backlog remains), the tick that still leaves a backlog is
//! counted as an overrun; later ticks catch up, one step each, toward the
//! current target. No step is lost; steps that cancel (the target came back
//! before they were sent) are never sent.
//!
//! **Late steps.** A step is due at the first tick whose position is past
//! its boundary (the position crossed it within the tick period before).
//! One sent on a later tick, out of the backlog, went out more than one tick
//! period after its boundary was crossed: it is counted in
//! [`StepStats::late`]. A step is late exactly when the tick before left
//! steps owed in the direction it goes (those were due earlier, and the
//! generator sends the oldest first); a step the other way, after the
//! target came back past the motor, is due at its own tick.

use crate::eval::Fx;
use core::sync::atomic::{AtomicBool, AtomicU32, AtomicUsize, Ordering};

/// Step direction.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Dir {
    /// Toward larger positions.
    Up,
    /// Toward smaller positions.
    Down,
}

/// Where step boundaries sit (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Rounding {
    /// Step index = position rounded half up (boundaries at `k + ½`).
    Nearest,
    /// Step index = floor(position) (boundaries at whole steps).
    Floor,
}

impl Rounding {
    /// Added to `p >> 15` before the final `>> 1`:
    /// `floor((p + 2^15) / 2^16) = (floor(p / 2^15) + 1) >> 1`, with no
    /// overflow at `i32::MAX`.
    const fn half(self) -> i32 {
        match self {
            Rounding::Nearest => 1,
            Rounding::Floor => 0,
        }
    }
}

/// Counters of a [`StepGen`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StepStats {
    /// Ticks processed.
    pub ticks: u64,
    /// Steps sent up.
    pub up: u64,
    /// Steps sent down.
    pub down: u64,
    /// Ticks that ended with a backlog (more than one step was due).
    pub overruns: u64,
    /// Largest backlog seen after a tick, in steps.
    pub max_backlog: u64,
    /// Steps sent on a later tick than the one they fell due at: more than
    /// one tick period after their boundary was crossed (see the module
    /// docs).
    pub late: u64,
}

/// Turns one position per tick into at most one step per tick.
///
/// Positions wrap every 65 536 steps ([`Fx`]); the generator counts the
/// steps it sent in an `i64`, so the motor's step index has no end, and
/// compares the step index of each position with it modulo 65 536 (the
/// target is never 32 768 steps away).
#[derive(Clone, Copy, Debug)]
pub struct StepGen {
    half: i32,
    /// Net step index sent, whole.
    emitted: i64,
    /// Step index of the last position, modulo 65 536 (as `count_with`
    /// gives it: `-32768..=32767`).
    target: i32,
    stats: StepStats,
}

/// `x` modulo 65 536, as a signed 16-bit value (`-32768..=32767`): the
/// difference of two step indices known modulo 65 536.
#[inline(always)]
fn wrap16(x: i32) -> i32 {
    (x << 16) >> 16
}

impl StepGen {
    /// A generator whose motor is at the step index of `start`.
    pub fn new(start: Fx, rounding: Rounding) -> Self {
        let half = rounding.half();
        let c = Self::count_with(start, half);
        StepGen {
            half,
            emitted: c as i64,
            target: c,
            stats: StepStats::default(),
        }
    }

    /// A generator whose motor is at whole step index `index` (any
    /// `i64`: the index does not wrap), at rest there.
    pub fn at_index(index: i64, rounding: Rounding) -> Self {
        let half = rounding.half();
        StepGen {
            half,
            emitted: index,
            target: wrap16(index as i32),
            stats: StepStats::default(),
        }
    }

    /// The position of whole step index `index`, wrapped as positions are
    /// ([`Fx`]).
    pub fn index_position(index: i64) -> Fx {
        Fx((index as i32).wrapping_mul(Fx::ONE))
    }

    #[inline]
    fn count_with(p: Fx, half: i32) -> i32 {
        ((p.0 >> 15) + half) >> 1
    }

    /// The step index of `p` under this generator's rounding.
    #[inline]
    pub fn count(&self, p: Fx) -> i64 {
        Self::count_with(p, self.half) as i64
    }

    /// Process one tick at position `p`: the step to send this tick, if any.
    #[inline]
    pub fn tick(&mut self, p: Fx) -> Option<Dir> {
        // Steps owed from earlier ticks (signed): the next ones in their
        // direction are late.
        let sent = self.emitted as i32;
        let owed = wrap16(self.target.wrapping_sub(sent));
        self.target = Self::count_with(p, self.half);
        self.stats.ticks += 1;
        let d = wrap16(self.target.wrapping_sub(sent));
        let out = if d > 0 {
            self.emitted += 1;
            self.stats.up += 1;
            if owed > 0 {
                self.stats.late += 1;
            }
            Some(Dir::Up)
        } else if d < 0 {
            self.emitted -= 1;
            self.stats.down += 1;
            if owed < 0 {
                self.stats.late += 1;
            }
            Some(Dir::Down)
        } else {
            None
        };
        if wrap16(self.target.wrapping_sub(self.emitted as i32)) != 0 {
            self.stats.overruns += 1;
            self.stats.max_backlog = self.stats.max_backlog.max(self.backlog());
        }
        out
    }

    /// Steps still owed to reach the last target (0 when caught up).
    pub fn backlog(&self) -> u64 {
        self.owed().unsigned_abs() as u64
    }

    /// Steps owed to reach the last target, signed.
    fn owed(&self) -> i32 {
        wrap16(self.target.wrapping_sub(self.emitted as i32))
    }

    /// Net step index sent so far (start index + up − down), whole: it
    /// does not wrap with the positions.
    pub fn position(&self) -> i64 {
        self.emitted
    }

    /// Step index of the last position seen, whole (the index sent plus
    /// the steps still owed).
    pub fn target(&self) -> i64 {
        self.emitted + self.owed() as i64
    }

    /// Steps sent late so far ([`StepStats::late`]), without copying the
    /// counters.
    pub fn late(&self) -> u64 {
        self.stats.late
    }

    /// Counters.
    pub fn stats(&self) -> StepStats {
        self.stats
    }
}

/// A step to send at a tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct StepEvent {
    /// Tick index (wrapping `u32`; at 100 kHz it wraps every 11.9 h, so the
    /// consumer compares ticks with `wrapping_sub`).
    pub tick: u32,
    /// Direction of the step.
    pub dir: Dir,
}

/// The queue had no room; the event was not stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct QueueFull(pub StepEvent);

/// A fixed-capacity single-producer single-consumer queue of [`StepEvent`]s,
/// lock-free with plain atomic loads and stores (works on Cortex-M0+, which
/// has no compare-and-swap).
///
/// One context (the main loop, computing ahead) calls [`StepQueue::push`];
/// one other (the timer interrupt) calls [`StepQueue::pop`] or
/// [`StepQueue::peek`]. Holds `N − 1` events. Misuse with two producers or
/// two consumers cannot cause undefined behaviour, only lost or repeated
/// events, so keep to one of each.
///
/// Why not `heapless::spsc::Queue`: it hands out its producer and consumer
/// through `split(&mut self)`, so a queue shared by a `static` between the
/// main loop and an interrupt needs `unsafe` or a cell to get them; this one
/// works through `&self` on a plain `static`, and the crate forbids `unsafe`.
#[derive(Debug)]
pub struct StepQueue<const N: usize> {
    ticks: [AtomicU32; N],
    ups: [AtomicBool; N],
    head: AtomicUsize,
    tail: AtomicUsize,
}

impl<const N: usize> Default for StepQueue<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> StepQueue<N> {
    /// An empty queue (`const`, so it can be a `static`).
    pub const fn new() -> Self {
        const { assert!(N >= 2, "a step queue needs at least 2 slots") };
        StepQueue {
            ticks: [const { AtomicU32::new(0) }; N],
            ups: [const { AtomicBool::new(false) }; N],
            head: AtomicUsize::new(0),
            tail: AtomicUsize::new(0),
        }
    }

    /// The slot after `i`. A compare, not `% N`: on a Cortex-M0+ a modulo
    /// by an `N` that is not a power of two is a library division, and the
    /// consumer runs in the timer interrupt.
    #[inline]
    fn after(i: usize) -> usize {
        if i + 1 >= N {
            0
        } else {
            i + 1
        }
    }

    /// Append an event (producer side).
    pub fn push(&self, ev: StepEvent) -> Result<(), QueueFull> {
        let tail = self.tail.load(Ordering::Relaxed);
        let next = Self::after(tail);
        if next == self.head.load(Ordering::Acquire) {
            return Err(QueueFull(ev));
        }
        self.ticks[tail].store(ev.tick, Ordering::Relaxed);
        self.ups[tail].store(ev.dir == Dir::Up, Ordering::Relaxed);
        self.tail.store(next, Ordering::Release);
        Ok(())
    }

    /// The oldest event and the slot it is in, if any (consumer side).
    fn front(&self) -> Option<(usize, StepEvent)> {
        let head = self.head.load(Ordering::Relaxed);
        if head == self.tail.load(Ordering::Acquire) {
            return None;
        }
        let dir = if self.ups[head].load(Ordering::Relaxed) {
            Dir::Up
        } else {
            Dir::Down
        };
        let tick = self.ticks[head].load(Ordering::Relaxed);
        Some((head, StepEvent { tick, dir }))
    }

    /// The oldest event, without removing it (consumer side).
    pub fn peek(&self) -> Option<StepEvent> {
        self.front().map(|(_, ev)| ev)
    }

    /// Remove and return the oldest event (consumer side).
    pub fn pop(&self) -> Option<StepEvent> {
        let (head, ev) = self.front()?;
        self.head.store(Self::after(head), Ordering::Release);
        Some(ev)
    }

    /// Number of events held.
    pub fn len(&self) -> usize {
        let (h, t) = (
            self.head.load(Ordering::Acquire),
            self.tail.load(Ordering::Acquire),
        );
        if t >= h {
            t - h
        } else {
            t + N - h
        }
    }

    /// True when no event is held.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Packs per-tick steps into 32-bit words for a PIO state machine: two bits
/// per tick, least significant first, bit 0 = STEP, bit 1 = DIR (1 = up),
/// 16 ticks per word.
///
/// DIR keeps its last value on ticks without a step, so it only changes on
/// a tick that also steps. The PIO program, once per tick, pulls the two
/// bits, sets the DIR pin first, waits the driver's direction setup time
/// (a few delay cycles), then raises STEP for the pulse width and lowers it.
#[derive(Clone, Copy, Debug, Default)]
pub struct PioPacker {
    word: u32,
    n: u32,
    dir_up: bool,
}

impl PioPacker {
    /// An empty packer; DIR starts low (down).
    pub fn new() -> Self {
        Self::default()
    }

    /// Add one tick; returns a full word every 16 ticks.
    pub fn push(&mut self, step: Option<Dir>) -> Option<u32> {
        if let Some(d) = step {
            self.dir_up = d == Dir::Up;
        }
        let bits = step.is_some() as u32 | ((self.dir_up as u32) << 1);
        self.word |= bits << (2 * self.n);
        self.n += 1;
        if self.n == 16 {
            let w = self.word;
            self.word = 0;
            self.n = 0;
            Some(w)
        } else {
            None
        }
    }

    /// Ticks held in the partial word.
    pub fn pending(&self) -> u32 {
        self.n
    }
}
