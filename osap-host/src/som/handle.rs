//! Talking to a function's control port: the request/reply client the
//! manager uses, and [`FunctionHandle`] for RPC from async Rust.

use super::description::Description;
use super::failure::{lookup, Failure, FailureTable};
use super::model::SomArg;
use super::{FnRef, SomError, Value};
use crate::{HostError, PortHandle, HOST_MTU};
use osap_core::codec::Writer;
use osap_core::route::Route;
use pipes_core::control::{ControlError, ControlKey, Reply, ReplyBody, Request};
use pipes_core::convert::{rule, Rule};
use pipes_core::failure::SignatureParts;
use pipes_core::{Args, ArgsWriter, Type};
use std::collections::{HashMap, HashSet};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// Sends function-protocol requests through one host port.
#[derive(Clone)]
pub(crate) struct Control {
    pub(crate) port: Arc<PortHandle>,
    pub(crate) timeout: Duration,
    pub(crate) retries: u8,
    /// Failure tables read so far, by route and control port (`None`: the
    /// function published none, or did not answer): each is read once,
    /// when its function first refuses with a failure code.
    pub(crate) tables: Arc<Mutex<Tables>>,
    /// Routes whose functions refused `[2][parts]` as malformed (firmware
    /// from before the signature's sections): their functions are asked
    /// for the signature alone, `[2]`, until the next refresh.
    pub(crate) no_sections: Arc<Mutex<HashSet<Route>>>,
}

/// Failure tables by route and control port.
pub(crate) type Tables = HashMap<(Route, u16), Option<FailureTable>>;

/// Where a function's control port is, from the host.
#[derive(Debug, Clone)]
pub(crate) struct Target {
    pub(crate) function: FnRef,
    pub(crate) route: Route,
    pub(crate) port: u16,
}

/// A successful reply's bytes (key and status included), parsed on demand.
pub(crate) struct ReplyBytes(Vec<u8>);

impl ReplyBytes {
    /// The reply's bytes.
    pub(crate) fn into_bytes(self) -> Vec<u8> {
        self.0
    }

    /// The reply's body, or the function's error.
    pub(crate) fn body(
        &self,
        at: &Target,
        request: &'static str,
        key: ControlKey,
    ) -> Result<ReplyBody<'_>, SomError> {
        let reply = Reply::parse(&self.0).map_err(|e| SomError::Malformed {
            function: at.function.clone(),
            request,
            detail: e.to_string(),
        })?;
        match reply.result {
            Err(error) => Err(SomError::Remote {
                function: at.function.clone(),
                request,
                // Named by the caller that can ask the function
                // ([`Control::name_refusal`]).
                failure: None,
                error,
            }),
            Ok(_) if reply.key != key.to_u8() => Err(SomError::Malformed {
                function: at.function.clone(),
                request,
                detail: format!("answers key {} instead of {}", reply.key, key.to_u8()),
            }),
            Ok(body) => Ok(body),
        }
    }
}

impl Control {
    /// Sends `request` and waits for its reply. Idempotent requests are
    /// retried on timeouts (up to `retries` times); others are sent once,
    /// so a lost reply never installs a pipe twice.
    pub(crate) async fn ask(
        &self,
        at: &Target,
        what: &'static str,
        request: &Request<'_>,
        idempotent: bool,
    ) -> Result<ReplyBytes, SomError> {
        let mut buf = vec![0u8; HOST_MTU];
        let mut w = Writer::new(&mut buf);
        request.encode(&mut w).map_err(|e| SomError::BadArguments {
            function: at.function.clone(),
            detail: format!("{what}: the request cannot be written: {e}"),
        })?;
        let n = w.len();
        buf.truncate(n);
        self.ask_raw(at, what, &buf, idempotent).await
    }

