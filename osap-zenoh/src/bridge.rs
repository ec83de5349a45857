//! One machine served on a zenoh session (see the crate docs for the keys).
//!
//! The bridge has two halves joined by channels:
//!
//! - the **machine side** runs on the machine's runtime (which may be a
//!   simulation in virtual time): it samples the state, forwards events
//!   and carries out requests, each in a task of its own, so a halt is
//!   answered while a job runs;
//! - the **zenoh side** runs on a multi-thread runtime in real time (zenoh
//!   needs one): its queryables turn queries into requests, and it
//!   publishes the latest state at its own real-time rate and every event.
//!
//! So zenoh's I/O never waits on the machine, nor the machine on zenoh.

use std::sync::Arc;
use std::time::Duration;

use osap_host::som::{parse_value, FnRef, SomError};
use osap_machine::job::{self, Program};
use osap_machine::svg::{self, SvgOptions};
use osap_machine::{Machine, MachineState};
use pipes_core::control::ControlError;
use serde_json::{json, Value as Json};
use tokio::runtime::Handle;
use tokio::sync::{mpsc, oneshot, watch};
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
    /// How often `osap/NAME/state` is published (real time).
    pub state_period: Duration,
    /// Sources sampled and published on `osap/NAME/capture/SOURCE`
    /// (`MODULE.FUNCTION[(ARGS)][.OUTPUT]`, as `osap capture` takes them).
    pub sources: Vec<String>,
    /// Their sampling period, µs.
    pub period_us: u32,
}

impl Default for BridgeOptions {
    fn default() -> Self {
        BridgeOptions {
            name: None,
            state_period: DEFAULT_STATE_PERIOD,
            sources: Vec::new(),
            period_us: 1_000,
        }
    }
}

/// Samples a source's channel holds before it drops (and counts) them.
const CAPTURE_QUEUE: usize = 1 << 16;

/// Why a bridge could not start.
#[derive(Debug, thiserror::Error)]
pub enum BridgeError {
    /// zenoh refused a declaration.
    #[error("zenoh: {0}")]
    Zenoh(String),
    /// A capture source was refused.
    #[error("--source {source_text}: {reason}")]
    Source {
        /// The source as given.
        source_text: String,
        /// Why.
        reason: String,
    },
}

fn zerr(e: impl std::fmt::Display) -> BridgeError {
    BridgeError::Zenoh(e.to_string())
}

/// An error reply: a name a program can match and a text a person reads.
fn error(name: &str, message: impl std::fmt::Display) -> String {
    json!({ "error": name, "message": message.to_string() }).to_string()
}

/// What a query asks of the machine side.
#[derive(Debug)]
enum Ask {
    Info,
    Call {
        key: String,
        payload: Option<Result<String, String>>,
    },
    Home,
    Halt,
    Job {
        payload: Option<Result<String, String>>,
        kind: Option<String>,
    },
}

/// The one job a bridge runs at a time, and how a halt stops it.
#[derive(Debug)]
struct Jobs {
    /// Held while a job runs (and while a halt stops one).
    running: tokio::sync::Mutex<()>,
    /// Set by a halt: the job stops queueing and ends.
    cancel: watch::Sender<bool>,
}

/// How a queryable turns its query into a request.
type AskOf = fn(&Query) -> Ask;

/// One request and where its answer goes.
#[derive(Debug)]
struct Request {
    ask: Ask,
    answer: oneshot::Sender<Result<Json, String>>,
}

/// A machine served on a zenoh session, until [`Bridge::close`].
#[derive(Debug)]
pub struct Bridge {
    keys: MachineKeys,
    machine_tasks: Vec<JoinHandle<()>>,
    zenoh_tasks: Vec<JoinHandle<()>>,
    streams: Vec<osap_machine::capture::Stream>,
}

fn payload_text(q: &Query) -> Option<Result<String, String>> {
    q.payload().map(|p| {
        p.try_to_string()
            .map(|t| t.into_owned())
            .map_err(|e| e.to_string())
    })
}

/// The zenoh side of one queryable: every query on `key` becomes a
/// request, answered when the machine side answers.
async fn serve_queries(
    session: Session,
    key: String,
    requests: mpsc::UnboundedSender<Request>,
    ask: AskOf,
) {
    let queryable = match session.declare_queryable(&key).await {
        Ok(q) => q,
        Err(e) => {
            tracing::error!("zenoh queryable {key}: {e}");
            return;
        }
    };
    while let Ok(q) = queryable.recv_async().await {
        // A reply names the key it answers for: the declared one, or the
        // query's own where the declared key has wildcards (a call).
        let reply_key = if key.contains('*') {
            q.key_expr().as_str().to_string()
        } else {
            key.clone()
        };
        let (answer, answered) = oneshot::channel();
        let sent = requests.send(Request {
            ask: ask(&q),
            answer,
        });
        tokio::spawn(async move {
            let result = match sent {
                Ok(()) => answered
                    .await
                    .unwrap_or_else(|_| Err(error("stopped", "the bridge is stopping"))),
                Err(_) => Err(error("stopped", "the bridge is stopping")),
            };
            let sent = match result {
                Ok(body) => q.reply(reply_key, body.to_string()).await,
                Err(body) => q.reply_err(body).await,
            };
            if let Err(e) = sent {
                tracing::warn!("zenoh reply to {}: {e}", q.key_expr());
            }
        });
    }
}

