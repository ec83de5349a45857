//! Lookahead motion planner: straight segments (and arcs split into chords)
//! in `N` axes, trapezoidal speed profiles, Klipper's junction and cruise
//! model, sampled at the timer's synchronized stamps.
//!
//! Model (see `docs/planner.md`):
//! - **Limits** ([`Limits`], [`VectorLimits`]): each axis has a speed and an
//!   acceleration limit, and the toolhead optionally a largest |v| and |a|
//!   (Klipper's `max_velocity`, `max_accel`). A segment's largest speed and
//!   acceleration are the largest that keep every axis within its limit
//!   along the segment's direction and within the vector limits, and the
//!   speed is also at most the segment's requested feed.
//! - **Junctions**: the speed through a corner is bounded by the junction
//!   deviation model (δ set directly or from Klipper's square-corner
//!   velocity, [`square_corner_deviation`]) and by Klipper's centripetal
//!   limit on the shorter neighbouring segment, which keeps chained chords
//!   of a curve within the acceleration laterally at any chord length; it
//!   is 0 at reversals, the full speed for collinear segments, and keeps
//!   each axis's velocity jump within [`Limits::max_jump`].
//! - **Minimum cruise ratio** ([`VectorLimits::min_cruise_ratio`], off by
//!   default): Klipper's cap on each segment's speed from a second
//!   lookahead at `acc · (1 − ratio)`, so short moves between slow corners
//!   cruise instead of accelerating and braking all the way.
//! - **Queue**: segments can be appended at any time, also while running.
//!   Each append runs a backward pass from the new tail (stopping where
//!   nothing changes) and a forward pass over the same stretch; the tail
//!   always ends at rest, so running out of segments stops safely. A segment
//!   that has started running is frozen.
//! - **Sampling**: [`Planner::sample`] gives the planned position at a
//!   synchronized stamp (µs, non-decreasing). Queued segments start when
//!   first sampled (at the first stamp after they were queued, or at
//!   [`Planner::start`]) and follow one another without pause.
//! - **Halt**: [`Planner::halt`] stops along the planned path as fast as
//!   each segment's acceleration allows, from the last sampled stamp on, and
//!   drops everything after the stop point.
//! - **Feed scale**: [`Planner::set_feed_scale`] scales the requested feed
//!   of every segment not yet started (within the axis limits) and replans.
//! - **Observability**: [`Planner::plan`] returns every running and queued
//!   segment's profile and timing, and can be evaluated at any time;
//!   [`Planner::stats`] counts segments.
//!
//! The PIPES class [`PlannerBlock`] (class name `Planner`) is the wire API;
//! its failure codes are [`PlanError::code`]:
//! 1 invalid limit, 2 non-finite coordinate, 3 invalid feed, 4 invalid arc,
//! 5 queue full, 6 stamp before the previous one, 7 busy (not idle),
//! 8 invalid capacity, 9 invalid feed scale, 10 move too long.

mod arc;
mod class;
mod limits;
mod model;
mod plan;
mod profile;

use std::collections::VecDeque;

pub use arc::Arc;
pub use class::{PlannerBlock, WIRE_CHORD_TOLERANCE};
pub use limits::{
    square_corner_deviation, Limits, PlanError, VectorLimits, KLIPPER_MIN_CRUISE_RATIO,
};
pub use model::AccelModel;
pub use plan::{Kin, Plan, PlannedSegment, Stats};
pub use profile::{AccelBands, Profile, ACCEL_BANDS};

use profile::{junction_speed, Segment};

/// Default number of queued (not yet running) segments.
pub const DEFAULT_CAPACITY: usize = 4096;

/// The most queue slots a planner reserves when it is made (a larger
/// capacity grows as needed): 262 144 segments, some 60 MB for three axes.
pub const QUEUE_RESERVE: usize = 1 << 18;

/// Largest feed scale [`Planner::set_feed_scale`] takes.
pub const MAX_FEED_SCALE: f64 = 10.0;

/// A segment with its frozen profile and start: the running one, or one of
/// a halt's stop that follows it.
#[derive(Clone, Debug)]
struct Running<const N: usize> {
    seg: Segment<N>,
    prof: Profile,
    /// Start, seconds after the planner's epoch.
    t0: f64,
}

impl<const N: usize> Running<N> {
    fn t_end(&self) -> f64 {
        self.t0 + self.prof.duration()
    }

    fn planned(&self, epoch: u64, running: bool) -> PlannedSegment<N> {
        planned(&self.seg, self.prof, epoch as f64 + self.t0 * 1e6, running)
    }
}

fn planned<const N: usize>(
    seg: &Segment<N>,
    prof: Profile,
    start_us: f64,
    running: bool,
) -> PlannedSegment<N> {
    PlannedSegment {
        id: seg.id,
        start: seg.start,
        end: seg.end,
        dir: seg.dir,
        profile: prof,
        junction_max: seg.junction_max,
        start_us,
        duration_us: prof.duration() * 1e6,
        running,
    }
}

/// How many segment starts a planner keeps for
/// [`Planner::segment_start`].
pub const BEGUN_KEPT: usize = 64;

