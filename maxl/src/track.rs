//! Time-keyed control-point queue and its evaluation.
//!
//! Stamps are synchronized time in µs (`u64`). A stamp must be a multiple of
//! the interval (`t & (Δt - 1) == 0`), so a point's knot index is `t >> shift`
//! and the spline parameter inside a segment is the low `shift` bits of `t`.
//!
//! The point stamped `T_i` is `P_i`; for `t` in `[T_i, T_{i+1})` the curve uses
//! `P_{i-1}..P_{i+2}`. At its own stamp the curve is at `(P_{i-1} + 4P_i +
//! P_{i+1}) / 6`: it is centred on the points (no time shift), and evaluating
//! at `t` needs the point stamped `T_i + 2Δt` — two intervals of lookahead,
//! plus one point in the past.

use crate::backstop::{BackstopLimits, StopProfile};
use crate::eval::Point;
use osap_core::time::SystemInstant;

/// A control-point interval: a power of two from 256 to 16384 µs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Interval {
    shift: u8,
}

/// The interval is not a power of two in 256..=16384 µs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct IntervalError(pub u32);

impl core::fmt::Display for IntervalError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "interval {} µs is not a power of two from 256 to 16384 µs",
            self.0
        )
    }
}

impl core::error::Error for IntervalError {}

impl Interval {
    /// Validate an interval in µs.
    pub const fn from_micros(us: u32) -> Result<Self, IntervalError> {
        if us.is_power_of_two() && us >= 256 && us <= 16384 {
            Ok(Interval {
                shift: us.trailing_zeros() as u8,
            })
        } else {
            Err(IntervalError(us))
        }
    }
    /// The interval in µs.
    pub const fn micros(self) -> u32 {
        1 << self.shift
    }
    /// log2 of the interval in µs (8..=14).
    pub const fn shift(self) -> u32 {
        self.shift as u32
    }
    /// The interval in seconds.
    pub fn seconds(self) -> f32 {
        self.micros() as f32 * 1e-6
    }
}

/// Why a point was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum PushError {
    /// The stamp is not a multiple of the interval.
    Misaligned,
    /// The stamp is not after the newest point (duplicate or late).
    Stale,
    /// More than one point is missing before this stamp; the point is refused.
    Gap {
        /// How many points are missing.
        missing: u64,
    },
    /// The backstop has latched; call [`Track::clear`] to start a new stream.
    Backstopped,
}

impl core::fmt::Display for PushError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            PushError::Misaligned => f.write_str("point time is not a multiple of the interval"),
            PushError::Stale => f.write_str("point is not after the newest point"),
            PushError::Gap { missing } => {
                write!(f, "{missing} points are missing before this one")
            }
            PushError::Backstopped => f.write_str("the backstop has latched"),
        }
    }
}

impl core::error::Error for PushError {}

/// What an accepted point did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PushOutcome {
    /// The point was added after the newest one.
    Appended,
    /// Exactly one point was missing; it was filled as the midpoint of its neighbours.
    FilledGap,
}

/// How a sample was produced.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TrackStatus {
    /// From the stream's control points.
    Tracking,
    /// The stream ran dry: following the jerk-limited stop (and at rest after it).
    Backstop,
}

/// Why no sample could be produced.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum EvalError {
    /// `t` needs points before the oldest held (not started, or already dropped).
    TooEarly,
    /// Fewer than four points: there is no curve, and no state to stop from.
    NotStarted,
}

impl core::fmt::Display for EvalError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            EvalError::TooEarly => "the time is before the oldest point held",
            EvalError::NotStarted => "fewer than four points: no curve yet",
        })
    }
}

impl core::error::Error for EvalError {}

/// One evaluation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample<K> {
    /// Whether the track was followed or the backstop took over.
    pub status: TrackStatus,
    /// The kinematics at the sampled time.
    pub kin: K,
}

