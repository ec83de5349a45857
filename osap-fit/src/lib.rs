//! Fitting process models to a machine's own measurements.
//!
//! A machine that can measure itself (a load cell on its filament, a
//! thermistor in its block, a current sense on its spindle) can replace
//! hand-tuned limits with a model fitted in place. This crate is the
//! process-independent part of that loop:
//!
//! - [`experiment`]: stepped experiments (a condition held, a setpoint
//!   stepped) and their reduction to steady values and transients;
//! - [`least_squares`]: any [`Model`](least_squares::Model) fitted by
//!   Levenberg–Marquardt, with parameter standard errors;
//! - [`lag`]: a first-order lag fitted over a whole record of input and
//!   output;
//! - [`melt`]: an extruder's melt-flow law and the flow it allows;
//! - [`step_response`]: a first-order process's time constant, seen
//!   through a sensor's own lag.
//!
//! The idea of fitting process models in situ and planning from them
//! comes from the thesis proposal "The End of GCode: Machine Architectures
//! for Feedback Systems Assembly" (its rheo-printer); docs/rheo.md shows
//! the method.

pub mod experiment;
pub mod lag;
pub mod least_squares;
pub mod melt;
pub mod step_response;

pub use least_squares::{fit, Fit, Model, Point};
pub use melt::{MeltFit, MeltModel};
pub use step_response::StepFit;

/// Why a fit could not be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum FitError {
    /// Too few measurements for the parameters.
    #[error("{points} measurements for {params} parameters: at least {} are needed", params + 1)]
    TooFewPoints {
        /// Measurements given.
        points: usize,
        /// Parameters to fit.
        params: usize,
    },
    /// Inputs of the wrong shape.
    #[error("{0}")]
    Shape(String),
    /// A value, or the model at some parameters, is not finite.
    #[error("not finite: {0}")]
    NotFinite(String),
    /// The measurements cannot tell the parameters apart.
    #[error("{0}")]
    Unidentifiable(String),
    /// The solver stopped without converging.
    #[error("the fit did not converge ({0})")]
    NoConvergence(String),
}
