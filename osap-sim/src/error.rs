//! The simulator's error type: bad configuration gets a message that says
//! what is wrong and where.

use std::fmt;

/// Why a simulation could not be built or a description not read.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum SimError {
    /// A parameter, node or link description is invalid (or a topology
    /// file could not be read).
    Config(String),
    /// Writing an output file (a plot, a report) failed.
    Output(String),
}

impl SimError {
    /// A configuration error with this message.
    pub fn config(message: impl Into<String>) -> Self {
        SimError::Config(message.into())
    }
}

impl fmt::Display for SimError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SimError::Config(m) => write!(f, "invalid simulation configuration: {m}"),
            SimError::Output(m) => write!(f, "output failed: {m}"),
        }
    }
}

impl std::error::Error for SimError {}
