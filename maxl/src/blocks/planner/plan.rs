//! The observable plan: each segment's profile and timing, and the planned
//! position, velocity and acceleration at any time.

use super::profile::Profile;

/// Position, velocity and acceleration of every axis (mm, mm/s, mm/s²).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Kin<const N: usize> {
    /// Position.
    pub pos: [f64; N],
    /// Velocity.
    pub vel: [f64; N],
    /// Acceleration.
    pub acc: [f64; N],
}

impl<const N: usize> Kin<N> {
    /// At rest at `pos`.
    pub fn rest(pos: [f64; N]) -> Self {
        Kin {
            pos,
            vel: [0.0; N],
            acc: [0.0; N],
        }
    }
}

/// One segment as planned.
#[derive(Clone, Debug, PartialEq)]
pub struct PlannedSegment<const N: usize> {
    /// Sequence number of the segment (0 for the first ever queued).
    pub id: u64,
    /// Where it starts.
    pub start: [f64; N],
    /// Where it ends.
    pub end: [f64; N],
    /// Each axis's change per unit of path length (a unit vector over
    /// the toolhead's axes when they move: see
    /// [`super::VectorLimits::path_axes`]).
    pub dir: [f64; N],
    /// Its speed profile (entry, cruise, exit speed, acceleration, ramps).
    pub profile: Profile,
    /// Largest entry speed its junction allows (mm/s).
    pub junction_max: f64,
    /// Start in synchronized time (µs, fractional).
    pub start_us: f64,
    /// Duration (µs).
    pub duration_us: f64,
    /// Whether it is running now (its profile is frozen).
    pub running: bool,
}

impl<const N: usize> PlannedSegment<N> {
    /// End in synchronized time (µs).
    pub fn end_us(&self) -> f64 {
        self.start_us + self.duration_us
    }

    /// The planned state `t_us` (synchronized µs) into the plan, clamped to
    /// this segment.
    pub fn state_at(&self, t_us: f64) -> Kin<N> {
        kin_at(
            &self.start,
            &self.dir,
            &self.profile,
            (t_us - self.start_us) * 1e-6,
        )
    }
}

/// The state `tau` seconds into a segment from `start` along `dir`.
pub(crate) fn kin_at<const N: usize>(
    start: &[f64; N],
    dir: &[f64; N],
    prof: &Profile,
    tau: f64,
) -> Kin<N> {
    let (s, v, a) = prof.at(tau);
    let mut k = Kin::rest(*start);
    for i in 0..N {
        k.pos[i] = start[i] + dir[i] * s;
        k.vel[i] = dir[i] * v;
        k.acc[i] = dir[i] * a;
    }
    k
}

/// The running and queued segments as planned now. Start times of segments
/// not yet running assume they follow one another without a pause.
#[derive(Clone, Debug, PartialEq)]
pub struct Plan<const N: usize> {
    /// The segments, in path order; the first may be running.
    pub segments: Vec<PlannedSegment<N>>,
    /// Where the planner rests before the first segment (its current
    /// position if idle).
    pub rest: [f64; N],
}

impl<const N: usize> Plan<N> {
    /// Total planned time (µs) from the first segment's start to rest.
    pub fn duration_us(&self) -> f64 {
        match (self.segments.first(), self.segments.last()) {
            (Some(a), Some(b)) => b.end_us() - a.start_us,
            _ => 0.0,
        }
    }

    /// The planned state at `t_us` (synchronized µs, any order): at rest
    /// before the first segment and after the last.
    pub fn state_at(&self, t_us: f64) -> Kin<N> {
        let segs = &self.segments;
        let Some(first) = segs.first() else {
            return Kin::rest(self.rest);
        };
        if t_us < first.start_us {
            return Kin::rest(first.start);
        }
        // Segments are in time order: binary search the one holding t.
        let i = segs.partition_point(|s| s.end_us() <= t_us);
        match segs.get(i) {
            Some(s) => s.state_at(t_us),
            None => Kin::rest(segs[segs.len() - 1].end),
        }
    }
}

/// Counters and state of the planner.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Stats {
    /// Segments queued since the planner was made (arc chords included).
    pub queued_total: u64,
    /// Segments finished.
    pub executed: u64,
    /// Segments not finished: queued plus the running one.
    pub pending: usize,
    /// Nothing running and nothing queued: at rest.
    pub idle: bool,
}
