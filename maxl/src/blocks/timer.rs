//! The graph's timer: the stamps every motion block samples at.
//!
//! One timer runs per motion graph. It emits synchronized-time stamps (µs,
//! multiples of the [`Interval`]) that lead real time by a gap, the *lead*:
//! at time `now` every stamp `s <= now + lead` has been emitted, in order,
//! each exactly once. After a stall (the caller was late) the next call
//! returns the whole backlog, so no stamp is ever skipped.
//!
//! **Why the lead is at least two intervals.** Evaluating the spline at `t`
//! needs the point stamped `⌊t⌋ + 2Δt` (see `docs/maxl.md`). The newest
//! emitted stamp `S` satisfies `S > now + lead − Δt`; with `lead ≥ 2Δt`,
//! `S > now + Δt`, and the smallest aligned stamp above `now + Δt` is
//! `⌊now⌋ + 2Δt`. So two intervals are exactly enough when delivery is
//! instant; the default of three leaves one interval for delivery.
//!
//! **Start.** The first call at `now` emits the largest aligned stamp not
//! after `now + lead`, `⌊now + lead⌋` (rounded down to the interval), and
//! nothing before it: every stamp, the first included, leads `now` by more
//! than `lead − Δt` and at most `lead`.
//!
//! # PIPES class `Timer` ([`TimerBlock`])
//!
//! A PIPES function emits one set of outputs per run, so the class emits one
//! stamp per run:
//!
//! | member | inputs | outputs | |
//! |---|---|---|---|
//! | constructor `Timer` | `interval_us: u32, lead_us: u32` | | fails 1 (bad interval), 2 (lead under two intervals) |
//! | `Timer.tick` | | `stamp: u64` | the next due stamp (one interval after the last), else the last one again; fails 3 before the runtime's time is known |
//! | `Timer.status` | | `last: u64, emitted: u64, max_burst: u64, now: u64` | `last` is 0 before the first stamp |
//! | `Timer.reset` | | | forget the stamps: the next tick starts again |
//!
//! Run `Timer.tick` as a source with input mode "on timer" at a period
//! shorter than the interval (a quarter of it is a good choice) and output
//! mode "on change": a run with nothing due returns the previous stamp, which
//! "on change" suppresses. A backlog after a stall drains at one stamp per
//! run, in order; with a period of Δt/4 a backlog of `B` stamps is gone
//! after about `B·Δt/3`.
//!
//! The class's loop hook stores the runtime's synchronized system time
//! (`now_us`), which `tick` uses; the failure codes are
//! [`TimerError::code`].

use core::fmt;

use pipes_core::function::CallError;

use crate::track::Interval;
use pipes_core::time::SystemInstant;

/// The default lead, in intervals.
pub const DEFAULT_LEAD_INTERVALS: u64 = 3;
/// The smallest lead, in intervals: the spline's lookahead.
pub const MIN_LEAD_INTERVALS: u64 = 2;

/// `Timer` failure code: the interval is not a power of two in 256..=16384 µs.
pub const FAIL_BAD_INTERVAL: u8 = 1;
/// `Timer` failure code: the lead is shorter than two intervals.
pub const FAIL_LEAD_TOO_SHORT: u8 = 2;
/// `Timer` failure code: `tick` ran before the loop hook saw the time.
pub const FAIL_NO_TIME: u8 = 3;

/// Why a timer could not be made, or could not tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum TimerError {
    /// The interval is not a power of two in 256..=16384 µs.
    BadInterval(u32),
    /// The lead is shorter than two intervals.
    LeadTooShort {
        /// The lead asked for, µs.
        lead_us: u64,
        /// The shortest allowed lead, µs.
        min_us: u64,
    },
    /// `TimerBlock::tick` ran before the loop hook gave it the time.
    NoTime,
}

impl TimerError {
    /// The PIPES failure code ([`FAIL_BAD_INTERVAL`],
    /// [`FAIL_LEAD_TOO_SHORT`], [`FAIL_NO_TIME`]).
    pub fn code(&self) -> u8 {
        match self {
            TimerError::BadInterval(_) => FAIL_BAD_INTERVAL,
            TimerError::LeadTooShort { .. } => FAIL_LEAD_TOO_SHORT,
            TimerError::NoTime => FAIL_NO_TIME,
        }
    }
}

