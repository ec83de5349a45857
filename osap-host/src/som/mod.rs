//! The system object model (SOM) and the manager that builds and edits it.
//!
//! - [`Manager`]: scans the network, asks every PIPES function for its
//!   signature, modes and pipes, and keeps the result as a [`Som`]. It
//!   connects functions with pipes ([`Manager::connect_named`] by argument
//!   name, [`Manager::connect`] by index) over the shortest
//!   route between their runtimes, checked against the conversion table, and
//!   disconnects them and sets their modes, keeping the model up to date.
//! - [`Som`] (in [`model`]): runtimes, links, functions, pipes and classes,
//!   as JSON (layout in `docs/som.md`).
//! - [`FunctionHandle`]: calls a function over the network from async Rust
//!   with [`Value`]s, before any proxy is generated.
//! - [`HostFunction`]: a function a script defines on the host runtime (or
//!   any [`Host`](crate::Host)); it is a real PIPES function, so pipes run
//!   from module functions to it and from it to module functions.
//! - [`attach_class`]: a PIPES class (`#[pipes_core::class]`) a script
//!   runs on a host runtime, its state shared with the script through a
//!   [`ClassHandle`]; its members are functions like any other.
//!
//! ```no_run
//! # async fn demo() -> Result<(), osap_host::som::SomError> {
//! use osap_host::som::{FnRef, Manager, PipeOptions, Value};
//! use osap_host::{Host, HostConfig};
//! let host = Host::start(HostConfig::default())?;
//! let mut manager = Manager::new(&host).await?;
//! manager.refresh().await?;
//! println!("{}", manager.som().to_json());
//! let (x, y) = (FnRef::new("x", "encoder"), FnRef::new("y", "stepper"));
//! manager.connect(&x, &y, &[0], &[0], PipeOptions::default()).await?;
//! let out = manager.function(&x)?.call(&[Value::F32(1.0)]).await?;
//! # let _ = out; Ok(()) }
//! ```

mod blocks;
mod cache;
mod description;
pub mod failure;
pub mod graph;
mod handle;
mod host_class;
mod host_fn;
mod manager;
pub mod model;
mod named;
pub mod proxy;
mod value;

pub use blocks::BlockClassInfo;
pub use cache::{SomCache, CACHE_VERSION};
pub use description::Description;
pub use handle::{describe, FunctionHandle};
pub use host_class::{attach_class, ClassHandle, SharedState};
pub use host_fn::{
    attach_function, HostBody, HostFnError, HostFunction, HOST_FN_PIPES, HOST_FN_STORE,
};
pub use manager::{Disconnect, Manager, ManagerOptions, PipeOptions, RefreshReport};
pub use model::{RuntimeLookupError, Som, SOM_VERSION};
pub use pipes_core::pipe::PipeStats;
/// PIPES values, owning their data as `Value<'static>` (pipes-core's type).
pub use pipes_core::{Element, Text, Value};
pub use value::{parse_value, value_json, value_text, ParseValueError};

use crate::HostError;
use pipes_core::control::ControlError;
use std::fmt;

/// A function named by its runtime's name and its own.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct FnRef {
    /// The runtime's name.
    pub runtime: String,
    /// The function's name.
    pub function: String,
}

impl FnRef {
    /// Function `function` on runtime `runtime`.
    pub fn new(runtime: impl Into<String>, function: impl Into<String>) -> FnRef {
        FnRef {
            runtime: runtime.into(),
            function: function.into(),
        }
    }
}

impl fmt::Display for FnRef {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "function {:?} on runtime {:?}",
            self.function, self.runtime
        )
    }
}

/// A remote error as [`SomError::Remote`] prints it: a named failure, or
/// the error as it is.
fn refusal(error: &ControlError, failure: &Option<Box<failure::Failure>>) -> String {
    match (error, failure) {
        (ControlError::CallFailed(_), Some(f)) => f.to_string(),
        _ => error.to_string(),
    }
}