/// A lookahead planner for straight segments in `N` axes.
#[derive(Clone, Debug)]
pub struct Planner<const N: usize> {
    limits: Limits<N>,
    vector: VectorLimits,
    capacity: usize,
    /// Segments not yet started, in path order.
    queue: VecDeque<Segment<N>>,
    /// The running segment (front) and the segments whose profiles are
    /// frozen after it (the rest of a halt's stop), back to back.
    frozen: VecDeque<Running<N>>,
    /// Entry speed of `queue[0]`, fixed by the last frozen segment's exit.
    fixed_entry: f64,
    /// Factor on the requested feed of segments not yet started.
    feed_scale: f64,
    /// Where the next appended segment starts.
    tail: [f64; N],
    /// Where the machine is (or will be) when nothing runs.
    rest: [f64; N],
    /// Synchronized time (µs) that planner times are measured from.
    epoch: Option<u64>,
    last_stamp: Option<u64>,
    pending_start: Option<u64>,
    next_id: u64,
    executed: u64,
    /// The latest segments begun: id, start (synchronized µs) and speed
    /// along the path there, at most [`BEGUN_KEPT`].
    begun: VecDeque<(u64, f64, f64)>,
    /// When the path last came to rest (synchronized µs).
    rest_since: Option<f64>,
    /// Speed- and direction-dependent acceleration limits, if any.
    model: Option<std::sync::Arc<dyn AccelModel<N>>>,
}

impl<const N: usize> Planner<N> {
    /// A planner at rest at the origin with [`DEFAULT_CAPACITY`].
    pub fn new(limits: Limits<N>) -> Result<Self, PlanError> {
        Self::with_capacity(limits, DEFAULT_CAPACITY)
    }

    /// A planner holding at most `capacity` segments not yet started.
    pub fn with_capacity(limits: Limits<N>, capacity: usize) -> Result<Self, PlanError> {
        Self::with_vector_limits(limits, VectorLimits::NONE, capacity)
    }

    /// A planner with toolhead (vector) limits and a minimum cruise ratio
    /// besides the per-axis limits, holding at most `capacity` segments not
    /// yet started.
    pub fn with_vector_limits(
        limits: Limits<N>,
        vector: VectorLimits,
        capacity: usize,
    ) -> Result<Self, PlanError> {
        limits.validate()?;
        vector.validate()?;
        if capacity == 0 {
            return Err(PlanError::InvalidCapacity);
        }
        Ok(Planner {
            limits,
            vector,
            capacity,
            // Reserved up front (up to QUEUE_RESERVE): a queue grown by
            // doubling copies every segment again at each step.
            queue: VecDeque::with_capacity(capacity.min(QUEUE_RESERVE)),
            frozen: VecDeque::new(),
            fixed_entry: 0.0,
            feed_scale: 1.0,
            tail: [0.0; N],
            rest: [0.0; N],
            epoch: None,
            last_stamp: None,
            pending_start: None,
            next_id: 0,
            executed: 0,
            begun: VecDeque::with_capacity(BEGUN_KEPT),
            rest_since: None,
            model: None,
        })
    }

    /// The limits.
    pub fn limits(&self) -> &Limits<N> {
        &self.limits
    }

    /// Bounds every segment's and corner's acceleration by `model` too
    /// (`None`: the limits alone), from now on: the queue is replanned.
    /// The running segment and a halt's stop keep their profiles.
    pub fn set_accel_model(&mut self, model: Option<std::sync::Arc<dyn AccelModel<N>>>) {
        self.model = model;
        for s in self.queue.iter_mut() {
            s.set_limits(&self.limits, &self.vector, self.feed_scale);
        }
        self.replan_all();
    }

    /// The acceleration model, if any.
    pub fn accel_model(&self) -> Option<&dyn AccelModel<N>> {
        self.model.as_deref()
    }

    /// The toolhead (vector) limits and minimum cruise ratio.
    pub fn vector_limits(&self) -> &VectorLimits {
        &self.vector
    }

    /// Sets the toolhead (vector) limits and minimum cruise ratio, at any
    /// time: every segment not yet started takes the new limits and the
    /// whole queue is replanned, as [`Planner::set_feed_scale`] does (the
    /// running segment, and a halt's stop, keep their profiles; if the path
    /// runs faster than a lowered limit there, the following segments brake
    /// at their acceleration limit until they are under it). Refused
    /// ([`PlanError::InvalidLimit`]) unless [`VectorLimits::validate`]
    /// passes; nothing changes then.
    pub fn set_vector_limits(&mut self, vector: VectorLimits) -> Result<(), PlanError> {
        vector.validate()?;
        if vector.path_axes != self.vector.path_axes && !self.is_idle() {
            // Queued segments were measured over the old path axes.
            return Err(PlanError::Busy);
        }
        self.vector = vector;
        for s in self.queue.iter_mut() {
            s.set_limits(&self.limits, &vector, self.feed_scale);
        }
        self.replan_all();
        Ok(())
    }

    /// Where the next segment starts: the end of the last one queued.
    pub fn tail(&self) -> [f64; N] {
        self.tail
    }

    /// Set the position, only when idle (nothing running or queued).
    pub fn set_position(&mut self, pos: [f64; N]) -> Result<(), PlanError> {
        check_finite(&pos)?;
        if !self.is_idle() {
            return Err(PlanError::Busy);
        }
        self.tail = pos;
        self.rest = pos;
        Ok(())
    }

