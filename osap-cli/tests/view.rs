//! `osap view` in a real browser: headless Chromium driven through
//! chromedriver (WebDriver), watching a served simulated plotter while
//! another process runs a job on it.
//! The page names every runtime, a link's load rises while the job runs, a
//! function called from the page answers with what only the module knows,
//! and a screenshot is saved. Without a token, a non-loopback address is
//! refused; with one, requests without it are.
//!
//! Needs Debian's `chromium` and `chromium-driver` (`.ci/run` installs
//! them). `OSAP_VIEW_SCREENSHOT=docs/img/osap-view.png` keeps the
//! screenshot there.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::{self, Receiver};
use std::time::{Duration, Instant};

use fantoccini::{Client, ClientBuilder, Locator};
use serde_json::{json, Value};

mod common;
use common::Killed;

const CHROMIUM: &str = "/usr/bin/chromium";

/// One test at a time: the simulated machines run in real time and need
/// the cores.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn serial() -> std::sync::MutexGuard<'static, ()> {
    ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner())
}
const CHROMEDRIVER: &str = "/usr/bin/chromedriver";

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Starts `osap view ARGS`; the child, its URL and its further stdout
/// lines.
fn start_view(args: &[&str]) -> (Killed, String, Receiver<String>) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_osap"))
        .arg("view")
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("start osap view");
    let stdout = child.stdout.take().unwrap();
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            println!("osap view> {line}");
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let child = Killed(child);
    let url = loop {
        let line = rx
            .recv_timeout(Duration::from_secs(60))
            .expect("osap view printed its URL");
        if let Some(url) = line.strip_prefix("osap view: ") {
            break url.to_string();
        }
    };
    (child, url, rx)
}

/// Waits for a stdout line starting with `prefix`.
fn wait_line(rx: &Receiver<String>, prefix: &str, limit: Duration) -> String {
    let end = Instant::now() + limit;
    loop {
        let left = end.saturating_duration_since(Instant::now());
        match rx.recv_timeout(left) {
            Ok(line) if line.starts_with(prefix) => return line,
            Ok(_) => {}
            Err(e) => panic!("no line {prefix:?} within {limit:?}: {e}"),
        }
    }
}

/// chromedriver and the browsers it starts, in a process group of their
/// own: dropped, the whole group is killed, so a failed test leaves no
/// browser behind.
struct Group(Child);

impl Drop for Group {
    fn drop(&mut self) {
        let _ = Command::new("kill")
            .args(["-KILL", "--", &format!("-{}", self.0.id())])
            .status();
        let _ = self.0.wait();
    }
}

/// chromedriver on a free port, once it accepts connections.
fn start_chromedriver() -> (Group, u16) {
    assert!(
        Path::new(CHROMEDRIVER).exists() && Path::new(CHROMIUM).exists(),
        "the browser test needs Debian's chromium and chromium-driver: apt-get install chromium chromium-driver"
    );
    let port = common::free_port();
    // At the lowest priority: the simulated machine runs in real time and
    // must not wait for the browser's rendering.
    let child: Child = Command::new("nice")
        .args(["-n", "19", CHROMEDRIVER])
        .process_group(0)
        .arg(format!("--port={port}"))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start chromedriver");
    let driver = Group(child);
    let end = Instant::now() + Duration::from_secs(20);
    while TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(Instant::now() < end, "chromedriver did not listen");
        std::thread::sleep(Duration::from_millis(50));
    }
    (driver, port)
}

async fn browser(port: u16, profile: &Path) -> Client {
    let mut caps = serde_json::Map::new();
    caps.insert(
        "goog:chromeOptions".into(),
        json!({
            "binary": CHROMIUM,
            "args": [
                "--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                "--disable-quic", "--no-first-run", "--disable-background-networking",
                "--disable-component-update", "--disable-sync", "--window-size=1400,1700",
                format!("--user-data-dir={}", profile.display()),
            ]
        }),
    );
    let connector = hyper_util::client::legacy::connect::HttpConnector::new();
    ClientBuilder::new(connector)
        .capabilities(caps)
        .connect(&format!("http://127.0.0.1:{port}"))
        .await
        .expect("a chromium session")
}