impl Bridge {
    /// Serves `machine` on `session`. Call it on the machine's runtime;
    /// `zenoh` is a handle of the multi-thread runtime the session was
    /// opened on (the same runtime's when that is where the machine runs).
    pub async fn start(
        session: Session,
        zenoh: Handle,
        machine: Machine,
        options: BridgeOptions,
    ) -> Result<Bridge, BridgeError> {
        let name = options
            .name
            .clone()
            .unwrap_or_else(|| machine.config().name.clone());
        let keys = MachineKeys::new(&name);
        let mut machine_tasks = Vec::new();
        let mut zenoh_tasks = Vec::new();

        // Events: subscribed to before anything else, so nothing from
        // here on is missed.
        let events_pub = {
            let (s, k) = (session.clone(), keys.events());
            zenoh
                .spawn(async move { s.declare_publisher(k).await })
                .await
        }
        .map_err(zerr)?
        .map_err(zerr)?;
        let (event_tx, mut event_rx) = mpsc::unbounded_channel::<Json>();
        let mut events = machine.events();
        machine_tasks.push(tokio::spawn(async move {
            loop {
                let body = match events.recv().await {
                    Ok(e) => json::event(&e),
                    // Said, never silent: the subscriber learns how many.
                    Err(tokio::sync::broadcast::error::RecvError::Lagged(n)) => {
                        json!({ "kind": "lost", "count": n })
                    }
                    Err(tokio::sync::broadcast::error::RecvError::Closed) => break,
                };
                if event_tx.send(body).is_err() {
                    break;
                }
            }
        }));
        zenoh_tasks.push(zenoh.spawn(async move {
            while let Some(body) = event_rx.recv().await {
                if let Err(e) = events_pub.put(body.to_string()).await {
                    tracing::warn!("zenoh events: {e}");
                }
            }
        }));

        // State: sampled on the machine side, published in real time.
        let state_pub = {
            let (s, k) = (session.clone(), keys.state());
            zenoh
                .spawn(async move { s.declare_publisher(k).await })
                .await
        }
        .map_err(zerr)?
        .map_err(zerr)?;
        let (state_tx, mut state_rx) = watch::channel(Json::Null);
        state_rx.mark_unchanged();
        let m = machine.clone();
        // The machine side samples at the same period on its own clock
        // (virtual time samples as often in virtual seconds).
        let period = options.state_period;
        machine_tasks.push(tokio::spawn(async move {
            let mut tick = tokio::time::interval(period);
            tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            loop {
                tick.tick().await;
                let Ok(t) = m.now_us().await else { continue };
                if state_tx.send(json::state(&m, t)).is_err() {
                    break;
                }
            }
        }));
        // Each sample is published as soon as it is taken, and at most
        // twice a period in real time: a machine in virtual time samples
        // faster than that, and its latest sample wins.
        zenoh_tasks.push(zenoh.spawn(async move {
            while state_rx.changed().await.is_ok() {
                let body = state_rx.borrow_and_update().to_string();
                if let Err(e) = state_pub.put(body).await {
                    tracing::warn!("zenoh state: {e}");
                }
                tokio::time::sleep(period / 2).await;
            }
        }));

        // Requests: queries in, answers out.
        let (request_tx, mut request_rx) = mpsc::unbounded_channel::<Request>();
        let queryables: [(String, AskOf); 5] = [
            (keys.info(), |_| Ask::Info),
            (keys.calls(), |q| Ask::Call {
                key: q.key_expr().as_str().to_string(),
                payload: payload_text(q),
            }),
            (keys.home(), |_| Ask::Home),
            (keys.halt(), |_| Ask::Halt),
            (keys.job(), |q| Ask::Job {
                payload: payload_text(q),
                kind: q.parameters().get("type").map(String::from),
            }),
        ];
        for (key, ask) in queryables {
            zenoh_tasks.push(zenoh.spawn(serve_queries(
                session.clone(),
                key,
                request_tx.clone(),
                ask,
            )));
        }
        let (m, k) = (machine.clone(), keys.clone());
        let jobs = Arc::new(Jobs {
            running: tokio::sync::Mutex::new(()),
            cancel: watch::channel(false).0,
        });
        machine_tasks.push(tokio::spawn(async move {
            while let Some(Request { ask, answer }) = request_rx.recv().await {
                let (m, k, jobs) = (m.clone(), k.clone(), jobs.clone());
                tokio::spawn(async move {
                    let result = match ask {
                        Ask::Info => {
                            serde_json::to_value(json::info(&m)).map_err(|e| error("internal", e))
                        }
                        Ask::Call { key, payload } => call(&m, &k, &key, payload).await,
                        Ask::Home => home(&m).await,
                        Ask::Halt => {
                            // The job stops queueing moves first, so that
                            // none follows the halt.
                            jobs.cancel.send_replace(true);
                            let held = jobs.running.lock().await;
                            let r = halt(&m).await;
                            jobs.cancel.send_replace(false);
                            drop(held);
                            r
                        }
                        Ask::Job { payload, kind } => match jobs.running.try_lock() {
                            Err(_) => Err(error(
                                "busy",
                                "a job is running: wait for its reply, or halt it",
                            )),
                            Ok(_running) => {
                                run_job(&m, payload, kind, jobs.cancel.subscribe()).await
                            }
                        },
                    };
                    let _ = answer.send(result);
                });
            }
        }));

        // Captures: each source streamed on its own, each sample
        // published as it comes.
        let mut streams = Vec::new();
        for source in &options.sources {
            let refused = |reason: String| BridgeError::Source {
                source_text: source.clone(),
                reason,
            };
            let (stream, rows) = machine
                .stream(&[source.as_str()], options.period_us, CAPTURE_QUEUE)
                .await
                .map_err(|e| refused(e.to_string()))?;
            let names: Vec<String> = stream.series().iter().map(|s| s.name.clone()).collect();
            streams.push(stream);
            let publisher = {
                let (s, k) = (session.clone(), keys.capture(source));
                zenoh
                    .spawn(async move { s.declare_publisher(k).await })
                    .await
            }
            .map_err(zerr)?
            .map_err(zerr)?;
            let (tx, mut rx) = mpsc::unbounded_channel::<Json>();
            // The stream's channel blocks: a thread of its own moves its
            // rows on, and ends when the stream stops.
            std::thread::Builder::new()
                .name(format!("capture {source}"))
                .spawn(move || {
                    while let Ok(row) = rows.recv() {
                        let body = json!({
                            "t": row.time_us as f64 * 1e-6,
                            "value": row.value,
                            "series": names.get(usize::from(row.series)),
                        });
                        if tx.send(body).is_err() {
                            break;
                        }
                    }
                })
                .map_err(|e| refused(e.to_string()))?;
            zenoh_tasks.push(zenoh.spawn(async move {
                while let Some(body) = rx.recv().await {
                    if let Err(e) = publisher.put(body.to_string()).await {
                        tracing::warn!("zenoh capture: {e}");
                    }
                }
            }));
        }

        Ok(Bridge {
            keys,
            machine_tasks,
            zenoh_tasks,
            streams,
        })
    }