    /// Nothing running and nothing queued.
    pub fn is_idle(&self) -> bool {
        self.frozen.is_empty() && self.queue.is_empty()
    }

    /// The last stamp sampled (µs), if any: its position is already sent,
    /// so nothing at or before it can change.
    pub fn last_stamp(&self) -> Option<u64> {
        self.last_stamp
    }

    /// The synchronized time (µs) the planner's times are measured from:
    /// the first stamp sampled or passed to [`Planner::start`], if any.
    pub fn epoch(&self) -> Option<u64> {
        self.epoch
    }

    /// The feed scale set by [`Planner::set_feed_scale`] (1 at first).
    pub fn feed_scale(&self) -> f64 {
        self.feed_scale
    }

    /// Queue a straight move from the tail to `target` at up to `feed` mm/s.
    /// Returns the number of segments queued: 0 for a move shorter than 1 nm
    /// (nothing to do), else 1. A move whose length overflows `f64` is
    /// refused ([`PlanError::MoveTooLong`]).
    pub fn line(&mut self, target: [f64; N], feed: f64) -> Result<usize, PlanError> {
        check_finite(&target)?;
        check_feed(feed)?;
        check_length(&self.tail, &target)?;
        if self.queue.len() >= self.capacity {
            return Err(PlanError::QueueFull {
                capacity: self.capacity,
            });
        }
        Ok(self.push(target, feed) as usize)
    }

    /// Queue an arc from the tail, split into chords within its tolerance.
    /// Returns the number of segments queued. Nothing is queued on error,
    /// also when the chords would not all fit in the queue.
    pub fn arc(&mut self, arc: &Arc<N>, feed: f64) -> Result<usize, PlanError> {
        check_feed(feed)?;
        let pts = arc.chords(self.tail)?;
        let mut from = self.tail;
        for p in &pts {
            check_finite(p)?;
            check_length(&from, p)?;
            from = *p;
        }
        if self.queue.len() + pts.len() > self.capacity {
            return Err(PlanError::QueueFull {
                capacity: self.capacity,
            });
        }
        Ok(pts.into_iter().filter(|p| self.push(*p, feed)).count())
    }

    /// Start the queued path at stamp `t` (µs) instead of at the first stamp
    /// sampled after queuing. Only while nothing runs, and not before the
    /// last sampled stamp.
    pub fn start(&mut self, t: u64) -> Result<(), PlanError> {
        if !self.frozen.is_empty() {
            return Err(PlanError::Busy);
        }
        self.check_stamp(t)?;
        self.epoch.get_or_insert(t);
        self.pending_start = Some(t);
        Ok(())
    }

    /// A controlled stop: from the last sampled stamp on, the path slows to
    /// rest as fast as each segment's own acceleration limit allows, along
    /// the planned path, and everything after the stop point is dropped.
    /// Returns where the machine comes to rest.
    ///
    /// - Stamps already sampled (up to [`Planner::last_stamp`]) keep their
    ///   position and velocity: the running segment's profile is frozen
    ///   from its start, so it is replaced by one that starts at the last
    ///   sampled stamp's position and speed along the path and decelerates.
    ///   The speed stays continuous there; only the acceleration steps (to
    ///   the deceleration limit).
    /// - The stopping distance may span several segments (short chords of a
    ///   curve): the stop follows them through their corners, each at its
    ///   own acceleration limit, and the segment where the speed reaches 0
    ///   is cut at exactly that point. These segments are frozen: the
    ///   feed scale and later appends do not change them.
    /// - Afterwards [`Planner::tail`] is the stop point, so new moves
    ///   continue from there (starting from rest once the stop is done), and
    ///   [`Planner::is_idle`] turns true once the stop has been sampled
    ///   through. Times stay keyed to the planner's epoch.
    /// - With nothing running (idle, nothing sampled yet, or segments queued
    ///   but not started) the queue (and any pending [`Planner::start`]) is
    ///   cleared and the rest position returned.
    ///
    /// The running segment, and each segment the stop runs through, counts
    /// as executed once its part of the stop has run (the running one at
    /// once if the halt finds it at rest); dropped segments never do.
    /// Never fails today; the `Result` keeps the wire API's shape.
    pub fn halt(&mut self) -> Result<[f64; N], PlanError> {
        self.pending_start = None;
        let queue = std::mem::take(&mut self.queue);
        let fixed_entry = std::mem::replace(&mut self.fixed_entry, 0.0);
        let (Some(last), Some(epoch), Some(run)) =
            (self.last_stamp, self.epoch, self.frozen.front())
        else {
            self.frozen.clear();
            self.tail = self.rest;
            return Ok(self.rest);
        };
        // The last sample lies within the running segment (t0 ≤ ts < end).
        let ts = secs(last, epoch);
        let (s0, v0, _) = run.prof.at(ts - run.t0);
        let mut first = run.seg.clone();
        first.start = point_along(&run.seg.start, &run.seg.dir, s0);
        first.len = (run.seg.len - s0).max(0.0);
        let at_halt = first.start;
        // The path ahead: the rest of the running segment, the frozen ones
        // after it, and the queue if the frozen ones run into it.
        let ahead = if fixed_entry > 0.0 { queue.len() } else { 0 };
        let path = std::iter::once(first)
            .chain(self.frozen.iter().skip(1).map(|r| r.seg.clone()))
            .chain(queue.into_iter().take(ahead));
        let stop = decelerate(path, v0, ts);
        let stop_point = stop.back().map_or(at_halt, |r| r.seg.end);
        if stop.is_empty() {
            // At rest already: the running segment ends here.
            self.rest = at_halt;
            self.executed += 1;
        }
        self.frozen = stop;
        self.tail = stop_point;
        Ok(stop_point)
    }

