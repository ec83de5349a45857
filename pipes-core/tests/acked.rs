//! Acknowledged pipes on a two-runtime in-memory network: a "sensor"
//! function on runtime A piped, with acknowledged delivery, to a "sink"
//! function on runtime B; the link between them can lose everything in
//! either direction.

mod common;

use std::ops::{Deref, DerefMut};

use common::Net;
use osap_core::route::Route;
use osap_core::Duration;
use pipes_core::control::{ControlError, Reply, ReplyBody, Request};
use pipes_core::function::{CallError, Implementation, Outputs, PipesFunction};
use pipes_core::pipe::{PipeConfig, PipeDelivery, DEFAULT_ACK_RETRIES, DEFAULT_ACK_TIMEOUT};
use pipes_core::signature::{Arg, Signature};
use pipes_core::{ScalarType, Type, Value};

const F32: Type = Type::Scalar(ScalarType::F32);

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

static SINK: Signature = Signature {
    name: "sink",
    inputs: &[Arg::new("v", F32)],
    outputs: &[],
};

/// Remembers every value it runs on.
#[derive(Default)]
struct Sink(Vec<f32>);

impl Implementation for Sink {
    fn signature(&self) -> &'static Signature {
        &SINK
    }
    fn call(&mut self, inputs: &[Value<'_>], _: &mut Outputs<'_>) -> Result<(), CallError> {
        let Value::F32(v) = inputs[0] else {
            return Err(CallError::Failed(pipes_core::FailureCode::Other(1)));
        };
        self.0.push(v);
        Ok(())
    }
}

type SensorFn = PipesFunction<Sensor, 1, 4, 64>;
type SinkFn = PipesFunction<Sink, 1, 2, 64>;

/// Host = A port 1, sensor = A port 2 (control), 3 (pipe); sink = B port 1.
/// A link 0 ↔ B link 0.
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
const SINK_PORT: u16 = 1;

impl World {
    fn new() -> World {
        World(Net::new(
            vec![Box::new(SensorFn::new(Sensor).unwrap())],
            vec![Box::new(SinkFn::new(Sink::default()).unwrap())],
        ))
    }

    fn sensor(&mut self) -> &mut SensorFn {
        self.on_a(0)
    }

    fn sink(&mut self) -> &mut SinkFn {
        self.on_b(0)
    }

    fn seen(&mut self) -> Vec<f32> {
        self.sink().implementation().0.clone()
    }

    /// Sends a request from the host to the sensor and returns the reply body.
    fn ask_sensor(&mut self, req: &Request<'_>) -> Vec<u8> {
        self.ask(Route::local(), SENSOR_PORT, req)
    }

    /// Calls the sensor with `x`: its output goes down the pipe.
    fn call_sensor(&mut self, x: f32) {
        let body = self.call(Route::local(), SENSOR_PORT, &[(0, Value::F32(x))]);
        assert!(Reply::parse(&body).unwrap().result.is_ok());
    }

    /// The pipe's counters, read over the network.
    fn stats(&mut self) -> pipes_core::pipe::PipeStats {
        let body = self.ask_sensor(&Request::GetPipeStats(0));
        match Reply::parse(&body).unwrap().result {
            Ok(ReplyBody::PipeStats { slot: 0, stats }) => stats,
            other => panic!("{other:?}"),
        }
    }
}

/// Sensor output 0 → sink input `input`, acknowledged, over link 0.
fn acked_pipe(input: u8) -> PipeConfig {
    PipeConfig::new(Route::through_links(&[0]).unwrap(), SINK_PORT, 10_000)
        .with(0, input)
        .unwrap()
        .with_delivery(PipeDelivery::Acked)
}

#[test]
fn acked_datagrams_arrive_in_order() {
    let mut w = World::new();
    // Set over the network: acknowledged pipes are accepted now.
    let body = w.ask_sensor(&Request::SetPipe {
        slot: 0,
        pipe: acked_pipe(0),
    });
    assert_eq!(
        Reply::parse(&body).unwrap().result,
        Ok(ReplyBody::PipeSet(0))
    );
    let p = w.sensor().pipe(0).unwrap();
    assert_eq!(
        (p.ack_timeout, p.max_retries),
        (DEFAULT_ACK_TIMEOUT, DEFAULT_ACK_RETRIES)
    );
    for x in [1.0, 2.0, 3.0] {
        w.call_sensor(x);
    }
    w.steps(10);
    assert_eq!(w.seen(), [1.0, 2.0, 3.0]);
    let s = w.stats();
    assert_eq!((s.sent, s.acked, s.retries, s.failures), (3, 3, 0, 0));
    assert_eq!((s.overflows, s.remote_errors), (0, 0));
    assert_eq!(w.sensor().pipe(0).unwrap().queued(), 0);
    // Every datagram arrived as a request, and each was answered.
    assert_eq!(w.sink().stats().datagrams, 3);
    assert_eq!(w.sensor().stats().malformed, 0);
}

