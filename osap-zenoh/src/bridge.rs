//! One machine served on a zenoh session (see the crate docs for the keys).
//!
//! Every queryable runs in its own task, and every query that takes time
//! (a call, homing, a halt, a job) in a task of its own, so a halt is
//! answered while a job runs.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use osap_host::som::{parse_value, FnRef, SomError};
use osap_machine::job::{self, Program};
use osap_machine::svg::{self, SvgOptions};
use osap_machine::{Machine, MachineState};
use pipes_core::control::ControlError;
use serde_json::{json, Value as Json};
use tokio::task::JoinHandle;
use zenoh::query::Query;
use zenoh::Session;

use crate::json::{self, JobSummary};
use crate::keys::MachineKeys;

/// How often the state is published by default: 20 Hz.
pub const DEFAULT_STATE_PERIOD: Duration = Duration::from_millis(50);

/// How long one function call may take before it is given up.
pub const CALL_TIMEOUT: Duration = Duration::from_secs(2);

/// A bridge's options.
#[derive(Debug, Clone)]
pub struct BridgeOptions {
    /// The name in the keys (`osap/NAME/…`); default the machine file's.
    pub name: Option<String>,
    /// How often `osap/NAME/state` is published.
    pub state_period: Duration,
}

impl Default for BridgeOptions {
    fn default() -> Self {
        BridgeOptions {
            name: None,
            state_period: DEFAULT_STATE_PERIOD,
        }
    }
}

/// Why a bridge could not start.
#[derive(Debug, thiserror::Error)]
pub enum BridgeError {
    /// zenoh refused a declaration.
    #[error("zenoh: {0}")]
    Zenoh(String),
}

fn zerr(e: impl std::fmt::Display) -> BridgeError {
    BridgeError::Zenoh(e.to_string())
}

/// A machine served on a zenoh session, until [`Bridge::close`].
#[derive(Debug)]
pub struct Bridge {
    keys: MachineKeys,
    tasks: Vec<JoinHandle<()>>,
}

/// An error reply: a name a program can match and a text a person reads.
fn error(name: &str, message: impl std::fmt::Display) -> String {
    json!({ "error": name, "message": message.to_string() }).to_string()
}

async fn reply(query: &Query, result: Result<Json, String>) {
    let sent = match result {
        Ok(body) => query.reply(query.key_expr().clone(), body.to_string()).await,
        Err(body) => query.reply_err(body).await,
    };
    if let Err(e) = sent {
        tracing::warn!("zenoh reply to {}: {e}", query.key_expr());
    }
}