/// What can go wrong building or using the system object model. Every
/// error about a function names it and its runtime.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SomError {
    /// The host runtime or its network failed (outside any one function).
    #[error(transparent)]
    Host(#[from] HostError),
    /// No runtime has this name in the model.
    #[error("no runtime named {0:?} in the system object model (refresh it?)")]
    NoSuchRuntime(String),
    /// More than one runtime has this name.
    #[error("{count} runtimes are named {name:?}: rename them to tell them apart")]
    AmbiguousRuntime {
        /// The name.
        name: String,
        /// How many have it.
        count: usize,
    },
    /// The runtime has no function with this name.
    #[error("{0}: no such function in the system object model")]
    NoSuchFunction(FnRef),
    /// A function answered a request with an error. A failure code of an
    /// osap-rs module's function prints by name (`QueueFull (code 8): ..`).
    #[error("{function}: {request} refused: {}", refusal(error, failure))]
    Remote {
        /// The function.
        function: FnRef,
        /// What was asked.
        request: &'static str,
        /// Its answer.
        error: ControlError,
        /// What `error`'s failure code means, when it is one
        /// ([`ControlError::CallFailed`]) and the host knows the device's
        /// codes (see [`failure`]). Boxed: errors stay small.
        failure: Option<Box<failure::Failure>>,
    },
    /// A request to a function got no reply, or could not be sent.
    #[error("{function}: {request} failed: {source}")]
    Network {
        /// The function.
        function: FnRef,
        /// What was asked.
        request: &'static str,
        /// Why.
        #[source]
        source: HostError,
    },
    /// A function's reply did not parse or did not answer the request.
    #[error("{function}: malformed reply to {request}: {detail}")]
    Malformed {
        /// The function.
        function: FnRef,
        /// What was asked.
        request: &'static str,
        /// What was wrong with it.
        detail: String,
    },
    /// Arguments given for a call or a dataflow push do not fit the
    /// function's signature.
    #[error("{function}: {detail}")]
    BadArguments {
        /// The function.
        function: FnRef,
        /// What does not fit.
        detail: String,
    },
    /// An output's type does not convert to the input's it would be piped to.
    #[error("{0}")]
    TypeMismatch(Box<TypeMismatch>),
    /// An argmap names outputs or inputs that do not exist, or is malformed.
    #[error("pipe from {source_fn} to {dest_fn}: {detail}")]
    Argmap {
        /// The source function.
        source_fn: FnRef,
        /// The destination function.
        dest_fn: FnRef,
        /// What is wrong.
        detail: String,
    },
    /// A pipe named by its arguments ([`Manager::connect_named`]) names an
    /// output or an input its function does not have: both ends, and what
    /// is missing. Boxed: errors stay small.
    #[error("{0}")]
    NoSuchArgument(Box<NoSuchArgument>),
    /// No route joins the two runtimes over the links the model knows.
    #[error("no route from runtime {from:?} to runtime {to:?} over the known links")]
    NoRoute {
        /// The source runtime.
        from: String,
        /// The destination runtime.
        to: String,
    },
    /// The function has no pipe matching what was asked to disconnect.
    #[error("{function}: {detail}")]
    NoSuchPipe {
        /// The source function.
        function: FnRef,
        /// What was looked for.
        detail: String,
    },
    /// A runtime's block manager refused a request.
    #[error("{runtime}: {request} refused: {error}")]
    Block {
        /// The runtime.
        runtime: String,
        /// What was asked.
        request: &'static str,
        /// Why it refused.
        error: pipes_core::manager::ManagerError,
    },
    /// The runtime has no block manager (a firmware from before blocks, or
    /// a host).
    #[error("runtime {0:?} cannot make blocks: it has no block manager (a firmware from before blocks?)")]
    NoBlockManager(String),
    /// A host function's definition is refused.
    #[error("host function {name:?}: {detail}")]
    BadDefinition {
        /// The function's name.
        name: String,
        /// What is wrong.
        detail: String,
    },
}

/// A pipe's pair of argument names of which one is not its function's
/// ([`SomError::NoSuchArgument`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("pipe from {source_fn} output {output:?} to {dest_fn} input {input:?}: {detail}")]
pub struct NoSuchArgument {
    /// The source function.
    pub source_fn: FnRef,
    /// The output's name.
    pub output: String,
    /// The destination function.
    pub dest_fn: FnRef,
    /// The input's name.
    pub input: String,
    /// Which is missing, and what the function has instead.
    pub detail: String,
}

/// A pair of a pipe's argmap whose types do not convert
/// ([`SomError::TypeMismatch`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "cannot pipe {source_fn} output {output} ({from}) to {dest_fn} input {input} ({to}): {reason}"
)]
pub struct TypeMismatch {
    /// The source function.
    pub source_fn: FnRef,
    /// Its output index.
    pub output: u8,
    /// The output's type name.
    pub from: String,
    /// The destination function.
    pub dest_fn: FnRef,
    /// Its input index.
    pub input: u8,
    /// The input's type name.
    pub to: String,
    /// Why the conversion is refused.
    pub reason: String,
}