    /// A feed override: the requested feed of every segment not yet started,
    /// and of every segment queued later, is scaled by `k` (finite, in
    /// (0, [`MAX_FEED_SCALE`]]; [`PlanError::InvalidFeedScale`] otherwise).
    /// The axis limits still bound each segment, so a large `k` cannot push
    /// a segment past them. The whole queue is replanned (junction limits,
    /// backward and forward passes).
    ///
    /// The running segment, and a halt's frozen stop, keep their profiles;
    /// so the first queued segment is entered at the speed the running one
    /// was planned to exit with. When a lower `k` leaves the path faster
    /// than its new limit there, the following segments slow at their
    /// acceleration limit until they are under it (above the new feed, never
    /// above the axis limits, for that stretch).
    pub fn set_feed_scale(&mut self, k: f64) -> Result<(), PlanError> {
        if !(k.is_finite() && k > 0.0 && k <= MAX_FEED_SCALE) {
            return Err(PlanError::InvalidFeedScale(k));
        }
        self.feed_scale = k;
        for s in self.queue.iter_mut() {
            s.scale_feed(k);
        }
        self.replan_all();
        Ok(())
    }

    /// The planned position at synchronized stamp `t` (µs). Stamps must not
    /// decrease; segments finished by `t` are retired.
    pub fn sample(&mut self, t: u64) -> Result<[f64; N], PlanError> {
        Ok(self.sample_kin(t)?.pos)
    }

    /// As [`Planner::sample`], with the planned velocity and acceleration.
    pub fn sample_kin(&mut self, t: u64) -> Result<Kin<N>, PlanError> {
        self.check_stamp(t)?;
        self.last_stamp = Some(t);
        let epoch = *self.epoch.get_or_insert(t);
        let ts = secs(t, epoch);
        loop {
            if let Some(run) = self.frozen.front() {
                if ts < run.t_end() {
                    let (seg, tau) = (&run.seg, ts - run.t0);
                    return Ok(plan::kin_at(&seg.start, &seg.dir, &run.prof, tau));
                }
                let t_end = run.t_end();
                self.rest = run.seg.end;
                self.frozen.pop_front();
                self.executed += 1;
                if !self.frozen.is_empty() {
                    // The next frozen segment starts at `t_end` already.
                    continue;
                }
                if self.queue.is_empty() {
                    self.fixed_entry = 0.0;
                    self.rest_since = Some(epoch as f64 + t_end * 1e6);
                    return Ok(Kin::rest(self.rest));
                }
                self.begin(t_end);
                continue;
            }
            if self.queue.is_empty() {
                return Ok(Kin::rest(self.rest));
            }
            let t0 = match self.pending_start {
                Some(p) if p > t => return Ok(Kin::rest(self.rest)),
                Some(p) => secs(p, epoch),
                None => ts,
            };
            self.pending_start = None;
            self.begin(t0);
        }
    }

    /// The running and queued segments as planned now.
    pub fn plan(&self) -> Plan<N> {
        let epoch = self.epoch.unwrap_or(0);
        let mut segments = Vec::with_capacity(self.queue.len() + self.frozen.len());
        segments.extend(
            self.frozen
                .iter()
                .enumerate()
                .map(|(i, r)| r.planned(epoch, i == 0)),
        );
        let mut t = match self.frozen.back() {
            Some(r) => epoch as f64 + r.t_end() * 1e6,
            None => self.pending_start.or(self.last_stamp).unwrap_or(epoch) as f64,
        };
        let mut entry = self.junction(0);
        for (i, s) in self.queue.iter().enumerate() {
            let exit = self.junction(i + 1);
            let prof = s.profile(entry, exit);
            entry = exit;
            let p = planned(s, prof, t, false);
            t = p.end_us();
            segments.push(p);
        }
        Plan {
            segments,
            rest: self.rest,
        }
    }

    /// The planned state at synchronized stamp `t` (µs, fractional), at or
    /// after the last stamp sampled, without sampling: what the running
    /// and queued segments will do then, as planned now (later appends and
    /// a halt may change it). Walks only the segments up to `t`, so a
    /// lookahead of a few milliseconds (pressure advance) stays cheap.
    pub fn state_at(&self, t: f64) -> Kin<N> {
        let epoch = self.epoch.unwrap_or(0) as f64;
        let ts = (t - epoch) * 1e-6;
        for r in &self.frozen {
            if ts < r.t_end() {
                let tau = (ts - r.t0).max(0.0);
                return plan::kin_at(&r.seg.start, &r.seg.dir, &r.prof, tau);
            }
        }
        let mut t0 = match self.frozen.back() {
            Some(r) => r.t_end(),
            None => match self.pending_start.or(self.last_stamp) {
                Some(p) => (p as f64 - epoch) * 1e-6,
                None => return Kin::rest(self.rest),
            },
        };
        let mut entry = self.junction(0);
        for (i, s) in self.queue.iter().enumerate() {
            let exit = self.junction(i + 1);
            let prof = s.profile(entry, exit);
            entry = exit;
            if ts < t0 + prof.duration() {
                return plan::kin_at(&s.start, &s.dir, &prof, (ts - t0).max(0.0));
            }
            t0 += prof.duration();
        }
        Kin::rest(self.tail)
    }