    /// The failure table the function at `at` publishes with its
    /// signature (`[2][1]`, `pipes_core::failure`), read once and kept
    /// until [`forget_tables`](Self::forget_tables). `None` if it publishes
    /// none: a function from before the tables refuses the request as
    /// malformed. A function that does not answer is asked once (no
    /// retries: a refusal waits for it) and not again; its codes stay
    /// numbers.
    pub(crate) async fn failure_table(&self, at: &Target) -> Option<FailureTable> {
        let key = (at.route, at.port);
        if let Some(known) = self.tables().get(&key) {
            return known.clone();
        }
        let request = Request::Describe(SignatureParts::FAILURES);
        let table = match self.ask(at, "get failure table", &request, false).await {
            Ok(reply) => match Reply::parse(&reply.0).map(|r| r.result) {
                Ok(Ok(ReplyBody::Signature(s))) => s
                    .failures()
                    .map(|t| t.iter().map(Failure::from).collect::<Vec<_>>().into()),
                _ => None,
            },
            Err(_) => None,
        };
        self.tables().insert(key, table.clone());
        table
    }

    /// The function at `at`'s documentation and failure table, asked for
    /// with its signature (`[2][07]`, one request, retried on timeouts).
    /// A function that refuses the request as malformed (one from before
    /// the signature's sections) is described as having neither. The table
    /// read is kept as [`failure_table`](Self::failure_table) keeps it.
    pub(crate) async fn describe(&self, at: &Target) -> Result<Description, SomError> {
        let parts = SignatureParts::FAILURES
            .with(SignatureParts::SUMMARY)
            .with(SignatureParts::DOCS);
        let what = "get signature with its docs";
        let reply = self.ask(at, what, &Request::Describe(parts), true).await?;
        let d = match reply.body(at, what, ControlKey::GetSignature) {
            Ok(ReplyBody::Signature(s)) => Description::from_view(&s),
            Ok(other) => {
                return Err(SomError::Malformed {
                    function: at.function.clone(),
                    request: what,
                    detail: format!("unexpected reply {other:?}"),
                })
            }
            Err(SomError::Remote {
                error: ControlError::Malformed,
                ..
            }) => Description::default(),
            Err(e) => return Err(e),
        };
        self.tables()
            .insert((at.route, at.port), d.failures.clone());
        Ok(d)
    }

    /// Whether the functions on `route` refused `[2][parts]` as malformed
    /// since the last refresh.
    pub(crate) fn without_sections(&self, route: &Route) -> bool {
        self.no_sections
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .contains(route)
    }

    /// Remembers that the functions on `route` do not read `[2][parts]`.
    pub(crate) fn set_without_sections(&self, route: Route) {
        self.no_sections
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .insert(route);
    }

    /// Forgets every failure table read and which runtimes read no
    /// sections (a new scan may find other functions at the same ports).
    pub(crate) fn forget_tables(&self) {
        self.no_sections
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clear();
        self.tables().clear();
    }

    fn tables(&self) -> std::sync::MutexGuard<'_, Tables> {
        // A poisoned map is still a cache: take it.
        self.tables.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// `error` with its failure code named, if it is a function's own
    /// refusal ([`ControlError::CallFailed`]) and the function's table
    /// names the code.
    pub(crate) async fn name_refusal(&self, at: &Target, error: SomError) -> SomError {
        match error {
            SomError::Remote {
                function,
                request,
                error: ControlError::CallFailed(code),
                failure: None,
            } => SomError::Remote {
                failure: self
                    .failure_table(at)
                    .await
                    .and_then(|t| lookup(&t, code.code()))
                    .map(Box::new),
                function,
                request,
                error: ControlError::CallFailed(code),
            },
            other => other,
        }
    }

    /// [`ask`](Self::ask) with the request already encoded.
    pub(crate) async fn ask_raw(
        &self,
        at: &Target,
        what: &'static str,
        body: &[u8],
        idempotent: bool,
    ) -> Result<ReplyBytes, SomError> {
        let mut attempt = 0;
        loop {
            match self
                .port
                .request(&at.route, at.port, body, self.timeout)
                .await
            {
                Ok(d) => return Ok(ReplyBytes(d.body)),
                Err(HostError::Timeout { .. }) if idempotent && attempt < self.retries => {
                    attempt += 1
                }
                Err(source) => {
                    return Err(SomError::Network {
                        function: at.function.clone(),
                        request: what,
                        source,
                    })
                }
            }
        }
    }
}

