//! The planner's PIPES class (wire API): `#[pipes_core::class]` over
//! [`PlannerBlock`], failing with the codes of [`PlanError::code`].

use pipes_core::function::CallError;

use super::{Arc, Limits, PlanError, Planner, VectorLimits};

/// Chord tolerance (mm) of arcs queued through the wire API.
pub const WIRE_CHORD_TOLERANCE: f64 = 0.002;

impl From<PlanError> for CallError {
    fn from(e: PlanError) -> CallError {
        CallError::Failed(e.code().into())
    }
}

/// A three-axis (x, y, z) [`Planner`] as the PIPES class `Planner`.
///
/// - constructor `Planner(vx, vy, vz, ax, ay, az, junction_deviation,
///   max_jump: f64)`: per-axis speed (mm/s) and acceleration (mm/s²) limits,
///   the junction deviation (mm) and one per-axis velocity-jump limit (mm/s,
///   `inf` for none);
/// - `Planner.line(x, y, z, feed: f64) -> queued: u32`;
/// - `Planner.arc(x, y, z, cx, cy: f64, clockwise: bool, feed: f64) ->
///   queued: u32`: an arc in the XY plane around (cx, cy), z linear, chords
///   within [`WIRE_CHORD_TOLERANCE`];
/// - `Planner.sample(stamp: u64) -> (stamp: u64, x, y, z: f64)`: the
///   planned position at a Timer's stamp, to pipe on to kinematics;
/// - `Planner.start(stamp: u64)`; `Planner.set_position(x, y, z: f64)`;
/// - `Planner.status() -> (queued: u32, executed: u64, idle: bool)`:
///   segments not yet finished, segments finished, at rest;
/// - `Planner.halt() -> (x, y, z: f64)`: a controlled stop along the
///   planned path from the last sampled stamp, dropping everything after
///   it; returns where the machine comes to rest;
/// - `Planner.set_feed_scale(k: f64)`: a feed override, `k` in (0, 10], on
///   every segment not yet started and those queued later (within the axis
///   limits);
/// - `Planner.set_vector_limits(speed, accel, min_cruise_ratio: f64)`: the
///   toolhead's largest speed |v| (mm/s) and acceleration |a| (mm/s²), `inf`
///   for none, and Klipper's minimum cruise ratio in [0, 1) (0 off), on top
///   of the per-axis limits ([`Planner::set_vector_limits`]; fails with 1).
///   A new block has none (`inf, inf, 0`).
///
/// The class's members are the methods of the same names. `queued` outputs
/// count segments not yet finished. Failures are `CallError::Failed(code)`
/// with the codes of [`PlanError::code`] (the constructor fails with 1).
#[derive(Clone, Debug)]
pub struct PlannerBlock {
    planner: Planner<3>,
}

impl PlannerBlock {
    /// The block around `planner` (e.g. one with its own queue capacity).
    pub fn from_planner(planner: Planner<3>) -> Self {
        PlannerBlock { planner }
    }

    /// The planner.
    pub fn planner(&self) -> &Planner<3> {
        &self.planner
    }

    /// The planner, mutably.
    pub fn planner_mut(&mut self) -> &mut Planner<3> {
        &mut self.planner
    }

    fn pending(&self) -> u32 {
        self.planner.stats().pending.try_into().unwrap_or(u32::MAX)
    }
}

#[pipes_core::class(name = "Planner")]
impl PlannerBlock {
    /// The constructor `Planner`: per-axis speed and acceleration limits,
    /// the junction deviation and the velocity-jump limit of every axis
    /// (see the type's docs); the default queue capacity.
    #[constructor]
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        vx: f64,
        vy: f64,
        vz: f64,
        ax: f64,
        ay: f64,
        az: f64,
        junction_deviation: f64,
        max_jump: f64,
    ) -> Result<PlannerBlock, PlanError> {
        let limits = Limits::new([vx, vy, vz], [ax, ay, az], junction_deviation)?
            .with_max_jump([max_jump; 3])?;
        Ok(PlannerBlock::from_planner(Planner::new(limits)?))
    }

    /// `Planner.line`: queue a line ([`Planner::line`]); returns the
    /// segments not yet finished.
    #[outputs = "queued"]
    pub fn line(&mut self, x: f64, y: f64, z: f64, feed: f64) -> Result<u32, PlanError> {
        self.planner.line([x, y, z], feed)?;
        Ok(self.pending())
    }

    /// `Planner.arc`: queue an XY arc around (cx, cy) ([`Planner::arc`]);
    /// returns the segments not yet finished.
    #[outputs = "queued"]
    #[allow(clippy::too_many_arguments)]
    pub fn arc(
        &mut self,
        x: f64,
        y: f64,
        z: f64,
        cx: f64,
        cy: f64,
        clockwise: bool,
        feed: f64,
    ) -> Result<u32, PlanError> {
        let arc = Arc {
            end: [x, y, z],
            plane: (0, 1),
            center: [cx, cy],
            clockwise,
            chord_tolerance: WIRE_CHORD_TOLERANCE,
        };
        self.planner.arc(&arc, feed)?;
        Ok(self.pending())
    }

    /// `Planner.sample`: the stamp and the planned position there
    /// ([`Planner::sample`]), in `f32` like the kinematics blocks and axis
    /// modules it pipes into (a receiver refuses an `f64` that `f32` cannot
    /// hold exactly; `f32` resolves 61 nm at 1 m).
    #[outputs = "stamp, x, y, z"]
    pub fn sample(&mut self, stamp: u64) -> Result<(u64, f32, f32, f32), PlanError> {
        let [x, y, z] = self.planner.sample(stamp)?;
        Ok((stamp, x as f32, y as f32, z as f32))
    }

    /// `Planner.start`: [`Planner::start`].
    pub fn start(&mut self, stamp: u64) -> Result<(), PlanError> {
        self.planner.start(stamp)
    }

    /// `Planner.set_position`: [`Planner::set_position`].
    pub fn set_position(&mut self, x: f64, y: f64, z: f64) -> Result<(), PlanError> {
        self.planner.set_position([x, y, z])
    }

    /// `Planner.status`: (segments not finished, finished, idle).
    #[outputs = "queued, executed, idle"]
    pub fn status(&self) -> (u32, u64, bool) {
        let s = self.planner.stats();
        (self.pending(), s.executed, s.idle)
    }

    /// `Planner.halt`: a controlled stop ([`Planner::halt`]); returns where
    /// the machine comes to rest.
    #[outputs = "x, y, z"]
    pub fn halt(&mut self) -> Result<(f64, f64, f64), PlanError> {
        let [x, y, z] = self.planner.halt()?;
        Ok((x, y, z))
    }

    /// `Planner.set_feed_scale`: [`Planner::set_feed_scale`] (fails with 9
    /// outside (0, 10]).
    pub fn set_feed_scale(&mut self, k: f64) -> Result<(), PlanError> {
        self.planner.set_feed_scale(k)
    }

    /// `Planner.set_vector_limits`: [`Planner::set_vector_limits`] with
    /// [`VectorLimits`] `{ max_speed: speed, max_accel: accel,
    /// min_cruise_ratio }` (fails with 1 on a bad value, changing nothing).
    pub fn set_vector_limits(
        &mut self,
        speed: f64,
        accel: f64,
        min_cruise_ratio: f64,
    ) -> Result<(), PlanError> {
        self.planner.set_vector_limits(VectorLimits {
            max_speed: speed,
            max_accel: accel,
            min_cruise_ratio,
            ..*self.planner.vector_limits()
        })
    }
}
