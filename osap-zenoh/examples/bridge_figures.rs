//! The bridge's figures, on a simulated plotter in real time (3 modules):
//! state and event latency from the machine to a zenoh subscriber, calls
//! per second through zenoh against direct OSAP, and the bridge's CPU cost
//! at 10 Hz state. docs/performance.md records a run of
//!
//! ```sh
//! cargo run --release -p osap-zenoh --example bridge_figures
//! ```
//!
//! (Linux: CPU time is read from /proc/self/stat.)

use std::time::{Duration, Instant};

use osap_machine::config::MachineFile;
use osap_machine::sim::SimOptions;
use osap_machine::Machine;
use osap_sim::machine::TimeMode;
use osap_zenoh::{Bridge, BridgeOptions, ZenohOptions};
use serde_json::Value;

/// This process's CPU time so far, s (user + system, at 100 ticks/s).
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // Fields after the command's closing parenthesis: utime is the 12th,
    // stime the 13th.
    let after = stat.rsplit_once(')').map_or("", |(_, r)| r);
    let f: Vec<f64> = after
        .split_whitespace()
        .map(|x| x.parse().unwrap_or(0.0))
        .collect();
    (f.get(11).unwrap_or(&0.0) + f.get(12).unwrap_or(&0.0)) / 100.0
}

fn percentile(v: &mut [f64], p: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * p).round() as usize]
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() {
    let cfg = MachineFile::load(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/machines/plotter.toml"
    ))
    .unwrap();
    let m = Machine::simulate_with(
        &cfg,
        SimOptions {
            time: TimeMode::RealTime,
        },
    )
    .await
    .unwrap();
    let idle = Duration::from_secs(10);

    // The machine alone, idle.
    tokio::time::sleep(Duration::from_secs(1)).await;
    let c0 = cpu_seconds();
    tokio::time::sleep(idle).await;
    let alone = cpu_seconds() - c0;

    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let bridge_config = ZenohOptions {
        listen: vec![endpoint.clone()],
        ..Default::default()
    }
    .bridge_config()
    .unwrap();
    let session = zenoh::open(bridge_config).await.unwrap();
    let bridge = Bridge::start(
        session.clone(),
        tokio::runtime::Handle::current(),
        m.clone(),
        BridgeOptions {
            state_period: Duration::from_millis(100),
            ..Default::default()
        },
    )
    .await
    .unwrap();

    // The bridge at 10 Hz, nobody subscribed.
    tokio::time::sleep(Duration::from_secs(1)).await;
    let c0 = cpu_seconds();
    tokio::time::sleep(idle).await;
    let bridged = cpu_seconds() - c0;

    let client_config = ZenohOptions {
        connect: vec![endpoint],
        ..Default::default()
    }
    .client_config()
    .unwrap();
    let client = zenoh::open(client_config).await.unwrap();
    let key = bridge.keys().clone();

    // State latency: each message's synchronized time against the
    // synchronized time it arrives at.
    let states = client.declare_subscriber(key.state()).await.unwrap();
    let c0 = cpu_seconds();
    let mut state_ms = Vec::new();
    while state_ms.len() < 100 {
        let s = states.recv_async().await.unwrap();
        let now = m.now_us().await.unwrap() as f64 * 1e-6;
        let v: Value = serde_json::from_str(&s.payload().try_to_string().unwrap()).unwrap();
        state_ms.push((now - v["t"].as_f64().unwrap()) * 1e3);
    }
    let subscribed = cpu_seconds() - c0;
    drop(states);

    // Event latency: the limit switches' edges while homing, stamped by
    // their modules, against when they arrive.
    let events = client.declare_subscriber(key.events()).await.unwrap();
    let watcher = m.clone();
    let event_ms = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
    let into = event_ms.clone();
    let timing = tokio::spawn(async move {
        while let Ok(s) = events.recv_async().await {
            let now = watcher.now_us().await.unwrap() as f64 * 1e-6;
            let v: Value = serde_json::from_str(&s.payload().try_to_string().unwrap()).unwrap();
            if v["kind"] == "limit" {
                into.lock()
                    .unwrap()
                    .push((now - v["t"].as_f64().unwrap()) * 1e3);
            }
        }
    });
    for _ in 0..3 {
        m.home().await.unwrap();
    }
    // The last edge's message is well under way by then.
    tokio::time::sleep(Duration::from_millis(500)).await;
    timing.abort();
    let mut event_ms = event_ms.lock().unwrap().clone();

    // Calls: one at a time, through zenoh and directly.
    let n = 300;
    let t0 = Instant::now();
    for _ in 0..n {
        let replies = client.get(key.call("a", "get_position")).await.unwrap();
        let reply = replies.recv_async().await.unwrap();
        assert!(reply.result().is_ok());
    }
    let zenoh_rate = n as f64 / t0.elapsed().as_secs_f64();
    let c0 = cpu_seconds();
    tokio::time::sleep(idle).await;
    let bridged_idle_again = cpu_seconds() - c0;
    let t0 = Instant::now();
    for _ in 0..n {
        m.call("a", "get_position", &[]).await.unwrap();
    }
    let direct_rate = n as f64 / t0.elapsed().as_secs_f64();

    println!("| figure | value |");
    println!("|---|---|");
    println!(
        "| state latency, machine to subscriber (100 messages) | p50 {:.2} ms, p99 {:.2} ms |",
        percentile(&mut state_ms.clone(), 0.5),
        percentile(&mut state_ms, 0.99)
    );
    println!(
        "| limit event latency, module edge to subscriber ({} edges) | p50 {:.2} ms, p99 {:.2} ms |",
        event_ms.len(),
        percentile(&mut event_ms.clone(), 0.5),
        percentile(&mut event_ms, 0.99)
    );
    println!("| calls/s, a.get_position through zenoh | {zenoh_rate:.0} |");
    println!("| calls/s, a.get_position direct | {direct_rate:.0} |");
    println!(
        "| CPU, the simulated machine alone | {:.1} % of a core |",
        100.0 * alone / idle.as_secs_f64()
    );
    println!(
        "| CPU added by the bridge at 10 Hz, nobody subscribed | {:.2} % of a core |",
        100.0 * (bridged - alone) / idle.as_secs_f64()
    );
    println!(
        "| CPU added by the bridge at 10 Hz with a subscriber in the same process | {:.1} % of a core |",
        100.0 * (subscribed - alone) / 10.0
    );
    println!(
        "| CPU added by the bridge at 10 Hz, nobody subscribed, measured again | {:.2} % of a core |",
        100.0 * (bridged_idle_again - alone) / idle.as_secs_f64()
    );
    bridge.close().await;
    client.close().await.unwrap();
    session.close().await.unwrap();
    m.stop().await.unwrap();
}