/// Writes `[key]` then an argument list of `args` (index, value).
fn encode_args(
    function: &FnRef,
    key: ControlKey,
    args: &[(u8, &Value<'static>)],
) -> Result<Vec<u8>, SomError> {
    let bad = |detail: String| SomError::BadArguments {
        function: function.clone(),
        detail,
    };
    let mut buf = vec![0u8; HOST_MTU];
    let mut w = Writer::new(&mut buf);
    w.u8(key.to_u8())
        .map_err(|e| bad(format!("cannot write the request: {e}")))?;
    let mut aw = ArgsWriter::new(&mut w).map_err(|e| bad(e.to_string()))?;
    for (i, v) in args {
        aw.push(*i, v).map_err(|e| {
            bad(format!(
                "argument {i}: {e} (the request must fit one packet)"
            ))
        })?;
    }
    aw.finish().map_err(|e| bad(e.to_string()))?;
    let n = w.len();
    buf.truncate(n);
    Ok(buf)
}

/// A PIPES function reachable from the host, for calls from async Rust.
///
/// Made by [`Manager::function`](super::Manager::function) from the system
/// object model; cheap to clone. Calls travel as sequential requests from
/// the manager's port and are never retried (a call may have effects).
#[derive(Clone)]
pub struct FunctionHandle {
    control: Control,
    target: Target,
    inputs: Vec<SomArg>,
    outputs: Vec<SomArg>,
}

impl std::fmt::Debug for FunctionHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FunctionHandle")
            .field("function", &self.target.function)
            .field("route", &self.target.route.to_string())
            .field("port", &self.target.port)
            .finish()
    }
}

impl FunctionHandle {
    pub(crate) fn new(
        control: Control,
        target: Target,
        inputs: Vec<SomArg>,
        outputs: Vec<SomArg>,
    ) -> FunctionHandle {
        FunctionHandle {
            control,
            target,
            inputs,
            outputs,
        }
    }

    /// The function's runtime and name.
    pub fn function(&self) -> &FnRef {
        &self.target.function
    }

    /// Its inputs, by index.
    pub fn inputs(&self) -> &[SomArg] {
        &self.inputs
    }

    /// Its outputs, by index.
    pub fn outputs(&self) -> &[SomArg] {
        &self.outputs
    }

    /// The route from the host to its runtime.
    pub fn route(&self) -> Route {
        self.target.route
    }

    /// Its control port's index.
    pub fn port(&self) -> u16 {
        self.target.port
    }

    /// The failure table the function publishes with its signature: what
    /// each of its refusal codes means, as the device names it. Read once
    /// and kept (until the next scan); `None` if the function publishes
    /// none or does not answer.
    pub async fn failure_table(&self) -> Option<FailureTable> {
        self.control.failure_table(&self.target).await
    }

    /// What the function says of itself: its documentation (summary and
    /// whole text) and its failure table, read from it now (one request;
    /// see [`Description`]). The table is kept as
    /// [`failure_table`](Self::failure_table) keeps it.
    pub async fn describe(&self) -> Result<Description, SomError> {
        self.control.describe(&self.target).await
    }

    /// The same handle waiting up to `timeout` for each reply.
    pub fn with_timeout(mut self, timeout: Duration) -> FunctionHandle {
        self.control.timeout = timeout;
        self
    }

    fn check_arg(&self, index: u8, value: &Value<'static>) -> Result<(), SomError> {
        let bad = |detail: String| SomError::BadArguments {
            function: self.target.function.clone(),
            detail,
        };
        let arg = self
            .inputs
            .get(usize::from(index))
            .ok_or_else(|| bad(format!("no input {index} ({})", describe(&self.inputs))))?;
        let Some(to) = arg.ty() else {
            // A type this build does not know: let the function judge.
            return Ok(());
        };
        let from = value.ty();
        if let Rule::Never(reason) = rule(&from, &to) {
            return Err(bad(format!(
                "input {index} ({}: {}) cannot take a {from}: {reason}",
                arg.name, arg.type_name
            )));
        }
        Ok(())
    }

