//! The manager: builds the system object model from the network and edits
//! the pipes and modes it describes.

use super::cache::{CachedSignature, SomCache};
use super::description::Description;
use super::handle::{arg_type, describe, Control, FunctionHandle, Target};
use super::host_class::{attach_class, ClassHandle};
use super::host_fn::{attach_function, HostFunction};
use super::model::{
    pipe_record, Som, SomArg, SomBlock, SomClass, SomFunction, SomInputMode, SomOutputMode, SomPipe,
};
use super::{FnRef, RuntimeLookupError, SomError, TypeMismatch};
use crate::map::{NetworkMap, PortRecord};
use crate::netrunner::{self, ScanFailure, ScanOptions};
use crate::Host;
use futures_util::future::join_all;
use futures_util::stream::{self, StreamExt};
use osap_core::route::Route;
use pipes_core::class::{PipesClass, CLASS_PORT_TYPE};
use pipes_core::control::{
    ControlError, ControlKey, InputMode, OutputMode, ReplyBody, Request, ANY_SLOT,
};
use pipes_core::convert::{rule, Rule};
use pipes_core::failure::SignatureParts;
use pipes_core::function::{FUNCTION_PORT_TYPE, PIPE_PORT_TYPE};
use pipes_core::manager::BLOCK_PORT_TYPE;
use pipes_core::pipe::{PipeConfig, PipeDelivery, PipeStats, MAX_ARGMAP};
use std::collections::HashMap;
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::Semaphore;
use tokio::time::Instant;

/// Functions read from one runtime at once: as many requests as a
/// microcontroller's link holds, so none waits in a full queue or is lost.
const AT_ONCE: usize = osap_core::stack::DEFAULT_LINK_QUOTA as usize;

/// What [`Manager::read_runtime`] read: functions, blocks, classes, what
/// failed, and how many signatures came from the cache.
type RuntimeRead = (
    Vec<SomFunction>,
    Option<Vec<SomBlock>>,
    Vec<SomClass>,
    Vec<String>,
    usize,
);

/// A function's signature, as read from it.
struct ScannedSignature {
    name: String,
    /// The first sentence of its docs (empty: none, or not read).
    summary: String,
    inputs: Vec<SomArg>,
    outputs: Vec<SomArg>,
}

/// How a manager talks to the network.
#[derive(Debug, Clone)]
pub struct ManagerOptions {
    /// How the network is scanned.
    pub scan: ScanOptions,
    /// How long to wait for each function's reply.
    pub timeout: Duration,
    /// Retries of requests that read (never of those that change state).
    pub retries: u8,
}

impl Default for ManagerOptions {
    fn default() -> Self {
        ManagerOptions {
            scan: ScanOptions::default(),
            timeout: Duration::from_millis(200),
            retries: 2,
        }
    }
}

/// How a pipe is set up by [`Manager::connect`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PipeOptions {
    /// Time-to-live of each datagram, µs.
    pub ttl_us: u16,
    /// Best-effort or acknowledged (each datagram retransmitted until the
    /// destination replies, at least once; the source's firmware sets the
    /// ack timeout and retry count, 20 ms and 3 by default).
    pub delivery: PipeDelivery,
    /// The slot to set; `None` takes the first free one.
    pub slot: Option<u8>,
    /// Refuse pairs the conversion table converts only for some values
    /// (`i32` → `u8`, `f64` → `f32`, ..), not just those it never converts.
    pub strict: bool,
}

impl Default for PipeOptions {
    fn default() -> Self {
        PipeOptions {
            ttl_us: 50_000,
            delivery: PipeDelivery::BestEffort,
            slot: None,
            strict: false,
        }
    }
}

/// Which pipes [`Manager::disconnect`] removes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Disconnect {
    /// The pipe in this slot.
    Slot(u8),
    /// Every pipe to this function.
    To(FnRef),
    /// Every pipe of the function.
    All,
}

/// What a refresh could not map.
#[derive(Debug, Clone, Default)]
pub struct RefreshReport {
    /// Runtimes the scan could not reach or read.
    pub scan_failures: Vec<ScanFailure>,
    /// Functions that could not be read: which, and why.
    pub function_failures: Vec<String>,
    /// How long it took.
    pub elapsed: Duration,
    /// How long the network scan took, of that (the rest read functions).
    pub scanned: Duration,
    /// Functions whose signature was taken from a cache
    /// ([`Manager::refresh_cached`]), not asked.
    pub from_cache: usize,
}

/// Builds the system object model and edits the network through it.
///
/// The model is a snapshot: [`refresh`](Manager::refresh) rebuilds it, and
/// the manager's own changes ([`connect`](Manager::connect),
/// [`disconnect`](Manager::disconnect), modes, host functions) update it as
/// they succeed. Changes others make are seen at the next refresh.
pub struct Manager {
    host: Host,
    control: Control,
    options: ManagerOptions,
    som: Som,
}

