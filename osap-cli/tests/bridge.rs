//! `osap bridge` and `osap fleet` with real zenoh sessions on loopback:
//! bridges in their own processes on simulated machines (virtual time),
//! a Rust client in this one.

mod common;

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::Duration;

use common::Killed;
use osap_zenoh::zenoh;
use serde_json::{json, Value};

fn examples() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../examples")
}

/// Starts `osap bridge MACHINE --sim --fast` on a free loopback port with
/// `extra` arguments; the process and its endpoint, once it says it
/// serves.
fn bridge(machine: &str, extra: &[&str]) -> (Killed, String) {
    let endpoint = format!("tcp/127.0.0.1:{}", common::free_port());
    let mut child = Command::new(env!("CARGO_BIN_EXE_osap"))
        .arg("bridge")
        .arg(examples().join("machines").join(machine))
        .args(["--sim", "--fast", "--zenoh-listen", &endpoint])
        .args(extra)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    assert!(line.contains("bridged on zenoh"), "{line:?}");
    (Killed(child), endpoint)
}

async fn client(endpoint: &str) -> zenoh::Session {
    let config = osap_zenoh::ZenohOptions {
        connect: vec![endpoint.to_string()],
        ..Default::default()
    }
    .client_config()
    .unwrap();
    zenoh::open(config).await.unwrap()
}

