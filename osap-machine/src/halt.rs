//! Halting a machine from the network alone (`osap halt`): every module of
//! the machine file gets its `halt` and every tool its off value, all
//! modules at once, with no [`Machine`](crate::Machine). Nothing is
//! configured and no clock is waited for, so a machine can be halted while
//! another process streams motion to it.
//!
//! Each module is reached as soon as it is found: a module the machine
//! file names by route at once (its route from the entry point, no scan),
//! a module named by name the moment a scan for runtimes meets it (it
//! reads no ports, and ends when every name is met). Then its first ports
//! are read, which say where each function of its kind is; each function
//! the halt needs (`halt`, and `pwm_write` or `digital_write` for its
//! tools) is asked its signature there and checked against the kind's
//! (every port is read if it is not there), and the calls go out, each
//! retried on a lost reply (halting and writing an off value are safe to
//! repeat).
//!
//! A module's `halt` stops its axis at once (no deceleration: an emergency
//! stop) and puts its outputs in their safe states; writing each tool's
//! off value besides (`off_duty`, or its pin low) switches a tool off on a
//! module with no safe values armed too.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Duration;

use futures_util::future::join_all;

use osap_core::route::Route;
use osap_host::map::RuntimeRecord;
use osap_host::netrunner::{self, Netrunner, ScanOptions};
use osap_host::som::{FunctionHandle, Manager, SomError, Value};
use osap_host::{Host, HostError};
use osap_module::functions::signature;
use pipes_core::function::FUNCTION_PORT_TYPE;
use pipes_core::signature::Signature;
use tokio::time::Instant;

use crate::config::{MachineFile, Output, Tool};
use crate::network::{file_route, Entry};

/// Port information requests in flight at once per module, while its
/// ports are searched for the functions a halt needs: what a
/// microcontroller's link holds at once (osap-core's default link quota),
/// so none waits behind the others long enough to expire.
const PORT_WINDOW: u16 = osap_core::stack::DEFAULT_LINK_QUOTA as u16;
/// The ports read first (1 to this, exclusive): enough to see where a
/// module's first two functions start (a function's control port, then
/// its two pipe slots), and so where each of its kind's functions is.
const FIRST_PORTS: u16 = 1 + PORT_WINDOW;

