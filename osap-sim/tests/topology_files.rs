//! One topology format: every shipped `osap-sim/topologies/*.toml` runs in
//! both simulators, and the discrete-event network built from a file has
//! the nodes, links and per-node link indices the simulated machine built
//! from it has, as seen over the network.

use osap_core::link::LinkGateway;
use osap_core::netresponder::key;
use osap_core::route::Route;
use osap_host::netrunner::Netrunner;
use osap_host::{HostError, PortHandle};
use osap_sim::machine::SimMachine;
use osap_sim::network::Gateway;
use osap_sim::topology::{SimSpec, HOST};
use osap_sim::{Network, Scenario, Sim, SimConfig};
use std::collections::VecDeque;
use std::path::PathBuf;
use std::time::Duration;

mod common;
use common::shipped;

/// Every `*.toml` in `osap-sim/topologies/` without an RS-485 bus: the
/// discrete-event simulator models none and refuses them (checked in
/// `bus_topologies_are_refused_by_the_discrete_event_simulator`; they run in
/// the simulated machines, `tests/bus.rs` and `tests/bus32.rs`).
fn shipped_files() -> Vec<PathBuf> {
    all_shipped_files()
        .into_iter()
        .filter(|p| SimSpec::load(p).is_ok_and(|m| m.buses.is_empty()))
        .collect()
}

/// Every `*.toml` in `osap-sim/topologies/`.
fn all_shipped_files() -> Vec<PathBuf> {
    let dir = shipped("");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    files.sort();
    assert!(files.len() >= 6, "{files:?}");
    files
}

#[test]
fn no_text_topologies_are_left() {
    for e in std::fs::read_dir(shipped("")).unwrap() {
        let path = e.unwrap().path();
        assert_eq!(
            path.extension().and_then(|e| e.to_str()),
            Some("toml"),
            "{}: topologies are TOML files",
            path.display()
        );
    }
}

#[test]
fn bus_topologies_are_refused_by_the_discrete_event_simulator() {
    let buses: Vec<PathBuf> = all_shipped_files()
        .into_iter()
        .filter(|p| SimSpec::load(p).is_ok_and(|m| !m.buses.is_empty()))
        .collect();
    assert!(buses.iter().any(|p| p.ends_with("bus32.toml")), "{buses:?}");
    for path in buses {
        let e = Network::load(&path).unwrap_err().to_string();
        assert!(
            e.contains("models no RS-485 bus"),
            "{}: {e}",
            path.display()
        );
    }
}

#[test]
fn every_shipped_topology_runs_in_the_discrete_event_simulator() {
    for path in shipped_files() {
        let file = path.display();
        let m = SimSpec::load(&path).unwrap_or_else(|e| panic!("{file}: {e}"));
        m.validate().unwrap();
        let t = Network::load(&path).unwrap_or_else(|e| panic!("{file}: {e}"));
        assert_eq!(Network::try_from(&m).unwrap(), t, "{file}");
        // Node 0 is the host, then the modules in file order.
        let names: Vec<&str> = t.nodes.iter().map(|n| n.name.as_str()).collect();
        let expected: Vec<&str> = std::iter::once(HOST)
            .chain(m.modules.iter().map(|s| s.name.as_str()))
            .collect();
        assert_eq!(names, expected, "{file}");
        assert_eq!(t.links.len(), m.links.len(), "{file}");
        assert_eq!(t.name, m.name, "{file}");

        let outcome = Scenario::from_spec(&m)
            .unwrap()
            .seconds(5.0)
            .run()
            .unwrap_or_else(|e| panic!("{file}: {e}"));
        let metrics = &outcome.metrics;
        assert_eq!(metrics.node_count(), t.nodes.len(), "{file}");
        assert!(metrics.all_tiered_time(255).is_some(), "{file}: not tiered");
        let converged = metrics.worst_convergence_time(50.0);
        assert!(
            converged.is_some_and(|s| s < 4.0),
            "{file}: within 50 µs after {converged:?} s"
        );
        let last = metrics.worst_abs().last().copied().unwrap();
        assert!(last < 50.0, "{file}: worst error {last} µs at the end");
    }
}

/// Asks the netresponder at the end of `route` for its name, retrying a
/// few times: a real-time machine on a loaded CI machine can miss one.
async fn name_at(port: &PortHandle, route: &Route) -> Result<String, HostError> {
    let mut attempt = 0;
    let reply = loop {
        match port
            .request(route, 0, &[key::NAME], Duration::from_secs(1))
            .await
        {
            Ok(r) => break r,
            Err(HostError::Timeout { .. }) if attempt < 3 => attempt += 1,
            Err(e) => return Err(e),
        }
    };
    assert_eq!(&reply.body[..2], &[key::NAME, 0], "{:?}", reply.body);
    Ok(String::from_utf8(reply.body[3..].to_vec()).unwrap())
}