impl std::fmt::Debug for Manager {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Manager")
            .field("options", &self.options)
            .field("runtimes", &self.som.runtimes.len())
            .finish()
    }
}

impl Manager {
    /// A manager on `host` (opens a port named `pipes_manager`), with an
    /// empty model until [`refresh`](Self::refresh).
    pub async fn new(host: &Host) -> Result<Manager, SomError> {
        Manager::with_options(host, ManagerOptions::default()).await
    }

    /// [`new`](Self::new) with options.
    pub async fn with_options(host: &Host, options: ManagerOptions) -> Result<Manager, SomError> {
        let port = host.open_port("pipes_manager").await?;
        Ok(Manager {
            host: host.clone(),
            control: Control {
                port: Arc::new(port),
                timeout: options.timeout,
                retries: options.retries,
                tables: Arc::default(),
                no_sections: Arc::default(),
            },
            options,
            som: Som::empty(),
        })
    }

    /// The model as last refreshed and edited.
    pub fn som(&self) -> &Som {
        &self.som
    }

    /// The host the manager runs on.
    pub fn host(&self) -> &Host {
        &self.host
    }

    /// Scans the network, then reads every PIPES function found (its
    /// signature, modes and pipes; every runtime at once, a few functions
    /// at a time on each), and replaces the model. Runtimes or
    /// functions that do not answer are left out and listed in the report;
    /// the rest of the model is built anyway.
    pub async fn refresh(&mut self) -> Result<RefreshReport, SomError> {
        self.refresh_with(|_| {}).await
    }

    /// [`refresh`](Self::refresh), calling `scanned` with the network's
    /// map as soon as the scan is done, before the functions are read: a
    /// caller can start what needs only routes (clock-sync waits) while
    /// the rest of the model is read.
    pub async fn refresh_with(
        &mut self,
        scanned: impl FnOnce(&NetworkMap),
    ) -> Result<RefreshReport, SomError> {
        self.refresh_from(None, scanned).await
    }

    /// [`refresh_with`](Self::refresh_with), taking from `cache` what it
    /// holds of each runtime's build (its ports, its built functions'
    /// signatures; see [`SomCache`]) instead of asking, and teaching it the
    /// builds it did not hold. Modes, pipes and blocks are read as always.
    /// Returns the report; `cache` tells whether it learnt anything new
    /// (save it then).
    pub async fn refresh_cached(
        &mut self,
        cache: &mut SomCache,
        scanned: impl FnOnce(&NetworkMap),
    ) -> Result<(RefreshReport, bool), SomError> {
        let report = self.refresh_from(Some(cache), scanned).await?;
        let learnt = cache.learn(&self.som);
        Ok((report, learnt))
    }

    async fn refresh_from(
        &mut self,
        cache: Option<&SomCache>,
        scanned: impl FnOnce(&NetworkMap),
    ) -> Result<RefreshReport, SomError> {
        let start = Instant::now();
        let scan = match cache {
            Some(c) => {
                netrunner::scan_known(&self.host, &self.options.scan, &c.known_ports()).await?
            }
            None => netrunner::scan(&self.host, &self.options.scan).await?,
        };
        scanned(&scan.map);
        let mut som = Som::from_map(&scan.map);
        self.control.forget_tables();
        let mut report = RefreshReport {
            scanned: start.elapsed(),
            scan_failures: scan.failures,
            ..RefreshReport::default()
        };
        // Every runtime at once, each with a few functions at a time; the
        // runtimes behind one bus share its few (a drop's replies queue for
        // the bus's turns, and too many at once would outwait their
        // timeouts): one gate per `map::gate_key`, as the scan's.
        let mut gates: HashMap<Vec<u8>, Semaphore> = HashMap::new();
        let keys: Vec<Vec<u8>> = som.runtimes.iter().map(|r| r.record.gate_key()).collect();
        for key in &keys {
            gates
                .entry(key.clone())
                .or_insert_with(|| Semaphore::new(AT_ONCE));
        }
        let read = join_all(
            (0..som.runtimes.len()).map(|ri| self.read_runtime(&som, ri, &gates[&keys[ri]], cache)),
        )
        .await;
        for (ri, (functions, blocks, classes, failed, cached)) in read.into_iter().enumerate() {
            report.from_cache += cached;
            som.runtimes[ri].functions = functions;
            if let Some(blocks) = blocks {
                som.runtimes[ri].blocks = blocks;
            }
            som.classes.extend(classes);
            report.function_failures.extend(failed);
        }
        group_members(&mut som);
        som.resolve_pipes();
        self.som = som;
        // Functions may have changed: their tables are read again when
        // they next refuse.
        self.control.forget_tables();
        report.elapsed = start.elapsed();
        // RUST_LOG=osap_host=debug: what a script's model holds.
        tracing::debug!(
            "system object model read in {:.1} ms: {} runtimes, {} functions, {} \
             classes, {} pipes; {} unreachable, {} functions unread",
            report.elapsed.as_secs_f64() * 1e3,
            self.som.runtimes.len(),
            self.som
                .runtimes
                .iter()
                .map(|r| r.functions.len())
                .sum::<usize>(),
            self.som.classes.len(),
            self.som.pipes.len(),
            report.scan_failures.len(),
            report.function_failures.len()
        );
        Ok(report)
    }

