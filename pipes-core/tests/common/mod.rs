//! The two-runtime in-memory network the PIPES integration tests share.
//!
//! Runtime A holds a host port (port 1) and then its functions; runtime B
//! holds only functions. A's link 0 is wired to B's link 0, and either
//! direction can be made to lose everything it carries.

// Each test binary uses a different part of the harness.
#![allow(dead_code)]

use osap_core::time::Instant;
use std::any::Any;

use osap_core::codec::{Reader, Writer};
use osap_core::link::queue::transfer;
use osap_core::port::{Delivery, Port, PortInfo, PortTx};
use osap_core::route::Route;
use osap_core::transport::Transport;
use osap_tests::{TestLink, TestPort, TestRuntime};
use pipes_core::control::{ControlError, Reply, ReplyBody, Request};
use pipes_core::{Args, ArgsWriter, Value};

/// Microseconds of runtime clock per [`Net::step`].
pub(crate) const STEP_US: u64 = 100;

/// A port the harness can hand back to a test by its concrete type.
pub(crate) trait TestFn: Port + Any {
    /// The port as `Any`, for the downcast.
    fn as_any_mut(&mut self) -> &mut dyn Any;
}

impl<T: Port + Any> TestFn for T {
    fn as_any_mut(&mut self) -> &mut dyn Any {
        self
    }
}

/// One port of a runtime: the host port, or a function (or class) port.
pub(crate) enum Slot {
    /// The test's own port, from which it sends requests.
    Host(TestPort),
    /// Anything under test.
    Fn(Box<dyn TestFn>),
}

impl Slot {
    fn port(&mut self) -> &mut dyn Port {
        match self {
            Slot::Host(p) => p,
            Slot::Fn(p) => &mut **p,
        }
    }
    fn port_ref(&self) -> &dyn Port {
        match self {
            Slot::Host(p) => p,
            Slot::Fn(p) => &**p,
        }
    }
}

impl Port for Slot {
    fn port_count(&self) -> u16 {
        self.port_ref().port_count()
    }
    fn info(&self, offset: u16) -> PortInfo<'_> {
        self.port_ref().info(offset)
    }
    fn clear_to_receive(&self, offset: u16) -> bool {
        self.port_ref().clear_to_receive(offset)
    }
    fn on_packet(&mut self, d: Delivery<'_>, tx: &mut PortTx<'_>) {
        self.port().on_packet(d, tx)
    }
    fn poll(&mut self, tx: &mut PortTx<'_>) {
        self.port().poll(tx)
    }
}

/// Runtimes A and B, their ports and the link between them.
pub(crate) struct Net {
    /// Runtime A (host port first).
    pub a: TestRuntime,
    /// Runtime B.
    pub b: TestRuntime,
    pa: Vec<Slot>,
    pb: Vec<Slot>,
    la: Vec<TestLink>,
    lb: Vec<TestLink>,
    /// The runtimes' clock, in microseconds.
    pub now: u64,
    seq: u16,
    /// Lose every packet A sends to B.
    pub lose_to_b: bool,
    /// Lose every packet B sends to A.
    pub lose_to_a: bool,
}

/// A test runtime with clock sync off, so only the test's traffic flows.
pub(crate) fn runtime(name: &str) -> TestRuntime {
    let mut r = TestRuntime::new("pipes_test", name).unwrap();
    let quiet = osap_core::clock::TimeConfig {
        enabled: false,
        ..Default::default()
    };
    r.clock_mut().set_config(quiet).unwrap();
    r
}

/// The route from A to B.
pub(crate) fn to_b() -> Route {
    Route::through_links(&[0]).unwrap()
}

fn downcast<T: 'static>(slot: &mut Slot) -> &mut T {
    match slot {
        Slot::Fn(f) => (**f)
            .as_any_mut()
            .downcast_mut()
            .expect("port of another type"),
        Slot::Host(_) => panic!("the host port is not a function"),
    }
}

impl Net {
    /// A with the host port and then `on_a`, B with `on_b`.
    pub(crate) fn new(on_a: Vec<Box<dyn TestFn>>, on_b: Vec<Box<dyn TestFn>>) -> Net {
        let mut pa = vec![Slot::Host(TestPort::default())];
        pa.extend(on_a.into_iter().map(Slot::Fn));
        Net {
            a: runtime("a"),
            b: runtime("b"),
            pa,
            pb: on_b.into_iter().map(Slot::Fn).collect(),
            la: vec![TestLink::new()],
            lb: vec![TestLink::new()],
            now: 1,
            seq: 0,
            lose_to_b: false,
            lose_to_a: false,
        }
    }

