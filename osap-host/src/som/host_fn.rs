//! PIPES functions defined by host code.
//!
//! A [`HostFunction`] is a signature and a Rust closure. Its signature
//! comes from Rust types ([`HostFunction::typed`]: the closure takes and
//! returns `#[derive(pipes_core::PipesArgs)]` structs, whose fields name
//! and type the arguments), or, for a list only known at run time (a
//! capture's chosen outputs), from a list ([`HostFunction::new`]: the
//! closure takes and returns [`Value`]s that own their data,
//! `Value<'static>`). Attached to a [`Host`] it runs as a real
//! `pipes_core::function::PipesFunction` port in that host's runtime: it
//! answers the whole function protocol, shows up in scans and in the system
//! object model, and pipes can run to it from module functions and from it
//! to module functions.

use super::SomError;
use crate::Host;
use pipes_core::control::{FailureCode, InputMode, OutputMode};
use pipes_core::docs::check_docs;
use pipes_core::export::PipesArgs;
use pipes_core::failure::{check_failures, Failure};
use pipes_core::function::{CallError, Implementation, Outputs, PipesFunction};
use pipes_core::signature::{Arg, Signature};
use pipes_core::{Type, Value};

/// Pipe slots of a host function.
pub const HOST_FN_PIPES: usize = 8;
/// Datagrams each pipe of a host function queues.
pub(crate) const HOST_FN_QUEUE: usize = 4;
/// Bytes of each input store, of the output buffer and of each queued
/// datagram of a host function: the largest value it takes, and the largest
/// set of outputs it sends.
pub const HOST_FN_STORE: usize = 512;

/// A host function's failure, which the caller sees as the call's error
/// (`CallError::Failed(code)` on the wire).
///
/// [`HostFnError::bad_input`] is the failure for inputs that are missing or
/// not of their declared type; any other code is the function's own
/// ([`FailureCode::Other`]), and what it means is the function's to say.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, thiserror::Error)]
#[error("host function failed with {code}")]
pub struct HostFnError {
    /// The failure code the caller receives.
    pub code: FailureCode,
}

impl HostFnError {
    /// A failure with the function's own code `code`. Codes pipes-core
    /// names (253 to 255) read as those failures on the caller's side.
    pub const fn new(code: u8) -> HostFnError {
        HostFnError {
            code: FailureCode::from_code(code),
        }
    }

    /// An input was missing or not of its declared type.
    pub const fn bad_input() -> HostFnError {
        HostFnError {
            code: FailureCode::InputDecodeFailed,
        }
    }
}

impl From<u8> for HostFnError {
    fn from(code: u8) -> HostFnError {
        HostFnError::new(code)
    }
}

impl From<FailureCode> for HostFnError {
    fn from(code: FailureCode) -> HostFnError {
        HostFnError { code }
    }
}

/// The body of a host function: the inputs (each already of its declared
/// type) in, the outputs (in output order, each converted to its declared
/// type under the conversion table) out, or the function's own failure.
pub type HostBody =
    Box<dyn FnMut(&[Value<'static>]) -> Result<Vec<Value<'static>>, HostFnError> + Send>;

struct HostImpl {
    sig: &'static Signature,
    body: HostBody,
    failures: &'static [Failure],
    docs: &'static str,
}

impl Implementation for HostImpl {
    fn signature(&self) -> &'static Signature {
        self.sig
    }

    fn failures(&self) -> &'static [Failure] {
        self.failures
    }

    fn docs(&self) -> &'static str {
        self.docs
    }

    fn call(&mut self, inputs: &[Value<'_>], outputs: &mut Outputs<'_>) -> Result<(), CallError> {
        let ins: Vec<Value<'static>> = inputs.iter().map(Value::to_owned_value).collect();
        let outs = (self.body)(&ins).map_err(|e| CallError::Failed(e.code))?;
        for (i, v) in outs.iter().enumerate() {
            let index = u8::try_from(i).map_err(|_| CallError::NoSuchOutput(u8::MAX))?;
            outputs.set(index, v)?;
        }
        Ok(())
    }
}

/// A PIPES function defined by host code (see the module docs).
pub struct HostFunction {
    sig: &'static Signature,
    body: HostBody,
    failures: &'static [Failure],
    docs: &'static str,
    input_mode: InputMode,
    output_mode: OutputMode,
}

impl std::fmt::Debug for HostFunction {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("HostFunction")
            .field("name", &self.sig.name)
            .field("input_mode", &self.input_mode)
            .field("output_mode", &self.output_mode)
            .finish()
    }
}

fn leak(s: &str) -> &'static str {
    Box::leak(s.to_string().into_boxed_str())
}