    /// Walks the running and queued segments in path order, each with its
    /// id, its start (seconds after the epoch) and its profile as planned
    /// now, while `f` returns true.
    fn walk(&self, mut f: impl FnMut(u64, f64, &Profile) -> bool) {
        for r in &self.frozen {
            if !f(r.seg.id, r.t0, &r.prof) {
                return;
            }
        }
        let epoch = self.epoch.unwrap_or(0) as f64;
        let mut t0 = match self.frozen.back() {
            Some(r) => r.t_end(),
            None => match self.pending_start.or(self.last_stamp) {
                Some(p) => (p as f64 - epoch) * 1e-6,
                None => return,
            },
        };
        let mut entry = self.junction(0);
        for (i, s) in self.queue.iter().enumerate() {
            let exit = self.junction(i + 1);
            let prof = s.profile(entry, exit);
            entry = exit;
            if !f(s.id, t0, &prof) {
                return;
            }
            t0 += prof.duration();
        }
    }

    /// The id of the segment that runs at synchronized `t_us` (at or after
    /// the last stamp sampled) as planned now, or, at rest, of the next
    /// segment to run ([`Stats::queued_total`] once everything queued has
    /// run).
    pub fn segment_at(&self, t_us: f64) -> u64 {
        let ts = (t_us - self.epoch.unwrap_or(0) as f64) * 1e-6;
        let mut at = self.next_id;
        self.walk(|id, t0, prof| {
            if ts < t0 + prof.duration() {
                at = id;
                return false;
            }
            true
        });
        at
    }

    /// Where the path's speed changes slope in (`from_us`, `to_us`]
    /// (synchronized µs, at or after the last stamp sampled) as planned
    /// now, in time order: where segments meet and where the path comes to
    /// rest (`true`), and the ends of ramps within a segment (`false`),
    /// each with the id of the segment running from there (at rest, the
    /// next to run).
    /// Between two of them a trapezoid's speed is linear in time, so a
    /// level that follows the speed (a laser's dynamic power) is exact when
    /// ramped linearly between them.
    pub fn speed_breaks(&self, from_us: f64, to_us: f64) -> Vec<(f64, u64, bool)> {
        let epoch = self.epoch.unwrap_or(0) as f64;
        let us = |s: f64| epoch + s * 1e6;
        let mut out = Vec::new();
        self.walk(|id, t0, prof| {
            let start = us(t0);
            if start > to_us {
                return false;
            }
            // (time, id from there, a boundary, kept)
            let ends = [
                (start, id, true, true),
                (us(t0 + prof.t_acc), id, false, prof.t_acc > 0.0),
                (
                    us(t0 + prof.t_acc + prof.t_cruise),
                    id,
                    false,
                    prof.t_dec > 0.0,
                ),
                // The next segment's start, or the path's end at rest.
                (us(t0 + prof.duration()), id + 1, true, true),
            ];
            for (t, id, boundary, keep) in ends {
                if keep && t > from_us && t <= to_us {
                    out.push((t, id, boundary));
                }
            }
            true
        });
        // A segment's end is the next one's start: once.
        out.dedup_by(|later, earlier| (later.0 - earlier.0).abs() < 1e-6 && later.1 == earlier.1);
        out
    }

    /// When the path last came to rest, synchronized µs (fractional): the
    /// end of the last segment run before the queue ran out; `None` before
    /// any.
    pub fn rest_since(&self) -> Option<f64> {
        self.rest_since
    }

    /// The id of the segment running at the last sampled stamp (segments
    /// are numbered from 0 in the order they were queued, as
    /// [`Stats::queued_total`] counts them); `None` at rest.
    pub fn running_id(&self) -> Option<u64> {
        self.frozen.front().map(|r| r.seg.id)
    }

    /// When segment `id` began (synchronized µs, fractional) and its speed
    /// along the path there, for the latest [`BEGUN_KEPT`] segments begun:
    /// where a tool switched between two segments switches on the
    /// synchronized clock.
    pub fn segment_start(&self, id: u64) -> Option<(f64, f64)> {
        self.begun
            .iter()
            .rev()
            .find(|b| b.0 == id)
            .map(|b| (b.1, b.2))
    }

    /// Counters and state.
    pub fn stats(&self) -> Stats {
        Stats {
            queued_total: self.next_id,
            executed: self.executed,
            pending: self.queue.len() + self.frozen.len(),
            idle: self.is_idle(),
        }
    }

    /// Refuses a stamp before the last sampled one.
    fn check_stamp(&self, t: u64) -> Result<(), PlanError> {
        match self.last_stamp {
            Some(last) if t < last => Err(PlanError::StampNotMonotonic { stamp: t, last }),
            _ => Ok(()),
        }
    }