/// Runs `script` in the page until it returns something other than null
/// (or `limit` passes).
async fn wait_js(c: &Client, script: &str, limit: Duration) -> Value {
    let end = Instant::now() + limit;
    loop {
        let v = c.execute(script, vec![]).await.expect("run script");
        if !v.is_null() {
            return v;
        }
        assert!(Instant::now() < end, "timed out waiting for {script}");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// `bytes/s` and load of the hub's link to module x in the page's state.
const HUB_TO_A: &str = r#"
const v = window.osapView; if (!v || !v.state || !v.info) return null;
const hub = v.info.runtimes.find(r => r.name === "hub");
const a = v.info.runtimes.find(r => r.name === "mill-x");
const link = hub.links.find(l => l.peer === a.id);
const s = v.state.links.find(l => l.runtime === hub.id && l.index === link.index);
if (!s) return null;
return [s.rx_bytes_per_s + s.tx_bytes_per_s, s.load === null ? -1 : s.load, v.state.time_us];
"#;

/// The page's reading of the hub's link to a once a newer state than
/// `after_us` has come: (bytes/s, load, time).
async fn hub_to_x(c: &Client, after_us: f64) -> (f64, f64, f64) {
    let end = Instant::now() + Duration::from_secs(10);
    loop {
        let v = wait_js(c, HUB_TO_A, Duration::from_secs(10)).await;
        let t = v[2].as_f64().unwrap_or(0.0);
        if t > after_us {
            return (v[0].as_f64().unwrap(), v[1].as_f64().unwrap(), t);
        }
        assert!(Instant::now() < end, "the page's state stopped changing");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// A mill served by `osap serve`, watched by `osap view` over TCP in
/// Chromium while a separate `osap run` runs a short job on it.
#[test]
fn the_page_shows_the_network_its_load_and_calls_its_functions() {
    let _one = serial();
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap()
        .block_on(browse_a_served_mill());
}

async fn browse_a_served_mill() {
    let dir = std::env::temp_dir().join(format!("osap-view-test-{}", std::process::id()));
    let captures = dir.join("captures");
    std::fs::create_dir_all(&captures).unwrap();
    std::fs::write(
        captures.join("ramp.csv"),
        "time_us,series,value\n1000,a.get_position.position,0\n2000,a.get_position.position,1\n3000,a.get_position.position,2\n",
    )
    .unwrap();
    // The browser first: its start-up takes both cores for a moment, and
    // the simulated machine runs in real time.
    let (_driver, port) = start_chromedriver();
    let c = browser(port, &dir.join("profile")).await;
    let mill = root().join("examples/machines/mill.toml");
    let (_server, addr) = common::serve(&mill);
    let (_view, url, _lines) = start_view(&[
        "--tcp",
        &addr,
        "--interval-ms",
        "500",
        "--http",
        "127.0.0.1:0",
        "--captures",
        captures.to_str().unwrap(),
    ]);
    c.goto(&url).await.unwrap();

    // Every runtime of the network is named on the page.
    let names = wait_js(
        &c,
        "const v = window.osapView; return v && v.info && v.state ? v.info.runtimes.map(r => r.name) : null;",
        Duration::from_secs(30),
    )
    .await;
    let names: Vec<String> = serde_json::from_value(names).unwrap();
    for expected in ["hub", "mill-x", "mill-y", "mill-z"] {
        assert!(names.iter().any(|n| n == expected), "{names:?}");
    }
    let text = c
        .find(Locator::Css("body"))
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    for n in &names {
        assert!(text.contains(n.as_str()), "{n} is not on the page");
    }

    // At rest the hub's link to x carries clock sync and the view's own
    // reads; while another process runs a job it carries the motion.
    let (_, _, t) = hub_to_x(&c, 0.0).await;
    let (idle_bytes, idle_load, mut t) = hub_to_x(&c, t).await;
    let out = dir.join("run");
    let job = dir.join("short.gcode");
    std::fs::write(
        &job,
        "G21 G90\nG1 X20 Y20 F1800\nG1 Z-5 F300\nG1 X40 Y35\nG1 X20\nG0 Z-3\n",
    )
    .unwrap();
    let mut run = Command::new(env!("CARGO_BIN_EXE_osap"))
        .arg("run")
        .arg(&mill)
        .arg(&job)
        .args(["--tcp", &addr, "--no-home", "--out"])
        .arg(&out)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let (mut busy_bytes, mut busy_load) = (0.0f64, 0.0f64);
    let end = Instant::now() + Duration::from_secs(180);
    let status = loop {
        if let Some(status) = run.try_wait().unwrap() {
            break status;
        }
        assert!(Instant::now() < end, "the job did not end");
        let (b, l, now) = hub_to_x(&c, t).await;
        t = now;
        busy_bytes = busy_bytes.max(b);
        busy_load = busy_load.max(l);
    };
    let mut err = String::new();
    run.stderr.take().unwrap().read_to_string(&mut err).unwrap();
    // The job is the load, not what is tested: three debug-built
    // processes and a browser on two cores can starve the simulated
    // machine's real-time stream, and then it stops with a fault (which
    // the page shows). The load rose either way.
    if !status.success() {
        println!("osap run ended early (the load was measured while it ran): {err}");
    }
    println!(
        "hub -> mill-x: {idle_bytes:.0} B/s (load {idle_load:.4}) at rest, up to {busy_bytes:.0} B/s (load {busy_load:.4}) during the job"
    );
    assert!(
        busy_bytes > 2.0 * idle_bytes + 500.0,
        "{busy_bytes} B/s during the job vs {idle_bytes} at rest"
    );
    assert!(
        busy_load > idle_load && idle_load >= 0.0,
        "{busy_load} vs {idle_load}"
    );

    // A call from the page reaches module z: digital_read answers with
    // the module's own synchronized time of the read, which is the time
    // the page shows, within its update interval and the call's trip.
    c.find(Locator::Css(r#"[data-function="mill-z/digital_read"]"#))
        .await
        .expect("mill-z/digital_read on the page")
        .click()
        .await
        .unwrap();
    c.find(Locator::Css(r#"#function-panel input[name="arg0"]"#))
        .await
        .unwrap()
        .send_keys("0")
        .await
        .unwrap();
    let before_us = hub_to_x(&c, 0.0).await.2;
    c.find(Locator::Id("call-button"))
        .await
        .unwrap()
        .click()
        .await
        .unwrap();
    let result = wait_js(
        &c,
        "const r = document.getElementById('call-result'); return r && r.textContent.includes('time') ? r.textContent : null;",
        Duration::from_secs(10),
    )
    .await;
    let result = result.as_str().unwrap().to_string();
    let module_us: f64 = result
        .split("time")
        .nth(1)
        .and_then(|t| {
            t.split(|ch: char| !ch.is_ascii_digit())
                .find(|w| !w.is_empty())
        })
        .and_then(|w| w.parse().ok())
        .unwrap_or_else(|| panic!("no time in {result:?}"));
    assert!(
        (module_us - before_us).abs() < 2e6,
        "module z read at {module_us} µs, the page showed {before_us} µs: {result}"
    );

    // The capture folder is offered for plotting.
    let files = wait_js(
        &c,
        "const s = document.getElementById('capture-file'); return s && s.options.length > 1 ? Array.from(s.options).map(o => o.value) : null;",
        Duration::from_secs(10),
    )
    .await;
    assert!(files.to_string().contains("ramp.csv"), "{files}");

    // The graph and the page from their top-left corner.
    c.execute(
        "document.querySelectorAll('*').forEach(e => { e.scrollLeft = 0; e.scrollTop = 0; }); window.scrollTo(0, 0);",
        vec![],
    )
    .await
    .unwrap();
    let png = c.screenshot().await.unwrap();
    assert!(
        png.starts_with(b"\x89PNG") && png.len() > 10_000,
        "{} bytes",
        png.len()
    );
    let shot = std::env::var_os("OSAP_VIEW_SCREENSHOT")
        .map(PathBuf::from)
        .unwrap_or_else(|| dir.join("osap-view.png"));
    std::fs::write(&shot, &png).unwrap();
    println!("screenshot: {}", shot.display());
    c.close().await.unwrap();
    let _ = std::fs::remove_dir_all(&dir);
}

/// One HTTP/1.1 GET; the status code and the body.
fn get(addr: &str, path: &str) -> (u16, String) {
    let mut s = TcpStream::connect(addr).unwrap();
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    let mut reply = String::new();
    s.read_to_string(&mut reply).unwrap();
    let code = reply
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or(0);
    let body = reply
        .split_once("\r\n\r\n")
        .map_or(String::new(), |(_, b)| b.to_string());
    (code, body)
}

fn get_status(addr: &str, path: &str) -> u16 {
    get(addr, path).0
}

fn addr_of(url: &str) -> String {
    url.trim_start_matches("http://")
        .split('/')
        .next()
        .unwrap()
        .to_string()
}

/// With a machine file and --job, the view runs the job: its state shows
/// the axes moving and the machine's state, then at rest and homed.
#[test]
fn a_job_run_by_the_view_shows_its_axes() {
    let _one = serial();
    let dir = std::env::temp_dir().join(format!("osap-view-job-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let job = dir.join("square.svg");
    std::fs::write(
        &job,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="40mm" height="40mm" viewBox="0 0 40 40"><rect x="10" y="10" width="20" height="20" fill="none" stroke="black"/></svg>"#,
    )
    .unwrap();
    let plotter = root().join("examples/machines/plotter.toml");
    let (_view, url, lines) = start_view(&[
        plotter.to_str().unwrap(),
        "--sim",
        "--http",
        "127.0.0.1:0",
        "--job",
        job.to_str().unwrap(),
    ]);
    let addr = addr_of(&url);
    let state = || -> Value {
        let (code, body) = get(&addr, "/api/state");
        assert_eq!(code, 200);
        serde_json::from_str(&body).unwrap()
    };
    let started = wait_line(&lines, "job: ", Duration::from_secs(90));
    assert!(!started.starts_with("job: failed"), "{started}");
    let mut seen_moving = false;
    let mut xs = Vec::new();
    let end = Instant::now() + Duration::from_secs(90);
    let mut done = false;
    while !done {
        assert!(Instant::now() < end, "the job did not end");
        let s = state();
        if s["machine"]["state"] == "Moving" {
            seen_moving = true;
            xs.push(s["axes"][0]["position"].as_f64().unwrap());
        }
        while let Ok(line) = lines.try_recv() {
            assert!(!line.starts_with("job: failed"), "{line}");
            done |= line.starts_with("job: done");
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    assert!(seen_moving, "the state never said Moving");
    let (lo, hi) = xs
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), x| {
            (l.min(*x), h.max(*x))
        });
    assert!(hi - lo > 5.0, "x moved only {lo}..{hi}");
    // After it: the next reading shows the machine at rest, homed.
    let t = state()["time_us"].as_f64().unwrap();
    let end = Instant::now() + Duration::from_secs(5);
    let s = loop {
        let s = state();
        if s["time_us"].as_f64().unwrap() > t {
            break s;
        }
        assert!(Instant::now() < end, "no new state");
        std::thread::sleep(Duration::from_millis(50));
    };
    assert_eq!(s["machine"]["state"], "Idle", "{s}");
    let axes = s["axes"].as_array().unwrap();
    assert_eq!(axes.len(), 2);
    assert!(axes.iter().all(|a| a["homed"] == true), "{s}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn remote_access_needs_a_token() {
    let _one = serial();
    let o = Command::new(env!("CARGO_BIN_EXE_osap"))
        .args(["view", "--sim"])
        .arg(root().join("examples/machines/plotter.toml"))
        .args(["--http", "0.0.0.0:0"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("--token"), "{stderr}");

    let token = "0123456789abcdef0123";
    let topology = root().join("osap-sim/topologies/small-machine.toml");
    let (_view, url, _lines) = start_view(&[
        "--sim",
        topology.to_str().unwrap(),
        "--http",
        "127.0.0.1:0",
        "--token",
        token,
    ]);
    assert!(url.ends_with(&format!("?token={token}")), "{url}");
    let addr = addr_of(&url);
    assert_eq!(get_status(&addr, "/api/info"), 401);
    assert_eq!(
        get_status(&addr, "/api/info?token=wrong-token-0000000"),
        401
    );
    assert_eq!(get_status(&addr, &format!("/api/info?token={token}")), 200);
    // The page itself holds no data and needs none.
    assert_eq!(get_status(&addr, "/"), 200);
}

/// One HTTP/1.1 request with the headers given (`Host` among them); the
/// status code and the body.
fn request(
    addr: &str,
    method: &str,
    path: &str,
    headers: &[(&str, &str)],
    body: &str,
) -> (u16, String) {
    let mut s = TcpStream::connect(addr).unwrap();
    let mut text = format!("{method} {path} HTTP/1.1\r\n");
    if !headers.iter().any(|(k, _)| *k == "Connection") {
        text += "Connection: close\r\n";
    }
    for (k, v) in headers {
        text += &format!("{k}: {v}\r\n");
    }
    if !body.is_empty() {
        text += &format!(
            "Content-Type: application/json\r\nContent-Length: {}\r\n",
            body.len()
        );
    }
    text += "\r\n";
    text += body;
    s.write_all(text.as_bytes()).unwrap();
    let mut reply = String::new();
    if headers.iter().any(|(k, _)| *k == "Upgrade") {
        // An upgraded connection stays open: its status line is enough.
        BufReader::new(s).read_line(&mut reply).unwrap();
    } else {
        s.read_to_string(&mut reply).unwrap();
    }
    let code = reply
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or(0);
    let body = reply
        .split_once("\r\n\r\n")
        .map_or(String::new(), |(_, b)| b.to_string());
    (code, body)
}

/// A page on another site in the same browser cannot drive the machine:
/// a call whose Origin is not the view's page is refused and has no
/// effect, and on loopback a request under any other Host name (a DNS
/// rebinding page) is refused, page and API alike.
#[test]
fn requests_from_other_pages_are_refused() {
    let _one = serial();
    let topology = root().join("osap-sim/topologies/small-machine.toml");
    let (_view, url, _lines) =
        start_view(&["--sim", topology.to_str().unwrap(), "--http", "127.0.0.1:0"]);
    let addr = addr_of(&url);
    let port = addr.rsplit(':').next().unwrap().to_string();

    // Host: the view's own names only.
    for host in [
        addr.clone(),
        format!("localhost:{port}"),
        format!("[::1]:{port}"),
    ] {
        let (code, _) = request(&addr, "GET", "/api/info", &[("Host", &host)], "");
        assert_eq!(code, 200, "{host}");
    }
    for host in [
        format!("evil.example:{port}"),
        "localhost".into(),
        String::new(),
    ] {
        for path in ["/api/info", "/", "/api/state"] {
            let (code, body) = request(&addr, "GET", path, &[("Host", &host)], "");
            assert_eq!(code, 403, "{host} {path}: {body}");
            assert!(body.contains("DNS rebinding"), "{body}");
        }
    }

    // Calls: x's set_enable, read back through get_status.
    let own = format!("http://{addr}");
    let call = |origin: Option<&str>, function: &str, args: &str| {
        let mut headers = vec![("Host", addr.as_str())];
        if let Some(o) = origin {
            headers.push(("Origin", o));
        }
        let body = format!(r#"{{"runtime": "x", "function": "{function}", "args": [{args}]}}"#);
        request(&addr, "POST", "/api/call", &headers, &body)
    };
    let enabled = |origin: Option<&str>| -> bool {
        let (code, body) = call(origin, "get_status", "");
        assert_eq!(code, 200, "{body}");
        let v: Value = serde_json::from_str(&body).unwrap();
        assert_eq!(v["ok"], true, "{v}");
        v["outputs"][2]["value"].as_bool().unwrap()
    };
    let before = enabled(Some(&own));
    let flip = if before { "\"false\"" } else { "\"true\"" };
    for evil in [
        "http://evil.example",
        "null",
        &format!("http://localhost:{port}"),
    ] {
        let (code, body) = call(Some(evil), "set_enable", flip);
        assert_eq!(code, 403, "{evil}: {body}");
        assert!(body.contains("its own page"), "{body}");
    }
    assert_eq!(enabled(None), before, "a refused call changed the module");
    // The page itself, and a program (no Origin), may call.
    let (code, body) = call(Some(&own), "set_enable", flip);
    assert_eq!(code, 200, "{body}");
    assert_eq!(enabled(None), !before);

    // The state websocket: from the page only.
    let upgrade = |origin: &str| {
        request(
            &addr,
            "GET",
            "/ws",
            &[
                ("Host", addr.as_str()),
                ("Origin", origin),
                ("Upgrade", "websocket"),
                ("Connection", "Upgrade"),
                ("Sec-WebSocket-Version", "13"),
                ("Sec-WebSocket-Key", "dGhlIHNhbXBsZSBub25jZQ=="),
            ],
            "",
        )
        .0
    };
    assert_eq!(upgrade("http://evil.example"), 403);
    assert_eq!(upgrade(&own), 101);
}

/// Off loopback the token guards the view, under whatever name the LAN
/// gives the machine.
#[test]
fn off_loopback_any_host_name_with_the_token() {
    let _one = serial();
    let token = "0123456789abcdef0123";
    let topology = root().join("osap-sim/topologies/small-machine.toml");
    let (_view, url, _lines) = start_view(&[
        "--sim",
        topology.to_str().unwrap(),
        "--http",
        "0.0.0.0:0",
        "--token",
        token,
    ]);
    let port = addr_of(&url).rsplit(':').next().unwrap().to_string();
    let addr = format!("127.0.0.1:{port}");
    let lan = format!("plotter.lan:{port}");
    let path = format!("/api/info?token={token}");
    assert_eq!(request(&addr, "GET", &path, &[("Host", &lan)], "").0, 200);
    assert_eq!(
        request(&addr, "GET", "/api/info", &[("Host", &lan)], "").0,
        401
    );
}