#[derive(Clone, Copy, Debug)]
struct Latched<K> {
    start_us: u64,
    edge: K,
    profile: StopProfile,
}

/// A bounded queue of `N` control points keyed by time, and its evaluator.
///
/// When full, pushing drops the oldest point; size `N` at least the stream's
/// advance in intervals plus 4.
#[derive(Clone, Debug)]
pub struct Track<P: Point, const N: usize> {
    iv: Interval,
    limits: BackstopLimits,
    buf: [P; N],
    head: usize,
    len: usize,
    /// Knot index of the oldest point.
    first: u64,
    latched: Option<Latched<P::Kin>>,
}

impl<P: Point, const N: usize> Track<P, N> {
    /// An empty track.
    pub fn new(iv: Interval, limits: BackstopLimits) -> Self {
        const { assert!(N >= 4, "a track needs at least 4 points") };
        Track {
            iv,
            limits,
            buf: [P::default(); N],
            head: 0,
            len: 0,
            first: 0,
            latched: None,
        }
    }

    /// The interval.
    pub fn interval(&self) -> Interval {
        self.iv
    }

    /// Number of points held.
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when no point is held.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Stamp of the newest point.
    pub fn last_time(&self) -> Option<SystemInstant> {
        (self.len > 0).then(|| SystemInstant::from_micros(self.last_idx() << self.iv.shift()))
    }

    /// The newest point (for a check of the next one against it, such as a
    /// [`crate::Limiter`]'s, before it is pushed).
    pub fn last_point(&self) -> Option<P> {
        (self.len > 0).then(|| self.buf[(self.head + self.len - 1) % N])
    }

    /// Knot index of the newest point (meaningful when `len > 0`).
    fn last_idx(&self) -> u64 {
        self.first + self.len as u64 - 1
    }

    /// The backstop's start time (µs) and duration (s) once it has latched.
    pub fn backstop(&self) -> Option<(SystemInstant, f32)> {
        self.latched
            .as_ref()
            .map(|l| (SystemInstant::from_micros(l.start_us), l.profile.duration()))
    }

    /// Forget every point and leave the backstop.
    pub fn clear(&mut self) {
        self.head = 0;
        self.len = 0;
        self.latched = None;
    }

    fn append(&mut self, p: P) {
        if self.len == N {
            self.head = (self.head + 1) % N;
            self.first += 1;
            self.len -= 1;
        }
        self.buf[(self.head + self.len) % N] = p;
        self.len += 1;
    }

    fn get(&self, idx: u64) -> Option<P> {
        let off = idx.checked_sub(self.first)?;
        (off < self.len as u64).then(|| self.buf[(self.head + off as usize) % N])
    }

    /// Add the point stamped `time` (system time).
    pub fn push(&mut self, time: SystemInstant, value: P) -> Result<PushOutcome, PushError> {
        let time = time.as_micros();
        if self.latched.is_some() {
            return Err(PushError::Backstopped);
        }
        if time & (self.iv.micros() as u64 - 1) != 0 {
            return Err(PushError::Misaligned);
        }
        let idx = time >> self.iv.shift();
        if self.len == 0 {
            self.first = idx;
            self.append(value);
            return Ok(PushOutcome::Appended);
        }
        let last = self.last_idx();
        if idx <= last {
            return Err(PushError::Stale);
        }
        match idx - last {
            1 => {
                self.append(value);
                Ok(PushOutcome::Appended)
            }
            2 => {
                let prev = self.buf[(self.head + self.len - 1) % N];
                self.append(P::midpoint(prev, value));
                self.append(value);
                Ok(PushOutcome::FilledGap)
            }
            d => Err(PushError::Gap { missing: d - 1 }),
        }
    }

