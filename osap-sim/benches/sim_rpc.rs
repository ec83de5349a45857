//! Host ↔ simulated module benchmarks.
//!
//! - `rpc/in_process`: a host port's request to a simulated module's
//!   netresponder (port 0, the NAME query) over an in-process link at zero
//!   latency (`single-usb.toml` with `zero_latency`).
//! - `rpc/loopback_tcp`: the same, from a second host joined to the first
//!   over a loopback TCP link (as `osap serve --sim FILE --tcp ADDR` serves
//!   it): client host → TCP → serving host → module.
//! - `rpc/host_host`: for comparison, the same query between two plain
//!   hosts joined in process (no simulated module).
//! - `scan/{1,8,64}`: a full network scan (`netrunner::scan`) of that many
//!   simulated stepper modules on zero-latency links (each on a hub's UART,
//!   the hubs in a tree under the host's USB, up to 7 children each; see
//!   [`tree`]), clock sync running as on hardware.
//!
//! The requests are made from a task on the (multi-thread) tokio runtime,
//! as a script's tasks would. `rpc_block_on/*` makes them from outside the
//! runtime through `block_on` instead, as `#[tokio::main]`'s main future
//! does: every request and reply then also crosses between that thread and
//! the runtime's workers, which costs tens of µs of wake-ups.
//!
//! Before criterion runs, each RPC path is also timed request by request
//! and its p50/p99 and requests per second printed, since criterion reports
//! means. `cargo bench -p osap-sim --bench sim_rpc`; add `-- --test` for a
//! quick check that everything runs.

use criterion::{BenchmarkId, Criterion};
use osap_core::netresponder::key;
use osap_core::route::Route;
use osap_host::link::{stream, tcp};
use osap_host::netrunner::{self, ScanOptions};
use osap_host::{Host, HostConfig, PortHandle};
use osap_sim::machine::SimMachine;
use osap_sim::topology::{LinkKind, LinkSpec, ModuleSpec, SimSpec, HOST};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

const TIMEOUT: Duration = Duration::from_secs(1);

fn host(name: &str) -> Host {
    Host::start(HostConfig::named(name)).expect("host starts")
}

fn shipped(name: &str) -> SimSpec {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("topologies")
        .join(name);
    SimSpec::load(path).expect("shipped topology loads")
}

/// A request path: a port, and a route from it to a module.
struct Path {
    port: PortHandle,
    route: Route,
    // Kept alive for the benchmark's duration.
    _keep: Vec<Box<dyn std::any::Any + Send + Sync>>,
}

impl Path {
    async fn round_trip(&self) {
        let reply = self
            .port
            .request(&self.route, 0, &[key::NAME], TIMEOUT)
            .await
            .expect("the module answers");
        debug_assert_eq!(reply.body[0], key::NAME);
    }
}

/// Host → module over an in-process, zero-latency link.
async fn in_process() -> Path {
    let host = host("bench");
    let topology = shipped("single-usb.toml").with_zero_latency(true);
    let machine = SimMachine::start(&host, &topology).await.unwrap();
    let route = machine.route_to("motor").unwrap();
    let port = host.open_port("bench").await.unwrap();
    Path {
        port,
        route,
        _keep: vec![Box::new(machine), Box::new(host)],
    }
}

/// Host → host, both plain hosts, joined in process.
async fn host_host() -> Path {
    let a = host("a");
    let b = host("b");
    let (link, _) = osap_host::link::memory::connect(&a, &b).await.unwrap();
    let port = a.open_port("bench").await.unwrap();
    Path {
        port,
        route: Route::through_links(&[link]).unwrap(),
        _keep: vec![Box::new(a), Box::new(b)],
    }
}

/// Client host → loopback TCP → serving host → module (zero latency).
async fn loopback_tcp() -> Path {
    let server = host("server");
    let topology = shipped("single-usb.toml").with_zero_latency(true);
    let machine = SimMachine::start(&server, &topology).await.unwrap();
    let listener = tcp::listen(&server, stream::loopback(0), false)
        .await
        .unwrap();
    let addr = listener.socket_addr().unwrap().to_string();
    let client = host("client");
    let link = tcp::connect(&client, &addr).await.unwrap();
    link.wait_connected(TIMEOUT).await.unwrap();
    listener.wait_connected(TIMEOUT).await.unwrap();
    let mut hops = vec![link.index()];
    hops.extend(machine.route_to("motor").unwrap().hops().map(|h| match h {
        osap_core::Instruction::LinkForward(l) => l,
        other => panic!("unexpected hop {other:?}"),
    }));
    let route = Route::through_links(&hops).unwrap();
    let port = client.open_port("bench").await.unwrap();
    Path {
        port,
        route,
        _keep: vec![
            Box::new(link),
            Box::new(listener),
            Box::new(machine),
            Box::new(client),
            Box::new(server),
        ],
    }
}

