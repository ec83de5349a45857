//! MAXL motion tracks (no_std, no alloc).
//!
//! A [`Track`] holds uniform cubic B-spline control points stamped in
//! synchronized time at a fixed power-of-two [`Interval`], evaluates position,
//! velocity, acceleration and jerk (Equation 2.1) in physical units with either
//! an `f32` or an integer-only fixed-point evaluator ([`Fx`]), fills a single
//! missing point, reports larger gaps, and falls back to a jerk-limited stop
//! ([`TrackStatus::Backstop`]) when points stop arriving.
//!
//! See `docs/maxl.md` for the fixed-point format and its error bound.
#![no_std]
#![forbid(unsafe_code)]

#[cfg(test)]
extern crate std;

pub mod backstop;
pub mod eval;
pub mod track;

pub use backstop::{BackstopLimits, StopProfile};
pub use eval::{eval_f64, Fx, KinF32, KinF64, KinFx, Point};
pub use track::{
    EvalError, Interval, IntervalError, PushError, PushOutcome, Sample, Track, TrackStatus,
};