impl HostFunction {
    /// A function `name(inputs) -> outputs` running `body`, its signature
    /// given as lists: for arguments known only at run time. A signature
    /// known when the code is written comes from Rust types instead
    /// ([`typed`](Self::typed)).
    ///
    /// Signatures of PIPES functions are static (firmware declares them in
    /// flash), so the signature is leaked: a few bytes per function defined,
    /// for the life of the process. Refused: more than 8 inputs or outputs,
    /// or a name longer than 255 bytes.
    pub fn new(
        name: &str,
        inputs: &[(&str, Type)],
        outputs: &[(&str, Type)],
        body: impl FnMut(&[Value<'static>]) -> Result<Vec<Value<'static>>, HostFnError> + Send + 'static,
    ) -> Result<HostFunction, SomError> {
        let args = |list: &[(&str, Type)]| -> &'static [Arg] {
            let v: Vec<Arg> = list.iter().map(|(n, t)| Arg::new(leak(n), *t)).collect();
            Box::leak(v.into_boxed_slice())
        };
        HostFunction::with_signature(name, args(inputs), args(outputs), Box::new(body))
    }

    /// A function `name(I) -> O` running `body`: its inputs are `I`'s
    /// fields and its outputs `O`'s (names and types, in field order; `()`
    /// for none), each a `#[derive(pipes_core::PipesArgs)]` struct. The
    /// name may be made at run time (`machine.status.<module>`), and `body`
    /// may hold state.
    ///
    /// ```
    /// use osap_host::som::{HostFnError, HostFunction};
    ///
    /// #[derive(pipes_core::PipesArgs)]
    /// struct Reading {
    ///     time: u64,
    ///     value: f32,
    /// }
    ///
    /// let mut sum = 0.0;
    /// let f = HostFunction::typed("sum.x", move |r: Reading| {
    ///     sum += r.value;
    ///     Ok::<(), HostFnError>(())
    /// })?;
    /// assert_eq!(f.signature().inputs[1].name, "value");
    /// # Ok::<(), osap_host::som::SomError>(())
    /// ```
    ///
    /// Inputs that do not decode as `I` fail the call with
    /// [`HostFnError::bad_input`] before `body` runs. The name is leaked
    /// as with [`new`](Self::new); refused: a name longer than 255 bytes.
    pub fn typed<I, O>(
        name: &str,
        mut body: impl FnMut(I) -> Result<O, HostFnError> + Send + 'static,
    ) -> Result<HostFunction, SomError>
    where
        I: PipesArgs,
        O: PipesArgs,
    {
        let body = move |ins: &[Value<'static>]| {
            let inputs = I::from_values(ins).map_err(|_| HostFnError::bad_input())?;
            let out = body(inputs)?;
            Ok((0..O::ARGS.len())
                .map_while(|k| out.value(k).map(|v| v.to_owned_value()))
                .collect())
        };
        HostFunction::with_signature(name, I::ARGS, O::ARGS, Box::new(body))
    }

    fn with_signature(
        name: &str,
        inputs: &'static [Arg],
        outputs: &'static [Arg],
        body: HostBody,
    ) -> Result<HostFunction, SomError> {
        let sig = Signature {
            name: leak(name),
            inputs,
            outputs,
        };
        sig.check().map_err(|e| SomError::BadDefinition {
            name: name.to_string(),
            detail: e.to_string(),
        })?;
        Ok(HostFunction {
            sig: Box::leak(Box::new(sig)),
            body,
            failures: &[],
            docs: "",
            input_mode: InputMode::default(),
            output_mode: OutputMode::default(),
        })
    }

    /// The same function starting in input mode `mode`. A host function is
    /// polled when its runtime is (on packets and commands), not on a timer
    /// of its own, so [`InputMode::OnTimer`] fires late on an idle host.
    pub fn with_input_mode(mut self, mode: InputMode) -> HostFunction {
        self.input_mode = mode;
        self
    }

    /// The same function publishing `failures` with its signature, so a
    /// host names its refusals ([`HostFnError`]'s codes) by them. Refused:
    /// a table beyond `pipes_core::failure::check_failures`'s limits.
    pub fn with_failures(mut self, failures: &'static [Failure]) -> Result<HostFunction, SomError> {
        check_failures(failures).map_err(|e| SomError::BadDefinition {
            name: self.sig.name.to_string(),
            detail: e.to_string(),
        })?;
        self.failures = failures;
        Ok(self)
    }

    /// The same function publishing `docs` with its signature: what it
    /// does, its first sentence a summary that `osap scan -f` shows (see
    /// `pipes_core::docs`; `osap describe` prints the whole text). Leaked
    /// as the name is. Refused: a text longer than
    /// [`MAX_DOCS`](pipes_core::docs::MAX_DOCS) bytes.
    pub fn with_docs(mut self, docs: &str) -> Result<HostFunction, SomError> {
        check_docs(docs).map_err(|e| SomError::BadDefinition {
            name: self.sig.name.to_string(),
            detail: e.to_string(),
        })?;
        self.docs = leak(docs);
        Ok(self)
    }

    /// The same function starting in output mode `mode`.
    pub fn with_output_mode(mut self, mode: OutputMode) -> HostFunction {
        self.output_mode = mode;
        self
    }

    /// Its name.
    pub fn name(&self) -> &'static str {
        self.sig.name
    }

    /// Its signature.
    pub fn signature(&self) -> &'static Signature {
        self.sig
    }

    /// The function as a port object, for [`Host::attach_port`]: a control
    /// port followed by [`HOST_FN_PIPES`] pipe ports.
    pub fn into_port(self) -> Result<Box<dyn osap_core::port::Port + Send>, SomError> {
        let name = self.sig.name;
        let mut f: PipesFunction<HostImpl, HOST_FN_PIPES, HOST_FN_QUEUE, HOST_FN_STORE> =
            PipesFunction::new(HostImpl {
                sig: self.sig,
                body: self.body,
                failures: self.failures,
                docs: self.docs,
            })
            .map_err(|e| SomError::BadDefinition {
                name: name.to_string(),
                detail: e.to_string(),
            })?;
        f.set_input_mode(self.input_mode);
        f.set_output_mode(self.output_mode);
        Ok(Box::new(f))
    }
}

/// Attaches `function` to `host`'s runtime; returns its control port's
/// index (its pipe ports follow). Works on any host, not only a manager's:
/// a process may run several runtimes.
pub async fn attach_function(host: &Host, function: HostFunction) -> Result<u16, SomError> {
    Ok(host.attach_port(function.into_port()?).await?)
}