/// `n` stepper modules `m0`, `m1`, … (the module firmware: a USB link and
/// one UART, so a stepper joins others only through a hub), each on a UART
/// of a hub; the hubs `h0`, `h1`, … in a tree with an uplink and up to 7
/// children each (8 links), as few levels as fit, the top hub on the host's
/// USB. Returns the topology and how many runtimes a scan finds: the host,
/// the hubs and the modules.
fn tree(n: usize, sync: bool) -> (SimSpec, usize) {
    const CHILDREN: usize = 7;
    let mut t = SimSpec {
        sync,
        ..SimSpec::new(&format!("tree{n}"))
    }
    .with_zero_latency(true);
    let mut level: Vec<String> = (0..n).map(|i| format!("m{i}")).collect();
    for name in &level {
        t = t.with_module(ModuleSpec::new(name, "stepper"));
    }
    let mut hubs = 0;
    loop {
        let parents: Vec<String> = (0..level.len().div_ceil(CHILDREN))
            .map(|_| {
                hubs += 1;
                format!("h{}", hubs - 1)
            })
            .collect();
        for name in &parents {
            t = t.with_module(ModuleSpec::new(name, "hub"));
        }
        for (i, child) in level.iter().enumerate() {
            t = t.with_link(LinkSpec::new(&parents[i / CHILDREN], child, LinkKind::Uart));
        }
        if let [top] = parents.as_slice() {
            t = t.with_link(LinkSpec::new(HOST, top, LinkKind::Usb));
            break;
        }
        level = parents;
    }
    (t, 1 + hubs + n)
}

fn percentile(sorted: &[Duration], p: f64) -> Duration {
    let i = ((sorted.len() as f64 - 1.0) * p).round() as usize;
    sorted[i]
}

/// Where the requests are made from.
#[derive(Clone, Copy)]
enum Caller {
    /// A task on the runtime.
    Task,
    /// The bench's own thread, through `block_on`.
    BlockOn,
}

/// Runs `n` round trips over `path` from `caller`, timing each when
/// `each` is set; returns the total time and the individual times.
fn run(
    rt: &tokio::runtime::Runtime,
    caller: Caller,
    path: &Arc<Path>,
    n: u64,
    each: bool,
) -> (Duration, Vec<Duration>) {
    let path = path.clone();
    let work = async move {
        let mut times = Vec::with_capacity(if each { n as usize } else { 0 });
        let start = Instant::now();
        for _ in 0..n {
            let t = Instant::now();
            path.round_trip().await;
            if each {
                times.push(t.elapsed());
            }
        }
        (start.elapsed(), times)
    };
    match caller {
        Caller::Task => rt.block_on(rt.spawn(work)).expect("bench task"),
        Caller::BlockOn => rt.block_on(work),
    }
}

/// Times `n` round trips one by one; prints p50, p99 and the rate.
fn report_percentiles(
    rt: &tokio::runtime::Runtime,
    group: &str,
    caller: Caller,
    name: &str,
    path: &Arc<Path>,
    n: usize,
) {
    run(rt, caller, path, (n / 10) as u64, false);
    let (total, mut sorted) = run(rt, caller, path, n as u64, true);
    sorted.sort();
    println!(
        "{group}/{name}: {n} round trips: p50 {:.1} µs, p99 {:.1} µs, max {:.1} µs, mean {:.1} µs, {:.0} round trips/s",
        percentile(&sorted, 0.5).as_secs_f64() * 1e6,
        percentile(&sorted, 0.99).as_secs_f64() * 1e6,
        sorted[sorted.len() - 1].as_secs_f64() * 1e6,
        total.as_secs_f64() * 1e6 / n as f64,
        n as f64 / total.as_secs_f64(),
    );
}

fn bench_rpc(c: &mut Criterion, rt: &tokio::runtime::Runtime, samples: usize) {
    let paths = [
        ("in_process", Arc::new(rt.block_on(in_process()))),
        ("loopback_tcp", Arc::new(rt.block_on(loopback_tcp()))),
        ("host_host", Arc::new(rt.block_on(host_host()))),
    ];
    for (group, caller) in [("rpc", Caller::Task), ("rpc_block_on", Caller::BlockOn)] {
        for (name, path) in &paths {
            report_percentiles(rt, group, caller, name, path, samples);
        }
    }
    for (group, caller) in [("rpc", Caller::Task), ("rpc_block_on", Caller::BlockOn)] {
        let mut g = c.benchmark_group(group);
        for (name, path) in &paths {
            g.bench_function(*name, |b| {
                b.iter_custom(|iters| run(rt, caller, path, iters, false).0)
            });
        }
        g.finish();
    }
}

fn bench_scan(c: &mut Criterion, rt: &tokio::runtime::Runtime) {
    let mut group = c.benchmark_group("scan");
    group.sample_size(10);
    for n in [1usize, 8, 64] {
        let host = host("bench");
        let (topology, runtimes) = tree(n, true);
        let machine = rt.block_on(SimMachine::start(&host, &topology)).unwrap();
        let options = ScanOptions::default();
        // Once up front: the scan finds them all.
        let report = rt.block_on(netrunner::scan(&host, &options)).unwrap();
        assert_eq!(report.map.runtimes.len(), runtimes, "{:?}", report.failures);
        println!(
            "scan/{n}: first scan {:.1} ms, {} runtimes, {} links",
            report.elapsed.as_secs_f64() * 1e3,
            report.map.runtimes.len(),
            report.map.links.len()
        );
        group.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| {
            b.iter_custom(|iters| {
                rt.block_on(async {
                    let start = Instant::now();
                    for _ in 0..iters {
                        let report = netrunner::scan(&host, &options).await.unwrap();
                        assert!(report.failures.is_empty(), "{:?}", report.failures);
                    }
                    start.elapsed()
                })
            })
        });
        drop(machine);
    }
    group.finish();
}

fn main() {
    let quick = std::env::args().any(|a| a == "--test");
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .expect("tokio runtime");
    // Hosts and machines spawn their tasks on it.
    let _guard = rt.enter();
    let mut c = Criterion::default().configure_from_args();
    bench_rpc(&mut c, &rt, if quick { 200 } else { 20_000 });
    bench_scan(&mut c, &rt);
    c.final_summary();
}