    /// Reads runtime `ri`'s PIPES functions, its blocks (`None`: it has
    /// no block manager) and its classes, as many functions at a time as
    /// `gate` lets (shared by the runtimes behind one bus), the built
    /// functions' signatures from `cache` where it knows the runtime's
    /// build; what failed, as text.
    async fn read_runtime(
        &self,
        som: &Som,
        ri: usize,
        gate: &Semaphore,
        cache: Option<&SomCache>,
    ) -> RuntimeRead {
        let record = &som.runtimes[ri].record;
        let identity = cache.and(record.build_identity());
        let known = |port: u16| cache?.signature(identity.as_ref()?, port);
        let of_type = |types: &[&str]| -> Vec<u16> {
            record
                .ports
                .iter()
                .filter(|p| types.contains(&p.type_name.as_str()))
                .map(|p| p.index)
                .collect()
        };
        let ports = of_type(&[FUNCTION_PORT_TYPE, BLOCK_PORT_TYPE]);
        let has_blocks = !of_type(&[BLOCK_PORT_TYPE]).is_empty();
        let class_ports = of_type(&[CLASS_PORT_TYPE]);
        let mut failed = Vec::new();
        let mut functions = Vec::new();
        let cached = ports.iter().filter(|&&p| known(p).is_some()).count();
        let read = stream::iter(ports.into_iter().map(|port| {
            let known = known(port);
            async move {
                let _turn = gate.acquire().await;
                self.read_function_known(som, ri, port, known).await
            }
        }))
        .buffered(AT_ONCE)
        .collect::<Vec<_>>()
        .await;
        for f in read {
            match f {
                Ok(f) => functions.push(f),
                Err(e) => failed.push(e.to_string()),
            }
        }
        let blocks = if has_blocks {
            match self.read_blocks(som, ri).await {
                Ok(b) => Some(b),
                Err(e) => {
                    failed.push(e.to_string());
                    None
                }
            }
        } else {
            None
        };
        let mut classes = Vec::new();
        let read = stream::iter(class_ports.into_iter().map(|port| async move {
            let _turn = gate.acquire().await;
            self.read_class(som, ri, port).await
        }))
        .buffered(AT_ONCE)
        .collect::<Vec<_>>()
        .await;
        for c in read {
            match c {
                Ok(c) => classes.push(c),
                Err(e) => failed.push(e.to_string()),
            }
        }
        (functions, blocks, classes, failed, cached)
    }

    /// Asks the control port `port` of runtime `ri` for its signature:
    /// where it is, its name, inputs and outputs.
    async fn read_signature(
        &self,
        som: &Som,
        ri: usize,
        port: u16,
    ) -> Result<(Target, ScannedSignature), SomError> {
        let at = port_target(som, ri, port);
        let sig = self.ask_signature(&at).await?;
        Ok((at, sig))
    }

