//! MAXL motion tracks (no_std, no alloc).
//!
//! A [`Track`] holds uniform cubic B-spline control points stamped in
//! synchronized time at a fixed power-of-two [`Interval`], evaluates position,
//! velocity, acceleration and jerk (Equation 2.1) in physical units with either
//! an `f32` or an integer-only fixed-point evaluator ([`Fx`]), fills a single
//! missing point, reports larger gaps, and falls back to a jerk-limited stop
//! ([`TrackStatus::Backstop`]) when points stop arriving.
//!
//! Beside position tracks: [`limit`] clamps incoming points to an axis's
//! velocity, acceleration and jerk limits, [`step`] turns a fixed-point
//! position into step/direction events, [`phase`] drives a stepper's two
//! coils from a sine table, and [`level`] holds level and event tracks
//! (laser power, a solenoid, a camera trigger) on the same time base.
//!
//! With the `std` feature, [`blocks`] adds the host's motion blocks as PIPES
//! classes: timer, one-dof axes, chirp, a lookahead planner, an optimizer
//! interface, kinematics, bed levelling and a reference interpolator.
//!
//! See `docs/maxl.md` for the fixed-point format and its error bound.
#![cfg_attr(not(feature = "std"), no_std)]
#![forbid(unsafe_code)]
// Lints as policy: documented, printable, and `pub` only where reachable.
#![warn(missing_docs, missing_debug_implementations, unreachable_pub)]

#[cfg(all(test, not(feature = "std")))]
extern crate std;

pub mod backstop;
pub mod bed;
pub mod eval;
pub mod level;
pub mod limit;
pub mod phase;
pub mod step;
pub mod track;

#[cfg(feature = "std")]
pub mod blocks;
#[cfg(feature = "std")]
pub mod motor;

pub use backstop::{BackstopLimits, StopProfile};
pub use eval::{eval_f64, Fx, KinF32, KinF64, KinFx, Point};
pub use eval::{TickEval, TickEvalError, MAX_TICKS_PER_SEGMENT};
pub use level::{EventTrack, Fired, LevelTrack, TimedPushError};
pub use limit::{AxisLimits, Clamped, LimitError, LimitStats, Limited, Limiter, RawLimits};
pub use phase::{Coils, PhaseOut};
pub use step::{Dir, PioPacker, QueueFull, Rounding, StepEvent, StepGen, StepQueue, StepStats};
pub use track::{
    EvalError, Interval, IntervalError, PushError, PushOutcome, Sample, Track, TrackStatus,
};
