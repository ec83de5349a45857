//! The PIPES functions of simulated modules, over the network: a `stepper`
//! runs the module firmware's logic (`osap_module::Module` on a simulated
//! board), so a scan finds the firmware's 32 functions on it, and calls
//! reach that logic through the same ports and codecs as on hardware. Here:
//! the function set and its signatures, argument conversion, every failure
//! code the firmware gives (`osap_module::stepper::StepperError`,
//! `osap_module::io::IoError`), the I/O pins against what the topology and
//! the test set, a timed pulse, and a restart that resets it all. A `hub`
//! has no functions; calls to the steppers behind it route through it.

use osap_core::codec::Writer;
use osap_core::route::Route;
use osap_core::transport::Transport;
use osap_host::map::RuntimeRecord;
use osap_host::netrunner::{self, ScanOptions};
use osap_host::{Host, HostConfig, PortHandle};
use osap_module::functions::SIGNATURES;
use osap_module::io::IoError;
use osap_module::stepper::{Mode, StepperError};
use osap_sim::machine::board::DigitalWrite;
use osap_sim::machine::{SharedModule, SimMachine};
use osap_sim::topology::{SimSpec, DRIVER_MICROSTEPS};
use pipes_core::control::{ControlError, ControlKey, Reply, ReplyBody, Request};
use pipes_core::function::FUNCTION_PORT_TYPE;
use pipes_core::signature::Signature;
use pipes_core::{ArgsWriter, ConvertReason, Value};
use std::time::{Duration, Instant};

mod common;
use common::shipped;

const ANSWER: Duration = Duration::from_secs(1);
/// The firmware's default control-point interval, µs.
const IV: u64 = 2048;

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

