//! The HTTP side of `osap view`: the embedded page, the network's
//! description, the state websocket, function calls and captures. With a
//! token, every request but the page's own files must carry it
//! (`?token=` or `Authorization: Bearer`).
//!
//! Against other pages in the same browser: a request that changes
//! state (any but GET) or opens the state websocket is refused (403) when
//! its `Origin` is not the view's own page. On a loopback address every
//! request is refused whose `Host` is not the view's address
//! (`127.0.0.1`, `localhost` or `[::1]` with its port): a page whose name
//! was rebound to 127.0.0.1 (DNS rebinding) would otherwise be the view's
//! own origin. Off loopback the token guards it, and the Host is whatever
//! name the LAN gives the machine.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{Query, Request, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use osap_host::som::{self, parse_value, FnRef};
use serde_json::{json, Value};
use tokio::sync::broadcast;

use super::info::Info;
use super::Source;

const INDEX: &str = include_str!("assets/index.html");
const APP_JS: &str = include_str!("assets/app.js");
const STYLE: &str = include_str!("assets/style.css");

/// How long a call from the page may take.
const CALL_TIMEOUT: Duration = Duration::from_secs(2);
/// Most points per series a capture is sent with.
const PLOT_POINTS: usize = 4_000;

/// What the handlers share.
#[derive(Clone)]
pub(crate) struct App {
    pub source: Arc<Source>,
    pub info: Arc<Info>,
    pub states: broadcast::Sender<String>,
    /// The newest state, for `GET /api/state`.
    pub latest: Arc<std::sync::Mutex<String>>,
    pub token: Option<String>,
    pub captures: Option<PathBuf>,
    /// The address the view listens on.
    pub listen: std::net::SocketAddr,
}

/// Serves until the task is aborted.
pub(crate) async fn serve(listener: tokio::net::TcpListener, app: App) {
    let api = Router::new()
        .route("/api/info", get(info))
        .route("/api/state", get(state))
        .route("/api/call", post(call))
        .route("/api/captures", get(captures))
        .route("/api/capture", get(capture))
        .route("/ws", get(ws))
        .route_layer(middleware::from_fn_with_state(app.clone(), require_token));
    let router = Router::new()
        .route(
            "/",
            get(|| async { page(INDEX, "text/html; charset=utf-8") }),
        )
        .route(
            "/app.js",
            get(|| async { page(APP_JS, "text/javascript; charset=utf-8") }),
        )
        .route(
            "/style.css",
            get(|| async { page(STYLE, "text/css; charset=utf-8") }),
        )
        .merge(api)
        .layer(middleware::from_fn_with_state(app.clone(), same_page))
        .with_state(app);
    if let Err(e) = axum::serve(listener, router).await {
        eprintln!("osap view: the server stopped: {e}");
    }
}

fn page(body: &'static str, kind: &'static str) -> Response {
    (
        [
            (header::CONTENT_TYPE, kind),
            (header::CACHE_CONTROL, "no-store"),
        ],
        body,
    )
        .into_response()
}

/// Whether `given` is the token, compared in constant time.
pub(super) fn token_matches(expected: &str, given: &str) -> bool {
    let (a, b) = (expected.as_bytes(), given.as_bytes());
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |d, (x, y)| d | (x ^ y)) == 0
}

async fn require_token(
    State(app): State<App>,
    Query(q): Query<std::collections::HashMap<String, String>>,
    headers: HeaderMap,
    request: Request,
    next: Next,
) -> Response {
    if let Some(expected) = &app.token {
        let bearer = headers
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.strip_prefix("Bearer "));
        let given = q.get("token").map(String::as_str).or(bearer);
        if !given.is_some_and(|g| token_matches(expected, g)) {
            return (
                StatusCode::UNAUTHORIZED,
                "this view needs its token: open the URL osap view printed",
            )
                .into_response();
        }
    }
    next.run(request).await
}

/// Refuses (403) a request from another page: one that changes state
/// or opens the websocket with an `Origin` that is not the view's own
/// page, and on a loopback address any request whose `Host` is not the
/// view's address.
async fn same_page(
    State(app): State<App>,
    headers: HeaderMap,
    request: Request,
    next: Next,
) -> Response {
    let header = |name| headers.get(name).and_then(|v| v.to_str().ok());
    let host = header(header::HOST);
    if let Err(why) = check_host(app.listen, host) {
        return (StatusCode::FORBIDDEN, why).into_response();
    }
    let changes =
        request.method() != axum::http::Method::GET || headers.contains_key(header::UPGRADE);
    if changes {
        if let Err(why) = check_origin(header(header::ORIGIN), host) {
            return (StatusCode::FORBIDDEN, why).into_response();
        }
    }
    next.run(request).await
}

