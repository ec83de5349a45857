//! The PIPES functions of simulated modules, over the network: found by a
//! scan, their signatures read back, called by RPC from a host port.

use osap_core::codec::Writer;
use osap_core::route::Route;
use osap_core::transport::Transport;
use osap_host::map::RuntimeRecord;
use osap_host::netrunner::{self, ScanOptions};
use osap_host::{Host, HostConfig, PortHandle};
use osap_sim::machine::functions::{
    self, ADD_CONTROL_POINT, COMPARATOR, GET_POSITION, GET_STATUS, GET_UPTIME, PULSE, READ_ANALOG,
    READ_PIN, SET_CURRENT,
};
use osap_sim::machine::{self, LinkKind, LinkSpec, ModuleSpec, SimMachine, Topology};
use pipes_core::control::{ControlError, ControlKey, Reply, ReplyBody, Request};
use pipes_core::function::FUNCTION_PORT_TYPE;
use pipes_core::signature::Signature;
use pipes_core::{ArgsWriter, ConvertReason, Value};
use std::time::Duration;

mod common;
use common::shipped;

const ANSWER: Duration = Duration::from_secs(1);

/// `[Call][args]`.
fn call_body(vals: &[(u8, Value<'_>)]) -> Vec<u8> {
    let mut buf = vec![0u8; 200];
    let mut w = Writer::new(&mut buf);
    w.u8(ControlKey::Call.to_u8()).unwrap();
    let mut a = ArgsWriter::new(&mut w).unwrap();
    for (i, v) in vals {
        a.push(*i, v).unwrap();
    }
    a.finish().unwrap();
    let n = w.len();
    buf.truncate(n);
    buf
}

fn request_body(req: &Request<'_>) -> Vec<u8> {
    let mut buf = vec![0u8; 200];
    let mut w = Writer::new(&mut buf);
    req.encode(&mut w).unwrap();
    let n = w.len();
    buf.truncate(n);
    buf
}

/// One function of one scanned runtime.
struct Fn {
    route: Route,
    port: u16,
}

impl Fn {
    /// Sends `body` as a request; returns the reply body.
    async fn ask(&self, host_port: &PortHandle, body: &[u8]) -> Vec<u8> {
        let reply = host_port
            .request(&self.route, self.port, body, ANSWER)
            .await
            .expect("the function answers");
        assert!(matches!(reply.transport, Transport::Reply(_)));
        reply.body
    }

    /// Calls with `vals`; the outputs, or the error reported.
    async fn call(
        &self,
        host_port: &PortHandle,
        vals: &[(u8, Value<'_>)],
    ) -> Result<Vec<(u8, Value<'static>)>, ControlError> {
        let body = self.ask(host_port, &call_body(vals)).await;
        let reply = Reply::parse(&body).expect("a well-formed reply");
        assert_eq!(reply.key, ControlKey::Call.to_u8());
        match reply.result? {
            ReplyBody::Returned(args) => Ok(args
                .iter()
                .map(|(i, v)| {
                    let v = match v {
                        Value::U64(x) => Value::U64(x),
                        Value::F32(x) => Value::F32(x),
                        Value::U16(x) => Value::U16(x),
                        Value::Bool(x) => Value::Bool(x),
                        other => panic!("unexpected output {other:?}"),
                    };
                    (i, v)
                })
                .collect()),
            other => panic!("unexpected reply {other:?}"),
        }
    }
}

/// The function named `name` in `rt`'s scanned ports.
fn find(rt: &RuntimeRecord, name: &str) -> Fn {
    let p = rt
        .ports
        .iter()
        .find(|p| p.type_name == FUNCTION_PORT_TYPE && p.name == name)
        .unwrap_or_else(|| panic!("{} has no function {name}: {:?}", rt.name, rt.ports));
    Fn {
        route: rt.route(),
        port: p.index,
    }
}

fn function_names(rt: &RuntimeRecord) -> Vec<&str> {
    rt.ports
        .iter()
        .filter(|p| p.type_name == FUNCTION_PORT_TYPE)
        .map(|p| p.name.as_str())
        .collect()
}

fn names(sigs: &[&Signature]) -> Vec<&'static str> {
    sigs.iter().map(|s| s.name).collect()
}

fn u64_out(outs: &[(u8, Value<'_>)], i: u8) -> u64 {
    match outs.iter().find(|(k, _)| *k == i) {
        Some((_, Value::U64(x))) => *x,
        other => panic!("output {i}: {other:?}"),
    }
}

fn f32_out(outs: &[(u8, Value<'_>)], i: u8) -> f32 {
    match outs.iter().find(|(k, _)| *k == i) {
        Some((_, Value::F32(x))) => *x,
        other => panic!("output {i}: {other:?}"),
    }
}

fn bool_out(outs: &[(u8, Value<'_>)], i: u8) -> bool {
    match outs.iter().find(|(k, _)| *k == i) {
        Some((_, Value::Bool(x))) => *x,
        other => panic!("output {i}: {other:?}"),
    }
}

async fn signature_of(f: &Fn, port: &PortHandle, sig: &Signature) {
    let body = f.ask(port, &request_body(&Request::GetSignature)).await;
    match Reply::parse(&body).unwrap().result {
        Ok(ReplyBody::Signature(view)) => {
            assert!(sig.matches(&view), "{} ≠ {:?}", sig.name, view)
        }
        other => panic!("unexpected reply {other:?}"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn small_machine_steppers_have_functions() {
    let host = Host::start(HostConfig::default()).unwrap();
    let topology = machine::load(shipped("small-machine.toml")).unwrap();
    let _machine = SimMachine::start(&host, &topology).await.unwrap();
    let report = netrunner::scan(&host, &ScanOptions::default())
        .await
        .unwrap();
    assert!(report.failures.is_empty(), "{:?}", report.failures);
    let map = &report.map;
    for name in ["x", "y", "z"] {
        let rt = map.find(name).unwrap();
        assert_eq!(
            function_names(rt),
            names(&functions::STEPPER_FUNCTIONS),
            "{name}"
        );
    }
    assert_eq!(
        function_names(map.find("hub").unwrap()),
        names(&functions::HUB_FUNCTIONS)
    );
    // A spindle has no function set yet.
    assert!(function_names(map.find("tool").unwrap()).is_empty());

    let port = host.open_port("test").await.unwrap();
    let x = map.find("x").unwrap();
    let (add, get, current, status) = (
        find(x, "add_control_point"),
        find(x, "get_position"),
        find(x, "set_current"),
        find(x, "get_status"),
    );
    for (f, sig) in [
        (&add, &ADD_CONTROL_POINT),
        (&get, &GET_POSITION),
        (&current, &SET_CURRENT),
        (&status, &GET_STATUS),
    ] {
        signature_of(f, &port, sig).await;
    }

    // Disabled at boot: no motion.
    let s = status.call(&port, &[]).await.unwrap();
    assert_eq!(s[0].1, Value::U16(0));
    assert!(!bool_out(&s, 1));
    let pos = get.call(&port, &[]).await.unwrap();
    let t0 = u64_out(&pos, 0);
    assert_eq!(f32_out(&pos, 1), 0.0);
    assert_eq!(
        add.call(&port, &[(0, Value::U64(t0 + 1_000)), (1, Value::F32(1.0))])
            .await,
        Err(ControlError::CallFailed(3)),
        "disabled"
    );
    assert_eq!(
        current.call(&port, &[(0, Value::F32(5.0))]).await,
        Err(ControlError::CallFailed(1)),
        "over the limit"
    );
    // An f64 that converts exactly is accepted for an f32 input.
    current.call(&port, &[(0, Value::F64(1.5))]).await.unwrap();
    let s = status.call(&port, &[]).await.unwrap();
    assert!(bool_out(&s, 1));

    // Move to 10.0 over 300 ms, then back to 4.0 over 100 ms.
    let t0 = u64_out(&get.call(&port, &[]).await.unwrap(), 0);
    let (t1, t2) = (t0 + 300_000, t0 + 400_000);
    let out = add
        .call(&port, &[(0, Value::U64(t1)), (1, Value::F32(10.0))])
        .await
        .unwrap();
    assert!(out.is_empty());
    add.call(&port, &[(0, Value::U32(t2 as u32)), (1, Value::I16(4))])
        .await
        .unwrap();
    let s = status.call(&port, &[]).await.unwrap();
    assert_eq!(s[0].1, Value::U16(2));
    // Going back in time is refused.
    assert_eq!(
        add.call(&port, &[(0, Value::U64(t1)), (1, Value::F32(0.0))])
            .await,
        Err(ControlError::CallFailed(1))
    );
    let mut last = (t0, 0.0f32);
    loop {
        let pos = get.call(&port, &[]).await.unwrap();
        let (t, p) = (u64_out(&pos, 0), f32_out(&pos, 1));
        assert!(t >= last.0, "the module's clock runs forward");
        if t < t1 {
            // Linear from where it stood when the point came, at most the
            // line from t0 (the point came after t0).
            let bound = 10.0 * (t - t0) as f32 / (t1 - t0) as f32;
            assert!(p >= last.1 && p <= bound + 1e-3, "{p} at {t}: {last:?}");
        } else if t < t2 {
            let expect = 10.0 - 6.0 * (t - t1) as f32 / (t2 - t1) as f32;
            assert!((p - expect).abs() < 1e-3, "{p} at {t}, expected {expect}");
        } else {
            assert_eq!(p, 4.0);
            break;
        }
        last = (t, p);
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let s = status.call(&port, &[]).await.unwrap();
    assert_eq!(s[0].1, Value::U16(0));

    // Wrong argument types: the typed error names the argument by index.
    let err = add
        .call(&port, &[(0, Value::Bool(true)), (1, Value::F32(1.0))])
        .await
        .unwrap_err();
    let ControlError::Convert { index, error } = err else {
        panic!("{err:?}");
    };
    assert_eq!(ADD_CONTROL_POINT.inputs[usize::from(index)].name, "time");
    assert_eq!(error.reason, ConvertReason::Impossible);
    let err = add
        .call(&port, &[(0, Value::U64(t2)), (1, Value::Utf8("far"))])
        .await
        .unwrap_err();
    assert!(
        matches!(err, ControlError::Convert { index: 1, .. }),
        "{err:?}"
    );
    assert_eq!(ADD_CONTROL_POINT.inputs[1].name, "position");
    // A value that would change is refused too (f64 → f32 lossy).
    let err = add
        .call(&port, &[(0, Value::U64(t2)), (1, Value::F64(0.1))])
        .await
        .unwrap_err();
    assert!(
        matches!(err, ControlError::Convert { index: 1, error } if error.reason == ConvertReason::Lossy),
        "{err:?}"
    );
    assert_eq!(
        add.call(&port, &[(0, Value::U64(t2))]).await,
        Err(ControlError::WrongArgCount {
            expected: 2,
            got: 1
        })
    );

    // The hub counts its uptime.
    let hub = find(map.find("hub").unwrap(), "get_uptime");
    signature_of(&hub, &port, &GET_UPTIME).await;
    let up = u64_out(&hub.call(&port, &[]).await.unwrap(), 0);
    assert!(up > 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn io_module_pins_and_comparator() {
    let host = Host::start(HostConfig::default()).unwrap();
    let topology = Topology::new("io")
        .with_module(ModuleSpec::new("io", "io"))
        .with_link(LinkSpec::new(machine::HOST, "io", LinkKind::Usb));
    let _machine = SimMachine::start(&host, &topology).await.unwrap();
    let report = netrunner::scan(&host, &ScanOptions::default())
        .await
        .unwrap();
    let rt = report.map.find("io").unwrap();
    assert_eq!(function_names(rt), names(&functions::IO_FUNCTIONS));
    let port = host.open_port("test").await.unwrap();
    let (read, pulse, analog, cmp) = (
        find(rt, "read_pin"),
        find(rt, "pulse"),
        find(rt, "read_analog"),
        find(rt, "comparator"),
    );
    for (f, sig) in [
        (&read, &READ_PIN),
        (&pulse, &PULSE),
        (&analog, &READ_ANALOG),
        (&cmp, &COMPARATOR),
    ] {
        signature_of(f, &port, sig).await;
    }

    let level = |outs: Vec<(u8, Value<'static>)>| bool_out(&outs, 1);
    assert!(!level(
        read.call(&port, &[(0, Value::U8(3))]).await.unwrap()
    ));
    pulse
        .call(&port, &[(0, Value::U8(3)), (1, Value::U32(150_000))])
        .await
        .unwrap();
    assert!(level(read.call(&port, &[(0, Value::U8(3))]).await.unwrap()));
    assert!(!level(
        read.call(&port, &[(0, Value::U8(4))]).await.unwrap()
    ));
    tokio::time::sleep(Duration::from_millis(200)).await;
    assert!(!level(
        read.call(&port, &[(0, Value::U8(3))]).await.unwrap()
    ));
    assert_eq!(
        read.call(&port, &[(0, Value::U8(functions::IO_PINS))])
            .await,
        Err(ControlError::CallFailed(1))
    );
    // A negative pin number is out of range for the u8 input.
    let err = pulse
        .call(&port, &[(0, Value::I8(-1)), (1, Value::U32(1))])
        .await
        .unwrap_err();
    assert!(
        matches!(err, ControlError::Convert { index: 0, error } if error.reason == ConvertReason::OutOfRange),
        "{err:?}"
    );

    // The analog input is the documented sine of the module's time.
    let a = analog.call(&port, &[]).await.unwrap();
    assert_eq!(f32_out(&a, 1), functions::analog_at(u64_out(&a, 0)));
    let c = cmp
        .call(&port, &[(0, Value::F32(-1.5)), (1, Value::F32(1.5))])
        .await
        .unwrap();
    assert!(bool_out(&c, 1), "the sine stays within ±1");
    let c = cmp
        .call(&port, &[(0, Value::F32(2.0)), (1, Value::F32(3.0))])
        .await
        .unwrap();
    assert!(!bool_out(&c, 1));
    assert_eq!(
        cmp.call(&port, &[(0, Value::F32(1.0)), (1, Value::F32(0.0))])
            .await,
        Err(ControlError::CallFailed(1))
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn restart_resets_the_simulated_hardware() {
    let host = Host::start(HostConfig::default()).unwrap();
    let topology = machine::load(shipped("single-usb.toml"))
        .unwrap()
        .with_zero_latency(true);
    let machine = SimMachine::start(&host, &topology).await.unwrap();
    let report = netrunner::scan(&host, &ScanOptions::default())
        .await
        .unwrap();
    let rt = report.map.find("motor").unwrap();
    let port = host.open_port("test").await.unwrap();
    let (current, status) = (find(rt, "set_current"), find(rt, "get_status"));
    current.call(&port, &[(0, Value::F32(1.0))]).await.unwrap();
    assert!(bool_out(&status.call(&port, &[]).await.unwrap(), 1));
    let motor = machine.module("motor").unwrap();
    motor.kill().await.unwrap();
    motor.restart().await.unwrap();
    // Same ports after the restart; the axis boots disabled again.
    let mut enabled = None;
    for _ in 0..50 {
        if let Ok(reply) = port
            .request(
                &status.route,
                status.port,
                &call_body(&[]),
                Duration::from_millis(100),
            )
            .await
        {
            let r = Reply::parse(&reply.body).unwrap();
            if let Ok(ReplyBody::Returned(a)) = r.result {
                enabled = a.get(1).map(|v| v == Value::Bool(true));
                break;
            }
        }
    }
    assert_eq!(enabled, Some(false));
}
