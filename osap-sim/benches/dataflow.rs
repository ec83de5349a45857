//! PIPES dataflow and function RPC benchmarks.
//!
//! - `dataflow/one_runtime`: a `source` function piped to a `sink`
//!   function in the same osap-core runtime (firmware-sized, like a
//!   simulated module's: 32 slots of 256 bytes). The source runs on a
//!   timer of period 0 (once per poll) and sends `n: u32` down its pipe
//!   (route: local); the sink runs on every datagram. The runtime's poll
//!   is driven directly in a tight loop, no tokio. Counted: datagrams the
//!   sink accepted.
//! - `dataflow/queue_link`: the same two functions in two runtimes joined
//!   by osap-core's `QueueLink` (`transfer` both ways after each poll),
//!   the pipe routed over the link.
//! - `rpc/get_position`: a host port's RPC call to a simulated stepper's
//!   `get_position` (no inputs, two outputs) over an in-process
//!   zero-latency link (`single-usb.toml` with `zero_latency`), from a
//!   task on the multi-thread tokio runtime.
//! - `rpc/add_point`: the same with two inputs and no outputs.
//!
//! Before criterion runs, each is also measured over a fixed wall time and
//! its rate printed (messages/s, calls/s). `cargo bench -p osap-sim
//! --bench dataflow`; add `-- --test` for a quick check that everything
//! runs.

use criterion::{Criterion, Throughput};
use osap_core::codec::Writer;
use osap_core::link::queue::{transfer, QueueLink};
use osap_core::route::Route;
use osap_host::netrunner::{self, ScanOptions};
use osap_host::{Host, HostConfig, PortHandle};
use osap_sim::machine::SimMachine;
use osap_sim::topology::SimSpec;
use pipes_core::control::{ControlKey, InputMode, OutputMode, Reply, ReplyBody};
use pipes_core::function::{CallError, Implementation, Outputs, PipesFunction};
use pipes_core::pipe::PipeConfig;
use pipes_core::signature::{Arg, Signature};
use pipes_core::{ArgsWriter, ScalarType, Type, Value};
use std::hint::black_box;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

const U32: Type = Type::Scalar(ScalarType::U32);

static SOURCE: Signature = Signature {
    name: "source",
    inputs: &[],
    outputs: &[Arg::new("n", U32)],
};

static SINK: Signature = Signature {
    name: "sink",
    inputs: &[Arg::new("n", U32)],
    outputs: &[],
};

/// `source() -> (n)` counts up; `sink(n)` sums what it gets.
struct Body {
    sig: &'static Signature,
    n: u32,
    sum: u64,
}

impl Implementation for Body {
    fn signature(&self) -> &'static Signature {
        self.sig
    }
    fn call(&mut self, inputs: &[Value<'_>], out: &mut Outputs<'_>) -> Result<(), CallError> {
        match inputs {
            [] => {
                self.n = self.n.wrapping_add(1);
                out.set(0, &Value::U32(self.n))
            }
            [Value::U32(n)] => {
                self.sum += u64::from(*n);
                Ok(())
            }
            _ => Err(CallError::Failed(pipes_core::FailureCode::Other(1))),
        }
    }
}

type Fun = PipesFunction<Body, 1, 2, 64>;
/// Sized like a simulated module's runtime.
type Rt = osap_core::Runtime<32, 256, 16, 1>;
type Link = QueueLink<32, 256>;

fn runtime(name: &str) -> Rt {
    let mut rt = Rt::new("bench", name).expect("runtime");
    let quiet = osap_core::clock::TimeConfig {
        enabled: false,
        ..Default::default()
    };
    rt.clock_mut().set_config(quiet).expect("time config");
    rt
}

fn source(route: Route, port: u16) -> Fun {
    let mut f = Fun::new(Body {
        sig: &SOURCE,
        n: 0,
        sum: 0,
    })
    .expect("signature");
    f.set_input_mode(InputMode::OnTimer(0));
    f.set_output_mode(OutputMode::Always);
    let pipe = PipeConfig::new(route, port, 10_000)
        .with(0, 0)
        .expect("argmap");
    f.set_pipe(0, pipe).expect("pipe");
    f
}

fn sink() -> Fun {
    let mut f = Fun::new(Body {
        sig: &SINK,
        n: 0,
        sum: 0,
    })
    .expect("signature");
    f.set_input_mode(InputMode::OnAnyFresh);
    f
}