/// On a loopback address, `host` must name it: its own text, or
/// `localhost`, `127.0.0.1` or `[::1]` with its port (the port may be left
/// out when it is 80).
pub(super) fn check_host(listen: std::net::SocketAddr, host: Option<&str>) -> Result<(), String> {
    if !listen.ip().is_loopback() {
        return Ok(());
    }
    let port = listen.port();
    let host = host.unwrap_or("").to_ascii_lowercase();
    let mut names = vec![
        listen.to_string(),
        format!("localhost:{port}"),
        format!("127.0.0.1:{port}"),
        format!("[::1]:{port}"),
    ];
    if port == 80 {
        names.extend([
            listen.ip().to_string(),
            "localhost".into(),
            "127.0.0.1".into(),
            "[::1]".into(),
        ]);
    }
    if names.contains(&host) {
        Ok(())
    } else {
        Err(format!(
            "Host {host:?} is not this view's address: open http://{listen}/ (a page on another name that reaches this port may be a DNS rebinding attack)"
        ))
    }
}

/// A browser's `origin` must be the view's own page: `http://` and the
/// request's `host`. No Origin at all is a program, not a page (browsers
/// send one with every POST and websocket).
fn check_origin(origin: Option<&str>, host: Option<&str>) -> Result<(), String> {
    let Some(origin) = origin else {
        return Ok(());
    };
    let own = host.map(|h| format!("http://{h}"));
    if own.is_some_and(|own| own.eq_ignore_ascii_case(origin)) {
        Ok(())
    } else {
        Err(format!(
            "Origin {origin:?} is not this view's page: osap view takes calls only from its own page"
        ))
    }
}

async fn info(State(app): State<App>) -> Json<Value> {
    Json(app.info.json.clone())
}

/// The newest state message (`null` before the first reading): what the
/// websocket pushes, for scripts that poll.
async fn state(State(app): State<App>) -> Response {
    let text = app.latest.lock().unwrap_or_else(|e| e.into_inner()).clone();
    ([(header::CONTENT_TYPE, "application/json")], text).into_response()
}

async fn ws(State(app): State<App>, upgrade: WebSocketUpgrade) -> Response {
    let states = app.states.subscribe();
    upgrade.on_upgrade(move |socket| push_states(socket, states))
}

/// Sends each state to the page until it goes away. A page that falls
/// behind skips states rather than holding up the others.
async fn push_states(mut socket: WebSocket, mut states: broadcast::Receiver<String>) {
    loop {
        tokio::select! {
            state = states.recv() => match state {
                Ok(text) => {
                    if socket.send(Message::Text(text.into())).await.is_err() {
                        return;
                    }
                }
                Err(broadcast::error::RecvError::Lagged(_)) => {}
                Err(broadcast::error::RecvError::Closed) => return,
            },
            incoming = socket.recv() => match incoming {
                Some(Ok(_)) => {}
                _ => return,
            },
        }
    }
}

/// `{"runtime", "function", "args": [text, ..]}`: calls the function with
/// the arguments parsed by its input types, and answers its outputs.
async fn call(State(app): State<App>, Json(body): Json<Value>) -> Response {
    let field = |k: &str| body.get(k).and_then(Value::as_str).map(str::to_string);
    let (Some(runtime), Some(function)) = (field("runtime"), field("function")) else {
        return (
            StatusCode::BAD_REQUEST,
            "give {\"runtime\": NAME, \"function\": NAME, \"args\": [TEXT, ..]}",
        )
            .into_response();
    };
    let texts: Vec<String> = body
        .get("args")
        .and_then(Value::as_array)
        .map(|a| {
            a.iter()
                .map(|v| match v {
                    Value::String(s) => s.clone(),
                    other => other.to_string(),
                })
                .collect()
        })
        .unwrap_or_default();
    Json(
        match call_function(&app, &runtime, &function, &texts).await {
            Ok(outputs) => json!({ "ok": true, "outputs": outputs }),
            Err(e) => json!({ "ok": false, "error": e }),
        },
    )
    .into_response()
}

async fn call_function(
    app: &App,
    runtime: &str,
    function: &str,
    texts: &[String],
) -> Result<Vec<Value>, String> {
    let manager = app
        .source
        .manager()
        .ok_or("no model of the network to call through")?;
    let handle = manager
        .lock()
        .await
        .function(&FnRef::new(runtime, function))
        .map_err(|e| e.to_string())?;
    let inputs = handle.inputs().to_vec();
    if texts.len() != inputs.len() {
        return Err(format!(
            "{function} takes {} inputs, {} given",
            inputs.len(),
            texts.len()
        ));
    }
    let mut args = Vec::new();
    for (input, text) in inputs.iter().zip(texts) {
        let ty = input
            .ty()
            .ok_or_else(|| format!("input {}: unknown type {}", input.name, input.type_name))?;
        args.push(parse_value(&ty, text).map_err(|e| format!("input {}: {e}", input.name))?);
    }
    let outputs = handle.outputs().to_vec();
    let values = tokio::time::timeout(CALL_TIMEOUT, handle.call(&args))
        .await
        .map_err(|_| format!("no answer from {runtime} within {CALL_TIMEOUT:?}"))?
        .map_err(|e| e.to_string())?;
    Ok(outputs
        .iter()
        .zip(values)
        .map(|(o, v)| json!({ "name": o.name, "type": o.type_name, "value": som::value_json(&v) }))
        .collect())
}