impl Bridge {
    /// Declares every key of `machine` on `session` and starts serving.
    pub async fn start(
        session: &Session,
        machine: Machine,
        options: BridgeOptions,
    ) -> Result<Bridge, BridgeError> {
        let name = options
            .name
            .clone()
            .unwrap_or_else(|| machine.config().name.clone());
        let keys = MachineKeys::new(&name);
        let mut tasks = Vec::new();

        // Events first: nothing that happens from here on is missed.
        let publisher = session.declare_publisher(keys.events()).await.map_err(zerr)?;
        let mut events = machine.events();
        tasks.push(tokio::spawn(async move {
            loop {
                let body = match events.recv().await {
                    Ok(e) => json::event(&e),
                    // Said, never silent: the subscriber learns how many.
                    Err(tokio::sync::broadcast::error::RecvError::Lagged(n)) => {
                        json!({ "kind": "lost", "count": n })
                    }
                    Err(tokio::sync::broadcast::error::RecvError::Closed) => break,
                };
                if let Err(e) = publisher.put(body.to_string()).await {
                    tracing::warn!("zenoh events: {e}");
                }
            }
        }));

        let publisher = session.declare_publisher(keys.state()).await.map_err(zerr)?;
        let m = machine.clone();
        let period = options.state_period;
        tasks.push(tokio::spawn(async move {
            let mut tick = tokio::time::interval(period);
            tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            loop {
                tick.tick().await;
                let Ok(t) = m.now_us().await else { continue };
                if let Err(e) = publisher.put(json::state(&m, t).to_string()).await {
                    tracing::warn!("zenoh state: {e}");
                }
            }
        }));

        let queryable = session.declare_queryable(keys.info()).await.map_err(zerr)?;
        let m = machine.clone();
        tasks.push(tokio::spawn(async move {
            while let Ok(q) = queryable.recv_async().await {
                let info = serde_json::to_value(json::info(&m)).map_err(|e| error("internal", e));
                reply(&q, info).await;
            }
        }));

        let queryable = session.declare_queryable(keys.calls()).await.map_err(zerr)?;
        let (m, k) = (machine.clone(), keys.clone());
        tasks.push(tokio::spawn(async move {
            while let Ok(q) = queryable.recv_async().await {
                let (m, k) = (m.clone(), k.clone());
                tokio::spawn(async move {
                    let result = call(&m, &k, &q).await;
                    reply(&q, result).await;
                });
            }
        }));

        let queryable = session.declare_queryable(keys.home()).await.map_err(zerr)?;
        let m = machine.clone();
        tasks.push(tokio::spawn(async move {
            while let Ok(q) = queryable.recv_async().await {
                let m = m.clone();
                tokio::spawn(async move {
                    let result = home(&m).await;
                    reply(&q, result).await;
                });
            }
        }));

        let queryable = session.declare_queryable(keys.halt()).await.map_err(zerr)?;
        let m = machine.clone();
        tasks.push(tokio::spawn(async move {
            while let Ok(q) = queryable.recv_async().await {
                let m = m.clone();
                tokio::spawn(async move {
                    let result = match m.halt().await {
                        Ok(r) => Ok(json!({
                            "halted": r.is_complete(),
                            "confirmed": r.confirmed,
                            "unreachable": r.unreachable.iter().map(|u| u.module.clone()).collect::<Vec<_>>(),
                        })),
                        Err(e) => Err(error("halt_failed", e)),
                    };
                    reply(&q, result).await;
                });
            }
        }));

        let queryable = session.declare_queryable(keys.job()).await.map_err(zerr)?;
        let m = machine.clone();
        let busy = Arc::new(AtomicBool::new(false));
        tasks.push(tokio::spawn(async move {
            while let Ok(q) = queryable.recv_async().await {
                if busy.swap(true, Ordering::AcqRel) {
                    reply(&q, Err(error("busy", "a job is running: wait for its reply, or halt it"))).await;
                    continue;
                }
                let (m, busy) = (m.clone(), busy.clone());
                tokio::spawn(async move {
                    let result = run_job(&m, &q).await;
                    busy.store(false, Ordering::Release);
                    reply(&q, result).await;
                });
            }
        }));

        Ok(Bridge { keys, tasks })
    }

    /// The keys it serves.
    pub fn keys(&self) -> &MachineKeys {
        &self.keys
    }

    /// Stops serving: every key is undeclared.
    pub fn close(self) {
        for t in self.tasks {
            t.abort();
        }
    }
}

/// `osap/NAME/call/MODULE/FUNCTION` with a JSON array of arguments.
async fn call(machine: &Machine, keys: &MachineKeys, q: &Query) -> Result<Json, String> {
    let key = q.key_expr().as_str();
    let (module, function) = keys
        .parse_call(key)
        .ok_or_else(|| error("bad_key", format!("{key}: ask osap/NAME/call/MODULE/FUNCTION")))?;
    let runtime = machine
        .modules()
        .get(module)
        .map(|m| m.runtime.clone())
        .ok_or_else(|| {
            let known: Vec<&String> = machine.modules().keys().collect();
            error("unknown_module", format!("no module {module}: this machine has {known:?}"))
        })?;
    let args: Vec<Json> = match q.payload() {
        None => Vec::new(),
        Some(p) => {
            let text = p
                .try_to_string()
                .map_err(|e| error("bad_arguments", format!("the payload is not UTF-8: {e}")))?;
            if text.trim().is_empty() {
                Vec::new()
            } else {
                serde_json::from_str(&text).map_err(|e| {
                    error("bad_arguments", format!("the payload must be a JSON array of arguments: {e}"))
                })?
            }
        }
    };
    let handle = machine
        .manager()
        .lock()
        .await
        .function(&FnRef::new(runtime.as_str(), function))
        .map_err(|e| error("unknown_function", e))?
        .with_timeout(CALL_TIMEOUT);
    let inputs = handle.inputs().to_vec();
    if args.len() != inputs.len() {
        return Err(error(
            "bad_arguments",
            format!(
                "{module}.{function} takes {} argument(s) ({}), {} given",
                inputs.len(),
                osap_host::som::describe(&inputs),
                args.len()
            ),
        ));
    }
    let mut values = Vec::with_capacity(args.len());
    for (input, arg) in inputs.iter().zip(&args) {
        let bad = |why: String| error("bad_arguments", format!("input {} ({}): {why}", input.name, input.type_name));
        let ty = input.ty().ok_or_else(|| bad("a type this build does not know".into()))?;
        let text = json::argument_text(arg).ok_or_else(|| bad(format!("{arg} is not a number, bool or string")))?;
        values.push(parse_value(&ty, &text).map_err(|e| bad(e.to_string()))?);
    }
    match handle.call(&values).await {
        Ok(outputs) => Ok(json!({ "outputs": outputs.iter().map(json::value).collect::<Vec<_>>() })),
        Err(SomError::Remote {
            error: ControlError::CallFailed(code),
            failure,
            ..
        }) => Err(match failure {
            Some(f) => json!({ "error": f.name, "message": f.reason, "code": f.code }).to_string(),
            None => json!({
                "error": "refused",
                "message": format!("{module}.{function} refused with failure code {}", code.code()),
                "code": code.code(),
            })
            .to_string(),
        }),
        Err(e) => Err(error("call_failed", e)),
    }
}

