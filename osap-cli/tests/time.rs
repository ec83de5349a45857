//! `osap time` against a served machine: JSON samples, settling, and a
//! second process that must not take the machine's clock.

use osap_core::clock::{ClockStatus, SyncState, TimeConfig};
use osap_core::netresponder::Status;
use osap_core::route::Route;
use osap_host::link::tcp;
use osap_host::netrunner::{self, Netrunner, ScanOptions, SyncGoal};
use osap_host::{Host, HostConfig, HostError};
use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

mod common;

fn shipped(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../osap-sim/topologies")
        .join(name)
}

const RUNTIMES: [&str; 7] = ["host", "sim-host", "hub", "x", "y", "z", "tool"];

#[test]
fn time_json_prints_one_object_per_runtime() {
    let (_server, addr) = common::serve(&shipped("small-machine.toml"));
    let out = Command::new(env!("CARGO_BIN_EXE_osap"))
        .args(["time", "--json", "--tcp", &addr])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let lines: Vec<serde_json::Value> = stdout
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect();
    let names: Vec<&str> = lines.iter().filter_map(|v| v["runtime"].as_str()).collect();
    assert_eq!(names, RUNTIMES, "{stdout}");
    for v in &lines {
        assert!(v.get("error").is_none(), "{v}");
        for field in ["state", "settled", "offset_us", "untrusted", "jumps"] {
            assert!(v.get(field).is_some(), "{field} missing in {v}");
        }
    }
    // The serving host is the machine's root; this client follows it.
    let sim_host = &lines[1];
    assert_eq!(sim_host["state"], "root", "{sim_host}");
    assert_eq!(sim_host["tier"], 0);
    assert_eq!(sim_host["settled"], true);
    assert_ne!(lines[0]["state"], "root", "{}", lines[0]);
}

#[test]
fn time_watch_shows_the_served_machine_settle() {
    let (_server, addr) = common::serve(&shipped("small-machine.toml"));
    let mut watch = common::Killed(
        Command::new(env!("CARGO_BIN_EXE_osap"))
            .args(["time", "--json", "--watch", "--interval", "200"])
            .args(["--tcp", &addr])
            .stdout(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let lines = BufReader::new(watch.0.stdout.take().unwrap()).lines();
    // Bounded: a cold start settles within seconds; a loaded machine gets
    // a minute.
    let deadline = Instant::now() + Duration::from_secs(60);
    let mut round: Vec<serde_json::Value> = Vec::new();
    let mut rounds = 0;
    for line in lines {
        let v: serde_json::Value = serde_json::from_str(&line.unwrap()).unwrap();
        if round.first().is_some_and(|f| f["t_s"] != v["t_s"]) {
            round.clear();
        }
        round.push(v);
        if round.len() < RUNTIMES.len() {
            continue;
        }
        rounds += 1;
        let settled = round.iter().all(|v| v["settled"] == true);
        if settled {
            for v in &round {
                let state = if v["runtime"] == "sim-host" {
                    "root"
                } else {
                    "synced"
                };
                assert_eq!(v["state"], state, "{v}");
                assert!(v["offset_us"].as_f64().unwrap().abs() <= 50.0, "{v}");
            }
            return;
        }
        assert!(
            Instant::now() < deadline,
            "not settled after {rounds} rounds: {round:?}"
        );
    }
    panic!("osap time --watch ended after {rounds} rounds");
}

/// Every served runtime's clock status, by name, read from `host`.
async fn statuses(host: &Host) -> Vec<(String, Route, ClockStatus)> {
    let map = netrunner::scan(host, &ScanOptions::default())
        .await
        .unwrap()
        .map;
    let runner = Netrunner::new(host).await.unwrap();
    let mut out = Vec::new();
    for r in map.runtimes.iter().filter(|r| !r.route.is_empty()) {
        let status = runner.clock_status(&r.route()).await.unwrap();
        out.push((r.name.clone(), r.route(), status));
    }
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_second_process_cannot_move_a_served_clock() {
    let (_server, addr) = common::serve(&shipped("small-machine.toml"));
    // A rogue: a host that claims to be a root (tier 0), attached over TCP.
    let rogue = Host::start(HostConfig::named("rogue")).unwrap();
    let link = tcp::connect(&rogue, &addr).await.unwrap();
    let runner = Netrunner::new(&rogue).await.unwrap();
    let goal = SyncGoal {
        max_offset: Duration::from_micros(200),
        quiet: Duration::from_millis(200),
        timeout: Duration::from_secs(60),
    };
    let before = statuses(&rogue).await;
    for (_, route, s) in before.iter().filter(|(_, _, s)| s.state != SyncState::Root) {
        runner
            .wait_synchronised(route, goal)
            .await
            .unwrap_or_else(|e| panic!("{e} ({s:?})"));
    }
    let before = statuses(&rogue).await;
    // It tries to demote the serving host so that it would follow.
    let sim_host = Route::through_links(&[link.index()]).unwrap();
    let demote = TimeConfig {
        root: false,
        ..runner.time_config(&sim_host).await.unwrap()
    };
    let err = runner
        .set_time_config(&sim_host, &demote)
        .await
        .unwrap_err();
    assert!(
        matches!(
            err,
            HostError::Remote {
                status: Status::Refused,
                ..
            }
        ),
        "{err}"
    );
    // And a second `osap time` process that insists on being a root runs
    // beside it.
    let out = tokio::task::spawn_blocking(move || {
        Command::new(env!("CARGO_BIN_EXE_osap"))
            .args(["time", "--clock", "root", "--tcp", &addr])
            .output()
            .unwrap()
    })
    .await
    .unwrap();
    assert!(out.status.success(), "{out:?}");
    let after = statuses(&rogue).await;
    assert_eq!(before.len(), 6, "{before:?}");
    // Every served runtime still follows the same source at the same tier,
    // within a few ms of it. (A module of a real-time simulation on a busy
    // 2-core machine is noisy, hundreds of µs at times, and may step while
    // it settles; following the rogue, whose time is a whole start-up
    // apart, would change tiers and take the serving host out of its root
    // state.)
    for ((name, _, b), (_, _, a)) in before.iter().zip(&after) {
        assert_eq!((a.tier, a.state), (b.tier, b.state), "{name}");
        assert!(a.offset_ns.abs() < 5_000_000, "{name}: {a:?}");
    }
    let (name, _, root) = &after[0];
    assert_eq!((name.as_str(), root.state), ("sim-host", SyncState::Root));
    assert!(root.stats.untrusted >= 1, "{root:?}");
}

#[test]
fn time_exits_non_zero_when_a_runtime_cannot_be_read() {
    let plotter =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../examples/machines/plotter.toml");
    let mut served = common::Controlled::start(&plotter);
    // Heard first: a module that never said a word before it froze is,
    // to a scan, an open link with no neighbour, not a failure.
    let scan = Command::new(env!("CARGO_BIN_EXE_osap"))
        .args(["scan", "--tcp", &served.addr])
        .output()
        .unwrap();
    assert!(scan.status.success(), "{scan:?}");
    assert_eq!(served.command("freeze b"), "ok freeze b");
    let out = Command::new(env!("CARGO_BIN_EXE_osap"))
        .args(["time", "--json", "--tcp", &served.addr])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("could not be read"), "{stderr}");
    // The others are still listed.
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("\"runtime\":\"sim-host\""), "{stdout}");
}