/// An output, owned.
fn owned(v: Value<'_>) -> Value<'static> {
    v.into_owned()
}

/// One function of one scanned runtime.
#[derive(Clone)]
struct Fn {
    name: String,
    route: Route,
    port: u16,
}

impl Fn {
    /// Sends `body` as a request; returns the reply body.
    async fn ask(&self, host_port: &PortHandle, body: &[u8]) -> Vec<u8> {
        let reply = host_port
            .request(&self.route, self.port, body, ANSWER)
            .await
            .unwrap_or_else(|e| panic!("{} answers: {e}", self.name));
        assert!(matches!(reply.transport, Transport::Reply(_)));
        reply.body
    }

    /// Calls with `vals` (input `i` is `vals[i]`); the outputs in order, or
    /// the error reported.
    async fn call(
        &self,
        host_port: &PortHandle,
        vals: &[Value<'_>],
    ) -> Result<Vec<Value<'static>>, ControlError> {
        let indexed: Vec<(u8, Value<'_>)> = vals
            .iter()
            .enumerate()
            .map(|(i, v)| (i as u8, v.reborrow()))
            .collect();
        self.call_indexed(host_port, &indexed).await
    }

    /// Calls with `vals` as (input index, value).
    async fn call_indexed(
        &self,
        host_port: &PortHandle,
        vals: &[(u8, Value<'_>)],
    ) -> Result<Vec<Value<'static>>, ControlError> {
        let body = self.ask(host_port, &call_body(vals)).await;
        let reply = Reply::parse(&body).expect("a well-formed reply");
        assert_eq!(reply.key, ControlKey::Call.to_u8());
        match reply.result? {
            ReplyBody::Returned(args) => {
                let outs: Vec<(u8, Value<'static>)> =
                    args.iter().map(|(i, v)| (i, owned(v))).collect();
                for (k, (i, _)) in outs.iter().enumerate() {
                    assert_eq!(usize::from(*i), k, "{}: outputs in order", self.name);
                }
                Ok(outs.into_iter().map(|(_, v)| v).collect())
            }
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
        name: name.to_string(),
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

fn firmware_names() -> Vec<&'static str> {
    SIGNATURES.iter().map(|s| s.name).collect()
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

fn u64_at(outs: &[Value<'_>], i: usize) -> u64 {
    match outs.get(i) {
        Some(Value::U64(x)) => *x,
        other => panic!("output {i}: {other:?}"),
    }
}

fn failed(code: u8) -> Result<Vec<Value<'static>>, ControlError> {
    Err(ControlError::CallFailed(code.into()))
}

fn stepper_failed(e: StepperError) -> Result<Vec<Value<'static>>, ControlError> {
    failed(e.code())
}

fn io_failed(e: IoError) -> Result<Vec<Value<'static>>, ControlError> {
    failed(e.code())
}

/// `get_status` as the firmware reports it: mode, queued, enabled, faults.
fn reported(mode: Mode, queued: u16, enabled: bool) -> Vec<Value<'static>> {
    vec![
        Value::U8(mode as u8),
        Value::U16(queued),
        Value::Bool(enabled),
        Value::U32(0),
    ]
}

/// A stepper's functions by name, scanned.
struct Functions {
    rt: RuntimeRecord,
}

impl Functions {
    fn get(&self, name: &str) -> Fn {
        find(&self.rt, name)
    }
}

/// Scans `host`; the runtime named `name`.
async fn scanned(host: &Host, name: &str) -> Functions {
    let report = netrunner::scan(host, &ScanOptions::default())
        .await
        .unwrap();
    assert!(report.failures.is_empty(), "{:?}", report.failures);
    Functions {
        rt: report.map.find(name).unwrap().clone(),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_stepper_presents_the_firmware_functions_through_the_hub() {
    let host = Host::start(HostConfig::default()).unwrap();
    let topology = SimSpec::load(shipped("small-machine.toml")).unwrap();
    let machine = SimMachine::start(&host, &topology).await.unwrap();
    let report = netrunner::scan(&host, &ScanOptions::default())
        .await
        .unwrap();
    assert!(report.failures.is_empty(), "{:?}", report.failures);
    let map = &report.map;
    // Every stepper has the firmware's functions in the firmware's order;
    // the hub, a router, has none.
    for name in ["x", "y", "z", "tool"] {
        assert_eq!(
            function_names(map.find(name).unwrap()),
            firmware_names(),
            "{name}"
        );
    }
    assert!(function_names(map.find("hub").unwrap()).is_empty());
    assert!(machine.module("hub").unwrap().module().is_none());

    // Every signature reads back as the firmware declares it.
    let port = host.open_port("test").await.unwrap();
    let x = map.find("x").unwrap();
    for sig in SIGNATURES {
        signature_of(&find(x, sig.name), &port, sig).await;
    }
    // Each stepper behind the hub answers on its own route (host → hub →
    // its UART), and is its own module: enabling x leaves the others alone.
    let route_of = |name: &str| machine.route_to(name).unwrap();
    for (k, name) in ["x", "y", "z", "tool"].into_iter().enumerate() {
        let rt = map.find(name).unwrap();
        assert_eq!(rt.route, vec![machine.host_links()[0], k as u8 + 1]);
        assert_eq!(Route::through_links(&rt.route).unwrap(), route_of(name));
        let s = find(rt, "get_status").call(&port, &[]).await.unwrap();
        assert_eq!(s, reported(Mode::Disabled, 0, false), "{name}");
    }
    find(x, "set_enable")
        .call(&port, &[Value::Bool(true)])
        .await
        .unwrap();
    for (name, on) in [("x", true), ("y", false), ("z", false), ("tool", false)] {
        let s = find(map.find(name).unwrap(), "get_status")
            .call(&port, &[])
            .await
            .unwrap();
        assert_eq!(s[2], Value::Bool(on), "{name}");
        let shared = machine.module(name).unwrap().module().unwrap();
        assert_eq!(shared.lock(|m| m.board().driver().enabled()), on, "{name}");
    }
}

/// host –USB– hub –UART– m: `m` with a maximum limit switch at 0.5 and its
/// I/O pins reading what `[module.io]` says. Without clock sync, so the
/// module's synchronized time is its local clock.
const IO_MACHINE: &str = r#"
name = "io-bench"
sync = false

[[module]]
name = "hub"
type = "hub"

[[module]]
name = "m"
type = "stepper"
rate_ppm = 25.0
[module.motor]
limit_max = 0.5
[module.io]
digital = [true, false, false, true]
analog = [0.25, 0.5, 1.0]

[[link]]
a = "host"
b = "hub"
kind = "usb"

[[link]]
a = "hub"
b = "m"
kind = "uart"
"#;

/// What `analog_read` returns for an input at `v` of full scale: a 12-bit
/// converter's reading shifted left by 4, over 65 535.
fn adc(v: f64) -> f32 {
    f32::from(((v * 4095.0).round() as u16) << 4) / 65_535.0
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stepper_functions_refuse_with_the_firmware_codes() {
    let host = Host::start(HostConfig::default()).unwrap();
    let topology = SimSpec::parse(IO_MACHINE).unwrap();
    let machine = SimMachine::start(&host, &topology).await.unwrap();
    let f = scanned(&host, "m").await;
    let shared = machine.module("m").unwrap().module().unwrap();
    let port = host.open_port("test").await.unwrap();
    let p = &port;
    let (add, status, counters, enable) = (
        f.get("add_point"),
        f.get("get_status"),
        f.get("get_counters"),
        f.get("set_enable"),
    );
    let (interval, scale, micro, halt) = (
        f.get("set_interval"),
        f.get("set_scale"),
        f.get("set_microsteps"),
        f.get("halt"),
    );
    use StepperError as E;

    // Boots disabled, standing at 0; its limit switch (above 0.5) released,
    // no edge yet.
    assert_eq!(
        status.call(p, &[]).await.unwrap(),
        reported(Mode::Disabled, 0, false)
    );
    assert_eq!(
        f.get("read_limit").call(p, &[]).await.unwrap(),
        [Value::U64(0), Value::Bool(true), Value::U32(0)]
    );
    let pos = f.get("get_position").call(p, &[]).await.unwrap();
    assert_eq!(pos[1], Value::F32(0.0));
    // Synchronized time now (no sync: the module's own clock).
    let now = u64_at(&pos, 0);
    let t = (now + 2_000_000).next_multiple_of(IV);
    assert_eq!(
        add.call(p, &[Value::U64(t), Value::F32(0.0)]).await,
        stepper_failed(E::Disabled)
    );

    // Settings: values the firmware or the simulated driver refuse.
    assert_eq!(
        interval.call(p, &[Value::U32(1000)]).await,
        stepper_failed(E::BadValue)
    );
    assert_eq!(
        interval.call(p, &[Value::U32(128)]).await,
        stepper_failed(E::BadValue)
    );
    assert_eq!(
        interval.call(p, &[Value::U32(32_768)]).await,
        stepper_failed(E::BadValue)
    );
    assert_eq!(
        scale.call(p, &[Value::F32(0.0)]).await,
        stepper_failed(E::BadValue)
    );
    assert_eq!(
        scale.call(p, &[Value::F32(-80.0)]).await,
        stepper_failed(E::BadValue)
    );
    assert_eq!(
        scale.call(p, &[Value::F32(f32::NAN)]).await,
        stepper_failed(E::BadValue)
    );
    // The simulated driver sets 1 to 256 microsteps, as the firmware
    // takes them.
    assert_eq!(DRIVER_MICROSTEPS, [1, 2, 4, 8, 16, 32, 64, 128, 256]);
    for bad in [0u16, 3, 48, 512, 1000] {
        assert_eq!(
            micro.call(p, &[Value::U16(bad)]).await,
            stepper_failed(E::BadValue),
            "{bad} microsteps"
        );
    }
    // A u8 converts to the u16 input.
    micro.call(p, &[Value::U8(16)]).await.unwrap();
    assert_eq!(shared.lock(|m| m.board().driver().microsteps()), 16);
    assert_eq!(shared.lock(|m| m.stepper.microsteps()), 16);
    micro.call(p, &[Value::U16(1)]).await.unwrap();
    interval.call(p, &[Value::U32(4096)]).await.unwrap();
    assert_eq!(shared.lock(|m| m.stepper.interval_us()), 4096);
    interval.call(p, &[Value::U32(IV as u32)]).await.unwrap();
    scale.call(p, &[Value::F32(100.0)]).await.unwrap();
    assert_eq!(shared.lock(|m| m.stepper.steps_per_unit()), 100.0);
    // The farthest a position may be: 2^46 microsteps (positions wrap on
    // the track, an axis has no end).
    enable.call(p, &[Value::Bool(true)]).await.unwrap();
    assert_eq!(
        status.call(p, &[]).await.unwrap(),
        reported(Mode::Idle, 0, true)
    );
    assert!(shared.lock(|m| m.board().driver().enabled()));
    assert_eq!(
        add.call(p, &[Value::U64(t), Value::F32(1e12)]).await,
        stepper_failed(E::OutOfRange)
    );
    assert_eq!(
        add.call(p, &[Value::U64(t), Value::F32(f32::INFINITY)])
            .await,
        stepper_failed(E::OutOfRange)
    );
    // A stream starts where the axis stands (within a microstep), on the
    // interval's grid.
    assert_eq!(
        add.call(p, &[Value::U64(t), Value::F32(1.0)]).await,
        stepper_failed(E::Discontinuous)
    );
    assert_eq!(
        add.call(p, &[Value::U64(t + 1), Value::F32(0.0)]).await,
        stepper_failed(E::Misaligned)
    );
    add.call(p, &[Value::U64(t), Value::F32(0.0)])
        .await
        .unwrap();
    assert_eq!(
        add.call(p, &[Value::U64(t), Value::F32(0.0)]).await,
        stepper_failed(E::Stale)
    );
    assert_eq!(
        add.call(p, &[Value::U64(t + 3 * IV), Value::F32(0.0)])
            .await,
        stepper_failed(E::Gap)
    );
    // One missing point is filled from its neighbours.
    add.call(p, &[Value::U64(t + 2 * IV), Value::F32(0.01)])
        .await
        .unwrap();
    assert_eq!(
        status.call(p, &[]).await.unwrap(),
        reported(Mode::Idle, 3, true)
    );
    // Settings wait for the stream to end.
    assert_eq!(
        interval.call(p, &[Value::U32(4096)]).await,
        stepper_failed(E::Busy)
    );
    assert_eq!(
        scale.call(p, &[Value::F32(80.0)]).await,
        stepper_failed(E::Busy)
    );
    assert_eq!(
        micro.call(p, &[Value::U16(2)]).await,
        stepper_failed(E::Busy)
    );
    assert_eq!(shared.lock(|m| m.board().driver().microsteps()), 1);
    // Points accepted, refused, the latest refusal's code, gaps filled.
    assert_eq!(
        counters.call(p, &[]).await.unwrap(),
        [
            Value::U32(2),
            Value::U32(7),
            Value::U8(E::Gap.code()),
            Value::U32(1)
        ]
    );

    // Halted: the stream is gone and points are refused until the motor is
    // powered again.
    assert!(halt.call(p, &[]).await.unwrap().is_empty());
    assert_eq!(
        status.call(p, &[]).await.unwrap(),
        reported(Mode::Halted, 0, true)
    );
    assert_eq!(
        add.call(p, &[Value::U64(t + 4 * IV), Value::F32(0.0)])
            .await,
        stepper_failed(E::Faulted)
    );
    enable.call(p, &[Value::Bool(false)]).await.unwrap();
    assert_eq!(
        status.call(p, &[]).await.unwrap(),
        reported(Mode::Disabled, 0, false)
    );
    assert!(!shared.lock(|m| m.board().driver().enabled()));
    enable.call(p, &[Value::Bool(true)]).await.unwrap();
    add.call(p, &[Value::U64(t + 4 * IV), Value::F32(0.0)])
        .await
        .unwrap();
    let c = counters.call(p, &[]).await.unwrap();
    assert_eq!(
        c[..3],
        [Value::U32(3), Value::U32(8), Value::U8(E::Faulted.code())]
    );
    // Nothing moved: the points all stood at 0 (0.01 is under a step).
    assert_eq!(
        f.get("get_steps").call(p, &[]).await.unwrap(),
        [Value::I64(0), Value::U64(0), Value::U64(0), Value::U64(0)]
    );
    assert!(shared.lock(|m| m.board().motor().edges().is_empty()));

    // Wrong arguments, refused by the function port before the firmware
    // sees them: the typed error names the argument by index.
    let err = add
        .call(p, &[Value::Bool(true), Value::F32(1.0)])
        .await
        .unwrap_err();
    let ControlError::Convert { index, error } = err else {
        panic!("{err:?}");
    };
    assert_eq!(SIGNATURES[0].inputs[usize::from(index)].name, "time");
    assert_eq!(error.reason, ConvertReason::Impossible);
    let err = add
        .call(p, &[Value::U64(t), Value::utf8("far")])
        .await
        .unwrap_err();
    assert!(
        matches!(err, ControlError::Convert { index: 1, .. }),
        "{err:?}"
    );
    assert_eq!(SIGNATURES[0].inputs[1].name, "position");
    // A value that would change is refused too (f64 → f32 lossy), one that
    // converts exactly is taken.
    let err = add
        .call(p, &[Value::U64(t), Value::F64(0.1)])
        .await
        .unwrap_err();
    assert!(
        matches!(err, ControlError::Convert { index: 1, error } if error.reason == ConvertReason::Lossy),
        "{err:?}"
    );
    assert_eq!(
        scale.call(p, &[Value::F64(-1.5)]).await,
        stepper_failed(E::BadValue)
    );
    assert_eq!(
        add.call_indexed(p, &[(0, Value::U64(t))]).await,
        Err(ControlError::WrongArgCount {
            expected: 2,
            got: 1
        })
    );
    // Negative for an unsigned input: out of range.
    let err = micro.call(p, &[Value::I8(-1)]).await.unwrap_err();
    assert!(
        matches!(err, ControlError::Convert { index: 0, error } if error.reason == ConvertReason::OutOfRange),
        "{err:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn io_functions_read_and_drive_the_simulated_pins() {
    let host = Host::start(HostConfig::default()).unwrap();
    let topology = SimSpec::parse(IO_MACHINE).unwrap();
    let machine = SimMachine::start(&host, &topology).await.unwrap();
    let m = machine.module("m").unwrap();
    let shared = m.module().unwrap();
    let f = scanned(&host, "m").await;
    let port = host.open_port("test").await.unwrap();
    let p = &port;
    let (dread, dwrite, pwm, analog, pulse, pulse_at) = (
        f.get("digital_read"),
        f.get("digital_write"),
        f.get("pwm_write"),
        f.get("analog_read"),
        f.get("pulse"),
        f.get("pulse_at"),
    );
    use IoError as E;
    let level = |outs: Vec<Value<'static>>| match outs[..] {
        [Value::U64(_), Value::Bool(l)] => l,
        _ => panic!("{outs:?}"),
    };

    // The digital pins read what [module.io] says; the board has 4, 2 PWM
    // outputs and 3 analog inputs.
    for (pin, want) in [(0u8, true), (1, false), (2, false), (3, true)] {
        assert_eq!(
            level(dread.call(p, &[Value::U8(pin)]).await.unwrap()),
            want,
            "pin {pin}"
        );
    }
    for pin in [4u8, 9, 255] {
        assert_eq!(
            dread.call(p, &[Value::U8(pin)]).await,
            io_failed(E::NoSuchPin)
        );
        assert_eq!(
            dwrite.call(p, &[Value::U8(pin), Value::Bool(true)]).await,
            io_failed(E::NoSuchPin)
        );
        assert_eq!(
            pulse.call(p, &[Value::U8(pin), Value::U32(10)]).await,
            io_failed(E::NoSuchPin)
        );
    }
    assert_eq!(
        analog.call(p, &[Value::U8(3)]).await,
        io_failed(E::NoSuchPin)
    );
    assert_eq!(
        pwm.call(p, &[Value::U8(2), Value::F32(0.5)]).await,
        io_failed(E::NoSuchPin)
    );
    for duty in [2.0f32, -0.1, f32::NAN] {
        assert_eq!(
            pwm.call(p, &[Value::U8(0), Value::F32(duty)]).await,
            io_failed(E::BadValue),
            "duty {duty}"
        );
    }
    // An outside signal changes what a pin reads.
    shared.lock(|m| assert!(m.board_mut().pins_mut().set_digital(1, true)));
    assert!(level(dread.call(p, &[Value::U8(1)]).await.unwrap()));

    // Writes drive the pins, and the board records them.
    dwrite
        .call(p, &[Value::U8(2), Value::Bool(true)])
        .await
        .unwrap();
    assert!(level(dread.call(p, &[Value::U8(2)]).await.unwrap()));
    pwm.call(p, &[Value::U8(1), Value::F32(0.25)])
        .await
        .unwrap();
    pwm.call(p, &[Value::U8(0), Value::F32(1.0)]).await.unwrap();
    let (pins, writes, duties) = shared.lock(|m| {
        let pins = m.board().pins();
        (pins.digital(), pins.writes().to_vec(), pins.pwm())
    });
    assert_eq!(pins, [true, true, true, true]);
    assert_eq!(writes.len(), 1);
    assert_eq!((writes[0].pin, writes[0].level), (2, true));
    assert_eq!(duties, [65_535, 16_384]);

    // Analog inputs: the topology's values through a 12-bit converter,
    // stamped with the module's synchronized time.
    let mut last = 0;
    for (ch, v) in [(0u8, 0.25), (1, 0.5), (2, 1.0)] {
        let out = analog.call(p, &[Value::U8(ch)]).await.unwrap();
        assert_eq!(out[1], Value::F32(adc(v)), "input {ch}");
        let t = u64_at(&out, 0);
        assert!(t >= last, "time runs forward");
        last = t;
    }
    shared.lock(|m| assert!(m.board_mut().pins_mut().set_analog(1, 0.123_456)));
    let out = analog.call(p, &[Value::U8(1)]).await.unwrap();
    assert_eq!(out[1], Value::F32(adc(0.123_456)));
    assert_ne!(adc(0.123_456), 0.123_456, "quantized");

    // A pulse: high now, low after its duration (ended from the module's
    // loop, so up to its wake-up latency late).
    assert_eq!(
        pulse.call(p, &[Value::U8(3), Value::U32(10_000_001)]).await,
        io_failed(E::BadValue),
        "over 10 s"
    );
    const PULSE_US: u64 = 50_000;
    pulse
        .call(p, &[Value::U8(3), Value::U32(PULSE_US as u32)])
        .await
        .unwrap();
    assert!(
        level(dread.call(p, &[Value::U8(3)]).await.unwrap()),
        "high during the pulse"
    );
    let writes_on = |pin: u8| -> Vec<DigitalWrite> {
        shared.lock(|m| {
            m.board()
                .pins()
                .writes()
                .iter()
                .filter(|w| w.pin == pin)
                .copied()
                .collect()
        })
    };
    let deadline = Instant::now() + Duration::from_secs(2);
    while writes_on(3).len() < 2 {
        assert!(
            Instant::now() < deadline,
            "the pulse never ended: {:?}",
            writes_on(3)
        );
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    let w = writes_on(3);
    assert_eq!((w[0].level, w[1].level), (true, false), "{w:?}");
    let length = (w[1].local - w[0].local).as_micros();
    eprintln!("pulse of {PULSE_US} µs: high for {length} µs (module clock)");
    assert!(
        (PULSE_US..PULSE_US + 10_000).contains(&length),
        "{length} µs"
    );
    assert!(!level(dread.call(p, &[Value::U8(3)]).await.unwrap()));

    // A pulse at a synchronized time (here the module's own clock): at
    // most 60 s ahead, 16 waiting at once.
    let now = u64_at(&dread.call(p, &[Value::U8(0)]).await.unwrap(), 0);
    assert_eq!(
        pulse_at
            .call(
                p,
                &[Value::U64(now + 61_000_000), Value::U8(0), Value::U32(10)]
            )
            .await,
        io_failed(E::BadValue),
        "over 60 s ahead"
    );
    assert_eq!(
        pulse_at
            .call(p, &[Value::U64(now), Value::U8(4), Value::U32(10)])
            .await,
        io_failed(E::NoSuchPin)
    );
    let start = now + 100_000;
    pulse_at
        .call(p, &[Value::U64(start), Value::U8(1), Value::U32(20_000)])
        .await
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(2);
    while writes_on(1).len() < 2 {
        assert!(
            Instant::now() < deadline,
            "the scheduled pulse never ended: {:?}",
            writes_on(1)
        );
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    let w = writes_on(1);
    let map = shared.lock(|m| m.time);
    let (on, off) = (
        map.system_time(w[0].local).as_micros(),
        map.system_time(w[1].local).as_micros(),
    );
    eprintln!(
        "pulse at {start}: high at {on} ({:+} µs), low at {off} ({:+} µs)",
        on as i64 - start as i64,
        off as i64 - (start + 20_000) as i64
    );
    assert_eq!((w[0].level, w[1].level), (true, false), "{w:?}");
    assert!(
        (start..start + 10_000).contains(&on),
        "started at {on}, due {start}"
    );
    assert!(
        (start + 20_000..start + 30_000).contains(&off),
        "ended at {off}"
    );
    // Sixteen may wait at once.
    for k in 0..16 {
        pulse_at
            .call(
                p,
                &[
                    Value::U64(now + 50_000_000 + k),
                    Value::U8(0),
                    Value::U32(10),
                ],
            )
            .await
            .unwrap();
    }
    assert_eq!(
        pulse_at
            .call(
                p,
                &[Value::U64(now + 50_000_000), Value::U8(0), Value::U32(10)]
            )
            .await,
        io_failed(E::Full)
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_restart_boots_the_firmware_afresh() {
    let host = Host::start(HostConfig::default()).unwrap();
    let topology = SimSpec::parse(IO_MACHINE).unwrap().with_zero_latency(true);
    let machine = SimMachine::start(&host, &topology).await.unwrap();
    let f = scanned(&host, "m").await;
    let port = host.open_port("test").await.unwrap();
    let p = &port;
    let m = machine.module("m").unwrap();
    let before = m.module().unwrap();

    // Change everything a call can change.
    f.get("set_scale")
        .call(p, &[Value::F32(400.0)])
        .await
        .unwrap();
    f.get("set_microsteps")
        .call(p, &[Value::U16(8)])
        .await
        .unwrap();
    f.get("set_enable")
        .call(p, &[Value::Bool(true)])
        .await
        .unwrap();
    f.get("digital_write")
        .call(p, &[Value::U8(0), Value::Bool(false)])
        .await
        .unwrap();
    f.get("pwm_write")
        .call(p, &[Value::U8(0), Value::F32(0.5)])
        .await
        .unwrap();
    assert_eq!(
        f.get("add_point")
            .call(p, &[Value::U64(1), Value::F32(0.0)])
            .await,
        stepper_failed(StepperError::Misaligned)
    );
    let changed = |s: &SharedModule| {
        s.lock(|m| {
            (
                m.stepper.enabled(),
                m.stepper.steps_per_unit(),
                m.board().driver().microsteps(),
                m.board().pins().digital()[0],
                m.board().pins().pwm()[0],
                m.stepper.counters().refused,
            )
        })
    };
    assert_eq!(changed(&before), (true, 3200.0, 8, false, 32_768, 1));

    m.kill().await.unwrap();
    m.restart().await.unwrap();
    // A fresh module on a fresh board; the ports answer as before.
    let after = m.module().unwrap();
    assert_eq!(changed(&after), (false, 80.0, 1, true, 0, 0));
    assert!(after.lock(|m| m.board().pins().writes().is_empty()));
    assert!(changed(&before).0, "the old instance is left as it was");
    let status = f.get("get_status");
    let mut answered = None;
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
            if let Ok(ReplyBody::Returned(a)) = Reply::parse(&reply.body).unwrap().result {
                answered = Some(a.iter().map(|(_, v)| owned(v)).collect::<Vec<_>>());
                break;
            }
        }
    }
    assert_eq!(answered, Some(reported(Mode::Disabled, 0, false)));
    assert_eq!(
        f.get("get_counters").call(p, &[]).await.unwrap(),
        [Value::U32(0), Value::U32(0), Value::U8(0), Value::U32(0)]
    );
    let d = f
        .get("digital_read")
        .call(p, &[Value::U8(0)])
        .await
        .unwrap();
    assert_eq!(
        d[1],
        Value::Bool(true),
        "pin 0 reads the topology's level again"
    );
}