/// `osap/NAME/home`: recovers a stopped or faulted machine (homing is what
/// makes its position trustworthy again), then homes every axis.
async fn home(machine: &Machine) -> Result<Json, String> {
    if matches!(machine.state(), MachineState::Faulted(_) | MachineState::Stopped) {
        machine.recover().await.map_err(|e| error("recover_failed", e))?;
    }
    machine.home().await.map_err(|e| error("homing_failed", e))?;
    Ok(json!({ "homed": machine.homed(), "position": machine.position() }))
}

/// The job a query carries: its text, and `type=gcode` or `type=svg`.
fn read_job(machine: &Machine, q: &Query) -> Result<Program, String> {
    let cfg = machine.config();
    let text = match q.payload() {
        Some(p) => p
            .try_to_string()
            .map_err(|e| error("bad_job", format!("the job is not UTF-8: {e}")))?
            .into_owned(),
        None => return Err(error("bad_job", "the query carries no job: put its text in the payload")),
    };
    match q.parameters().get("type") {
        Some("gcode") => {
            let g = osap_machine::gcode::read_with(&text, &job::gcode_options(cfg, None))
                .map_err(|e| error("bad_job", e))?;
            job::from_gcode(cfg, &g, &machine.position()).map_err(|e| error("bad_job", e))
        }
        Some("svg") => {
            let drawing = svg::read(&text, &SvgOptions::default()).map_err(|e| error("bad_job", e))?;
            job::from_svg(cfg, &drawing, cfg.limits.velocity / 2.0).map_err(|e| error("bad_job", e))
        }
        other => Err(error(
            "bad_job",
            format!("type={}: say type=gcode or type=svg in the selector", other.unwrap_or("(none)")),
        )),
    }
}

/// `osap/NAME/job`: homes if needed, runs the job, and sums it up.
async fn run_job(machine: &Machine, q: &Query) -> Result<Json, String> {
    let program = read_job(machine, q)?;
    if matches!(machine.state(), MachineState::Faulted(_) | MachineState::Stopped) {
        return Err(error(
            "not_ready",
            format!(
                "the machine is {}: home it (osap/NAME/home recovers it) before a job",
                json::state_name(&machine.state())
            ),
        ));
    }
    let homing: Vec<bool> = machine
        .config()
        .axis_names()
        .iter()
        .map(|a| machine.config().axes[*a].homing.is_some())
        .collect();
    if machine.homed().iter().zip(&homing).any(|(h, needs)| *needs && !h) {
        machine.home().await.map_err(|e| error("homing_failed", e))?;
    }
    let cfg = machine.config();
    let planned_s = program
        .planned_seconds(cfg, &machine.position())
        .map_err(|e| error("bad_job", e))?;
    machine.start_recording().await.map_err(|e| error("job_failed", e))?;
    let t0 = machine.now_us().await.map_err(|e| error("job_failed", e))?;
    let began = tokio::time::Instant::now();
    let result = machine.run_program(&program, |_| {}).await;
    let executed_s = began.elapsed().as_secs_f64();
    let following_error = match machine.take_recording(t0).await {
        Ok(r) => r.following_error().into_iter().collect(),
        Err(_) => Default::default(),
    };
    let mut faults = Vec::new();
    if let Err(e) = result {
        faults.push(e.to_string());
    }
    if let MachineState::Faulted(reason) = machine.state() {
        if !faults.iter().any(|f| f.contains(&reason)) {
            faults.push(reason);
        }
    }
    let summary = JobSummary {
        planned_s,
        executed_s,
        faults,
        following_error,
    };
    serde_json::to_value(summary).map_err(|e| error("internal", e))
}