    /// Asks the control port `at` for its function's name, inputs,
    /// outputs and summary line, in one request (`[2][02]`: a function's
    /// failure table is read when it first refuses, see
    /// [`Control::failure_table`], its whole docs on demand,
    /// [`describe`](Self::describe)). A function that refuses that as
    /// malformed (firmware from before the signature's sections) is asked
    /// again with `[2]`, and so are the other functions on its runtime
    /// from then on, until the next refresh.
    async fn ask_signature(&self, at: &Target) -> Result<ScannedSignature, SomError> {
        let what = "get signature";
        let sections = !self.control.without_sections(&at.route);
        let request = if sections {
            Request::Describe(SignatureParts::SUMMARY)
        } else {
            Request::GetSignature
        };
        let mut sig = self.control.ask(at, what, &request, true).await?;
        if sections {
            if let Err(SomError::Remote {
                error: ControlError::Malformed,
                ..
            }) = sig.body(at, what, ControlKey::GetSignature)
            {
                self.control.set_without_sections(at.route);
                sig = self
                    .control
                    .ask(at, what, &Request::GetSignature, true)
                    .await?;
            }
        }
        match sig.body(at, what, ControlKey::GetSignature)? {
            ReplyBody::Signature(s) => {
                let args = |l: pipes_core::signature::ArgList<'_>| -> Vec<SomArg> {
                    l.iter()
                        .map(|a| SomArg {
                            name: a.name.to_string(),
                            type_name: a.ty.name().to_string(),
                        })
                        .collect()
                };
                Ok(ScannedSignature {
                    name: s.name().to_string(),
                    summary: s.summary().unwrap_or_default().to_string(),
                    inputs: args(s.inputs()),
                    outputs: args(s.outputs()),
                })
            }
            other => Err(unexpected(at, "get signature", &other)),
        }
    }

    /// Reads the class whose port is `port` on runtime `ri` (its members
    /// are grouped later, by [`group_members`]).
    async fn read_class(&self, som: &Som, ri: usize, port: u16) -> Result<SomClass, SomError> {
        let (
            at,
            ScannedSignature {
                name,
                inputs: constructor,
                outputs,
                ..
            },
        ) = self.read_signature(som, ri, port).await?;
        if !outputs.is_empty() {
            return Err(SomError::Malformed {
                function: at.function,
                request: "get signature",
                detail: format!(
                    "a class constructor has no outputs, this one has {}",
                    describe(&outputs)
                ),
            });
        }
        Ok(SomClass {
            runtime: ri,
            name,
            members: Vec::new(),
            port,
            constructor,
        })
    }

    /// Reads the function whose control port is `port` on runtime `ri`.
    pub(super) async fn read_function(
        &self,
        som: &Som,
        ri: usize,
        port: u16,
    ) -> Result<SomFunction, SomError> {
        self.read_function_known(som, ri, port, None).await
    }

    /// [`read_function`](Self::read_function), its signature taken from
    /// `known` when given (a cached build's) instead of asked.
    async fn read_function_known(
        &self,
        som: &Som,
        ri: usize,
        port: u16,
        known: Option<&CachedSignature>,
    ) -> Result<SomFunction, SomError> {
        let r = &som.runtimes[ri];
        let (at, sig) = match known {
            Some(k) => (
                port_target(som, ri, port),
                ScannedSignature {
                    name: k.name.clone(),
                    summary: k.summary.clone(),
                    inputs: k.inputs.clone(),
                    outputs: k.outputs.clone(),
                },
            ),
            None => self.read_signature(som, ri, port).await?,
        };
        let ScannedSignature {
            name,
            summary,
            inputs,
            outputs,
        } = sig;
        let at = Target {
            function: FnRef::new(r.record.name.clone(), name.clone()),
            ..at
        };
        let input_mode = match self
            .control
            .ask(&at, "get input mode", &Request::GetInputMode, true)
            .await?
            .body(&at, "get input mode", ControlKey::GetInputMode)?
        {
            ReplyBody::InputMode(m) => SomInputMode::from(m),
            other => return Err(unexpected(&at, "get input mode", &other)),
        };
        let output_mode = match self
            .control
            .ask(&at, "get output mode", &Request::GetOutputMode, true)
            .await?
            .body(&at, "get output mode", ControlKey::GetOutputMode)?
        {
            ReplyBody::OutputMode(m) => SomOutputMode::from(m),
            other => return Err(unexpected(&at, "get output mode", &other)),
        };
        let (slots, used) = match self
            .control
            .ask(&at, "get pipe count", &Request::GetPipeCount, true)
            .await?
            .body(&at, "get pipe count", ControlKey::GetPipeCount)?
        {
            ReplyBody::PipeCount { slots, used } => (slots, used),
            other => return Err(unexpected(&at, "get pipe count", &other)),
        };
        let mut pipes = Vec::new();
        for slot in 0..slots {
            if pipes.len() >= usize::from(used) {
                break;
            }
            let reply = self
                .control
                .ask(&at, "get pipe", &Request::GetPipe(slot), true)
                .await?;
            match reply.body(&at, "get pipe", ControlKey::GetPipe)? {
                ReplyBody::Pipe { pipe: None, .. } => {}
                ReplyBody::Pipe {
                    pipe: Some(config), ..
                } => pipes.push(
                    pipe_record(slot, &config).ok_or_else(|| SomError::Malformed {
                        function: at.function.clone(),
                        request: "get pipe",
                        detail: format!("slot {slot}'s route has a hop that is not a link"),
                    })?,
                ),
                other => return Err(unexpected(&at, "get pipe", &other)),
            }
        }
        // The pipe ports follow the control port.
        let pipe_ports = (1..=u16::from(slots))
            .map(|k| port + k)
            .filter(|p| {
                r.record
                    .ports
                    .iter()
                    .any(|x| x.index == *p && x.type_name == PIPE_PORT_TYPE)
            })
            .collect();
        Ok(SomFunction {
            name,
            summary,
            port,
            pipe_ports,
            inputs,
            outputs,
            input_mode,
            output_mode,
            pipe_slots: slots,
            pipes,
        })
    }

    /// Runtime index of `f`'s runtime in the model.
    fn runtime(&self, f: &FnRef) -> Result<usize, SomError> {
        self.som.runtime_index(&f.runtime).map_err(|e| match e {
            RuntimeLookupError::Ambiguous { count } => SomError::AmbiguousRuntime {
                name: f.runtime.clone(),
                count,
            },
            _ => SomError::NoSuchRuntime(f.runtime.clone()),
        })
    }

    /// Runtime index and function of `f` in the model.
    pub(super) fn locate(&self, f: &FnRef) -> Result<(usize, &SomFunction), SomError> {
        let ri = self.runtime(f)?;
        let func = self
            .som
            .function(ri, &f.function)
            .ok_or_else(|| SomError::NoSuchFunction(f.clone()))?;
        Ok((ri, func))
    }

    fn target(&self, f: &FnRef) -> Result<(usize, Target), SomError> {
        let (ri, func) = self.locate(f)?;
        Ok((
            ri,
            Target {
                function: f.clone(),
                route: host_route(&self.som, ri),
                port: func.port,
            },
        ))
    }

    /// A handle for calling `f` from async Rust.
    pub fn function(&self, f: &FnRef) -> Result<FunctionHandle, SomError> {
        let (_, func) = self.locate(f)?;
        let (inputs, outputs) = (func.inputs.clone(), func.outputs.clone());
        let (_, target) = self.target(f)?;
        Ok(FunctionHandle::new(
            self.control.clone(),
            target,
            inputs,
            outputs,
        ))
    }

    /// What function `f` says of itself: its documentation and its failure
    /// table, read from it now (one request; see [`Description`]).
    pub async fn describe(&self, f: &FnRef) -> Result<Description, SomError> {
        let (_, target) = self.target(f)?;
        self.control.describe(&target).await
    }

    /// A handle for the function whose control port is `port` on the
    /// runtime `runtime` at `route`, read from the function itself (one
    /// request: its signature) instead of the model: for a caller that
    /// knows where a function is and cannot wait for a
    /// [`refresh`](Self::refresh) (`osap halt`). The handle names the
    /// function as it answers; check it is the one you meant
    /// ([`FunctionHandle::function`], its inputs and outputs) before
    /// calling it.
    pub async fn function_at(
        &self,
        runtime: &str,
        route: Route,
        port: u16,
    ) -> Result<FunctionHandle, SomError> {
        let mut at = Target {
            function: FnRef::new(runtime, format!("port {port}")),
            route,
            port,
        };
        let sig = self.ask_signature(&at).await?;
        at.function = FnRef::new(runtime, sig.name);
        Ok(FunctionHandle::new(
            self.control.clone(),
            at,
            sig.inputs,
            sig.outputs,
        ))
    }

    /// Pipes `source`'s outputs `outputs[i]` to `dest`'s inputs `inputs[i]`.
    ///
    /// Checks the argmap (same lengths, at most 8 pairs, existing indices,
    /// no input twice) and every pair's types against the conversion table:
    /// a pair that never converts is refused, and with
    /// [`PipeOptions::strict`] so is one that converts only some values.
    /// The route is the shortest (in hops) from the source's runtime to the
    /// destination's over the model's open links, with its MTU; the pipe is
    /// installed on the source function over the network, so data then
    /// flows runtime to runtime, through the host only if the route does.
    /// Returns the pipe as the model now lists it.
    pub async fn connect(
        &mut self,
        source: &FnRef,
        dest: &FnRef,
        outputs: &[u8],
        inputs: &[u8],
        options: PipeOptions,
    ) -> Result<SomPipe, SomError> {
        let (si, sf) = self.locate(source)?;
        let (di, df) = self.locate(dest)?;
        let argmap_err = |detail: String| SomError::Argmap {
            source_fn: source.clone(),
            dest_fn: dest.clone(),
            detail,
        };
        if outputs.len() != inputs.len() {
            return Err(argmap_err(format!(
                "{} outputs but {} inputs: they are paired by position",
                outputs.len(),
                inputs.len()
            )));
        }
        if outputs.is_empty() || outputs.len() > MAX_ARGMAP {
            return Err(argmap_err(format!(
                "{} pairs: a pipe maps 1 to {MAX_ARGMAP}",
                outputs.len()
            )));
        }
        for (&o, &i) in outputs.iter().zip(inputs) {
            let out = sf.outputs.get(usize::from(o)).ok_or_else(|| {
                argmap_err(format!(
                    "no output {o} (outputs: {})",
                    describe(&sf.outputs)
                ))
            })?;
            let inp = df.inputs.get(usize::from(i)).ok_or_else(|| {
                argmap_err(format!("no input {i} (inputs: {})", describe(&df.inputs)))
            })?;
            let mismatch = |reason: String| {
                SomError::TypeMismatch(Box::new(TypeMismatch {
                    source_fn: source.clone(),
                    output: o,
                    from: out.type_name.clone(),
                    dest_fn: dest.clone(),
                    input: i,
                    to: inp.type_name.clone(),
                    reason,
                }))
            };
            let from = arg_type(out).map_err(mismatch)?;
            let to = arg_type(inp).map_err(mismatch)?;
            match rule(&from, &to) {
                Rule::Never(reason) => return Err(mismatch(format!("never converts ({reason})"))),
                Rule::IfExact if options.strict => {
                    return Err(mismatch(
                        "converts only values that fit exactly (strict pipes refuse this)".into(),
                    ))
                }
                _ => {}
            }
        }
        let no_route = || SomError::NoRoute {
            from: source.runtime.clone(),
            to: dest.runtime.clone(),
        };
        let path = self.som.path(si, di).ok_or_else(no_route)?;
        let route = path.route().ok_or_else(no_route)?;
        let mut config =
            PipeConfig::new(route, df.port, options.ttl_us).with_delivery(options.delivery);
        for (&o, &i) in outputs.iter().zip(inputs) {
            config
                .map(o, i)
                .map_err(|e| argmap_err(format!("output {o} -> input {i}: {e}")))?;
        }
        let (_, at) = self.target(source)?;
        let request = Request::SetPipe {
            slot: options.slot.unwrap_or(ANY_SLOT),
            pipe: config,
        };
        let reply = self.control.ask(&at, "set pipe", &request, false).await?;
        let slot = match reply.body(&at, "set pipe", ControlKey::SetPipe)? {
            ReplyBody::PipeSet(s) => s,
            other => return Err(unexpected(&at, "set pipe", &other)),
        };
        let record = pipe_record(slot, &config).ok_or_else(no_route)?;
        self.edit_function(si, &source.function, |f| {
            f.pipes.retain(|p| p.slot != slot);
            f.pipes.push(record);
            f.pipes.sort_by_key(|p| p.slot);
        });
        self.som
            .pipes
            .iter()
            .find(|p| p.source.runtime == si && p.source.port == at.port && p.slot == slot)
            .cloned()
            .ok_or_else(|| SomError::NoSuchPipe {
                function: source.clone(),
                detail: format!("slot {slot} was set but is not in the model"),
            })
    }

    /// Removes pipes of `source`: one slot, every pipe to a function, or
    /// all. Returns the slots wiped. Refuses (naming the function) when no
    /// pipe matches.
    pub async fn disconnect(
        &mut self,
        source: &FnRef,
        which: Disconnect,
    ) -> Result<Vec<u8>, SomError> {
        let (si, sf) = self.locate(source)?;
        let slots: Vec<u8> = match &which {
            Disconnect::Slot(s) => vec![*s],
            Disconnect::All => vec![ANY_SLOT],
            Disconnect::To(dest) => {
                let (di, df) = self.locate(dest)?;
                let found: Vec<u8> = sf
                    .pipes
                    .iter()
                    .filter(|p| {
                        p.destination
                            .as_ref()
                            .is_some_and(|d| d.runtime == di && d.port == df.port)
                    })
                    .map(|p| p.slot)
                    .collect();
                if found.is_empty() {
                    return Err(SomError::NoSuchPipe {
                        function: source.clone(),
                        detail: format!("no pipe to {dest}"),
                    });
                }
                found
            }
        };
        let (_, at) = self.target(source)?;
        for &slot in &slots {
            self.control
                .ask(&at, "wipe pipe", &Request::WipePipe(slot), true)
                .await?
                .body(&at, "wipe pipe", ControlKey::WipePipe)?;
        }
        let all = slots.contains(&ANY_SLOT);
        let mut wiped = Vec::new();
        self.edit_function(si, &source.function, |f| {
            f.pipes.retain(|p| {
                let gone = all || slots.contains(&p.slot);
                if gone {
                    wiped.push(p.slot);
                }
                !gone
            });
        });
        if !all {
            // A wiped empty slot is still wiped.
            wiped = slots;
        }
        Ok(wiped)
    }

    /// Reads the counters of `f`'s pipe in slot `slot` over the network
    /// (datagrams sent, dropped on a full queue, not sendable, refused by
    /// the destination, acknowledged, sent again, dropped unacknowledged,
    /// and the destination's last refusal). An empty slot
    /// is refused by the function ([`ControlError::NoSuchPipe`] in
    /// [`SomError::Remote`]). The model is not changed.
    ///
    /// [`ControlError::NoSuchPipe`]: pipes_core::control::ControlError::NoSuchPipe
    pub async fn pipe_stats(&self, f: &FnRef, slot: u8) -> Result<PipeStats, SomError> {
        let (_, at) = self.target(f)?;
        let reply = self
            .control
            .ask(&at, "get pipe stats", &Request::GetPipeStats(slot), true)
            .await?;
        match reply.body(&at, "get pipe stats", ControlKey::GetPipeStats)? {
            ReplyBody::PipeStats { slot: s, stats } if s == slot => Ok(stats),
            other => Err(unexpected(&at, "get pipe stats", &other)),
        }
    }

    /// Installs again, over the network, every pipe and mode the model
    /// lists for the functions of `runtime`: for a runtime that rebooted
    /// and lost what was set on it (the model keeps what this manager
    /// set). Each pipe goes back in its own slot, before the modes (a run
    /// before its pipe exists would count as sent). Returns how many pipes
    /// were installed.
    pub async fn reinstate(&mut self, runtime: &str) -> Result<usize, SomError> {
        let ri = self
            .som
            .runtime_index(runtime)
            .map_err(|_| SomError::NoSuchRuntime(runtime.to_string()))?;
        let functions = self.som.runtimes[ri].functions.clone();
        let mut installed = 0;
        for f in &functions {
            let fref = FnRef::new(runtime, &f.name);
            let (_, at) = self.target(&fref)?;
            for p in &f.pipes {
                let pipe = p.config().ok_or_else(|| SomError::NoSuchPipe {
                    function: fref.clone(),
                    detail: format!("slot {}: the model's route is not valid", p.slot),
                })?;
                let request = Request::SetPipe { slot: p.slot, pipe };
                // Its own slot: setting it twice sets it once.
                self.control
                    .ask(&at, "set pipe", &request, true)
                    .await?
                    .body(&at, "set pipe", ControlKey::SetPipe)?;
                installed += 1;
            }
            let output: OutputMode = f.output_mode.into();
            if output != OutputMode::default() {
                self.control
                    .ask(
                        &at,
                        "set output mode",
                        &Request::SetOutputMode(output),
                        true,
                    )
                    .await?
                    .body(&at, "set output mode", ControlKey::SetOutputMode)?;
            }
            let input: InputMode = f.input_mode.into();
            if input != InputMode::default() {
                self.control
                    .ask(&at, "set input mode", &Request::SetInputMode(input), true)
                    .await?
                    .body(&at, "set input mode", ControlKey::SetInputMode)?;
            }
        }
        Ok(installed)
    }

    /// Sets when `f` runs on dataflow.
    pub async fn set_input_mode(&mut self, f: &FnRef, mode: InputMode) -> Result<(), SomError> {
        let (ri, at) = self.target(f)?;
        self.control
            .ask(&at, "set input mode", &Request::SetInputMode(mode), true)
            .await?
            .body(&at, "set input mode", ControlKey::SetInputMode)?;
        self.edit_function(ri, &f.function, |x| x.input_mode = mode.into());
        Ok(())
    }

    /// Sets when `f` sends its outputs.
    pub async fn set_output_mode(&mut self, f: &FnRef, mode: OutputMode) -> Result<(), SomError> {
        let (ri, at) = self.target(f)?;
        self.control
            .ask(&at, "set output mode", &Request::SetOutputMode(mode), true)
            .await?
            .body(&at, "set output mode", ControlKey::SetOutputMode)?;
        self.edit_function(ri, &f.function, |x| x.output_mode = mode.into());
        Ok(())
    }

    /// Defines `function` on the manager's host runtime and adds it to the
    /// model (runtime 0, once the model has been refreshed; before that the
    /// next refresh finds it). Returns its reference for
    /// [`connect`](Self::connect) and [`function`](Self::function).
    pub async fn define(&mut self, function: HostFunction) -> Result<FnRef, SomError> {
        let name = function.name();
        let count = 1 + super::HOST_FN_PIPES as u16;
        let port = attach_function(&self.host, function).await?;
        let Some(host_rt) = self.som.runtimes.first() else {
            return Ok(FnRef::new(String::new(), name));
        };
        let fref = FnRef::new(host_rt.record.name.clone(), name);
        let ports = &mut self.som.runtimes[0].record.ports;
        ports.retain(|p| p.index < port || p.index >= port + count);
        ports.push(PortRecord {
            index: port,
            type_name: FUNCTION_PORT_TYPE.into(),
            name: name.into(),
        });
        ports.extend((1..count).map(|k| PortRecord {
            index: port + k,
            type_name: PIPE_PORT_TYPE.into(),
            name: String::new(),
        }));
        ports.sort_by_key(|p| p.index);
        let f = self.read_function(&self.som, 0, port).await?;
        let functions = &mut self.som.runtimes[0].functions;
        functions.retain(|x| x.port != port);
        functions.push(f);
        functions.sort_by_key(|x| x.port);
        self.som.resolve_pipes();
        Ok(fref)
    }

    /// Attaches an instance of class `C`, starting from `state`, to the
    /// manager's host runtime (see [`attach_class`]) and adds the class and
    /// its members to the model (runtime 0, once the model has been
    /// refreshed; before that the next refresh finds them). Members are
    /// then named for [`connect`](Self::connect) and
    /// [`function`](Self::function) by
    /// `FnRef::new(<host runtime>, handle.member("..").unwrap())`.
    pub async fn define_class<C>(&mut self, state: C) -> Result<ClassHandle<C>, SomError>
    where
        C: PipesClass + Send + 'static,
    {
        let handle = attach_class(&self.host, state).await?;
        if self.som.runtimes.is_empty() {
            return Ok(handle);
        }
        let fn_count = 1 + super::HOST_FN_PIPES as u16;
        let mut records = vec![PortRecord {
            index: handle.port(),
            type_name: CLASS_PORT_TYPE.into(),
            name: C::NAME.into(),
        }];
        for &(name, port) in handle.members() {
            records.push(PortRecord {
                index: port,
                type_name: FUNCTION_PORT_TYPE.into(),
                name: name.into(),
            });
            records.extend((1..fn_count).map(|k| PortRecord {
                index: port + k,
                type_name: PIPE_PORT_TYPE.into(),
                name: String::new(),
            }));
        }
        let ports = &mut self.som.runtimes[0].record.ports;
        ports.retain(|p| !records.iter().any(|r| r.index == p.index));
        ports.extend(records);
        ports.sort_by_key(|p| p.index);
        let class = self.read_class(&self.som, 0, handle.port()).await?;
        let mut functions = Vec::with_capacity(handle.members().len());
        for &(_, port) in handle.members() {
            functions.push(self.read_function(&self.som, 0, port).await?);
        }
        let own = |p: u16| p == handle.port() || handle.members().iter().any(|m| m.1 == p);
        let host_fns = &mut self.som.runtimes[0].functions;
        host_fns.retain(|f| !own(f.port));
        host_fns.extend(functions);
        host_fns.sort_by_key(|f| f.port);
        self.som
            .classes
            .retain(|c| !(c.runtime == 0 && own(c.port)));
        self.som.classes.push(class);
        self.som.classes.sort_by_key(|c| (c.runtime, c.port));
        group_members(&mut self.som);
        self.som.resolve_pipes();
        Ok(handle)
    }

    /// A handle for calling the constructor of class `class` on runtime
    /// `runtime`: a call (with the constructor's inputs) rebuilds the
    /// instance's state and returns no outputs.
    pub fn constructor(&self, runtime: &str, class: &str) -> Result<FunctionHandle, SomError> {
        let fref = FnRef::new(runtime, class);
        let ri = self.runtime(&fref)?;
        let c = self
            .som
            .class(ri, class)
            .ok_or_else(|| SomError::NoSuchFunction(fref.clone()))?;
        let inputs = c.constructor.clone();
        let target = Target {
            function: fref,
            route: host_route(&self.som, ri),
            port: c.port,
        };
        Ok(FunctionHandle::new(
            self.control.clone(),
            target,
            inputs,
            Vec::new(),
        ))
    }

    /// Edits runtime `ri` of the model, then resolves the pipes again.
    pub(super) fn edit_runtime(
        &mut self,
        ri: usize,
        edit: impl FnOnce(&mut super::model::SomRuntime),
    ) {
        if let Some(r) = self.som.runtimes.get_mut(ri) {
            edit(r);
        }
        self.som.resolve_pipes();
    }

    /// The request client.
    pub(super) fn control(&self) -> &Control {
        &self.control
    }

    /// The index of the runtime named `name` in the model.
    pub(super) fn runtime_index(&self, name: &str) -> Result<usize, SomError> {
        self.runtime(&FnRef::new(name, ""))
    }

    /// Where `f`'s control port is.
    pub(super) fn target_of(&self, f: &FnRef) -> Result<(usize, Target), SomError> {
        self.target(f)
    }

    pub(super) fn edit_function(
        &mut self,
        ri: usize,
        name: &str,
        edit: impl FnOnce(&mut SomFunction),
    ) {
        if let Some(f) = self
            .som
            .runtimes
            .get_mut(ri)
            .and_then(|r| r.functions.iter_mut().find(|f| f.name == name))
        {
            edit(f);
        }
        self.som.resolve_pipes();
    }
}