/// Source and sink in one runtime: source at ports 1–2, sink at 3–4.
struct OneRuntime {
    rt: Rt,
    ports: [Fun; 2],
    links: [Link; 1],
    now: u64,
}

impl OneRuntime {
    fn new() -> Self {
        OneRuntime {
            rt: runtime("one"),
            ports: [source(Route::local(), 3), sink()],
            links: [Link::new()],
            now: 1,
        }
    }

    fn received(&self) -> u64 {
        u64::from(self.ports[1].stats().datagrams)
    }

    /// Polls until the sink got `n` more datagrams; returns the polls made.
    fn run(&mut self, n: u64) -> u64 {
        let target = self.received() + n;
        let mut polls = 0;
        while self.received() < target {
            let now = osap_core::Instant::from_micros(self.now);
            self.rt.poll(now, &mut self.ports, &mut self.links);
            self.now += 1;
            polls += 1;
        }
        polls
    }
}

/// Source on runtime A piped over A's link 0 to the sink on runtime B
/// (port 1).
struct TwoRuntimes {
    a: Rt,
    b: Rt,
    pa: [Fun; 1],
    pb: [Fun; 1],
    la: [Link; 1],
    lb: [Link; 1],
    now: u64,
}

impl TwoRuntimes {
    fn new() -> Self {
        TwoRuntimes {
            a: runtime("a"),
            b: runtime("b"),
            pa: [source(Route::through_links(&[0]).expect("route"), 1)],
            pb: [sink()],
            la: [Link::new()],
            lb: [Link::new()],
            now: 1,
        }
    }

    fn received(&self) -> u64 {
        u64::from(self.pb[0].stats().datagrams)
    }

    fn run(&mut self, n: u64) -> u64 {
        let target = self.received() + n;
        let mut polls = 0;
        while self.received() < target {
            let now = osap_core::Instant::from_micros(self.now);
            self.a.poll(now, &mut self.pa, &mut self.la);
            transfer(&mut self.la[0], &mut self.lb[0], usize::MAX);
            self.b.poll(now, &mut self.pb, &mut self.lb);
            transfer(&mut self.lb[0], &mut self.la[0], usize::MAX);
            self.now += 1;
            polls += 1;
        }
        polls
    }
}

/// Runs `run` in batches for about `wall`; prints and returns messages/s.
fn rate(name: &str, wall: Duration, mut run: impl FnMut(u64) -> u64) -> f64 {
    run(10_000);
    let start = Instant::now();
    let (mut msgs, mut polls) = (0u64, 0u64);
    while start.elapsed() < wall {
        polls += run(10_000);
        msgs += 10_000;
    }
    let secs = start.elapsed().as_secs_f64();
    let r = msgs as f64 / secs;
    println!(
        "dataflow/{name}: {msgs} messages in {:.3} s: {r:.0} messages/s, {:.1} ns/message, {:.2} polls/message",
        secs,
        secs * 1e9 / msgs as f64,
        polls as f64 / msgs as f64,
    );
    r
}

fn bench_dataflow(c: &mut Criterion, wall: Duration) {
    let mut one = OneRuntime::new();
    let mut two = TwoRuntimes::new();
    rate("one_runtime", wall, |n| one.run(n));
    rate("queue_link", wall, |n| two.run(n));
    let mut g = c.benchmark_group("dataflow");
    g.throughput(Throughput::Elements(1));
    g.bench_function("one_runtime", |b| {
        b.iter_custom(|iters| {
            let t = Instant::now();
            black_box(one.run(iters));
            t.elapsed()
        })
    });
    g.bench_function("queue_link", |b| {
        b.iter_custom(|iters| {
            let t = Instant::now();
            black_box(two.run(iters));
            t.elapsed()
        })
    });
    g.finish();
    // Every datagram arrived in order, none lost: the sink's sum is 1 + 2 + … + n.
    for (name, f) in [("one_runtime", &one.ports[1]), ("queue_link", &two.pb[0])] {
        let n = u64::from(f.stats().datagrams);
        assert_eq!(f.implementation().sum, n * (n + 1) / 2, "{name}");
    }
}

/// A host port and a stepper function's control port.
struct Rpc {
    port: PortHandle,
    route: Route,
    get_position: u16,
    add_point: u16,
    // Kept alive for the benchmark's duration.
    _keep: (SimMachine, Host),
}