    /// Starts `queue[0]` at `t0` seconds after the epoch, freezing its exit.
    /// Only while nothing is frozen.
    fn begin(&mut self, t0: f64) {
        let exit = self.junction(1);
        let Some(seg) = self.queue.pop_front() else {
            return;
        };
        let prof = seg.profile(self.fixed_entry, exit);
        self.fixed_entry = exit;
        if self.begun.len() == BEGUN_KEPT {
            self.begun.pop_front();
        }
        let start_us = self.epoch.unwrap_or(0) as f64 + t0 * 1e6;
        self.begun.push_back((seg.id, start_us, prof.at(0.0).1));
        self.frozen.push_back(Running { seg, prof, t0 });
        self.refix_front();
    }

    /// The speed the plan passes into `queue[i]` at: the fixed entry for
    /// `i = 0`, the lookahead's entry within the minimum cruise ratio's caps
    /// on both sides of the junction otherwise, and 0 past the tail.
    fn junction(&self, i: usize) -> f64 {
        let q = &self.queue;
        match (i, q.get(i)) {
            (_, None) => 0.0,
            (0, Some(_)) => self.fixed_entry,
            (_, Some(s)) => {
                let cap2 = s.cruise2.min(q[i - 1].cruise2);
                cap2.min(s.entry2).sqrt()
            }
        }
    }

    /// Whether the minimum cruise ratio is on.
    fn mcr(&self) -> bool {
        self.vector.min_cruise_ratio > 0.0
    }

    /// Appends a checked segment to `target` and replans; false if too short.
    fn push(&mut self, target: [f64; N], feed: f64) -> bool {
        let Ok(Some(mut seg)) = Segment::new(
            self.next_id,
            self.tail,
            target,
            feed,
            self.feed_scale,
            &self.limits,
            &self.vector,
        ) else {
            // The caller checked the length; a move under 1 nm is dropped.
            return false;
        };
        let prev = self
            .queue
            .back()
            .or_else(|| self.frozen.back().map(|r| &r.seg));
        seg.junction_max = prev.map_or(0.0, |p| {
            junction_speed(p, &seg, &self.limits, &self.vector, self.model.as_deref())
        });
        if let Some(m) = &self.model {
            seg.apply_model(m.as_ref());
        }
        let mcr = self.mcr();
        if mcr {
            let r = self.vector.min_cruise_ratio;
            seg.mcr_fwd = match self.queue.back() {
                Some(p) => (seg.junction_max * seg.junction_max).min(p.mcr_fwd + p.mcr_delta(r)),
                None => self.fixed_entry * self.fixed_entry,
            };
        }
        self.next_id += 1;
        self.tail = target;
        self.queue.push_back(seg);
        let from = self.replan();
        if mcr {
            self.smooth_tail(from);
        }
        true
    }

    /// Backward pass from the new tail until an entry bound stops changing,
    /// then a forward pass over the changed stretch. Returns the first index
    /// whose entry may have changed.
    fn replan(&mut self) -> usize {
        // The passes run on a slice when the queue is contiguous (always,
        // until segments start leaving its front): no wrapping index.
        let from = match self.queue.as_mut_slices() {
            (q, []) => backward(q),
            _ => backward(&mut self.queue),
        };
        self.forward(from);
        from
    }

    /// Forward pass from `queue[from]` to the tail.
    fn forward(&mut self, from: usize) {
        let fixed2 = self.fixed_entry * self.fixed_entry;
        match self.queue.as_mut_slices() {
            (q, []) => forward(q, from, fixed2),
            _ => forward(&mut self.queue, from, fixed2),
        }
    }

    /// Minimum cruise ratio, after an append whose lookahead changed the
    /// entries from `from` on: the smoothed pass's backward bounds from the
    /// tail until they stop changing, then the caps of every segment whose
    /// hill may have changed.
    fn smooth_tail(&mut self, from: usize) {
        let r = self.vector.min_cruise_ratio;
        let q = &mut self.queue;
        let k = q.len() - 1;
        let mut next = 0.0;
        let mut changed = 0;
        for i in (0..=k).rev() {
            let s = q[i].mcr_fwd.min(next + q[i].mcr_delta(r));
            if i < k && s == q[i].mcr_start {
                changed = i + 1;
                break;
            }
            q[i].mcr_start = s;
            next = s;
        }
        // The segment before the first change sees a new next segment; the
        // rising segments before it take their hill's peak from it, up to
        // one whose peak lies within itself.
        let mut h = changed.min(from).saturating_sub(1);
        while h > 0 {
            let p = &q[h - 1];
            if p.hill >= 0.0 && p.mcr_fwd + p.mcr_delta(r) <= q[h].mcr_start {
                h -= 1;
            } else {
                break;
            }
        }
        self.refresh_caps(h, k);
    }

