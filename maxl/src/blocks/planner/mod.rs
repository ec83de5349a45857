//! Lookahead motion planner: straight segments (and arcs split into chords)
//! in `N` axes, trapezoidal speed profiles, junction deviation at corners,
//! sampled at the timer's synchronized stamps.
//!
//! Model (see `docs/planner.md`):
//! - **Limits** ([`Limits`]): each axis has a speed and an acceleration
//!   limit. A segment's largest speed and acceleration are the largest that
//!   keep every axis within its limit along the segment's direction, and the
//!   speed is also at most the segment's requested feed.
//! - **Junctions**: the speed through a corner comes from the junction
//!   deviation model, is 0 at reversals, the full speed for collinear
//!   segments, and keeps each axis's velocity jump within
//!   [`Limits::max_jump`].
//! - **Queue**: segments can be appended at any time, also while running.
//!   Each append runs a backward pass from the new tail (stopping where
//!   nothing changes) and a forward pass over the same stretch; the tail
//!   always ends at rest, so running out of segments stops safely. A segment
//!   that has started running is frozen.
//! - **Sampling**: [`Planner::sample`] gives the planned position at a
//!   synchronized stamp (µs, non-decreasing). Queued segments start when
//!   first sampled (at the first stamp after they were queued, or at
//!   [`Planner::start`]) and follow one another without pause.
//! - **Observability**: [`Planner::plan`] returns every running and queued
//!   segment's profile and timing, and can be evaluated at any time;
//!   [`Planner::stats`] counts segments.
//!
//! The PIPES class [`PlannerBlock`] (class name `Planner`) is the wire API;
//! its failure codes are [`PlanError::code`]:
//! 1 invalid limit, 2 non-finite coordinate, 3 invalid feed, 4 invalid arc,
//! 5 queue full, 6 stamp before the previous one, 7 busy (not idle),
//! 8 invalid capacity.

mod arc;
mod class;
mod limits;
mod plan;
mod profile;

use std::collections::VecDeque;

pub use arc::Arc;
pub use class::{PlannerBlock, WIRE_CHORD_TOLERANCE};
pub use limits::{Limits, PlanError};
pub use plan::{Kin, Plan, PlannedSegment, Stats};
pub use profile::Profile;

use profile::{junction_speed, Segment};

/// Default number of queued (not yet running) segments.
pub const DEFAULT_CAPACITY: usize = 4096;

