//! What a function says of itself: its documentation and its refusal
//! codes, read on demand.
//!
//! A refresh reads each function's summary (the first sentence of its
//! documentation, `pipes_core::docs`) in the same request as its
//! signature, `[2][02]`, so [`SomFunction::summary`](super::model::SomFunction)
//! costs no extra round trip. The whole text and the failure table are
//! longer (up to 2 KiB and a few KiB): [`Manager::describe`](super::Manager::describe)
//! and [`FunctionHandle::describe`](super::FunctionHandle::describe) ask
//! for them, `[2][07]`, when someone wants to read them (`osap describe`).
//!
//! A function from before the docs answers without their sections: it
//! reads as undocumented. One from before any section refuses the request
//! as malformed: it reads as undocumented and without a table.

use super::failure::{Failure, FailureTable};
use pipes_core::signature::SignatureView;

/// A function's documentation and failure table, as it sent them.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Description {
    /// The first sentence of its documentation (empty: none).
    pub summary: String,
    /// Its whole documentation, lines separated by `\n` (empty: none).
    pub docs: String,
    /// What each of its refusal codes means; `None` if it publishes no
    /// table (a function from before the tables).
    pub failures: Option<FailureTable>,
}

impl Description {
    /// What a reply to `[2][parts]` carried.
    pub(crate) fn from_view(s: &SignatureView<'_>) -> Description {
        Description {
            summary: s.summary().unwrap_or_default().to_owned(),
            docs: s.docs().unwrap_or_default().to_owned(),
            failures: s
                .failures()
                .map(|t| t.iter().map(Failure::from).collect::<Vec<_>>().into()),
        }
    }
}