/// One query's reply: Ok(JSON) or Err(JSON of the error reply).
async fn ask(
    s: &zenoh::Session,
    selector: &str,
    payload: Option<String>,
    secs: u64,
) -> Result<Value, Value> {
    let mut get = s.get(selector).timeout(Duration::from_secs(secs));
    if let Some(p) = payload {
        get = get.payload(p);
    }
    let replies = get.await.unwrap();
    let reply = replies.recv_async().await.expect("no reply");
    let parse = |b: &zenoh::bytes::ZBytes| -> Value {
        serde_json::from_str(&b.try_to_string().unwrap()).unwrap()
    };
    match reply.result() {
        Ok(sample) => Ok(parse(sample.payload())),
        Err(e) => Err(parse(e.payload())),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_reads_info_state_and_events_calls_and_runs_a_job() {
    let (_bridge, endpoint) = bridge(
        "plotter.toml",
        &["--source", "a.analog_read(0)", "--period-us", "10000"],
    );
    let s = client(&endpoint).await;

    let info = ask(&s, "osap/plotter/info", None, 5).await.unwrap();
    assert_eq!(info["name"], "plotter");
    assert_eq!(info["kind"], "plotter");
    assert_eq!(info["modules"], json!(["a", "b", "z"]));
    assert_eq!(info["axes"], json!(["x", "y"]));
    assert_eq!(info["tools"], json!(["pen"]));

    // At least 10 state messages in 2 s (20 Hz by default), each whole.
    let states = s.declare_subscriber("osap/plotter/state").await.unwrap();
    let events = s.declare_subscriber("osap/plotter/events").await.unwrap();
    let until = tokio::time::Instant::now() + Duration::from_secs(2);
    let mut n = 0;
    while let Ok(Ok(sample)) = tokio::time::timeout_at(until, states.recv_async()).await {
        let v: Value = serde_json::from_str(&sample.payload().try_to_string().unwrap()).unwrap();
        assert!(v["t"].as_f64().unwrap() > 0.0, "{v}");
        assert!(
            v["position"]["x"].is_number() && v["homed"]["y"].is_boolean(),
            "{v}"
        );
        n += 1;
    }
    assert!(n >= 10, "{n} state messages in 2 s");
    // A subscriber's queue is bounded: one nobody drains holds up the
    // session's other replies. Undeclared once read.
    drop(states);

    // The capture: samples of a's analog input, in time order, every
    // 10 ms of the (virtual) synchronized clock.
    let samples = s
        .declare_subscriber("osap/plotter/capture/a.analog_read(0)")
        .await
        .unwrap();
    let mut times = Vec::new();
    while times.len() < 50 {
        let sample = tokio::time::timeout(Duration::from_secs(5), samples.recv_async())
            .await
            .expect("no capture samples")
            .unwrap();
        let v: Value = serde_json::from_str(&sample.payload().try_to_string().unwrap()).unwrap();
        assert!(v["value"].is_number(), "{v}");
        times.push(v["t"].as_f64().unwrap());
    }
    drop(samples);
    // Stamped by a's clock: 10 ms apart, within its sync's corrections.
    for w in times.windows(2).skip(1) {
        let dt = w[1] - w[0];
        assert!((0.00998..0.01002).contains(&dt), "{times:?}");
    }

    // Any module function: a's position, then a call with a wrong count.
    let got = ask(&s, "osap/plotter/call/a/get_position", Some("[]".into()), 5)
        .await
        .unwrap();
    assert_eq!(got["outputs"].as_array().map(Vec::len), Some(2), "{got}");
    let refused = ask(
        &s,
        "osap/plotter/call/a/get_position",
        Some("[1]".into()),
        5,
    )
    .await
    .unwrap_err();
    assert_eq!(refused["error"], "bad_arguments", "{refused}");
    let refused = ask(&s, "osap/plotter/call/q/get_position", None, 5)
        .await
        .unwrap_err();
    assert_eq!(refused["error"], "unknown_module", "{refused}");
    // The module's own refusal, by its name and text.
    let refused = ask(&s, "osap/plotter/call/z/analog_read", Some("[9]".into()), 5)
        .await
        .unwrap_err();
    assert_eq!(refused["error"], "NoSuchPin", "{refused}");
    assert!(
        refused["message"].as_str().unwrap().contains("no such pin"),
        "{refused}"
    );

    // A small G-code job: the bridge homes first (the events say so),
    // then runs it and sums it up.
    let job = "G21 G90\nG0 X20 Y20\nG1 X60 Y20 F3000\nG1 X60 Y50\nG1 X20 Y20\n";
    let summary = ask(&s, "osap/plotter/job?type=gcode", Some(job.into()), 120)
        .await
        .unwrap();
    assert!(
        summary["faults"].as_array().unwrap().is_empty(),
        "{summary}"
    );
    let planned = summary["planned_s"].as_f64().unwrap();
    let executed = summary["executed_s"].as_f64().unwrap();
    assert!(planned > 0.1 && executed >= planned, "{summary}");
    assert!(
        summary["following_error"]["x"].as_f64().unwrap() < 0.1,
        "{summary}"
    );
    let mut homed = Vec::new();
    while let Ok(sample) = events.try_recv() {
        let Some(sample) = sample else { break };
        let v: Value = serde_json::from_str(&sample.payload().try_to_string().unwrap()).unwrap();
        if v["kind"] == "homed" {
            homed.push(v["axis"].as_str().unwrap().to_string());
        }
    }
    assert_eq!(homed, ["x", "y"]);
    let bad = ask(&s, "osap/plotter/job?type=dxf", Some(job.into()), 5)
        .await
        .unwrap_err();
    assert_eq!(bad["error"], "bad_job", "{bad}");
    s.close().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_halt_query_stops_a_running_job() {
    let (_bridge, endpoint) = bridge("plotter.toml", &[]);
    let s = client(&endpoint).await;
    assert!(ask(&s, "osap/plotter/home", None, 120).await.is_ok());
    // Slow lines: about 80 s of motion.
    let job = "G21 G90\nG1 X150 Y100 F120\nG1 X10 Y10\n".to_string();
    let s2 = s.clone();
    let running =
        tokio::spawn(async move { ask(&s2, "osap/plotter/job?type=gcode", Some(job), 300).await });
    // Once it moves, a second job is refused, and a halt stops it.
    let states = s.declare_subscriber("osap/plotter/state").await.unwrap();
    loop {
        let sample = states.recv_async().await.unwrap();
        let v: Value = serde_json::from_str(&sample.payload().try_to_string().unwrap()).unwrap();
        if v["state"] == "moving" {
            break;
        }
    }
    let busy = ask(&s, "osap/plotter/job?type=gcode", Some("G1 X1\n".into()), 5)
        .await
        .unwrap_err();
    assert_eq!(busy["error"], "busy", "{busy}");
    let halted = ask(&s, "osap/plotter/halt", None, 10).await.unwrap();
    assert_eq!(halted["halted"], true, "{halted}");
    let summary = running.await.unwrap().unwrap();
    let faults = summary["faults"].as_array().unwrap();
    assert!(!faults.is_empty(), "{summary}");
    assert!(
        summary["executed_s"].as_f64().unwrap() < 0.5 * summary["planned_s"].as_f64().unwrap(),
        "{summary}"
    );
    s.close().await.unwrap();
}

#[test]
fn two_bridges_and_fleet_lists_both() {
    let (_a, a) = bridge("plotter.toml", &[]);
    let (_b, b) = bridge("mill.toml", &["--name", "shop/mill#2"]);
    let o = Command::new(env!("CARGO_BIN_EXE_osap"))
        .args(["fleet", "--zenoh-connect", &a, "--zenoh-connect", &b])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{text}");
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 2, "{text}");
    assert!(lines[0].starts_with("plotter  plotter  idle"), "{text}");
    // The name's special characters are replaced in its keys.
    assert!(lines[1].starts_with("shop_mill_2  mill  idle"), "{text}");
}

/// A plain HTTP GET: the status and the body.
fn http_get(addr: &str, path: &str) -> (u16, String) {
    use std::io::{Read, Write};
    let mut c = std::net::TcpStream::connect(addr).unwrap();
    write!(
        c,
        "GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    let mut text = String::new();
    c.read_to_string(&mut text).unwrap();
    let status = text[9..12].parse().unwrap();
    let body = text
        .split_once("\r\n\r\n")
        .map_or("", |(_, b)| b)
        .to_string();
    (status, body)
}

#[test]
fn the_fleet_view_shows_a_card_per_machine() {
    let (_a, a) = bridge("plotter.toml", &[]);
    let (_b, b) = bridge("mill.toml", &[]);
    let mut view = Command::new(env!("CARGO_BIN_EXE_osap"))
        .args([
            "view",
            "--zenoh",
            &a,
            "--zenoh",
            &b,
            "--http",
            "127.0.0.1:0",
        ])
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut line = String::new();
    let mut out = BufReader::new(view.stdout.take().unwrap());
    out.read_line(&mut line).unwrap();
    let _view = Killed(view);
    let url = line.split_whitespace().last().unwrap().to_string();
    let addr = url
        .trim_start_matches("http://")
        .trim_end_matches('/')
        .to_string();
    // Both machines, each with its info and a state, within 10 s.
    let mut fleet = Value::Null;
    for _ in 0..100 {
        let (status, body) = http_get(&addr, "/api/fleet");
        assert_eq!(status, 200, "{body}");
        fleet = serde_json::from_str(&body).unwrap();
        let ready = fleet.as_array().is_some_and(|m| {
            m.len() == 2
                && m.iter()
                    .all(|c| c["info"].is_object() && c["state"].is_object())
        });
        if ready {
            break;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let names: Vec<&str> = fleet
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["mill", "plotter"], "{fleet}");
    assert_eq!(fleet[1]["info"]["kind"], "plotter", "{fleet}");
    assert!(fleet[0]["state"]["position"]["z"].is_number(), "{fleet}");
    let (status, page) = http_get(&addr, "/");
    assert_eq!(status, 200);
    assert!(
        page.contains("Machines on zenoh") && page.contains("/machine/"),
        "{page}"
    );
    let (status, one) = http_get(&addr, "/api/fleet/plotter");
    assert_eq!(status, 200);
    assert_eq!(
        serde_json::from_str::<Value>(&one).unwrap()["name"],
        "plotter"
    );
    assert_eq!(http_get(&addr, "/machine/plotter").0, 200);
    assert_eq!(http_get(&addr, "/api/fleet/lathe").0, 404);
}

#[test]
fn a_second_bridge_on_a_taken_endpoint_fails_before_starting() {
    let (_a, endpoint) = bridge("plotter.toml", &[]);
    let o = Command::new(env!("CARGO_BIN_EXE_osap"))
        .arg("bridge")
        .arg(examples().join("machines/mill.toml"))
        .args(["--sim", "--fast", "--zenoh-listen", &endpoint])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("zenoh"), "{err}");
    // Nothing was served: the line that says so never came.
    assert!(!String::from_utf8_lossy(&o.stdout).contains("bridged"));
}

#[test]
fn a_bad_source_is_refused_with_2() {
    let o = Command::new(env!("CARGO_BIN_EXE_osap"))
        .arg("bridge")
        .arg(examples().join("machines/plotter.toml"))
        .args([
            "--sim",
            "--fast",
            "--zenoh-listen",
            &format!("tcp/127.0.0.1:{}", common::free_port()),
        ])
        .args(["--source", "a.no_such_function"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("--source a.no_such_function"), "{err}");
}

#[test]
fn a_bridge_off_loopback_without_tls_is_refused() {
    for endpoint in ["tcp/0.0.0.0:7447", "tls/0.0.0.0:7447"] {
        let o = Command::new(env!("CARGO_BIN_EXE_osap"))
            .arg("bridge")
            .arg(examples().join("machines/plotter.toml"))
            .args(["--sim", "--fast", "--zenoh-listen", endpoint])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{err}");
        assert!(
            err.contains(endpoint) && err.contains("authenticat"),
            "{err}"
        );
    }
}
