//! Every shipped topology (`osap-sim/topologies/*.toml`) scans to its own
//! graph: every module once, every link and every bus drop once as an edge
//! between the right two runtimes, and no failure. The scan asks no
//! runtime back across the link it was reached on (a point-to-point link
//! or a bus), so this is what shows that skipping the way back lost no
//! runtime and no edge.

use osap_host::map::NetworkMap;
use osap_host::netrunner::{scan, ScanOptions};
use osap_host::{Host, HostConfig};
use osap_sim::machine::{virtual_runtime, SimMachine, TimeMode};
use osap_sim::topology::{SimSpec, HOST};
use std::time::Duration;

mod common;

/// The name the host runtime has in these tests.
const HOST_NAME: &str = "h";

/// Each edge of `map` as its two ends, `name:link`, the lesser first;
/// sorted.
fn edges(map: &NetworkMap) -> Vec<String> {
    let mut out: Vec<String> = map
        .links
        .iter()
        .map(|e| {
            let end = |r: usize, l: u8| format!("{}:{l}", map.runtimes[r].name);
            let (a, b) = (end(e.a.runtime, e.a.link), end(e.b.runtime, e.b.link));
            if a <= b {
                format!("{a} {b}")
            } else {
                format!("{b} {a}")
            }
        })
        .collect();
    out.sort();
    out
}

/// The pairs of runtimes `spec` joins (links, then each bus's head and
/// drops), by name, the lesser first; sorted.
fn joined(spec: &SimSpec) -> Vec<(String, String)> {
    let name = |n: &str| if n == HOST { HOST_NAME } else { n }.to_string();
    let pair = |a: &str, b: &str| {
        let (a, b) = (name(a), name(b));
        if a <= b {
            (a, b)
        } else {
            (b, a)
        }
    };
    let mut out: Vec<(String, String)> = spec
        .links
        .iter()
        .map(|l| pair(&l.a, &l.b))
        .chain(
            spec.buses
                .iter()
                .flat_map(|b| b.drops.iter().map(|d| pair(&b.head, d))),
        )
        .collect();
    out.sort();
    out
}

#[test]
fn every_shipped_topology_scans_to_its_own_graph() {
    let mut files: Vec<_> = std::fs::read_dir(common::shipped(""))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    files.sort();
    assert!(files.len() >= 8, "{files:?}");
    for path in files {
        let spec = SimSpec::load(&path).unwrap();
        let map = virtual_runtime().unwrap().block_on(async {
            let host = Host::start(HostConfig::named(HOST_NAME)).unwrap();
            let sim = SimMachine::start_with(&host, &spec, TimeMode::Virtual)
                .await
                .unwrap();
            tokio::time::sleep(Duration::from_millis(300)).await;
            let report = scan(&host, &ScanOptions::default()).await.unwrap();
            assert!(
                report.failures.is_empty(),
                "{}: {:?}",
                path.display(),
                report.failures
            );
            sim.stop().await.unwrap();
            report.map
        });
        let file = path.file_name().unwrap().to_string_lossy();
        // Every module once, and the host.
        let mut found: Vec<&str> = map.runtimes.iter().map(|r| r.name.as_str()).collect();
        found.sort_unstable();
        let mut expected: Vec<&str> = spec
            .modules
            .iter()
            .map(|m| m.name.as_str())
            .chain([HOST_NAME])
            .collect();
        expected.sort_unstable();
        assert_eq!(found, expected, "{file}");
        // Every link and drop once, between the right two runtimes.
        let ends = edges(&map);
        let pairs: Vec<(String, String)> = ends
            .iter()
            .map(|e| {
                let (a, b) = e.split_once(' ').unwrap();
                let name = |s: &str| s.rsplit_once(':').unwrap().0.to_string();
                (name(a), name(b))
            })
            .collect();
        let mut pairs_sorted = pairs.clone();
        pairs_sorted.sort();
        assert_eq!(pairs_sorted, joined(&spec), "{file}: {ends:?}");
        // What docs/performance.md compares before and after.
        println!(
            "{file}: {} runtimes, {} edges: {}",
            map.runtimes.len(),
            ends.len(),
            ends.join(", ")
        );
    }
}