#[test]
fn a_stalled_link_keeps_the_queue_in_order() {
    let mut w = World::new();
    w.sensor().set_pipe(0, acked_pipe(0)).unwrap();
    w.lose_to_b = true;
    for x in [1.0, 2.0, 3.0] {
        w.call_sensor(x);
    }
    // One datagram in flight, the others wait behind it.
    let p = w.sensor().pipe(0).unwrap();
    assert!(p.awaiting_ack());
    assert_eq!((p.queued(), p.stats.sent), (3, 1));
    w.lose_to_b = false;
    // Within the timeout (20 ms) nothing is sent again; after it, the front is.
    w.steps(150);
    assert!(w.seen().is_empty());
    assert_eq!(w.sensor().pipe(0).unwrap().stats.retries, 0);
    w.steps(100);
    assert_eq!(w.seen(), [1.0, 2.0, 3.0]);
    let s = w.stats();
    assert_eq!((s.sent, s.acked, s.retries, s.failures), (3, 3, 1, 0));
}

#[test]
fn lost_acks_mean_retransmission_and_duplicates() {
    let mut w = World::new();
    w.sensor().set_pipe(0, acked_pipe(0)).unwrap();
    w.sensor()
        .set_ack_policy(0, Duration::from_millis(1), 3)
        .unwrap();
    w.lose_to_a = true;
    w.call_sensor(1.0);
    w.steps(5);
    // Delivered once, its acknowledgement lost; not yet late.
    assert_eq!(w.seen(), [1.0]);
    assert_eq!(w.sensor().pipe(0).unwrap().stats.retries, 0);
    w.steps(10);
    // Late: sent again with the same sequence number, delivered again.
    assert_eq!(w.sensor().pipe(0).unwrap().stats.retries, 1);
    assert_eq!(w.seen(), [1.0, 1.0]);
    w.lose_to_a = false;
    w.steps(15);
    let s = w.stats();
    assert_eq!((s.sent, s.acked, s.failures), (1, 1, 0));
    assert!(s.retries >= 1);
    assert_eq!(w.seen().len(), 1 + s.retries as usize);
    assert_eq!(w.sensor().pipe(0).unwrap().queued(), 0);
    // The next datagram goes out at once, and only once.
    let before = w.seen().len();
    w.call_sensor(2.0);
    w.steps(5);
    assert_eq!(w.seen()[before..], [2.0]);
    assert_eq!(w.stats().acked, 2);
}

#[test]
fn unacknowledged_datagrams_fail_after_the_retries() {
    let mut w = World::new();
    w.sensor().set_pipe(0, acked_pipe(0)).unwrap();
    w.sensor()
        .set_ack_policy(0, Duration::from_millis(1), 2)
        .unwrap();
    w.lose_to_b = true;
    w.call_sensor(1.0);
    w.call_sensor(2.0);
    // Each: 1 send + 2 retries, 1 ms apart, then dropped.
    w.steps(100);
    let s = w.stats();
    assert_eq!((s.sent, s.retries, s.failures, s.acked), (2, 4, 2, 0));
    assert_eq!(w.sensor().pipe(0).unwrap().queued(), 0);
    assert!(w.seen().is_empty());
    // The link is back: the next one arrives.
    w.lose_to_b = false;
    w.call_sensor(3.0);
    w.steps(5);
    assert_eq!(w.seen(), [3.0]);
    let s = w.stats();
    assert_eq!((s.acked, s.failures), (1, 2));
}

#[test]
fn refusals_are_answers_not_losses() {
    let mut w = World::new();
    // The sink has no input 4: it refuses each datagram, in its reply.
    w.sensor().set_pipe(0, acked_pipe(4)).unwrap();
    w.call_sensor(1.0);
    w.steps(300);
    let s = w.stats();
    assert_eq!((s.sent, s.acked, s.retries, s.failures), (1, 0, 0, 0));
    assert_eq!(s.remote_errors, 1);
    assert_eq!(s.last_remote_error, Some(ControlError::NoSuchInput(4)));
    assert_eq!(w.sink().stats().refused, 1);
}
