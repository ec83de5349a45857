//! PIPES functions on a two-runtime in-memory network: a "sensor" function
//! on runtime A piped to an "accumulator" function on runtime B, driven by a
//! host port on A through the function protocol.

mod common;

use osap_core::time::Instant;
use std::ops::{Deref, DerefMut};

use common::{args, err, ok, runtime, to_b, Net};
use osap_core::codec::Writer;
use osap_core::route::Route;
use osap_core::stack::Owner;
use osap_tests::{TestLink, TestRuntime};
use pipes_core::control::{
    ControlError, ControlKey, InputMode, OutputMode, ReplyBody, Request, ANY_SLOT,
};
use pipes_core::failure::{Failure, SignatureParts};
use pipes_core::function::{CallError, Implementation, Outputs, PipesFunction};
use pipes_core::pipe::{PipeConfig, PipeDelivery};
use pipes_core::signature::{Arg, Signature};
use pipes_core::{Message, MessageKey, ScalarType, Type, Value};

const F32: Type = Type::Scalar(ScalarType::F32);
const F64: Type = Type::Scalar(ScalarType::F64);

static SENSOR: Signature = Signature {
    name: "sensor",
    inputs: &[Arg::new("x", F32)],
    outputs: &[Arg::new("y", F32)],
};

/// y = x.
struct Sensor;

impl Implementation for Sensor {
    fn signature(&self) -> &'static Signature {
        &SENSOR
    }
    fn call(&mut self, inputs: &[Value<'_>], out: &mut Outputs<'_>) -> Result<(), CallError> {
        out.set(0, &inputs[0])
    }
}

static ACC: Signature = Signature {
    name: "accumulator",
    inputs: &[Arg::new("a", F64), Arg::new("b", F64)],
    outputs: &[Arg::new("total", F64)],
};

/// total += a + b; remembers every run.
#[derive(Default)]
struct Acc {
    total: f64,
    runs: Vec<(f64, f64)>,
}

impl Implementation for Acc {
    fn signature(&self) -> &'static Signature {
        &ACC
    }
    fn call(&mut self, inputs: &[Value<'_>], out: &mut Outputs<'_>) -> Result<(), CallError> {
        let (Value::F64(a), Value::F64(b)) = (&inputs[0], &inputs[1]) else {
            return Err(CallError::Failed(pipes_core::FailureCode::Other(1)));
        };
        let (a, b) = (*a, *b);
        self.total += a + b;
        self.runs.push((a, b));
        out.set(0, &Value::F64(self.total))
    }
    fn failures(&self) -> &'static [Failure] {
        &ACC_FAILURES
    }
}

/// The accumulator's own failure code, published with its signature.
static ACC_FAILURES: [Failure; 1] = [Failure {
    code: 1,
    name: "NotF64",
    reason: "an input was not an f64: a bug in the conversions",
}];

type SensorFn = PipesFunction<Sensor, 2, 2, 64>;
type AccFn = PipesFunction<Acc, 2, 2, 64>;

/// Host = A port 1, sensor = A ports 2 (control), 3, 4 (pipes); accumulator
/// = B ports 1 (control), 2, 3 (pipes). A link 0 ↔ B link 0.
struct World(Net);

impl Deref for World {
    type Target = Net;
    fn deref(&self) -> &Net {
        &self.0
    }
}

impl DerefMut for World {
    fn deref_mut(&mut self) -> &mut Net {
        &mut self.0
    }
}

const SENSOR_PORT: u16 = 2;
const SENSOR_PIPE0: u16 = 3;
const ACC_PORT: u16 = 1;

impl World {
    fn new() -> World {
        World(Net::new(
            vec![Box::new(SensorFn::new(Sensor).unwrap())],
            vec![Box::new(AccFn::new(Acc::default()).unwrap())],
        ))
    }

    fn sensor(&mut self) -> &mut SensorFn {
        self.on_a(0)
    }

    fn acc(&mut self) -> &mut AccFn {
        self.on_b(0)
    }