/// Lists under each class the functions of its runtime named
/// `"<class>.<member>"`, in port order.
fn group_members(som: &mut Som) {
    for c in &mut som.classes {
        c.members = som.runtimes.get(c.runtime).map_or(Vec::new(), |r| {
            let mut fns: Vec<&SomFunction> = r
                .functions
                .iter()
                .filter(|f| {
                    f.name
                        .strip_prefix(c.name.as_str())
                        .and_then(|rest| rest.strip_prefix('.'))
                        .is_some_and(|m| !m.is_empty())
                })
                .collect();
            fns.sort_by_key(|f| f.port);
            fns.iter().map(|f| f.name.clone()).collect()
        });
    }
}

/// The route from the host (runtime 0) to runtime `ri`, with its MTU.
/// Where the control port `port` of runtime `ri` is, named as its port
/// record names it.
fn port_target(som: &Som, ri: usize, port: u16) -> Target {
    let r = &som.runtimes[ri];
    let listed = r
        .record
        .ports
        .iter()
        .find(|p| p.index == port)
        .map_or(String::new(), |p| p.name.clone());
    Target {
        function: FnRef::new(r.record.name.clone(), listed),
        route: host_route(som, ri),
        port,
    }
}

pub(super) fn host_route(som: &Som, ri: usize) -> Route {
    som.runtimes
        .get(ri)
        .map_or(Route::local(), |r| r.record.route())
}

fn unexpected(at: &Target, request: &'static str, body: &ReplyBody<'_>) -> SomError {
    SomError::Malformed {
        function: at.function.clone(),
        request,
        detail: format!("unexpected reply {body:?}"),
    }
}