/// Checks, over the network of the machine `path` describes, that every
/// link gateway of the discrete-event network built from the same file is
/// where the machine has it: the same peer behind the same link index, the
/// same type, name, MTU and state, and the same number of gateways.
async fn same_links_as_the_machine(path: PathBuf) {
    let file = path.display().to_string();
    let m = SimSpec::load(&path).unwrap();
    let t = Network::load(&path).unwrap();
    let sim = Sim::new(&t, SimConfig::default()).unwrap();
    let gateways = t.gateways().unwrap();
    let ends = t.endpoints();
    let host = common::host(HOST);
    let machine = SimMachine::start(&host, &m).await.unwrap();
    let host_links = machine.host_links().to_vec();
    assert_eq!(host_links.len(), gateways[0].len(), "{file}: host links");

    // Routes from the host in the simulator's indices (the host's first hop
    // in the machine's host link indices), breadth first over the links in
    // file order, as the machine picks its routes.
    let mut paths: Vec<Option<Vec<u8>>> = vec![None; t.nodes.len()];
    paths[0] = Some(Vec::new());
    let mut queue = VecDeque::from([0usize]);
    while let Some(n) = queue.pop_front() {
        for e in &ends {
            for (from, to) in [(e[0], e[1]), (e[1], e[0])] {
                if from.0 != n || paths[to.0].is_some() {
                    continue;
                }
                let hop = if n == 0 {
                    host_links[from.1]
                } else {
                    from.1 as u8
                };
                let mut p = paths[n].clone().unwrap();
                p.push(hop);
                paths[to.0] = Some(p);
                queue.push_back(to.0);
            }
        }
    }
    let route = |hops: &[u8]| Route::through_links(hops).unwrap();

    let port = host.open_port("links").await.unwrap();
    let nr = Netrunner::new(&host).await.unwrap();
    for (n, node) in t.nodes.iter().enumerate() {
        let name = &node.name;
        let path = paths[n]
            .clone()
            .unwrap_or_else(|| panic!("{file}: {name} unreached"));
        if n > 0 {
            assert_eq!(
                machine.route_to(name),
                Some(route(&path)),
                "{file}: route to {name}"
            );
            assert_eq!(&name_at(&port, &route(&path)).await.unwrap(), name);
            let info = nr.runtime_info(&route(&path), 1).await.unwrap();
            assert_eq!(
                usize::from(info.link_count),
                gateways[n].len(),
                "{file}: {name}'s link count"
            );
        }
        for (index, g) in gateways[n].iter().enumerate() {
            let hop = if n == 0 {
                host_links[index]
            } else {
                index as u8
            };
            let des = &sim.node(n).links()[index];
            if n > 0 {
                let record = nr.link_info(&route(&path), hop).await.unwrap();
                let what = format!("{file}: {name} link {index}");
                assert_eq!(record.index, hop, "{what}");
                if des.info().type_name != "udp" {
                    assert_eq!(record.type_name, des.info().type_name, "{what}");
                }
                assert_eq!(record.name, des.info().name, "{what}");
                assert_eq!(record.open, des.is_open(), "{what}");
                assert_eq!(record.mtu, des.model().mtu(), "{what}");
            }
            match *g {
                Gateway::Link { link, side } => {
                    let peer = ends[link][side.other().index()].0;
                    let mut beyond = path.clone();
                    beyond.push(hop);
                    assert_eq!(
                        name_at(&port, &route(&beyond)).await.unwrap(),
                        t.nodes[peer].name,
                        "{file}: behind {name}'s link {index}"
                    );
                }
                Gateway::Unconnected(_) => assert!(!des.is_connected(), "{file}"),
            }
        }
    }
    machine.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn corexy_plotter_has_the_machines_nodes_links_and_link_indices() {
    let path = shipped("corexy-plotter.toml");
    let t = Network::load(&path).unwrap();
    let names: Vec<&str> = t.nodes.iter().map(|n| n.name.as_str()).collect();
    assert_eq!(names, ["host", "hub", "a", "b", "z"]);
    let types: Vec<&str> = t.links.iter().map(|l| l.model.type_name()).collect();
    assert_eq!(types, ["usb_cdc", "uart", "uart", "uart"]);
    // The hub's links in file order; each stepper's UART at the firmware's
    // link 1, its USB link 0 there and never open.
    let n = |name: &str| t.node_index(name).unwrap();
    assert_eq!(
        t.endpoints(),
        [
            [(n("host"), 0), (n("hub"), 0)],
            [(n("hub"), 1), (n("a"), 1)],
            [(n("hub"), 2), (n("b"), 1)],
            [(n("hub"), 3), (n("z"), 1)],
        ]
    );
    for stepper in ["a", "b", "z"] {
        let g = &t.gateways().unwrap()[n(stepper)];
        assert!(matches!(g[0], Gateway::Unconnected(_)), "{stepper}");
    }
    same_links_as_the_machine(path).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_shipped_topology_has_the_machines_link_indices() {
    for path in shipped_files() {
        same_links_as_the_machine(path).await;
    }
}