    fn call_sensor(&mut self, x: f32) -> Vec<u8> {
        self.call(Route::local(), SENSOR_PORT, &[(0, Value::F32(x))])
    }

    /// A raw pipe datagram from the host to the accumulator.
    fn datagram_to_acc(&mut self, vals: &[(u8, Value<'_>)]) {
        let mut buf = [0u8; 100];
        let mut w = Writer::new(&mut buf[1..]);
        Message::encode(&mut w, MessageKey::PipeDatagram, vals).unwrap();
        let n = 1 + w.len();
        self.host().queue(to_b(), ACC_PORT, 10_000, &buf[..n]);
        self.steps(4);
    }
}

/// Pipe sensor output 0 → accumulator input `input`, over link 0.
fn pipe_to_acc(input: u8) -> PipeConfig {
    PipeConfig::new(to_b(), ACC_PORT, 10_000)
        .with(0, input)
        .unwrap()
}

#[test]
fn signature_over_the_network() {
    let mut w = World::new();
    let body = w.ask(to_b(), ACC_PORT, &Request::GetSignature);
    let ReplyBody::Signature(s) = ok(&body) else {
        panic!()
    };
    assert!(ACC.matches(&s));
    assert_eq!(s.inputs().get(1).unwrap().name, "b");
}

#[test]
fn failure_table_over_the_network_only_when_asked() {
    let mut w = World::new();
    let body = w.ask(to_b(), ACC_PORT, &Request::GetSignature);
    let ReplyBody::Signature(s) = ok(&body) else {
        panic!()
    };
    assert_eq!(s.failures(), None, "`[2]` gets the old layout");
    let body = w.ask(
        to_b(),
        ACC_PORT,
        &Request::Describe(SignatureParts::FAILURES),
    );
    let ReplyBody::Signature(s) = ok(&body) else {
        panic!()
    };
    assert!(ACC.matches(&s));
    let table = s.failures().expect("a table when asked");
    assert_eq!(table.len(), 1);
    assert_eq!(
        table.get(1).unwrap().to_string(),
        "NotF64 (code 1): an input was not an f64: a bug in the conversions"
    );
    // A function with no table of its own answers an empty one.
    let body = w.ask(
        Route::local(),
        SENSOR_PORT,
        &Request::Describe(SignatureParts::FAILURES),
    );
    let ReplyBody::Signature(s) = ok(&body) else {
        panic!()
    };
    assert!(s.failures().unwrap().is_empty());
}

#[test]
fn rpc_call_drives_the_pipe() {
    let mut w = World::new();
    // The accumulator has b already; on_any_fresh then runs it on a.
    w.datagram_to_acc(&[(1, Value::F64(0.5))]);
    assert_eq!(w.acc().stats().datagrams, 1);
    assert_eq!(w.acc().stats().runs, 0, "a holds no value yet");

    let body = w.ask(
        Route::local(),
        SENSOR_PORT,
        &Request::SetPipe {
            slot: ANY_SLOT,
            pipe: pipe_to_acc(0),
        },
    );
    assert_eq!(ok(&body), ReplyBody::PipeSet(0));

    let body = w.call_sensor(2.0);
    let ReplyBody::Returned(out) = ok(&body) else {
        panic!()
    };
    assert_eq!(out.get(0), Some(Value::F32(2.0)));
    w.steps(4);
    // f32 2.0 arrived for an f64 input, converted exactly.
    assert_eq!(w.acc().implementation().runs, vec![(2.0, 0.5)]);
    assert_eq!(w.acc().implementation().total, 2.5);
    assert_eq!(w.sensor().pipe(0).unwrap().stats.sent, 1);
    assert_eq!(w.acc().input(0), Some(Value::F64(2.0)));
}

#[test]
fn set_get_wipe_pipe_over_the_network() {
    let mut w = World::new();
    let host_to_sensor_on_b = to_b(); // the accumulator's table, remotely
    let body = w.ask(host_to_sensor_on_b, ACC_PORT, &Request::GetPipeCount);
    assert_eq!(ok(&body), ReplyBody::PipeCount { slots: 2, used: 0 });

    let back = PipeConfig::new(Route::through_links(&[0]).unwrap(), SENSOR_PORT, 5000)
        .with(0, 0)
        .unwrap();
    let body = w.ask(
        to_b(),
        ACC_PORT,
        &Request::SetPipe {
            slot: 1,
            pipe: back,
        },
    );
    assert_eq!(ok(&body), ReplyBody::PipeSet(1));
    let body = w.ask(to_b(), ACC_PORT, &Request::GetPipe(1));
    assert_eq!(
        ok(&body),
        ReplyBody::Pipe {
            slot: 1,
            pipe: Some(back)
        }
    );
    let body = w.ask(to_b(), ACC_PORT, &Request::GetPipe(0));
    assert_eq!(
        ok(&body),
        ReplyBody::Pipe {
            slot: 0,
            pipe: None
        }
    );
    let body = w.ask(to_b(), ACC_PORT, &Request::GetPipe(2));
    assert_eq!(err(&body), ControlError::NoSuchPipe(2));

    // Fill the table, then one more.
    let body = w.ask(
        to_b(),
        ACC_PORT,
        &Request::SetPipe {
            slot: ANY_SLOT,
            pipe: back,
        },
    );
    assert_eq!(ok(&body), ReplyBody::PipeSet(0));
    let body = w.ask(
        to_b(),
        ACC_PORT,
        &Request::SetPipe {
            slot: ANY_SLOT,
            pipe: back,
        },
    );
    assert_eq!(err(&body), ControlError::PipeTableFull);
    // A bad argmap is refused; acknowledged delivery is taken (and kept).
    let bad = PipeConfig::new(Route::local(), 1, 1).with(3, 0).unwrap();
    let body = w.ask(to_b(), ACC_PORT, &Request::SetPipe { slot: 0, pipe: bad });
    assert_eq!(err(&body), ControlError::BadArgmap(3));
    let acked = back.with_delivery(PipeDelivery::Acked);
    let body = w.ask(
        to_b(),
        ACC_PORT,
        &Request::SetPipe {
            slot: 0,
            pipe: acked,
        },
    );
    assert_eq!(ok(&body), ReplyBody::PipeSet(0));
    let body = w.ask(to_b(), ACC_PORT, &Request::GetPipe(0));
    assert_eq!(
        ok(&body),
        ReplyBody::Pipe {
            slot: 0,
            pipe: Some(acked)
        }
    );

    let body = w.ask(to_b(), ACC_PORT, &Request::WipePipe(1));
    assert_eq!(ok(&body), ReplyBody::Done);
    let body = w.ask(to_b(), ACC_PORT, &Request::GetPipeCount);
    assert_eq!(ok(&body), ReplyBody::PipeCount { slots: 2, used: 1 });
    let body = w.ask(to_b(), ACC_PORT, &Request::WipePipe(ANY_SLOT));
    assert_eq!(ok(&body), ReplyBody::Done);
    let body = w.ask(to_b(), ACC_PORT, &Request::GetPipeCount);
    assert_eq!(ok(&body), ReplyBody::PipeCount { slots: 2, used: 0 });
    assert_eq!(w.acc().stats().refused, 3);
}

#[test]
fn on_all_fresh_waits_for_both_inputs() {
    let mut w = World::new();
    let body = w.ask(
        to_b(),
        ACC_PORT,
        &Request::SetInputMode(InputMode::OnAllFresh),
    );
    assert_eq!(ok(&body), ReplyBody::Done);
    let body = w.ask(to_b(), ACC_PORT, &Request::GetInputMode);
    assert_eq!(ok(&body), ReplyBody::InputMode(InputMode::OnAllFresh));
    w.sensor().set_pipe(0, pipe_to_acc(0)).unwrap();

    w.call_sensor(1.0);
    w.steps(4);
    assert_eq!(w.acc().stats().datagrams, 1);
    assert!(w.acc().implementation().runs.is_empty(), "b is not fresh");
    w.datagram_to_acc(&[(1, Value::F64(10.0))]);
    assert_eq!(w.acc().implementation().runs, vec![(1.0, 10.0)]);
    // Both are stale again: a new a alone does not run it, under on_all_fresh.
    w.call_sensor(3.0);
    w.steps(4);
    assert_eq!(w.acc().implementation().runs.len(), 1);
    w.datagram_to_acc(&[(1, Value::F64(20.0))]);
    assert_eq!(
        w.acc().implementation().runs,
        vec![(1.0, 10.0), (3.0, 20.0)]
    );
}

#[test]
fn on_change_suppresses_repeats() {
    let mut w = World::new();
    w.acc().set_input_mode(InputMode::OnAnyFresh);
    w.datagram_to_acc(&[(1, Value::F64(0.0))]);
    w.sensor().set_pipe(0, pipe_to_acc(0)).unwrap();
    let body = w.ask(
        Route::local(),
        SENSOR_PORT,
        &Request::SetOutputMode(OutputMode::OnChange),
    );
    assert_eq!(ok(&body), ReplyBody::Done);
    for x in [1.0, 1.0, 2.0, 2.0, 2.0, 1.0] {
        w.call_sensor(x);
    }
    w.steps(4);
    assert_eq!(w.sensor().stats().calls, 6);
    assert_eq!(w.sensor().stats().suppressed, 3);
    assert_eq!(w.sensor().pipe(0).unwrap().stats.sent, 3);
    let a: Vec<f64> = w.acc().implementation().runs.iter().map(|r| r.0).collect();
    assert_eq!(a, vec![1.0, 2.0, 1.0]);
}

#[test]
fn queue_overflow_is_counted() {
    let mut w = World::new();
    w.datagram_to_acc(&[(1, Value::F64(0.0))]);
    w.sensor().set_pipe(0, pipe_to_acc(0)).unwrap();
    // The pipe's port may hold no packets: it is never clear to send.
    w.a.stack_quota(SENSOR_PIPE0, 0);
    for x in [1.0, 2.0, 3.0, 4.0] {
        w.call_sensor(x);
    }
    let p = w.sensor().pipe(0).unwrap();
    assert_eq!((p.queued(), p.stats.overflows, p.stats.sent), (2, 2, 0));
    // The counters are readable over the network.
    let body = w.ask(Route::local(), SENSOR_PORT, &Request::GetPipeStats(0));
    let ReplyBody::PipeStats { slot: 0, stats } = ok(&body) else {
        panic!("{body:?}")
    };
    assert_eq!((stats.sent, stats.overflows, stats.send_errors), (0, 2, 0));
    assert_eq!(stats.last_remote_error, None);
    let body = w.ask(Route::local(), SENSOR_PORT, &Request::GetPipeStats(1));
    assert_eq!(err(&body), ControlError::NoSuchPipe(1));
    let body = w.ask(Route::local(), SENSOR_PORT, &Request::GetPipeStats(9));
    assert_eq!(err(&body), ControlError::NoSuchPipe(9));
    w.a.stack_quota(SENSOR_PIPE0, 4);
    w.steps(6);
    let p = w.sensor().pipe(0).unwrap();
    assert_eq!((p.queued(), p.stats.overflows, p.stats.sent), (0, 2, 2));
    // The newest two arrived, the oldest two were dropped and counted.
    let a: Vec<f64> = w.acc().implementation().runs.iter().map(|r| r.0).collect();
    assert_eq!(a, vec![3.0, 4.0]);
}

trait Quota {
    fn stack_quota(&mut self, port: u16, max: u8);
}

impl Quota for TestRuntime {
    fn stack_quota(&mut self, port: u16, max: u8) {
        self.set_quota(Owner::Port(port), max).unwrap();
    }
}

#[test]
fn refused_datagrams_are_reported_to_the_pipe() {
    let mut w = World::new();
    // Sensor output 0 goes to accumulator input 5, which does not exist.
    w.sensor().set_pipe(0, pipe_to_acc(5)).unwrap();
    w.call_sensor(1.0);
    w.steps(6);
    assert_eq!(w.acc().stats().refused, 1);
    let p = w.sensor().pipe(0).unwrap();
    assert_eq!(p.stats.remote_errors, 1);
    assert_eq!(
        p.stats.last_remote_error,
        Some(ControlError::NoSuchInput(5))
    );
    let body = w.ask(Route::local(), SENSOR_PORT, &Request::GetPipeStats(0));
    let ReplyBody::PipeStats { stats, .. } = ok(&body) else {
        panic!("{body:?}")
    };
    assert_eq!((stats.sent, stats.remote_errors), (1, 1));
    assert_eq!(stats.last_remote_error, Some(ControlError::NoSuchInput(5)));
}

#[test]
fn call_errors_name_the_argument() {
    let mut w = World::new();
    let two = args(&[(0, Value::F32(1.0)), (1, Value::F32(1.0))]);
    let a = pipes_core::Args::decode(&mut osap_core::codec::Reader::new(&two)).unwrap();
    let body = w.ask(Route::local(), SENSOR_PORT, &Request::Call(a));
    assert_eq!(
        err(&body),
        ControlError::WrongArgCount {
            expected: 1,
            got: 2
        }
    );

    let lossy = args(&[(0, Value::F64(0.1))]);
    let a = pipes_core::Args::decode(&mut osap_core::codec::Reader::new(&lossy)).unwrap();
    let body = w.ask(Route::local(), SENSOR_PORT, &Request::Call(a));
    let ControlError::Convert { index: 0, error } = err(&body) else {
        panic!()
    };
    assert_eq!(error.reason, pipes_core::ConvertReason::Lossy);
    assert_eq!((error.from, error.to), (F64, F32));

    let text = args(&[(0, Value::utf8("1.0"))]);
    let a = pipes_core::Args::decode(&mut osap_core::codec::Reader::new(&text)).unwrap();
    let body = w.ask(Route::local(), SENSOR_PORT, &Request::Call(a));
    assert!(matches!(
        err(&body),
        ControlError::Convert { index: 0, error } if error.reason == pipes_core::ConvertReason::Impossible
    ));

    // Unknown key and garbage get typed errors, never a panic.
    for junk in [&[0x7f_u8][..], &[3, 9], &[6, 0, 40], &[]] {
        let seq = w.next_seq();
        let mut p = vec![1, seq as u8, 0];
        p.extend_from_slice(junk);
        let before = w.host().received.len();
        w.host().queue(Route::local(), SENSOR_PORT, 10_000, &p);
        w.steps(3);
        let r = w.host().received[before].payload.clone();
        let e = err(&r[3..]);
        if junk.first() == Some(&0x7f) {
            assert_eq!(e, ControlError::UnknownKey(0x7f));
        } else {
            assert_eq!(e, ControlError::Malformed);
        }
    }
    assert_eq!(w.sensor().stats().calls, 0);
    assert_eq!(
        ControlKey::PipeDatagram.to_u8(),
        MessageKey::PipeDatagram.to_u8()
    );
}

#[test]
fn timer_mode_runs_a_source() {
    static TICK: Signature = Signature {
        name: "tick",
        inputs: &[],
        outputs: &[Arg::new("n", Type::Scalar(ScalarType::U32))],
    };
    let mut n = 0u32;
    let imp =
        pipes_core::function::FnImpl::new(&TICK, move |_: &[Value<'_>], o: &mut Outputs<'_>| {
            n += 1;
            o.set(0, &Value::U32(n))
        });
    let mut f: PipesFunction<_, 1, 2, 32> = PipesFunction::new(imp).unwrap();
    f.set_input_mode(InputMode::OnTimer(1000));
    let mut rt = runtime("t");
    let mut ports = [f];
    let mut links: [TestLink; 0] = [];
    for t in (0..=10_000).step_by(100) {
        rt.poll(Instant::from_micros(t), &mut ports, &mut links);
    }
    // First tick is armed at t = 0, due at 1000, then every 1000 µs.
    assert_eq!(ports[0].stats().runs, 10);
    assert_eq!(
        ports[0].last_outputs().unwrap().get(0),
        Some(Value::U32(10))
    );
}