impl fmt::Display for TimerError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            TimerError::BadInterval(us) => write!(
                f,
                "interval {us} µs is not a power of two in 256..=16384 µs"
            ),
            TimerError::LeadTooShort { lead_us, min_us } => write!(
                f,
                "lead {lead_us} µs is under two intervals ({min_us} µs): the spline needs two intervals of lookahead"
            ),
            TimerError::NoTime => f.write_str(
                "the runtime's time is not known yet: the class's loop hook has not run",
            ),
        }
    }
}

impl core::error::Error for TimerError {}

impl From<TimerError> for CallError {
    fn from(e: TimerError) -> CallError {
        CallError::Failed(e.code().into())
    }
}

/// What a timer has done.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TimerStats {
    /// Stamps emitted.
    pub emitted: u64,
    /// The most stamps due at one call (1 when never late).
    pub max_burst: u64,
    /// Calls that found more than one stamp due (the caller was late).
    pub catch_ups: u64,
}

/// The stamps due at one call, in order (see [`Timer::due`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Stamps {
    next: u64,
    step: u64,
    remaining: u64,
}

impl Iterator for Stamps {
    type Item = u64;

    fn next(&mut self) -> Option<u64> {
        if self.remaining == 0 {
            return None;
        }
        let s = self.next;
        self.remaining -= 1;
        self.next = self.next.saturating_add(self.step);
        Some(s)
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        let n = usize::try_from(self.remaining).unwrap_or(usize::MAX);
        (n, usize::try_from(self.remaining).ok())
    }
}

/// The graph's timer (see the module docs).
#[derive(Clone, Debug)]
pub struct Timer {
    iv: Interval,
    lead_us: u64,
    /// The last stamp emitted; `None` before the first (the next one to
    /// emit is one interval after it, [`Timer::next`]).
    last: Option<u64>,
    stats: TimerStats,
}

impl Timer {
    /// A timer at `interval` whose stamps lead real time by `lead_us`
    /// (at least two intervals).
    pub fn new(interval: Interval, lead_us: u64) -> Result<Timer, TimerError> {
        let min_us = MIN_LEAD_INTERVALS * u64::from(interval.micros());
        if lead_us < min_us {
            return Err(TimerError::LeadTooShort { lead_us, min_us });
        }
        Ok(Timer::unchecked(interval, lead_us))
    }

    /// A timer with the default lead of three intervals.
    pub fn with_default_lead(interval: Interval) -> Timer {
        Timer::unchecked(
            interval,
            DEFAULT_LEAD_INTERVALS * u64::from(interval.micros()),
        )
    }

    /// A timer whose lead is already known to be long enough.
    fn unchecked(iv: Interval, lead_us: u64) -> Timer {
        Timer {
            iv,
            lead_us,
            last: None,
            stats: TimerStats::default(),
        }
    }

    /// A timer from raw µs values, as the PIPES constructor takes them.
    pub fn from_micros(interval_us: u32, lead_us: u64) -> Result<Timer, TimerError> {
        let iv =
            Interval::from_micros(interval_us).map_err(|_| TimerError::BadInterval(interval_us))?;
        Timer::new(iv, lead_us)
    }

    /// The stamp interval.
    pub fn interval(&self) -> Interval {
        self.iv
    }

    /// The lead, µs.
    pub fn lead_us(&self) -> u64 {
        self.lead_us
    }

    /// The newest stamp allowed at `now_us`: `now + lead` rounded down to
    /// the interval.
    pub fn horizon(&self, now_us: u64) -> u64 {
        now_us.saturating_add(self.lead_us) & !(self.step() - 1)
    }

    /// The interval, µs.
    fn step(&self) -> u64 {
        u64::from(self.iv.micros())
    }

    /// The next stamp to emit; `None` before the first.
    fn next(&self) -> Option<u64> {
        self.last.map(|l| l.saturating_add(self.step()))
    }

    /// The last stamp emitted.
    pub fn last_stamp(&self) -> Option<u64> {
        self.last
    }

    /// The counters.
    pub fn stats(&self) -> TimerStats {
        self.stats
    }

    /// How many stamps are due at `now_us`, without emitting them.
    pub fn pending(&self, now_us: u64) -> u64 {
        let h = self.horizon(now_us);
        match self.next() {
            None => 1,
            Some(n) if n > h => 0,
            Some(n) => (h - n) / self.step() + 1,
        }
    }