/// Why a module (or a tool) could not be confirmed halted (or off).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum HaltFailure {
    /// Nothing on the network matches the module's name or route.
    #[error("no module {wanted} on the network ({found}); check the cables, `osap scan`, or the machine file's [modules]")]
    NotFound {
        /// What was looked for: a name, or a route from the host.
        wanted: String,
        /// What was found instead.
        found: String,
    },
    /// The runtime does not present the function as the module does.
    #[error("{function}: {detail}; is it a module of this machine (`osap scan -f`)?")]
    NotAModule {
        /// The function the halt needs.
        function: &'static str,
        /// What the runtime has instead.
        detail: String,
    },
    /// The tool's module was not reached.
    #[error("its module {0} was not reached")]
    ModuleUnreached(String),
    /// A request to the runtime failed (no reply, a link down).
    #[error(transparent)]
    Host(#[from] HostError),
    /// The call failed or was refused.
    #[error(transparent)]
    Call(#[from] SomError),
}

/// Why the halt could not start at all.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum HaltError {
    /// The host runtime could not open its ports.
    #[error(transparent)]
    Host(#[from] HostError),
    /// The host could not open its function client.
    #[error(transparent)]
    Som(#[from] SomError),
}

/// A tool switched off, or why not.
#[derive(Debug)]
pub struct ToolOff {
    /// The tool's name in `[tools]`.
    pub tool: String,
    /// The output written.
    pub output: Output,
    /// The off value written: the PWM duty, or 0 for a pin written low.
    pub value: f64,
    /// Whether the module confirmed it.
    pub result: Result<(), HaltFailure>,
}

/// What became of one module of the machine file.
#[derive(Debug)]
pub struct ModuleHalt {
    /// Its key in `[modules]`.
    pub key: String,
    /// Its runtime name, when it answered.
    pub runtime: Option<String>,
    /// Its route from this host (link indices), when known.
    pub route: Option<Vec<u8>>,
    /// When it was found, from the start of [`halt`].
    pub found_after: Option<Duration>,
    /// When its halt went out, from the start of [`halt`].
    pub sent_after: Option<Duration>,
    /// When it confirmed its halt, from the start of [`halt`].
    pub halted_after: Option<Duration>,
    /// Whether it confirmed its halt.
    pub halt: Result<(), HaltFailure>,
    /// Its tools, each switched off or not.
    pub tools: Vec<ToolOff>,
}

impl ModuleHalt {
    /// Whether it confirmed its halt and every tool off.
    pub fn confirmed(&self) -> bool {
        self.halt.is_ok() && self.tools.iter().all(|t| t.result.is_ok())
    }
}

/// What [`halt`] did, module by module.
#[derive(Debug)]
pub struct HaltReport {
    /// One entry per module of the machine file, in key order.
    pub modules: Vec<ModuleHalt>,
    /// How long the whole halt took.
    pub elapsed: Duration,
}

impl HaltReport {
    /// Whether every module confirmed its halt and every tool its off
    /// value.
    pub fn all_confirmed(&self) -> bool {
        self.modules.iter().all(ModuleHalt::confirmed)
    }
}

/// What the module tasks share.
struct Ctx {
    runner: Netrunner,
    manager: Manager,
    tools: BTreeMap<String, Tool>,
    start: Instant,
}

/// Halts every module of `cfg` reached from `host` (links already open;
/// `entry`: where the file's routes start) and switches every tool off,
/// all modules at once. Returns once every module has answered or failed;
/// the report says which is which.
pub async fn halt(host: &Host, cfg: &MachineFile, entry: Entry) -> Result<HaltReport, HaltError> {
    let start = Instant::now();
    let ctx = Arc::new(Ctx {
        runner: Netrunner::new(host).await?,
        manager: Manager::new(host).await?,
        tools: cfg.tools.clone(),
        start,
    });
    let mut tasks = tokio::task::JoinSet::new();
    let mut failed = Vec::new();
    // Name → the keys that name it.
    let mut named: BTreeMap<String, Vec<String>> = BTreeMap::new();
    for (key, m) in &cfg.modules {
        match (&m.route, &m.name) {
            (Some(route), _) => {
                let hops = entry.from_host(&file_route(route));
                match Route::through_links(&hops) {
                    Ok(r) => {
                        tasks.spawn(halt_module(ctx.clone(), key.clone(), None, r, hops));
                    }
                    Err(e) => failed.push(not_found(&ctx, key, format!("at route {hops:?}"), e)),
                }
            }
            (None, Some(name)) => named.entry(name.clone()).or_default().push(key.clone()),
            (None, None) => failed.push(not_found(
                &ctx,
                key,
                "(neither name nor route given)".into(),
                "",
            )),
        }
    }
    if !named.is_empty() {
        let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel::<RuntimeRecord>();
        let options = ScanOptions::default();
        // A machine started only with each name on one runtime (see
        // `find_modules`): the scan ends when every name is met.
        let mut unmet: std::collections::BTreeSet<&String> = named.keys().collect();
        let scan = netrunner::scan_runtimes(host, &options, |r| {
            tracing::debug!(
                "halt: met {:?} at route {:?} after {:.1} ms",
                r.name,
                r.route,
                start.elapsed().as_secs_f64() * 1e3
            );
            if unmet.remove(&r.name) {
                let _ = tx.send(r.clone());
            }
            !unmet.is_empty()
        });
        tokio::pin!(scan);
        let mut seen = std::collections::BTreeSet::new();
        let mut spawn = |r: RuntimeRecord, tasks: &mut tokio::task::JoinSet<ModuleHalt>| {
            seen.insert(r.name.clone());
            for key in named.get(&r.name).into_iter().flatten() {
                tasks.spawn(halt_module(
                    ctx.clone(),
                    key.clone(),
                    Some(r.name.clone()),
                    r.route(),
                    r.route.clone(),
                ));
            }
        };
        let report = loop {
            tokio::select! {
                report = &mut scan => break report,
                Some(r) = rx.recv() => spawn(r, &mut tasks),
            }
        };
        while let Ok(r) = rx.try_recv() {
            spawn(r, &mut tasks);
        }
        let found = match &report {
            Ok(report) => format!(
                "found: {}",
                report
                    .map
                    .runtimes
                    .iter()
                    .skip(1)
                    .map(|r| r.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
            Err(e) => format!("the scan failed: {e}"),
        };
        for (name, keys) in &named {
            if !seen.contains(name) {
                for key in keys {
                    failed.push(not_found(&ctx, key, format!("named {name:?}"), &found));
                }
            }
        }
    }
    let mut modules = failed;
    while let Some(done) = tasks.join_next().await {
        if let Ok(m) = done {
            modules.push(m);
        }
    }
    // A task that panicked or was cancelled: its module is not confirmed.
    for key in cfg.modules.keys() {
        if !modules.iter().any(|m| &m.key == key) {
            modules.push(not_found(&ctx, key, "(its halt did not finish)".into(), ""));
        }
    }
    modules.sort_by(|a, b| a.key.cmp(&b.key));
    Ok(HaltReport {
        modules,
        elapsed: start.elapsed(),
    })
}

/// A module that was not found, and its tools not reached.
fn not_found(ctx: &Ctx, key: &str, wanted: String, found: impl ToString) -> ModuleHalt {
    ModuleHalt {
        key: key.to_string(),
        runtime: None,
        route: None,
        found_after: None,
        sent_after: None,
        halted_after: None,
        halt: Err(HaltFailure::NotFound {
            wanted,
            found: found.to_string(),
        }),
        tools: tools_of(ctx, key)
            .map(|(name, t)| ToolOff {
                tool: name.clone(),
                output: t.output,
                value: off_value(t),
                result: Err(HaltFailure::ModuleUnreached(key.to_string())),
            })
            .collect(),
    }
}

fn tools_of<'a>(ctx: &'a Ctx, key: &'a str) -> impl Iterator<Item = (&'a String, &'a Tool)> {
    ctx.tools.iter().filter(move |(_, t)| t.module == key)
}

/// A tool's off value: its `off_duty` on PWM, 0 (low) on a pin.
fn off_value(t: &Tool) -> f64 {
    match t.output {
        Output::Pwm(_) => t.off_duty,
        Output::Digital(_) => 0.0,
    }
}

/// Halts the module `key` at `route` and switches its tools off.
async fn halt_module(
    ctx: Arc<Ctx>,
    key: String,
    runtime: Option<String>,
    route: Route,
    hops: Vec<u8>,
) -> ModuleHalt {
    let tools: Vec<(String, Tool)> = tools_of(&ctx, &key)
        .map(|(n, t)| (n.clone(), t.clone()))
        .collect();
    let mut out = ModuleHalt {
        key: key.clone(),
        runtime,
        route: Some(hops),
        found_after: Some(ctx.start.elapsed()),
        sent_after: None,
        halted_after: None,
        halt: Ok(()),
        tools: Vec::new(),
    };
    let unreached = |out: &mut ModuleHalt, e: HaltFailure| {
        out.halt = Err(e);
        out.tools = tools
            .iter()
            .map(|(name, t)| ToolOff {
                tool: name.clone(),
                output: t.output,
                value: off_value(t),
                result: Err(HaltFailure::ModuleUnreached(key.clone())),
            })
            .collect();
    };
    // Its first ports say where its functions are.
    let ports = match read_ports(&ctx.runner, &route, 1..FIRST_PORTS).await {
        Ok(p) => Ports::new(p),
        Err(e) => {
            unreached(&mut out, e.into());
            return out;
        }
    };
    // Named in messages only: the module found by route is asked its name
    // beside the halt's first request.
    let runtime = out
        .runtime
        .clone()
        .unwrap_or_else(|| format!("modules.{key}"));
    let handle = |sig: &'static Signature| {
        let ctx = ctx.clone();
        let runtime = runtime.clone();
        let ports = &ports;
        async move {
            let at = |port: u16| {
                let (ctx, runtime) = (ctx.clone(), runtime.clone());
                async move {
                    let h = ctx.manager.function_at(&runtime, route, port).await?;
                    check(&h, sig)?;
                    Ok::<FunctionHandle, HaltFailure>(h)
                }
            };
            // Where the kind's layout puts it (its signature says whether
            // it is there), else found by reading every port.
            if let Some(port) = ports.listed(sig).or_else(|| ports.guess(sig)) {
                match at(port).await {
                    Ok(h) => return Ok(h),
                    Err(HaltFailure::NotAModule { .. }) => {}
                    Err(e) => return Err(e),
                }
            }
            let all = read_ports(&ctx.runner, &route, 1..u16::MAX).await?;
            match Ports::new(all).listed(sig) {
                Some(port) => at(port).await,
                None => Err(HaltFailure::NotAModule {
                    function: sig.name,
                    detail: "it has no function of that name".into(),
                }),
            }
        }
    };
    let halt = if out.runtime.is_some() {
        handle(&signature::halt).await
    } else {
        let (h, name) = tokio::join!(handle(&signature::halt), ctx.runner.name(&route));
        out.runtime = name.ok();
        h
    };
    out.sent_after = Some(ctx.start.elapsed());
    out.halt = match halt {
        Ok(h) => h.call_idempotent(&[]).await.map(|_| ()).map_err(Into::into),
        Err(e) => Err(e),
    };
    if out.halt.is_ok() {
        out.halted_after = Some(ctx.start.elapsed());
    }
    for (name, t) in &tools {
        let (sig, args) = match t.output {
            Output::Pwm(ch) => (
                &signature::pwm_write,
                [Value::U8(ch), Value::F32(t.off_duty as f32)],
            ),
            Output::Digital(pin) => (
                &signature::digital_write,
                [Value::U8(pin), Value::Bool(false)],
            ),
        };
        let result = match handle(sig).await {
            Ok(h) => h
                .call_idempotent(&args)
                .await
                .map(|_| ())
                .map_err(Into::into),
            Err(e) => Err(e),
        };
        out.tools.push(ToolOff {
            tool: name.clone(),
            output: t.output,
            value: off_value(t),
            result,
        });
    }
    out
}

/// The function ports a module lists, as far as read: `(port, name)`.
struct Ports(Vec<(u16, String)>);

impl Ports {
    fn new(records: Vec<osap_host::map::PortRecord>) -> Ports {
        Ports(
            records
                .into_iter()
                .filter(|r| r.type_name == FUNCTION_PORT_TYPE)
                .map(|r| (r.index, r.name))
                .collect(),
        )
    }

    /// The port of `sig`'s function, if read.
    fn listed(&self, sig: &Signature) -> Option<u16> {
        self.0.iter().find(|(_, n)| n == sig.name).map(|(p, _)| *p)
    }

    /// Where `sig`'s function is if the module presents the stepper set
    /// with as many pipe slots per function as its first functions have:
    /// the first functions read say where each function starts.
    fn guess(&self, sig: &Signature) -> Option<u16> {
        let set = &osap_module::functions::SIGNATURES;
        let index = set.iter().position(|s| s.name == sig.name)?;
        let [(p0, n0), (p1, n1), ..] = self.0.as_slice() else {
            return None;
        };
        if n0 != set[0].name || n1 != set.get(1)?.name {
            return None;
        }
        let stride = p1.checked_sub(*p0)?;
        u16::try_from(index)
            .ok()?
            .checked_mul(stride)?
            .checked_add(*p0)
    }
}

/// The records of ports `range` of the runtime at `route`, a window at a
/// time, until the range or the runtime's ports end (a port it refuses to
/// describe).
async fn read_ports(
    runner: &Netrunner,
    route: &Route,
    range: std::ops::Range<u16>,
) -> Result<Vec<osap_host::map::PortRecord>, HostError> {
    let mut out = Vec::new();
    let mut next = range.start;
    while next < range.end {
        let end = next.saturating_add(PORT_WINDOW).min(range.end);
        let window = join_all((next..end).map(|i| runner.port_info(route, i))).await;
        for r in window {
            match r {
                Ok(r) => out.push(r),
                Err(HostError::Remote { .. }) => return Ok(out),
                Err(e) => return Err(e),
            }
        }
        next = end;
    }
    Ok(out)
}

/// Checks the function at `h` is `expected`: name, inputs and outputs
/// with their types.
fn check(h: &FunctionHandle, expected: &Signature) -> Result<(), HaltFailure> {
    let same = |found: &[osap_host::som::model::SomArg], wanted: &[pipes_core::signature::Arg]| {
        found.len() == wanted.len()
            && found
                .iter()
                .zip(wanted)
                .all(|(f, w)| f.name == w.name && f.type_name == w.ty.name())
    };
    if h.function().function == expected.name
        && same(h.inputs(), expected.inputs)
        && same(h.outputs(), expected.outputs)
    {
        return Ok(());
    }
    Err(HaltFailure::NotAModule {
        function: expected.name,
        detail: format!(
            "its port {} is {}({}) -> ({})",
            h.port(),
            h.function().function,
            osap_host::som::describe(h.inputs()),
            osap_host::som::describe(h.outputs())
        ),
    })
}