/// Capture files in the captures folder (names only).
async fn captures(State(app): State<App>) -> Json<Value> {
    let files = app
        .captures
        .as_deref()
        .map(list_captures)
        .unwrap_or_default();
    Json(json!({ "files": files }))
}

fn list_captures(dir: &Path) -> Vec<String> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut files: Vec<String> = entries
        .flatten()
        .filter_map(|e| e.file_name().into_string().ok())
        .filter(|n| n.ends_with(".parquet") || n.ends_with(".csv"))
        .collect();
    files.sort();
    files
}

/// `?file=NAME`: the capture's series, each thinned to at most
/// [`PLOT_POINTS`] points.
async fn capture(
    State(app): State<App>,
    Query(q): Query<std::collections::HashMap<String, String>>,
) -> Response {
    let Some(dir) = &app.captures else {
        return (StatusCode::NOT_FOUND, "no --captures folder").into_response();
    };
    let Some(name) = q.get("file") else {
        return (StatusCode::BAD_REQUEST, "give ?file=NAME").into_response();
    };
    // Only a file listed in the folder: no paths.
    if !list_captures(dir).contains(name) {
        return (StatusCode::NOT_FOUND, format!("no capture {name:?}")).into_response();
    }
    let path = dir.join(name);
    let read =
        tokio::task::spawn_blocking(move || osap_machine::capture::Capture::read(&path)).await;
    match read {
        Ok(Ok(c)) => {
            let series: Vec<Value> = c
                .series
                .iter()
                .map(|s| {
                    let step = s.time_us.len().div_ceil(PLOT_POINTS).max(1);
                    json!({
                        "name": s.name,
                        "time_us": s.time_us.iter().step_by(step).collect::<Vec<_>>(),
                        "value": s.value.iter().step_by(step).collect::<Vec<_>>(),
                    })
                })
                .collect();
            Json(json!({ "series": series })).into_response()
        }
        Ok(Err(e)) => (StatusCode::UNPROCESSABLE_ENTITY, e.to_string()).into_response(),
        Err(e) => (StatusCode::INTERNAL_SERVER_ERROR, e.to_string()).into_response(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_compare_whole() {
        assert!(token_matches("abcdefghijklmnop", "abcdefghijklmnop"));
        assert!(!token_matches("abcdefghijklmnop", "abcdefghijklmnoq"));
        assert!(!token_matches("abcdefghijklmnop", "abcdefghijklmno"));
        assert!(!token_matches("abcdefghijklmnop", ""));
    }

    #[test]
    fn a_loopback_view_answers_only_to_its_own_names() {
        let at: std::net::SocketAddr = "127.0.0.1:7078".parse().unwrap();
        for ok in [
            "127.0.0.1:7078",
            "localhost:7078",
            "LocalHost:7078",
            "[::1]:7078",
        ] {
            assert_eq!(check_host(at, Some(ok)), Ok(()), "{ok}");
        }
        for bad in [
            "evil.example:7078",
            "localhost",
            "127.0.0.1:7079",
            "localhost.evil.example:7078",
            "",
        ] {
            let e = check_host(at, Some(bad)).unwrap_err();
            assert!(e.contains("DNS rebinding"), "{e}");
        }
        assert!(check_host(at, None).is_err());
        // Port 80 may be left out.
        let web: std::net::SocketAddr = "127.0.0.1:80".parse().unwrap();
        assert_eq!(check_host(web, Some("localhost")), Ok(()));
        // Off loopback, any name the LAN gives it (the token guards it).
        let lan: std::net::SocketAddr = "0.0.0.0:7078".parse().unwrap();
        assert_eq!(check_host(lan, Some("plotter.local:7078")), Ok(()));
    }

    #[test]
    fn only_the_own_page_may_change_state() {
        let host = Some("127.0.0.1:7078");
        assert_eq!(check_origin(Some("http://127.0.0.1:7078"), host), Ok(()));
        assert_eq!(check_origin(None, host), Ok(()));
        for bad in [
            "http://evil.example",
            "http://127.0.0.1:7079",
            "https://127.0.0.1:7078",
            "null",
        ] {
            let e = check_origin(Some(bad), host).unwrap_err();
            assert!(e.contains("its own page"), "{e}");
        }
        assert!(check_origin(Some("http://127.0.0.1:7078"), None).is_err());
    }
}