    /// After `queue[0]` became the first segment not started: its entry is
    /// the fixed one, which the minimum cruise ratio's caps may have lowered
    /// below its planned entry. Carries that forward through the entries
    /// (and, with the ratio on, the smoothed pass) until nothing changes.
    fn refix_front(&mut self) {
        let fixed = self.fixed_entry;
        let mcr = self.mcr();
        let r = self.vector.min_cruise_ratio;
        let q = &mut self.queue;
        if q.is_empty() {
            return;
        }
        let mut hi = 0;
        if q[0].entry2 != fixed * fixed {
            q[0].entry2 = fixed * fixed;
            for i in 1..q.len() {
                let e = q[i].back2.min(q[i - 1].reach2(q[i - 1].entry2));
                if e == q[i].entry2 {
                    break;
                }
                q[i].entry2 = e;
                hi = i;
            }
        }
        if !mcr {
            return;
        }
        if q[0].mcr_fwd != fixed * fixed {
            q[0].mcr_fwd = fixed * fixed;
            let mut tf = 0;
            for i in 1..q.len() {
                let c = q[i].bound();
                let f = (c * c).min(q[i - 1].mcr_fwd + q[i - 1].mcr_delta(r));
                if f == q[i].mcr_fwd {
                    break;
                }
                q[i].mcr_fwd = f;
                tf = i;
            }
            let mut next = q.get(tf + 1).map_or(0.0, |n| n.mcr_start);
            for i in (0..=tf).rev() {
                let s = q[i].mcr_fwd.min(next + q[i].mcr_delta(r));
                q[i].mcr_start = s;
                next = s;
            }
            hi = hi.max(tf);
        }
        self.refresh_caps(0, hi);
    }

    /// Minimum cruise ratio: each segment's cap from the smoothed pass (run
    /// at `acc · (1 − ratio)`), as Klipper's lookahead assigns it. Where the
    /// smoothed profile rises at a segment's start, the cap is the peak of
    /// its hill (the point where the smoothed rise meets the smoothed fall,
    /// in this segment or a later one) and of the segment's own trapezoid;
    /// where it falls, the cap of the segment before, within its own entry.
    ///
    /// Recomputes the hills over `lo..=hi` (backward, from the stored values
    /// after `hi`), then the caps from `lo` on, past `hi` as long as they
    /// change. The caller guarantees that after `hi` the smoothed bounds and
    /// entries are unchanged.
    fn refresh_caps(&mut self, lo: usize, hi: usize) {
        let r = self.vector.min_cruise_ratio;
        let q = &mut self.queue;
        let k = q.len() - 1;
        let (mut next_s, mut next_hill) =
            q.get(hi + 1).map_or((0.0, 0.0), |n| (n.mcr_start, n.hill));
        let mut last = hi == k;
        for i in (lo..=hi).rev() {
            let s = &mut q[i];
            let d = s.mcr_delta(r);
            let reach = next_s + d;
            s.hill = if s.mcr_fwd < reach {
                // Rising: the peak lies in this segment if the rise meets
                // the fall within it, or if the next one falls (or is none).
                if last || s.mcr_fwd + d > next_s || next_hill < 0.0 {
                    (s.mcr_start + reach) * 0.5
                } else {
                    next_hill
                }
            } else {
                -1.0
            };
            next_s = s.mcr_start;
            next_hill = s.hill;
            last = false;
        }
        let mut prev = match lo {
            0 => self.frozen.back().map_or(f64::INFINITY, |r| r.seg.cruise2),
            _ => q[lo - 1].cruise2,
        };
        for i in lo..=k {
            let s = &q[i];
            let c = if s.hill >= 0.0 {
                let e1 = q.get(i + 1).map_or(0.0, |n| n.entry2);
                let peak = (s.entry2 + e1 + 2.0 * s.acc * s.len) * 0.5;
                peak.min(s.hill)
            } else {
                prev.min(s.entry2)
            };
            if i > hi && c == s.cruise2 {
                break;
            }
            q[i].cruise2 = c;
            prev = c;
        }
    }

    /// Recomputes every queued segment's junction limit (its speed limit
    /// changed) and replans the whole queue.
    ///
    /// The entry of `queue[0]` is fixed by the frozen profile before it, so
    /// the path cannot slow faster than full deceleration from there: the
    /// floors carry that speed forward and raise the backward pass's bounds
    /// to it, keeping the plan within the acceleration limits when a lower
    /// feed scale would ask for a sharper slowdown (the segments above their
    /// new speed limit decelerate at their limit until they are under it).
    fn replan_all(&mut self) {
        let limits = &self.limits;
        let vector = &self.vector;
        let model = self.model.as_deref();
        let q = &mut self.queue;
        let mut floor = self.fixed_entry;
        for i in 0..q.len() {
            let prev = match i {
                0 => self.frozen.back().map(|r| &r.seg),
                _ => Some(&q[i - 1]),
            };
            let jm = prev.map_or(0.0, |p| junction_speed(p, &q[i], limits, vector, model));
            let s = &mut q[i];
            s.junction_max = jm;
            s.floor = floor;
            if let Some(m) = model {
                s.apply_model(m);
            }
            floor = s.reach_down(floor);
        }
        let mut next = 0.0;
        for s in q.iter_mut().rev() {
            s.back2 = s.bound2().min(s.reach2(next));
            next = s.back2;
        }
        self.forward(0);
        if self.queue.is_empty() {
            return;
        }
        if !self.mcr() {
            for s in self.queue.iter_mut() {
                s.cruise2 = f64::INFINITY;
            }
            return;
        }
        let r = self.vector.min_cruise_ratio;
        let q = &mut self.queue;
        let mut f = self.fixed_entry * self.fixed_entry;
        for i in 0..q.len() {
            if i > 0 {
                let c = q[i].bound();
                f = (c * c).min(f + q[i - 1].mcr_delta(r));
            }
            q[i].mcr_fwd = f;
        }
        let mut next = 0.0;
        for s in q.iter_mut().rev() {
            s.mcr_start = s.mcr_fwd.min(next + s.mcr_delta(r));
            next = s.mcr_start;
        }
        let k = q.len() - 1;
        self.refresh_caps(0, k);
    }
}