    /// Calls the function with one value per input (in input order) and
    /// returns its outputs (in output order). The outputs also go down the
    /// function's pipes, so a call drives dataflow.
    ///
    /// Values are converted to the inputs' types by the function, under the
    /// conversion table: an `f32` may be given for an `f64` input, never a
    /// value that would change. Errors name the function and its runtime:
    /// wrong argument count or types (checked here first), the function's
    /// own refusal ([`SomError::Remote`], e.g. a lossy conversion or the
    /// function failing), no reply, or a malformed reply.
    pub async fn call(&self, args: &[Value<'static>]) -> Result<Vec<Value<'static>>, SomError> {
        self.call_once_or_more(args, false).await
    }

    /// [`call`](Self::call) for a function whose effect does not depend on
    /// how often it runs (a getter, or a setter of a value): a request or
    /// reply lost on the way is retried on timeout, as the manager's own
    /// idempotent requests are. Never use it for a function that queues or
    /// counts what it is given.
    pub async fn call_idempotent(
        &self,
        args: &[Value<'static>],
    ) -> Result<Vec<Value<'static>>, SomError> {
        self.call_once_or_more(args, true).await
    }

    async fn call_once_or_more(
        &self,
        args: &[Value<'static>],
        idempotent: bool,
    ) -> Result<Vec<Value<'static>>, SomError> {
        if args.len() != self.inputs.len() {
            return Err(SomError::BadArguments {
                function: self.target.function.clone(),
                detail: format!(
                    "expected {} argument{} ({}), got {}",
                    self.inputs.len(),
                    if self.inputs.len() == 1 { "" } else { "s" },
                    describe(&self.inputs),
                    args.len()
                ),
            });
        }
        let indexed: Vec<(u8, &Value<'static>)> =
            args.iter().enumerate().map(|(i, v)| (i as u8, v)).collect();
        for (i, v) in &indexed {
            self.check_arg(*i, v)?;
        }
        let body = encode_args(&self.target.function, ControlKey::Call, &indexed)?;
        let reply = self
            .control
            .ask_raw(&self.target, "call", &body, idempotent)
            .await?;
        match reply.body(&self.target, "call", ControlKey::Call) {
            Ok(ReplyBody::Returned(outs)) => self.outputs_of(&outs),
            Ok(other) => Err(self.malformed("call", format!("unexpected reply {other:?}"))),
            Err(e) => Err(self.control.name_refusal(&self.target, e).await),
        }
    }

    /// Sends values to some inputs as a dataflow message (`pipe_datagram`,
    /// as a request so refusals come back): `(input index, value)` pairs.
    /// The function stores them as fresh and runs if its input mode says
    /// so, exactly as if they had come down a pipe.
    pub async fn push(&self, args: &[(u8, Value<'static>)]) -> Result<(), SomError> {
        let indexed: Vec<(u8, &Value<'static>)> = args.iter().map(|(i, v)| (*i, v)).collect();
        for (i, v) in &indexed {
            self.check_arg(*i, v)?;
        }
        let body = encode_args(&self.target.function, ControlKey::PipeDatagram, &indexed)?;
        let reply = self
            .control
            .ask_raw(&self.target, "pipe datagram", &body, false)
            .await?;
        match reply.body(&self.target, "pipe datagram", ControlKey::PipeDatagram) {
            Ok(_) => Ok(()),
            Err(e) => Err(self.control.name_refusal(&self.target, e).await),
        }
    }

    fn malformed(&self, request: &'static str, detail: String) -> SomError {
        SomError::Malformed {
            function: self.target.function.clone(),
            request,
            detail,
        }
    }

    fn outputs_of(&self, outs: &Args<'_>) -> Result<Vec<Value<'static>>, SomError> {
        let mut values: Vec<Option<Value<'static>>> = vec![None; self.outputs.len()];
        for (i, v) in outs.iter() {
            let slot = values
                .get_mut(usize::from(i))
                .ok_or_else(|| self.malformed("call", format!("returned unknown output {i}")))?;
            *slot = Some(v.to_owned_value());
        }
        values
            .into_iter()
            .enumerate()
            .map(|(i, v)| v.ok_or_else(|| self.malformed("call", format!("output {i} missing"))))
            .collect()
    }
}

/// A function's inputs or outputs as text: `a: f32, b: f32`, or `none`.
pub fn describe(args: &[SomArg]) -> String {
    if args.is_empty() {
        return "none".into();
    }
    args.iter()
        .map(|a| format!("{}: {}", a.name, a.type_name))
        .collect::<Vec<_>>()
        .join(", ")
}

/// The type of `arg`, or the error naming the unknown type.
pub(crate) fn arg_type(arg: &SomArg) -> Result<Type, String> {
    arg.ty()
        .ok_or_else(|| format!("type {:?} is not known to this build", arg.type_name))
}
