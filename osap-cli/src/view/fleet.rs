//! `osap view --zenoh ENDPOINT`: every machine bridged on zenoh on one
//! page, a card each (kind, state, position, homing, its latest event),
//! each linking to its own page of state and events. Read-only: the page
//! changes nothing on any machine.

use std::collections::{BTreeMap, VecDeque};
use std::process::ExitCode;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use axum::extract::{Path, Query, Request, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::{Json, Router};
use serde_json::{json, Value};

use super::http::{check_host, token_matches};
use super::ViewArgs;
use crate::bridge_cmd::{close, open_zenoh};
use crate::machine_cmd::Failure;

/// Events kept per machine.
const EVENTS_KEPT: usize = 50;
/// How often the fleet is asked who is there.
const LIST_EVERY: Duration = Duration::from_secs(2);

const FLEET_PAGE: &str = include_str!("assets/fleet.html");
const MACHINE_PAGE: &str = include_str!("assets/fleet-machine.html");

/// What the page knows of one machine.
#[derive(Debug, Default)]
struct Card {
    info: Option<Value>,
    state: Option<Value>,
    events: VecDeque<Value>,
}

type Fleet = Arc<Mutex<BTreeMap<String, Card>>>;

#[derive(Clone)]
struct FleetApp {
    fleet: Fleet,
    token: Option<String>,
    listen: std::net::SocketAddr,
}

/// The NAME of a key `osap/NAME/…`.
fn machine_of(key: &str) -> Option<String> {
    key.strip_prefix("osap/")?
        .split('/')
        .next()
        .map(String::from)
}

fn card_json(name: &str, c: &Card) -> Value {
    json!({
        "name": name,
        "info": c.info,
        "state": c.state,
        "events": c.events,
    })
}

/// Runs the fleet view until Ctrl-C.
pub(crate) async fn view_fleet(args: ViewArgs) -> Result<ExitCode, Failure> {
    let config = osap_zenoh::ZenohOptions {
        listen: Vec::new(),
        connect: args.zenoh.clone(),
        file: args.zenoh_config.clone(),
    }
    .client_config()
    .map_err(|e| Failure::refused(e.to_string()))?;
    // The page's address first: a port in use fails before zenoh starts.
    let listener = tokio::net::TcpListener::bind(args.http)
        .await
        .map_err(|e| Failure::refused(format!("--http {}: {e}", args.http)))?;
    let (rt, session) = open_zenoh(config).await?;
    let fleet: Fleet = Arc::default();

    let mut tasks = Vec::new();
    for (key, is_state) in [("osap/*/state", true), ("osap/*/events", false)] {
        let (s, f) = (session.clone(), fleet.clone());
        tasks.push(rt.spawn(async move {
            let Ok(sub) = s.declare_subscriber(key).await else {
                return;
            };
            while let Ok(sample) = sub.recv_async().await {
                let Some(name) = machine_of(sample.key_expr().as_str()) else {
                    continue;
                };
                let Ok(text) = sample.payload().try_to_string() else {
                    continue;
                };
                let Ok(v) = serde_json::from_str::<Value>(&text) else {
                    continue;
                };
                let mut fleet = f.lock().unwrap_or_else(|e| e.into_inner());
                let card = fleet.entry(name).or_default();
                if is_state {
                    card.state = Some(v);
                } else {
                    card.events.push_back(v);
                    if card.events.len() > EVENTS_KEPT {
                        card.events.pop_front();
                    }
                }
            }
        }));
    }
    let (s, f) = (session.clone(), fleet.clone());
    tasks.push(rt.spawn(async move {
        loop {
            if let Ok(found) = osap_zenoh::fleet::list(&s, Duration::from_millis(1500)).await {
                let mut fleet = f.lock().unwrap_or_else(|e| e.into_inner());
                for m in found {
                    fleet.entry(m.key_name).or_default().info = serde_json::to_value(m.info).ok();
                }
            }
            tokio::time::sleep(LIST_EVERY).await;
        }
    }));

    let listen = match listener.local_addr() {
        Ok(a) => a,
        Err(e) => {
            close(rt, session).await;
            return Err(Failure::refused(e.to_string()));
        }
    };
    let app = FleetApp {
        fleet,
        token: args.token.clone(),
        listen,
    };
    let api = Router::new()
        .route("/api/fleet", get(list))
        .route("/api/fleet/{name}", get(one))
        .route_layer(middleware::from_fn_with_state(app.clone(), guard));
    let router = Router::new()
        .route("/", get(|| async { page(FLEET_PAGE) }))
        .route("/machine/{name}", get(|| async { page(MACHINE_PAGE) }))
        .merge(api)
        .layer(middleware::from_fn_with_state(app.clone(), host_only))
        .with_state(app);
    let url = match &args.token {
        Some(t) => format!("http://{listen}/?token={t}"),
        None => format!("http://{listen}/"),
    };
    // One line: whoever reads it may close the pipe after it.
    println!("osap view (fleet on zenoh; Ctrl-C stops): {url}");
    let server = tokio::spawn(async move { axum::serve(listener, router).await });
    let _ = tokio::signal::ctrl_c().await;
    server.abort();
    for t in tasks {
        t.abort();
    }
    close(rt, session).await;
    Ok(ExitCode::SUCCESS)
}

fn page(body: &'static str) -> Response {
    (
        [
            (header::CONTENT_TYPE, "text/html; charset=utf-8"),
            (header::CACHE_CONTROL, "no-store"),
        ],
        body,
    )
        .into_response()
}

async fn list(State(app): State<FleetApp>) -> Json<Value> {
    let fleet = app.fleet.lock().unwrap_or_else(|e| e.into_inner());
    Json(Value::Array(
        fleet.iter().map(|(n, c)| card_json(n, c)).collect(),
    ))
}

async fn one(State(app): State<FleetApp>, Path(name): Path<String>) -> Response {
    let fleet = app.fleet.lock().unwrap_or_else(|e| e.into_inner());
    match fleet.get(&name) {
        Some(c) => Json(card_json(&name, c)).into_response(),
        None => (
            StatusCode::NOT_FOUND,
            format!("no machine {name} seen on zenoh"),
        )
            .into_response(),
    }
}

/// With a token, every API request carries it (`?token=`).
async fn guard(
    State(app): State<FleetApp>,
    Query(q): Query<std::collections::HashMap<String, String>>,
    request: Request,
    next: Next,
) -> Response {
    if let Some(expected) = &app.token {
        if !q.get("token").is_some_and(|g| token_matches(expected, g)) {
            return (
                StatusCode::UNAUTHORIZED,
                "token required: open the page from the URL osap view printed",
            )
                .into_response();
        }
    }
    next.run(request).await
}

/// On loopback, only requests naming the view's own address (against DNS
/// rebinding).
async fn host_only(
    State(app): State<FleetApp>,
    headers: HeaderMap,
    request: Request,
    next: Next,
) -> Response {
    let host = headers.get(header::HOST).and_then(|v| v.to_str().ok());
    if let Err(why) = check_host(app.listen, host) {
        return (StatusCode::FORBIDDEN, why).into_response();
    }
    next.run(request).await
}