/// The segments of a queue, indexed: a slice, or the deque itself.
trait Segments<const N: usize>: core::ops::IndexMut<usize, Output = Segment<N>> {
    fn count(&self) -> usize;
}

impl<const N: usize> Segments<N> for [Segment<N>] {
    fn count(&self) -> usize {
        self.len()
    }
}

impl<const N: usize> Segments<N> for VecDeque<Segment<N>> {
    fn count(&self) -> usize {
        self.len()
    }
}

/// The backward pass from the tail (ending at rest) until an entry bound
/// stops changing; returns the first index whose entry may have changed.
#[inline]
fn backward<const N: usize, Q: Segments<N> + ?Sized>(q: &mut Q) -> usize {
    let k = q.count() - 1;
    q[k].back2 = q[k].bound2().min(q[k].reach2(0.0));
    for i in (0..k).rev() {
        let nb = q[i].bound2().min(q[i].reach2(q[i + 1].back2));
        if nb == q[i].back2 {
            return i + 1;
        }
        q[i].back2 = nb;
    }
    0
}

/// The forward pass from `from` to the tail; `fixed2` is the entry² of the
/// first segment.
#[inline]
fn forward<const N: usize, Q: Segments<N> + ?Sized>(q: &mut Q, from: usize, fixed2: f64) {
    for i in from..q.count() {
        q[i].entry2 = if i == 0 {
            fixed2
        } else {
            q[i].back2.min(q[i - 1].reach2(q[i - 1].entry2))
        };
    }
}

/// The point `s` along `dir` from `start` (as [`plan::kin_at`] computes it).
fn point_along<const N: usize>(start: &[f64; N], dir: &[f64; N], s: f64) -> [f64; N] {
    std::array::from_fn(|i| start[i] + dir[i] * s)
}

/// Full deceleration from speed `v` at `t` (s after the epoch) along
/// `path`, each segment at its own acceleration limit: the segments passed
/// through and the one where the speed reaches 0, cut at that point, with
/// their profiles and start times.
fn decelerate<const N: usize>(
    path: impl Iterator<Item = Segment<N>>,
    mut v: f64,
    mut t: f64,
) -> VecDeque<Running<N>> {
    let mut out: VecDeque<Running<N>> = VecDeque::new();
    for mut seg in path {
        if v <= 0.0 {
            break;
        }
        if seg.len <= 0.0 {
            continue;
        }
        let d = v * v / (2.0 * seg.acc);
        // Within rounding of the end counts as stopping at the end, so a
        // stop planned onto a vertex does not leak a sliver past it.
        let v1 = if d <= seg.len * (1.0 + 1e-12) + 1e-12 {
            if d < seg.len {
                seg.len = d;
                seg.end = point_along(&seg.start, &seg.dir, d);
            }
            0.0
        } else {
            (v * v - 2.0 * seg.acc * seg.len).max(0.0).sqrt()
        };
        seg.entry2 = v * v;
        seg.back2 = v * v;
        let prof = Profile::plan(seg.len, v, v1, v, seg.acc);
        let run = Running { seg, prof, t0: t };
        t = run.t_end();
        out.push_back(run);
        v = v1;
    }
    // The path ahead ends at rest, so speed left at its end is rounding:
    // end the last segment at rest.
    if let (true, Some(last)) = (v > 0.0, out.back_mut()) {
        let (s, e) = (&last.seg, last.prof.entry);
        last.prof = Profile::plan(s.len, e, 0.0, e, s.acc);
    }
    out
}

/// Seconds from `epoch` to `t` (µs), negative if `t` is earlier.
fn secs(t: u64, epoch: u64) -> f64 {
    (t as i128 - epoch as i128) as f64 * 1e-6
}

fn check_finite<const N: usize>(p: &[f64; N]) -> Result<(), PlanError> {
    match p.iter().position(|c| !c.is_finite()) {
        Some(axis) => Err(PlanError::NonFiniteCoordinate { axis }),
        None => Ok(()),
    }
}

/// Refuses a move whose length overflows `f64`.
fn check_length<const N: usize>(from: &[f64; N], to: &[f64; N]) -> Result<(), PlanError> {
    let len2: f64 = (0..N).map(|i| (to[i] - from[i]) * (to[i] - from[i])).sum();
    if len2.is_finite() {
        Ok(())
    } else {
        Err(PlanError::MoveTooLong)
    }
}

fn check_feed(feed: f64) -> Result<(), PlanError> {
    if feed.is_finite() && feed > 0.0 {
        Ok(())
    } else {
        Err(PlanError::InvalidFeed(feed))
    }
}