    /// Evaluate at synchronized time `t`. Latches the backstop when `t`
    /// is past the known curve (needs the point at `T_i + 2Δt`).
    pub fn sample(&mut self, t: SystemInstant) -> Result<Sample<P::Kin>, EvalError> {
        let t = t.as_micros();
        if let Some(l) = &self.latched {
            return Ok(self.backstop_at(l, t));
        }
        if let Some((seg, du)) = self.segment_at(SystemInstant::from_micros(t)) {
            return Ok(Sample {
                status: TrackStatus::Tracking,
                kin: P::eval(&seg, du, self.iv),
            });
        }
        if self.len < 4 {
            return Err(EvalError::NotStarted);
        }
        let shift = self.iv.shift();
        if t >> shift < self.first + 1 {
            return Err(EvalError::TooEarly);
        }
        // Ran dry: stop from the state at the end of the last known segment.
        let last = self.last_idx();
        let seg = self.segment(last - 2);
        let edge = P::eval(&seg, self.iv.micros(), self.iv);
        let (v, a) = P::vel_acc_f32(&edge);
        let l = Latched {
            start_us: (last - 1) << shift,
            edge,
            profile: StopProfile::plan(v, a, self.limits),
        };
        self.latched = Some(l);
        Ok(self.backstop_at(&l, t))
    }

    /// The control points `P_{i-1}..P_{i+2}` of the segment holding `t` and
    /// `t`'s offset in it (µs), when that segment is fully known and the
    /// backstop has not latched; `None` otherwise (then [`Track::sample`]
    /// decides: `TooEarly`, `NotStarted` or the backstop). For a per-tick
    /// evaluator such as [`crate::eval::TickEval`].
    pub fn segment_at(&self, t: SystemInstant) -> Option<([P; 4], u32)> {
        let t = t.as_micros();
        if self.latched.is_some() || self.len < 4 {
            return None;
        }
        let i = t >> self.iv.shift();
        if i < self.first + 1 || i + 2 > self.last_idx() {
            return None;
        }
        let du = (t & (self.iv.micros() as u64 - 1)) as u32;
        Some((self.segment(i), du))
    }

    fn segment(&self, i: u64) -> [P; 4] {
        let g = |k| self.get(k).unwrap_or_default();
        [g(i - 1), g(i), g(i + 1), g(i + 2)]
    }

    fn backstop_at(&self, l: &Latched<P::Kin>, t: u64) -> Sample<P::Kin> {
        let tau = t.saturating_sub(l.start_us) as f32 * 1e-6;
        let (dp, v, a, j) = l.profile.at(tau);
        Sample {
            status: TrackStatus::Backstop,
            kin: P::with_offset(&l.edge, dp, v, a, j),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::Fx;

    #[test]
    fn segment_at_only_for_fully_known_segments() {
        let iv = Interval::from_micros(256).unwrap();
        let lim = BackstopLimits {
            max_acc: 1e4,
            max_jerk: 1e6,
        };
        let mut tr: Track<Fx, 8> = Track::new(iv, lim);
        for k in 0..3u64 {
            tr.push(SystemInstant::from_micros(k * 256), Fx(k as i32))
                .unwrap();
        }
        assert_eq!(
            tr.segment_at(SystemInstant::from_micros(256)),
            None,
            "fewer than 4 points"
        );
        tr.push(SystemInstant::from_micros(768), Fx(3)).unwrap();
        assert_eq!(
            tr.segment_at(SystemInstant::from_micros(255)),
            None,
            "needs P_-1"
        );
        assert_eq!(
            tr.segment_at(SystemInstant::from_micros(256 + 17)),
            Some(([Fx(0), Fx(1), Fx(2), Fx(3)], 17))
        );
        assert_eq!(
            tr.segment_at(SystemInstant::from_micros(512)),
            None,
            "needs the point at 1024"
        );
        // Running dry latches the backstop; then there is no segment.
        assert!(tr.sample(SystemInstant::from_micros(600)).is_ok());
        assert_eq!(tr.segment_at(SystemInstant::from_micros(256)), None);
    }
}