    /// The host port.
    pub(crate) fn host(&mut self) -> &mut TestPort {
        match &mut self.pa[0] {
            Slot::Host(h) => h,
            Slot::Fn(_) => unreachable!("A's first port is the host"),
        }
    }

    /// The `i`th of `on_a`, as its concrete type.
    pub(crate) fn on_a<T: 'static>(&mut self, i: usize) -> &mut T {
        downcast(&mut self.pa[1 + i])
    }

    /// The `i`th of `on_b`, as its concrete type.
    pub(crate) fn on_b<T: 'static>(&mut self, i: usize) -> &mut T {
        downcast(&mut self.pb[i])
    }

    /// Polls both runtimes once, moves the link's packets, advances the clock.
    pub(crate) fn step(&mut self) {
        self.a
            .poll(Instant::from_micros(self.now), &mut self.pa, &mut self.la);
        self.b
            .poll(Instant::from_micros(self.now), &mut self.pb, &mut self.lb);
        if self.lose_to_b {
            while self.la[0].take_sent().is_some() {}
        }
        if self.lose_to_a {
            while self.lb[0].take_sent().is_some() {}
        }
        transfer(&mut self.la[0], &mut self.lb[0], usize::MAX);
        transfer(&mut self.lb[0], &mut self.la[0], usize::MAX);
        self.now += STEP_US;
    }

    /// `n` steps.
    pub(crate) fn steps(&mut self, n: usize) {
        for _ in 0..n {
            self.step();
        }
    }

    /// A fresh request sequence number.
    pub(crate) fn next_seq(&mut self) -> u16 {
        self.seq = self.seq.wrapping_add(1);
        self.seq
    }

    /// Sends a request from the host and returns the reply body.
    pub(crate) fn ask(&mut self, route: Route, dst: u16, req: &Request<'_>) -> Vec<u8> {
        let seq = self.next_seq();
        let mut buf = [0u8; 200];
        Transport::Request(seq).encode(&mut buf).unwrap();
        let mut w = Writer::new(&mut buf[3..]);
        req.encode(&mut w).unwrap();
        let n = 3 + w.len();
        let before = self.host().received.len();
        self.host().queue(route, dst, 10_000, &buf[..n]);
        for _ in 0..50 {
            self.step();
            if self.host().received.len() > before {
                let p = self.host().received[before].payload.clone();
                let (t, body) = Transport::decode(&p).unwrap();
                assert_eq!(t, Transport::Reply(seq));
                return body.to_vec();
            }
        }
        panic!("no reply to {req:?}");
    }

    /// Calls the function at `dst` with `vals` and returns the reply body.
    pub(crate) fn call(&mut self, route: Route, dst: u16, vals: &[(u8, Value<'_>)]) -> Vec<u8> {
        let args = args(vals);
        let a = Args::decode(&mut Reader::new(&args)).unwrap();
        self.ask(route, dst, &Request::Call(a))
    }
}

/// `vals` encoded as a call's argument list.
pub(crate) fn args(vals: &[(u8, Value<'_>)]) -> Vec<u8> {
    let mut buf = vec![0u8; 100];
    let mut w = Writer::new(&mut buf);
    let mut a = ArgsWriter::new(&mut w).unwrap();
    for (i, v) in vals {
        a.push(*i, v).unwrap();
    }
    a.finish().unwrap();
    let n = w.len();
    buf.truncate(n);
    buf
}

/// The body of a successful reply; panics on an error reply.
pub(crate) fn ok(body: &[u8]) -> ReplyBody<'_> {
    let r = Reply::parse(body).unwrap();
    r.result.unwrap_or_else(|e| panic!("error reply {e}"))
}

/// The error of an error reply; panics on success.
pub(crate) fn err(body: &[u8]) -> ControlError {
    Reply::parse(body).unwrap().result.unwrap_err()
}

/// A call reply's outputs, checked to be in index order.
pub(crate) fn returned(body: &[u8]) -> Vec<Value<'_>> {
    let ReplyBody::Returned(out) = ok(body) else {
        panic!("not a call reply")
    };
    out.iter()
        .enumerate()
        .map(|(i, (index, v))| {
            assert_eq!(usize::from(index), i);
            v
        })
        .collect()
}