/// The segment running now, with its frozen profile.
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

    fn planned(&self, epoch: u64) -> PlannedSegment<N> {
        planned(&self.seg, self.prof, epoch as f64 + self.t0 * 1e6, true)
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

/// A lookahead planner for straight segments in `N` axes.
#[derive(Clone, Debug)]
pub struct Planner<const N: usize> {
    limits: Limits<N>,
    capacity: usize,
    /// Segments not yet started, in path order.
    queue: VecDeque<Segment<N>>,
    running: Option<Running<N>>,
    /// Entry speed of `queue[0]`, fixed by the running segment's exit.
    fixed_entry: f64,
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
}

impl<const N: usize> Planner<N> {
    /// A planner at rest at the origin with [`DEFAULT_CAPACITY`].
    pub fn new(limits: Limits<N>) -> Result<Self, PlanError> {
        Self::with_capacity(limits, DEFAULT_CAPACITY)
    }

    /// A planner holding at most `capacity` segments not yet started.
    pub fn with_capacity(limits: Limits<N>, capacity: usize) -> Result<Self, PlanError> {
        limits.validate()?;
        if capacity == 0 {
            return Err(PlanError::InvalidCapacity);
        }
        Ok(Planner {
            limits,
            capacity,
            queue: VecDeque::new(),
            running: None,
            fixed_entry: 0.0,
            tail: [0.0; N],
            rest: [0.0; N],
            epoch: None,
            last_stamp: None,
            pending_start: None,
            next_id: 0,
            executed: 0,
        })
    }

    /// The limits.
    pub fn limits(&self) -> &Limits<N> {
        &self.limits
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
        self.running.is_none() && self.queue.is_empty()
    }

    /// Queue a straight move from the tail to `target` at up to `feed` mm/s.
    /// Returns the number of segments queued: 0 for a move shorter than 1 nm
    /// (nothing to do), else 1.
    pub fn line(&mut self, target: [f64; N], feed: f64) -> Result<usize, PlanError> {
        check_finite(&target)?;
        check_feed(feed)?;
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
        if self.running.is_some() {
            return Err(PlanError::Busy);
        }
        self.check_stamp(t)?;
        self.epoch.get_or_insert(t);
        self.pending_start = Some(t);
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
            if let Some(run) = &self.running {
                if ts < run.t_end() {
                    let (seg, tau) = (&run.seg, ts - run.t0);
                    return Ok(plan::kin_at(&seg.start, &seg.dir, &run.prof, tau));
                }
                let t_end = run.t_end();
                self.rest = run.seg.end;
                self.running = None;
                self.executed += 1;
                if self.queue.is_empty() {
                    self.fixed_entry = 0.0;
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
        let mut segments = Vec::with_capacity(self.queue.len() + 1);
        let mut t = match &self.running {
            Some(r) => {
                segments.push(r.planned(epoch));
                epoch as f64 + r.t_end() * 1e6
            }
            None => self.pending_start.or(self.last_stamp).unwrap_or(epoch) as f64,
        };
        for (i, s) in self.queue.iter().enumerate() {
            let exit = self.queue.get(i + 1).map_or(0.0, |n| n.entry);
            let prof = Profile::plan(s.len, s.entry, exit, s.v_max, s.acc);
            let p = planned(s, prof, t, false);
            t = p.end_us();
            segments.push(p);
        }
        Plan {
            segments,
            rest: self.rest,
        }
    }

    /// Counters and state.
    pub fn stats(&self) -> Stats {
        Stats {
            queued_total: self.next_id,
            executed: self.executed,
            pending: self.queue.len() + self.running.is_some() as usize,
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
    fn begin(&mut self, t0: f64) {
        let Some(seg) = self.queue.pop_front() else {
            return;
        };
        let exit = self.queue.front().map_or(0.0, |n| n.entry);
        let prof = Profile::plan(seg.len, self.fixed_entry, exit, seg.v_max, seg.acc);
        self.fixed_entry = exit;
        self.running = Some(Running { seg, prof, t0 });
    }

    /// Appends a checked segment to `target` and replans; false if too short.
    fn push(&mut self, target: [f64; N], feed: f64) -> bool {
        let Some(mut seg) = Segment::new(self.next_id, self.tail, target, feed, &self.limits)
        else {
            return false;
        };
        let prev = self
            .queue
            .back()
            .or_else(|| self.running.as_ref().map(|r| &r.seg));
        seg.junction_max = prev.map_or(0.0, |p| junction_speed(p, &seg, &self.limits));
        self.next_id += 1;
        self.tail = target;
        self.queue.push_back(seg);
        self.replan();
        true
    }

    /// Backward pass from the new tail until an entry bound stops changing,
    /// then a forward pass over the changed stretch.
    fn replan(&mut self) {
        let q = &mut self.queue;
        let k = q.len() - 1;
        q[k].back = q[k].junction_max.min(q[k].reach(0.0));
        let mut from = 0;
        for i in (0..k).rev() {
            let nb = q[i].junction_max.min(q[i].reach(q[i + 1].back));
            if nb == q[i].back {
                from = i + 1;
                break;
            }
            q[i].back = nb;
        }
        for i in from..=k {
            q[i].entry = if i == 0 {
                self.fixed_entry
            } else {
                q[i].back.min(q[i - 1].reach(q[i - 1].entry))
            };
        }
    }
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

fn check_feed(feed: f64) -> Result<(), PlanError> {
    if feed.is_finite() && feed > 0.0 {
        Ok(())
    } else {
        Err(PlanError::InvalidFeed(feed))
    }
}