    /// The keys it serves.
    pub fn keys(&self) -> &MachineKeys {
        &self.keys
    }

    /// Stops serving: the captures are unwired, every task ends and its
    /// keys are undeclared. Call it on the machine's runtime.
    pub async fn close(self) {
        for s in self.streams {
            s.stop().await;
        }
        for t in self.machine_tasks.into_iter().chain(self.zenoh_tasks) {
            t.abort();
        }
    }
}

async fn halt(machine: &Machine) -> Result<Json, String> {
    match machine.halt().await {
        Ok(r) => Ok(json!({
            "halted": r.is_complete(),
            "confirmed": r.confirmed,
            "unreachable": r.unreachable.iter().map(|u| u.module.clone()).collect::<Vec<_>>(),
        })),
        Err(e) => Err(error("halt_failed", e)),
    }
}

/// `osap/NAME/call/MODULE/FUNCTION` with a JSON array of arguments.
async fn call(
    machine: &Machine,
    keys: &MachineKeys,
    key: &str,
    payload: Option<Result<String, String>>,
) -> Result<Json, String> {
    let (module, function) = keys.parse_call(key).ok_or_else(|| {
        error(
            "bad_key",
            format!("{key}: ask osap/NAME/call/MODULE/FUNCTION"),
        )
    })?;
    let runtime = machine
        .modules()
        .get(module)
        .map(|m| m.runtime.clone())
        .ok_or_else(|| {
            let known: Vec<&String> = machine.modules().keys().collect();
            error(
                "unknown_module",
                format!("no module {module}: this machine has {known:?}"),
            )
        })?;
    let args: Vec<Json> = match payload {
        None => Vec::new(),
        Some(p) => {
            let text =
                p.map_err(|e| error("bad_arguments", format!("the payload is not UTF-8: {e}")))?;
            if text.trim().is_empty() {
                Vec::new()
            } else {
                serde_json::from_str(&text).map_err(|e| {
                    error(
                        "bad_arguments",
                        format!("the payload must be a JSON array of arguments: {e}"),
                    )
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
        let bad = |why: String| {
            error(
                "bad_arguments",
                format!("input {} ({}): {why}", input.name, input.type_name),
            )
        };
        let ty = input
            .ty()
            .ok_or_else(|| bad("a type this build does not know".into()))?;
        let text = json::argument_text(arg)
            .ok_or_else(|| bad(format!("{arg} is not a number, bool or string")))?;
        values.push(parse_value(&ty, &text).map_err(|e| bad(e.to_string()))?);
    }
    match handle.call(&values).await {
        Ok(outputs) => Ok(
            json!({ "outputs": outputs.iter().map(osap_host::som::value_json).collect::<Vec<_>>() }),
        ),
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
    if matches!(
        machine.state(),
        MachineState::Faulted(_) | MachineState::Stopped
    ) {
        machine
            .recover()
            .await
            .map_err(|e| error("recover_failed", e))?;
    }
    machine
        .home()
        .await
        .map_err(|e| error("homing_failed", e))?;
    Ok(json!({ "homed": machine.homed(), "position": machine.position() }))
}

/// The job a query carries: its text, and `type=gcode` or `type=svg`.
fn read_job(
    machine: &Machine,
    payload: Option<Result<String, String>>,
    kind: Option<String>,
) -> Result<Program, String> {
    let cfg = machine.config();
    let text = match payload {
        Some(p) => p.map_err(|e| error("bad_job", format!("the job is not UTF-8: {e}")))?,
        None => {
            return Err(error(
                "bad_job",
                "the query carries no job: put its text in the payload",
            ))
        }
    };
    match kind.as_deref() {
        Some("gcode") => {
            let g = osap_machine::gcode::read_with(&text, &job::gcode_options(cfg, None))
                .map_err(|e| error("bad_job", e))?;
            job::from_gcode(cfg, &g, &machine.position()).map_err(|e| error("bad_job", e))
        }
        Some("svg") => {
            let drawing =
                svg::read(&text, &SvgOptions::default()).map_err(|e| error("bad_job", e))?;
            job::from_svg(cfg, &drawing, cfg.limits.velocity / 2.0).map_err(|e| error("bad_job", e))
        }
        other => Err(error(
            "bad_job",
            format!(
                "type={}: say type=gcode or type=svg in the selector",
                other.unwrap_or("(none)")
            ),
        )),
    }
}

/// `osap/NAME/job`: homes if needed, runs the job, and sums it up.
async fn run_job(
    machine: &Machine,
    payload: Option<Result<String, String>>,
    kind: Option<String>,
    mut cancel: watch::Receiver<bool>,
) -> Result<Json, String> {
    let program = read_job(machine, payload, kind)?;
    if matches!(
        machine.state(),
        MachineState::Faulted(_) | MachineState::Stopped
    ) {
        return Err(error(
            "not_ready",
            format!(
                "the machine is {}: home it (osap/NAME/home recovers it) before a job",
                json::state_name(&machine.state())
            ),
        ));
    }
    if !machine.is_homed() {
        tokio::select! {
            r = machine.home() => r.map_err(|e| error("homing_failed", e))?,
            _ = cancel.wait_for(|c| *c) => return Err(error("halted", "halted while homing before the job")),
        }
    }
    let cfg = machine.config();
    let planned_s = program
        .planned_seconds(cfg, &machine.position())
        .map_err(|e| error("bad_job", e))?;
    machine
        .start_recording()
        .await
        .map_err(|e| error("job_failed", e))?;
    let t0 = machine.now_us().await.map_err(|e| error("job_failed", e))?;
    let began = tokio::time::Instant::now();
    // A halt drops the program where it stands: no move is queued after it.
    let result = tokio::select! {
        r = machine.run_program(&program, |_| {}) => r.map(|_| ()).map_err(|e| e.to_string()),
        _ = cancel.wait_for(|c| *c) => Err("halted by osap/NAME/halt".to_string()),
    };
    let executed_s = began.elapsed().as_secs_f64();
    let following_error = match machine.take_recording(t0).await {
        Ok(r) => r.following_error().into_iter().collect(),
        // The job ran; only its measurement is missing: said, not hidden.
        Err(e) => {
            tracing::warn!("job summary without following error: {e}");
            Default::default()
        }
    };
    let mut faults = Vec::new();
    if let Err(e) = result {
        faults.push(e);
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