fn call_body(vals: &[(u8, Value<'_>)]) -> Vec<u8> {
    let mut buf = vec![0u8; 64];
    let mut w = Writer::new(&mut buf);
    w.u8(ControlKey::Call.to_u8()).expect("room");
    let mut a = ArgsWriter::new(&mut w).expect("room");
    for (i, v) in vals {
        a.push(*i, v).expect("room");
    }
    a.finish().expect("room");
    let n = w.len();
    buf.truncate(n);
    buf
}

async fn rpc_setup() -> Rpc {
    let host = Host::start(HostConfig::named("bench")).expect("host");
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("topologies")
        .join("single-usb.toml");
    let topology = SimSpec::load(path)
        .expect("shipped topology")
        .with_zero_latency(true);
    let machine = SimMachine::start(&host, &topology).await.expect("machine");
    let report = netrunner::scan(&host, &ScanOptions::default())
        .await
        .expect("scan");
    let motor = report.map.find("motor").expect("motor").clone();
    let port_of = |name: &str| {
        motor
            .ports
            .iter()
            .find(|p| p.name == name)
            .map(|p| p.index)
            .expect("function")
    };
    let rpc = Rpc {
        port: host.open_port("bench").await.expect("port"),
        route: motor.route(),
        get_position: port_of("get_position"),
        add_point: port_of("add_point"),
        _keep: (machine, host),
    };
    let set_enable = port_of("set_enable");
    let reply = rpc
        .port
        .request(
            &rpc.route,
            set_enable,
            &call_body(&[(0, Value::Bool(true))]),
            Duration::from_secs(1),
        )
        .await
        .expect("set_enable");
    assert!(Reply::parse(&reply.body).expect("reply").result.is_ok());
    rpc
}

#[derive(Clone, Copy)]
enum Call {
    GetPosition,
    AddPoint,
}

async fn calls(rpc: &Rpc, call: Call, n: u64) -> Duration {
    let get = call_body(&[]);
    let start = Instant::now();
    for i in 0..n {
        let (port, body) = match call {
            Call::GetPosition => (rpc.get_position, get.clone()),
            // Points far in the future: the first starts too far from
            // where the axis stands or the rest come after a gap, so every
            // call is refused by the module's logic (still a full round
            // trip).
            Call::AddPoint => (
                rpc.add_point,
                call_body(&[(0, Value::U64(u64::MAX / 2 + i)), (1, Value::F32(1.0))]),
            ),
        };
        let reply = rpc
            .port
            .request(&rpc.route, port, &body, Duration::from_secs(1))
            .await
            .expect("the module answers");
        let r = Reply::parse(&reply.body).expect("reply");
        if let Call::GetPosition = call {
            assert!(matches!(r.result, Ok(ReplyBody::Returned(_))));
        }
    }
    start.elapsed()
}

fn bench_rpc(c: &mut Criterion, rt: &tokio::runtime::Runtime, n: u64) {
    let rpc = Arc::new(rt.block_on(rpc_setup()));
    for (name, call) in [
        ("get_position", Call::GetPosition),
        ("add_point", Call::AddPoint),
    ] {
        let r = rpc.clone();
        let elapsed = rt
            .block_on(rt.spawn(async move {
                calls(&r, call, n / 10).await;
                calls(&r, call, n).await
            }))
            .expect("bench task");
        println!(
            "rpc/{name}: {n} calls in {:.3} s: {:.0} calls/s, {:.1} µs/call",
            elapsed.as_secs_f64(),
            n as f64 / elapsed.as_secs_f64(),
            elapsed.as_secs_f64() * 1e6 / n as f64
        );
    }
    let mut g = c.benchmark_group("rpc");
    g.throughput(Throughput::Elements(1));
    for (name, call) in [
        ("get_position", Call::GetPosition),
        ("add_point", Call::AddPoint),
    ] {
        g.bench_function(name, |b| {
            b.iter_custom(|iters| {
                let r = rpc.clone();
                rt.block_on(rt.spawn(async move { calls(&r, call, iters).await }))
                    .expect("bench task")
            })
        });
    }
    g.finish();
}

fn main() {
    let quick = std::env::args().any(|a| a == "--test");
    let mut c = Criterion::default().configure_from_args();
    bench_dataflow(
        &mut c,
        Duration::from_millis(if quick { 100 } else { 2_000 }),
    );
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .expect("tokio runtime");
    let _guard = rt.enter();
    bench_rpc(&mut c, &rt, if quick { 500 } else { 20_000 });
    c.final_summary();
}
