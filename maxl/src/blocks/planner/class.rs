//! The planner's PIPES class (wire API), written out by hand because its
//! constructor and members fail with codes ([`PlanError::code`]).

use pipes_core::class::PipesClass;
use pipes_core::export::{input, PipesOutputs, NO_SUCH_MEMBER};
use pipes_core::function::{CallError, Outputs};
use pipes_core::signature::{Arg, Signature};
use pipes_core::{ScalarType, Type, Value};

use super::{Arc, Limits, PlanError, Planner};

const F64: Type = Type::Scalar(ScalarType::F64);
const U64: Type = Type::Scalar(ScalarType::U64);
const U32: Type = Type::Scalar(ScalarType::U32);
const BOOL: Type = Type::Scalar(ScalarType::Bool);

/// Chord tolerance (mm) of arcs queued through the wire API.
pub const WIRE_CHORD_TOLERANCE: f64 = 0.002;

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
///   segments not yet finished, segments finished, at rest.
///
/// `queued` outputs count segments not yet finished. Failures are
/// `CallError::Failed(code)` with the codes of [`PlanError::code`].
#[derive(Clone, Debug)]
pub struct PlannerBlock {
    planner: Planner<3>,
}

impl PlannerBlock {
    /// The block around `planner`.
    pub fn new(planner: Planner<3>) -> Self {
        PlannerBlock { planner }
    }

    /// The block with the constructor's limits (see the type's docs).
    pub fn from_limits(
        vel: [f64; 3],
        acc: [f64; 3],
        junction_deviation: f64,
        max_jump: f64,
    ) -> Result<Self, PlanError> {
        let limits = Limits::new(vel, acc, junction_deviation)?.with_max_jump([max_jump; 3])?;
        Ok(PlannerBlock::new(Planner::new(limits)?))
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

    /// `Planner.line`: queue a line; returns the segments not yet finished.
    pub fn wire_line(&mut self, x: f64, y: f64, z: f64, feed: f64) -> Result<u32, PlanError> {
        self.planner.line([x, y, z], feed)?;
        Ok(self.pending())
    }

    /// `Planner.arc`: queue an XY arc; returns the segments not yet finished.
    #[allow(clippy::too_many_arguments)]
    pub fn wire_arc(
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

    /// `Planner.sample`: the stamp and the planned position there.
    pub fn wire_sample(&mut self, stamp: u64) -> Result<(u64, f64, f64, f64), PlanError> {
        let [x, y, z] = self.planner.sample(stamp)?;
        Ok((stamp, x, y, z))
    }

    /// `Planner.status`: (segments not finished, finished, idle).
    pub fn wire_status(&self) -> (u32, u64, bool) {
        let s = self.planner.stats();
        (self.pending(), s.executed, s.idle)
    }
}

static CONSTRUCTOR: Signature = Signature {
    name: "Planner",
    inputs: &[
        Arg::new("vx", F64),
        Arg::new("vy", F64),
        Arg::new("vz", F64),
        Arg::new("ax", F64),
        Arg::new("ay", F64),
        Arg::new("az", F64),
        Arg::new("junction_deviation", F64),
        Arg::new("max_jump", F64),
    ],
    outputs: &[],
};
static LINE: Signature = Signature {
    name: "Planner.line",
    inputs: &[
        Arg::new("x", F64),
        Arg::new("y", F64),
        Arg::new("z", F64),
        Arg::new("feed", F64),
    ],
    outputs: &[Arg::new("queued", U32)],
};
static ARC: Signature = Signature {
    name: "Planner.arc",
    inputs: &[
        Arg::new("x", F64),
        Arg::new("y", F64),
        Arg::new("z", F64),
        Arg::new("cx", F64),
        Arg::new("cy", F64),
        Arg::new("clockwise", BOOL),
        Arg::new("feed", F64),
    ],
    outputs: &[Arg::new("queued", U32)],
};
static SAMPLE: Signature = Signature {
    name: "Planner.sample",
    inputs: &[Arg::new("stamp", U64)],
    outputs: &[
        Arg::new("stamp", U64),
        Arg::new("x", F64),
        Arg::new("y", F64),
        Arg::new("z", F64),
    ],
};
static START: Signature = Signature {
    name: "Planner.start",
    inputs: &[Arg::new("stamp", U64)],
    outputs: &[],
};
static SET_POSITION: Signature = Signature {
    name: "Planner.set_position",
    inputs: &[Arg::new("x", F64), Arg::new("y", F64), Arg::new("z", F64)],
    outputs: &[],
};
static STATUS: Signature = Signature {
    name: "Planner.status",
    inputs: &[],
    outputs: &[
        Arg::new("queued", U32),
        Arg::new("executed", U64),
        Arg::new("idle", BOOL),
    ],
};

fn failed(e: PlanError) -> CallError {
    CallError::Failed(e.code())
}

impl PipesClass for PlannerBlock {
    const NAME: &'static str = "Planner";
    const CONSTRUCTOR: &'static Signature = &CONSTRUCTOR;
    const MEMBERS: &'static [&'static Signature] =
        &[&LINE, &ARC, &SAMPLE, &START, &SET_POSITION, &STATUS];

    fn construct(v: &[Value<'_>]) -> Result<Self, CallError> {
        let f = |i| input::<f64>(v, i);
        PlannerBlock::from_limits([f(0)?, f(1)?, f(2)?], [f(3)?, f(4)?, f(5)?], f(6)?, f(7)?)
            .map_err(failed)
    }

    fn call_member(
        &mut self,
        index: usize,
        v: &[Value<'_>],
        out: &mut Outputs<'_>,
    ) -> Result<(), CallError> {
        let f = |i| input::<f64>(v, i);
        match index {
            0 => {
                let q = self.wire_line(f(0)?, f(1)?, f(2)?, f(3)?).map_err(failed)?;
                (q,).write(out)
            }
            1 => {
                let cw = input::<bool>(v, 5)?;
                let q = self
                    .wire_arc(f(0)?, f(1)?, f(2)?, f(3)?, f(4)?, cw, f(6)?)
                    .map_err(failed)?;
                (q,).write(out)
            }
            2 => {
                let r = self.wire_sample(input::<u64>(v, 0)?).map_err(failed)?;
                r.write(out)
            }
            3 => self.planner.start(input::<u64>(v, 0)?).map_err(failed),
            4 => self
                .planner
                .set_position([f(0)?, f(1)?, f(2)?])
                .map_err(failed),
            5 => self.wire_status().write(out),
            _ => Err(CallError::Failed(NO_SUCH_MEMBER)),
        }
    }
}