    /// Emits every stamp due at `now_us`: all not yet emitted with
    /// `stamp <= now + lead`, in order. Empty when nothing is due (also when
    /// `now_us` went backwards).
    pub fn due(&mut self, now_us: u64) -> Stamps {
        let n = self.pending(now_us);
        let first = self.next().unwrap_or_else(|| self.horizon(now_us));
        let step = self.step();
        let out = Stamps {
            next: first,
            step,
            remaining: n,
        };
        if n > 0 {
            let last = first.saturating_add((n - 1).saturating_mul(step));
            self.record(last, n, n);
        }
        out
    }

    /// Emits at most one stamp: the next one, if it is due at `now_us`.
    /// A backlog drains one stamp per call, never skipping.
    pub fn next_due(&mut self, now_us: u64) -> Option<u64> {
        let n = self.pending(now_us);
        if n == 0 {
            return None;
        }
        let s = self.next().unwrap_or_else(|| self.horizon(now_us));
        self.record(s, 1, n);
        Some(s)
    }

    /// Forgets the emitted stamps: the next call starts again as the first.
    pub fn reset(&mut self) {
        self.last = None;
    }

    /// `emitted` stamps up to `last` went out at a call that found `due`
    /// stamps due (more than one only after a first stamp: the first call
    /// finds exactly one).
    fn record(&mut self, last: u64, emitted: u64, due: u64) {
        self.stats.emitted += emitted;
        self.stats.max_burst = self.stats.max_burst.max(due);
        if due > 1 {
            self.stats.catch_ups += 1;
        }
        self.last = Some(last);
    }
}

/// A [`Timer`] as the PIPES class `Timer` (see the module docs), with the
/// runtime's time its loop hook stores for `tick`.
///
/// Its methods are the class's members; the plain timer is the public
/// `timer` field.
#[derive(Clone, Debug)]
pub struct TimerBlock {
    /// The timer.
    pub timer: Timer,
    /// The runtime's time as the loop hook last gave it.
    now: Option<SystemInstant>,
}

impl TimerBlock {
    /// A block over a timer built in Rust; the time is not known yet.
    pub fn from_timer(timer: Timer) -> TimerBlock {
        TimerBlock { timer, now: None }
    }

    /// The runtime's time as the loop hook last gave it.
    pub fn now(&self) -> Option<SystemInstant> {
        self.now
    }
}

#[pipes_core::class(name = "Timer")]
impl TimerBlock {
    /// The constructor `Timer`: a timer at `interval_us` whose stamps lead
    /// the runtime's time by `lead_us` (fails with codes 1 and 2).
    #[constructor]
    pub fn new(interval_us: u32, lead_us: u32) -> Result<TimerBlock, TimerError> {
        Ok(TimerBlock::from_timer(Timer::from_micros(
            interval_us,
            u64::from(lead_us),
        )?))
    }

    /// `Timer.tick`: the next due stamp at the time the loop hook last
    /// stored, else the last stamp again; [`TimerError::NoTime`] (code 3)
    /// before the hook has run.
    #[outputs = "stamp"]
    pub fn tick(&mut self) -> Result<u64, TimerError> {
        let now = self.now.ok_or(TimerError::NoTime)?.as_micros();
        let t = &mut self.timer;
        // The first call always emits a stamp, so `last` is set from then on.
        t.next_due(now).or(t.last_stamp()).ok_or(TimerError::NoTime)
    }

    /// `Timer.status`: `(last, emitted, max_burst, now)`, with 0 for what is
    /// not known yet.
    #[outputs = "last, emitted, max_burst, now"]
    pub fn status(&self) -> (u64, u64, u64, u64) {
        let stats = self.timer.stats();
        (
            self.timer.last_stamp().unwrap_or(0),
            stats.emitted,
            stats.max_burst,
            self.now.map_or(0, SystemInstant::as_micros),
        )
    }

    /// `Timer.reset`: forgets the emitted stamps; the next tick starts
    /// again as the first.
    pub fn reset(&mut self) {
        self.timer.reset();
    }

    /// The loop hook: stores the runtime's synchronized system time (call
    /// it by hand to drive the block from a script).
    #[loop_hook]
    pub fn set_now(&mut self, now: SystemInstant) {
        self.now = Some(now);
    }
}
