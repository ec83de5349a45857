//! The system object model and the manager, on host runtimes joined
//! in-process: h – a – b, with PIPES functions attached to a and b (and
//! defined on h by the manager), and a PIPES class on a or h.

use osap_core::route::Route;
use osap_core::stack::Owner;
use osap_host::link::memory;
use osap_host::som::model::{SomArg, SomDelivery, SomInputMode, SomOutputMode};
use osap_host::som::{
    attach_class, attach_function, Disconnect, FnRef, HostFnError, HostFunction, Manager,
    PipeOptions, PipeStats, Som, SomError, Value,
};
use osap_host::Host;
use pipes_core::control::{ControlError, FailureCode, InputMode, OutputMode, Request, ANY_SLOT};
use pipes_core::pipe::{PipeConfig, PipeDelivery};
use pipes_core::{ScalarType, Type};
use std::sync::{Arc, Mutex};
use std::time::Duration;

mod common;
use common::{host, refresh};

const F32: Type = Type::Scalar(ScalarType::F32);
const F64: Type = Type::Scalar(ScalarType::F64);
const U32: Type = Type::Scalar(ScalarType::U32);

type Seen = Arc<Mutex<Vec<f64>>>;

struct Net {
    h: Host,
    // Kept so the runtimes stay up.
    _a: Host,
    _b: Host,
    /// Values b's accumulator received (its input a).
    acc_seen: Seen,
    acc_port: u16,
}

/// h – a – b. a: `sensor(x: f32) -> y: f32` (y = x). b: `acc(a: f64) ->
/// total: f64` (running sum) and `text(s: utf8) -> n: u32`, and `fail() ->
/// ()` failing with code 7.
async fn net() -> Net {
    let (h, a, b) = (host("h"), host("a"), host("b"));
    let sensor = HostFunction::new("sensor", &[("x", F32)], &[("y", F32)], |i| {
        Ok(vec![i[0].clone()])
    })
    .unwrap();
    attach_function(&a, sensor).await.unwrap();
    let acc_seen: Seen = Arc::default();
    let seen = acc_seen.clone();
    let mut total = 0.0;
    let acc = HostFunction::new("acc", &[("a", F64)], &[("total", F64)], move |i| {
        let Value::F64(x) = i[0] else {
            return Err(HostFnError::new(1));
        };
        seen.lock().unwrap().push(x);
        total += x;
        Ok(vec![Value::F64(total)])
    })
    .unwrap();
    let acc_port = attach_function(&b, acc).await.unwrap();
    let text = HostFunction::new("text", &[("s", Type::Utf8)], &[("n", U32)], |i| {
        let Value::Utf8(s) = &i[0] else {
            return Err(HostFnError::bad_input());
        };
        Ok(vec![Value::U32(s.len() as u32)])
    })
    .unwrap();
    attach_function(&b, text).await.unwrap();
    let fail = HostFunction::new("fail", &[], &[], |_| Err(HostFnError::new(7))).unwrap();
    attach_function(&b, fail).await.unwrap();
    memory::connect(&h, &a).await.unwrap(); // h link 0 – a link 0
    memory::connect(&a, &b).await.unwrap(); // a link 1 – b link 0
    Net {
        h,
        _a: a,
        _b: b,
        acc_seen,
        acc_port,
    }
}

async fn wait_for(seen: &Seen, what: impl Fn(&[f64]) -> bool) -> Vec<f64> {
    for _ in 0..200 {
        {
            let v = seen.lock().unwrap();
            if what(&v) {
                return v.clone();
            }
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    let v = seen.lock().unwrap().clone();
    panic!("condition not met; saw {v:?}");
}

fn refs() -> (FnRef, FnRef, FnRef) {
    (
        FnRef::new("a", "sensor"),
        FnRef::new("b", "acc"),
        FnRef::new("b", "text"),
    )
}

#[tokio::test]
async fn refresh_builds_the_model_and_it_round_trips_through_json() {
    let n = net().await;
    // A pipe set up before the scan, between two runtimes the host is not
    // on the path of: a.sensor -> b.acc, over a's link 1.
    let port = n.h.open_port("script").await.unwrap();
    let route = Route::through_links(&[1]).unwrap().with_mtu(1024);
    let pipe = PipeConfig::new(route, n.acc_port, 10_000)
        .with(0, 0)
        .unwrap();
    let mut body = vec![0u8; 64];
    let mut w = osap_core::codec::Writer::new(&mut body);
    Request::SetPipe {
        slot: ANY_SLOT,
        pipe,
    }
    .encode(&mut w)
    .unwrap();
    let len = w.len();
    body.truncate(len);
    let a_route = Route::through_links(&[0]).unwrap();
    let sensor_port = 1; // the first port attached to a
    let reply = port
        .request(&a_route, sensor_port, &body, Duration::from_millis(500))
        .await
        .unwrap();
    assert_eq!(reply.body, [6, 0, 0], "set pipe: ok, slot 0");

    let mut m = Manager::new(&n.h).await.unwrap();
    refresh(&mut m).await;
    let som = m.som();
    let names: Vec<_> = som
        .runtimes
        .iter()
        .map(|r| r.record.name.as_str())
        .collect();
    assert_eq!(names, ["h", "a", "b"]);
    assert!(som.classes.is_empty());
    let a = &som.runtimes[1];
    assert_eq!(a.record.route, [0]);
    assert_eq!(a.functions.len(), 1);
    let sensor = &a.functions[0];
    assert_eq!(sensor.name, "sensor");
    assert_eq!(sensor.port, 1);
    assert_eq!(sensor.pipe_ports, (2..=9).collect::<Vec<u16>>());
    assert_eq!(sensor.inputs[0].name, "x");
    assert_eq!(sensor.inputs[0].type_name, "f32");
    assert_eq!(sensor.outputs[0].type_name, "f32");
    assert_eq!(sensor.input_mode, SomInputMode::OnAnyFresh);
    assert_eq!(sensor.output_mode, SomOutputMode::Always);
    assert_eq!(sensor.pipe_slots, 8);
    let b_fns: Vec<_> = som.runtimes[2]
        .functions
        .iter()
        .map(|f| f.name.as_str())
        .collect();
    assert_eq!(b_fns, ["acc", "text", "fail"]);

    // The pre-configured pipe, resolved to its destination function.
    assert_eq!(som.pipes.len(), 1);
    let p = &som.pipes[0];
    assert_eq!(p.source.runtime_name, "a");
    assert_eq!(p.source.function.as_deref(), Some("sensor"));
    let d = p.destination.as_ref().unwrap();
    assert_eq!(
        (d.runtime_name.as_str(), d.function.as_deref()),
        ("b", Some("acc"))
    );
    assert_eq!(p.route, [1]);
    assert_eq!((p.argmap[0].output, p.argmap[0].input), (0, 0));
    assert_eq!(p.ttl_us, 10_000);
    assert_eq!(sensor.pipes[0].destination.as_ref(), Some(d));

    let json = som.to_json();
    assert_eq!(&Som::from_json(&json).unwrap(), som);
    assert!(json.contains("\"mode\": \"on_any_fresh\""), "{json}");
    assert!(json.contains("\"type\": \"f32\""), "{json}");
    let wrong = json.replacen("\"version\": 1", "\"version\": 99", 1);
    let err = Som::from_json(&wrong).unwrap_err();
    assert!(matches!(
        err,
        osap_host::error::JsonError::Version {
            found: 99,
            supported: 1,
            ..
        }
    ));
    assert_eq!(
        err.to_string(),
        "system object model version 99 is not supported (this build reads 1)"
    );
    assert_eq!(
        Som::from_json("{").unwrap_err().to_string(),
        serde_json::from_str::<serde_json::Value>("{")
            .unwrap_err()
            .to_string()
    );

    // Runtimes by name: one, none, or several.
    assert_eq!(
        som.runtime_index(&som.runtimes[1].record.name.clone()),
        Ok(1)
    );
    let missing = som.runtime_index("no such runtime").unwrap_err();
    assert_eq!(missing, osap_host::som::RuntimeLookupError::NotFound);
    assert_eq!(missing.to_string(), "no runtime has this name");
    let mut twice = som.clone();
    twice.runtimes[2].record.name = twice.runtimes[1].record.name.clone();
    let both = twice
        .runtime_index(&twice.runtimes[1].record.name)
        .unwrap_err();
    assert_eq!(
        both,
        osap_host::som::RuntimeLookupError::Ambiguous { count: 2 }
    );
    assert_eq!(both.to_string(), "2 runtimes have this name");
}

#[tokio::test]
async fn routes_start_at_the_source_runtime() {
    let n = net().await;
    let mut m = Manager::new(&n.h).await.unwrap();
    m.refresh().await.unwrap();
    let som = m.som();
    // From b back to h: b's link 0 to a, then a's link 0 to h.
    let path = som.path(2, 0).unwrap();
    assert_eq!(path.links, [0, 0]);
    assert_eq!(path.runtimes, [2, 1, 0]);
    assert_eq!(som.path(1, 2).unwrap().links, [1]);
    assert!(som.path(0, 0).unwrap().links.is_empty());
    assert!(path.mtu > 0 && path.mtu <= 1024);
}

#[tokio::test]
async fn connect_makes_data_flow_module_to_module_and_through_host_functions() {
    let n = net().await;
    let mut m = Manager::new(&n.h).await.unwrap();
    m.refresh().await.unwrap();
    let (sensor, acc, _) = refs();

    // Host functions: a source the script calls, and a sink it watches.
    let gen = m
        .define(HostFunction::new("gen", &[("v", F32)], &[("v", F32)], |i| Ok(i.to_vec())).unwrap())
        .await
        .unwrap();
    let sink_seen: Seen = Arc::default();
    let s = sink_seen.clone();
    let sink = m
        .define(
            HostFunction::new("sink", &[("total", F64)], &[], move |i| {
                s.lock().unwrap().extend(i[0].as_f64());
                Ok(vec![])
            })
            .unwrap(),
        )
        .await
        .unwrap();
    assert_eq!(gen, FnRef::new("h", "gen"));
    assert!(m.som().function(0, "sink").is_some());

    // a.sensor -> b.acc: a's link 1, the host is not on the path.
    let p = m
        .connect(&sensor, &acc, &[0], &[0], PipeOptions::default())
        .await
        .unwrap();
    assert_eq!(p.route, [1]);
    assert_eq!(p.destination.unwrap().function.as_deref(), Some("acc"));
    // b.acc -> h.sink (module to host), h.gen -> a.sensor (host to module).
    let back = m
        .connect(&acc, &sink, &[0], &[0], PipeOptions::default())
        .await
        .unwrap();
    assert_eq!(back.route, [0, 0]);
    m.connect(&gen, &sensor, &[0], &[0], PipeOptions::default())
        .await
        .unwrap();
    assert_eq!(m.som().pipes.len(), 3);

    // Calling a.sensor: the reply, and its output arrives at b.acc.
    let out = m
        .function(&sensor)
        .unwrap()
        .call(&[Value::F32(2.5)])
        .await
        .unwrap();
    assert_eq!(out, [Value::F32(2.5)]);
    wait_for(&n.acc_seen, |v| v == [2.5]).await;
    wait_for(&sink_seen, |v| v == [2.5]).await;

    // Calling h.gen drives the whole chain: gen -> sensor -> acc -> sink.
    m.function(&gen)
        .unwrap()
        .call(&[Value::F32(1.5)])
        .await
        .unwrap();
    wait_for(&n.acc_seen, |v| v == [2.5, 1.5]).await;
    wait_for(&sink_seen, |v| v == [2.5, 4.0]).await;

    // The network agrees with the model.
    let before = m.som().pipes.clone();
    m.refresh().await.unwrap();
    assert_eq!(m.som().pipes, before);
}

#[tokio::test]
async fn type_mismatches_and_bad_argmaps_are_refused_naming_the_pair() {
    let n = net().await;
    let mut m = Manager::new(&n.h).await.unwrap();
    m.refresh().await.unwrap();
    let (sensor, acc, text) = refs();
    let e = m
        .connect(&sensor, &text, &[0], &[0], PipeOptions::default())
        .await
        .unwrap_err();
    assert!(matches!(e, SomError::TypeMismatch(_)), "{e:?}");
    let msg = e.to_string();
    for part in [
        "\"sensor\"",
        "\"a\"",
        "\"text\"",
        "\"b\"",
        "f32",
        "utf8",
        "output 0",
        "input 0",
    ] {
        assert!(msg.contains(part), "{msg} lacks {part}");
    }
    // f64 -> f32 converts only some values: allowed, unless strict.
    let strict = PipeOptions {
        strict: true,
        ..PipeOptions::default()
    };
    let e = m
        .connect(&acc, &sensor, &[0], &[0], strict)
        .await
        .unwrap_err();
    assert!(e.to_string().contains("strict"), "{e}");
    let e = m
        .connect(&sensor, &acc, &[1], &[0], PipeOptions::default())
        .await
        .unwrap_err();
    assert!(
        e.to_string().contains("no output 1 (outputs: y: f32)"),
        "{e}"
    );
    let e = m
        .connect(
            &sensor,
            &FnRef::new("b", "nope"),
            &[0],
            &[0],
            PipeOptions::default(),
        )
        .await
        .unwrap_err();
    assert!(matches!(e, SomError::NoSuchFunction(_)), "{e}");
    assert!(m.som().pipes.is_empty());
}

/// A total, as a typed host function takes it.
#[derive(pipes_core::PipesArgs)]
struct Total {
    total: f64,
}

#[tokio::test]
async fn pipes_connect_by_argument_name_and_a_missing_name_names_both_ends() {
    let n = net().await;
    let mut m = Manager::new(&n.h).await.unwrap();
    m.refresh().await.unwrap();
    let (sensor, acc, _) = refs();
    let seen: Seen = Arc::default();
    let s = seen.clone();
    let sink = m
        .define(
            HostFunction::typed("sink", move |t: Total| {
                s.lock().unwrap().push(t.total);
                Ok::<(), HostFnError>(())
            })
            .unwrap(),
        )
        .await
        .unwrap();
    let inputs = &m.som().function(0, "sink").unwrap().inputs;
    assert_eq!(
        inputs,
        &[SomArg {
            name: "total".into(),
            type_name: "f64".into()
        }]
    );

    // By name: a.sensor's y -> b.acc's a -> h.sink's total.
    let p = m
        .connect_named(&sensor, &acc, &[("y", "a")], PipeOptions::default())
        .await
        .unwrap();
    assert_eq!(p.route, [1]);
    m.connect_named(&acc, &sink, &[("total", "total")], PipeOptions::default())
        .await
        .unwrap();
    m.function(&sensor)
        .unwrap()
        .call(&[Value::F32(2.0)])
        .await
        .unwrap();
    wait_for(&seen, |v| v == [2.0]).await;

    // A renamed input: refused before anything is set, naming both
    // functions, both arguments, and what the function has instead.
    let before = m.som().pipes.len();
    let e = m
        .connect_named(&sensor, &acc, &[("y", "amount")], PipeOptions::default())
        .await
        .unwrap_err();
    assert!(matches!(e, SomError::NoSuchArgument(_)), "{e:?}");
    let msg = e.to_string();
    for part in [
        "\"sensor\"",
        "\"a\"",
        "output \"y\"",
        "\"acc\"",
        "\"b\"",
        "input \"amount\"",
        "has no input \"amount\" (inputs: a: f64)",
    ] {
        assert!(msg.contains(part), "{msg} lacks {part}");
    }
    // A missing output, likewise.
    let e = m
        .connect_named(&sensor, &acc, &[("x", "a")], PipeOptions::default())
        .await
        .unwrap_err();
    let msg = e.to_string();
    for part in [
        "output \"x\"",
        "input \"a\"",
        "has no output \"x\" (outputs: y: f32)",
    ] {
        assert!(msg.contains(part), "{msg} lacks {part}");
    }
    assert_eq!(m.som().pipes.len(), before);
}

#[tokio::test]
async fn disconnect_and_modes_update_the_network_and_the_model() {
    let n = net().await;
    let mut m = Manager::new(&n.h).await.unwrap();
    m.refresh().await.unwrap();
    let (sensor, acc, _) = refs();
    m.connect(&sensor, &acc, &[0], &[0], PipeOptions::default())
        .await
        .unwrap();
    assert_eq!(m.som().pipes.len(), 1);
    let wiped = m
        .disconnect(&sensor, Disconnect::To(acc.clone()))
        .await
        .unwrap();
    assert_eq!(wiped, [0]);
    assert!(m.som().pipes.is_empty());
    let e = m
        .disconnect(&sensor, Disconnect::To(acc.clone()))
        .await
        .unwrap_err();
    assert!(e.to_string().contains("no pipe to function \"acc\""), "{e}");
    m.refresh().await.unwrap();
    assert!(m.som().pipes.is_empty(), "wiped on the function too");
    // Data no longer flows.
    m.function(&sensor)
        .unwrap()
        .call(&[Value::F32(1.0)])
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(30)).await;
    assert!(n.acc_seen.lock().unwrap().is_empty());

    m.set_input_mode(&acc, InputMode::OnTimer(1000))
        .await
        .unwrap();
    m.set_output_mode(&acc, OutputMode::OnChange).await.unwrap();
    let f = m.som().function(2, "acc").unwrap();
    assert_eq!(f.input_mode, SomInputMode::OnTimer { interval_us: 1000 });
    m.refresh().await.unwrap();
    let f = m.som().function(2, "acc").unwrap();
    assert_eq!(f.input_mode, SomInputMode::OnTimer { interval_us: 1000 });
    assert_eq!(f.output_mode, SomOutputMode::OnChange);

    // Every slot at once.
    m.connect(&sensor, &acc, &[0], &[0], PipeOptions::default())
        .await
        .unwrap();
    m.disconnect(&sensor, Disconnect::All).await.unwrap();
    assert!(m.som().pipes.is_empty());
}

#[tokio::test]
async fn calls_report_errors_naming_the_function_and_runtime() {
    let n = net().await;
    let mut m = Manager::new(&n.h).await.unwrap();
    m.refresh().await.unwrap();
    let (sensor, _, text) = refs();
    let f = m.function(&sensor).unwrap();
    let e = f.call(&[]).await.unwrap_err();
    assert_eq!(
        e.to_string(),
        "function \"sensor\" on runtime \"a\": expected 1 argument (x: f32), got 0"
    );
    let e = f.call(&[Value::from("hi")]).await.unwrap_err();
    assert!(e.to_string().contains("cannot take a utf8"), "{e}");
    // Checked by the function itself: a lossy conversion.
    let e = f.call(&[Value::F64(0.1)]).await.unwrap_err();
    match &e {
        SomError::Remote {
            error: ControlError::Convert { index: 0, .. },
            ..
        } => {}
        other => panic!("{other:?}"),
    }
    assert!(
        e.to_string()
            .starts_with("function \"sensor\" on runtime \"a\": call refused"),
        "{e}"
    );
    let e = m
        .function(&FnRef::new("b", "fail"))
        .unwrap()
        .call(&[])
        .await
        .unwrap_err();
    assert!(e.to_string().contains("failed with code 7"), "{e}");
    assert!(
        matches!(
            e,
            SomError::Remote {
                error: ControlError::CallFailed(FailureCode::Other(7)),
                ..
            }
        ),
        "{e:?}"
    );
    let out = m
        .function(&text)
        .unwrap()
        .call(&[Value::from("four")])
        .await
        .unwrap();
    assert_eq!(out, [Value::U32(4)]);
    // Dataflow pushes run the function like a pipe would.
    m.function(&FnRef::new("b", "acc"))
        .unwrap()
        .push(&[(0, Value::F32(0.5))])
        .await
        .unwrap();
    wait_for(&n.acc_seen, |v| v == [0.5]).await;
    let e = m.function(&FnRef::new("x", "y")).unwrap_err();
    assert!(matches!(e, SomError::NoSuchRuntime(_)), "{e}");
}

#[tokio::test]
async fn detached_ports_keep_indices_stable() {
    let h = host("h");
    let f1 = HostFunction::new("one", &[], &[], |_| Ok(vec![])).unwrap();
    let f2 = HostFunction::new("two", &[], &[], |_| Ok(vec![])).unwrap();
    let i1 = attach_function(&h, f1).await.unwrap();
    let i2 = attach_function(&h, f2).await.unwrap();
    assert_eq!((i1, i2), (1, 10));
    let p = h.open_port("script").await.unwrap();
    assert_eq!(p.index(), 19);
    assert!(h.detach_port(i1).await.unwrap().is_some());
    assert!(h.detach_port(i1).await.unwrap().is_none());
    let q = h.open_port("script2").await.unwrap();
    assert_eq!(q.index(), 20, "the detached place is kept");
    drop(p);
    let r = h.open_port("script3").await.unwrap();
    assert_eq!(r.index(), 19, "a closed handle's index is reused");
}

// ---- classes ----------------------------------------------------------------

/// A running total shared by its members.
#[derive(Debug)]
struct Tally {
    total: f32,
    adds: u32,
    ticks: u64,
}

#[pipes_core::class]
impl Tally {
    #[constructor]
    fn new(start: f32) -> Self {
        Tally {
            total: start,
            adds: 0,
            ticks: 0,
        }
    }

    #[outputs = "total"]
    fn add(&mut self, x: f32) -> f32 {
        self.total += x;
        self.adds += 1;
        self.total
    }

    #[outputs = "total, adds"]
    fn read(&self) -> (f32, u32) {
        (self.total, self.adds)
    }

    fn reset(&mut self) {
        self.total = 0.0;
        self.adds = 0;
    }

    #[loop_hook]
    fn tick(&mut self, _now: pipes_core::time::SystemInstant) {
        self.ticks += 1;
    }
}

const TALLY_MEMBERS: [&str; 3] = ["Tally.add", "Tally.read", "Tally.reset"];

async fn wait_state<T>(state: &Mutex<T>, what: impl Fn(&T) -> bool) {
    for _ in 0..200 {
        if what(&state.lock().unwrap()) {
            return;
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    panic!("state condition not met");
}

#[tokio::test]
async fn refresh_lists_classes_with_their_constructor_and_members() {
    let n = net().await;
    let tally = attach_class(&n._a, Tally::new(1.0)).await.unwrap();
    assert_eq!(tally.member("read"), Some("Tally.read"));
    assert_eq!(tally.member_port("add"), Some(tally.port() + 1));
    assert_eq!(tally.member("tick"), None, "the loop hook is no member");

    let mut m = Manager::new(&n.h).await.unwrap();
    let report = m.refresh().await.unwrap();
    assert!(report.function_failures.is_empty(), "{report:?}");
    let som = m.som();
    let a = som.runtime_index("a").unwrap();
    assert_eq!(som.classes.len(), 1, "{:?}", som.classes);
    let class = som.class(a, "Tally").unwrap();
    assert_eq!(class.port, tally.port());
    assert_eq!(
        class.constructor,
        [SomArg {
            name: "start".into(),
            type_name: "f32".into()
        }]
    );
    assert_eq!(class.members, TALLY_MEMBERS);
    let port = som.runtimes[a]
        .record
        .ports
        .iter()
        .find(|p| p.index == class.port)
        .unwrap();
    assert_eq!(
        (port.type_name.as_str(), port.name.as_str()),
        ("pipes_class", "Tally")
    );
    // Members are functions of their runtime like any other.
    for (name, port) in tally.members() {
        let f = som.function(a, name).unwrap();
        assert_eq!(f.port, *port);
    }
    let add = som.function(a, "Tally.add").unwrap();
    assert_eq!(add.inputs[0].type_name, "f32");
    assert_eq!(add.outputs[0].name, "total");
    let read = som.function(a, "Tally.read").unwrap();
    assert_eq!(read.outputs[1].type_name, "u32");
    // The class port is not a function.
    assert!(som.function(a, "Tally").is_none());

    // The classes round-trip through JSON, and the version is unchanged.
    let json = som.to_json();
    assert!(json.contains("\"version\": 1"), "{json}");
    assert!(json.contains("\"Tally.reset\""), "{json}");
    assert_eq!(&Som::from_json(&json).unwrap(), som);
    // A version 1 layout written before classes were found still reads.
    let mut old: serde_json::Value = serde_json::from_str(&json).unwrap();
    let c = &mut old["classes"][0];
    c.as_object_mut().unwrap().remove("port");
    c.as_object_mut().unwrap().remove("constructor");
    let old = Som::from_json(&old.to_string()).unwrap();
    assert_eq!(old.classes[0].port, 0);
    assert!(old.classes[0].constructor.is_empty());

    // The constructor rebuilds the state over the network.
    let read = m.function(&FnRef::new("a", "Tally.read")).unwrap();
    assert_eq!(
        read.call(&[]).await.unwrap(),
        [Value::F32(1.0), Value::U32(0)]
    );
    let ctor = m.constructor("a", "Tally").unwrap();
    assert!(ctor.call(&[Value::F32(10.0)]).await.unwrap().is_empty());
    assert_eq!(tally.state().lock().unwrap().total, 10.0);
    assert_eq!(
        read.call(&[]).await.unwrap(),
        [Value::F32(10.0), Value::U32(0)]
    );
    assert!(matches!(
        m.constructor("a", "Nope"),
        Err(SomError::NoSuchFunction(_))
    ));
    assert!(matches!(
        m.constructor("a", "Tally").unwrap().call(&[]).await,
        Err(SomError::BadArguments { .. })
    ));
}

#[tokio::test]
async fn host_class_members_share_state_through_function_handles() {
    let n = net().await;
    let mut m = Manager::new(&n.h).await.unwrap();
    m.refresh().await.unwrap();
    let tally = m.define_class(Tally::new(0.0)).await.unwrap();
    // Defined after the refresh: in the model at once.
    let class = m.som().class(0, "Tally").unwrap();
    assert_eq!(class.members, TALLY_MEMBERS);
    assert_eq!(class.port, tally.port());
    assert_eq!(class.constructor[0].name, "start");

    let member = |name: &str| m.function(&FnRef::new("h", name)).unwrap();
    let (add, read, reset) = (
        member("Tally.add"),
        member("Tally.read"),
        member("Tally.reset"),
    );
    assert_eq!(
        add.call(&[Value::F32(2.0)]).await.unwrap(),
        [Value::F32(2.0)]
    );
    assert_eq!(
        add.call(&[Value::F32(3.0)]).await.unwrap(),
        [Value::F32(5.0)]
    );
    // Another member reads what add wrote.
    assert_eq!(
        read.call(&[]).await.unwrap(),
        [Value::F32(5.0), Value::U32(2)]
    );
    // The script sees (and may change) the same state.
    {
        let mut s = tally.state().lock().unwrap();
        assert_eq!((s.total, s.adds), (5.0, 2));
        assert!(s.ticks > 0, "the loop hook runs on the host's polls");
        s.total = 100.0;
    }
    assert_eq!(
        read.call(&[]).await.unwrap(),
        [Value::F32(100.0), Value::U32(2)]
    );
    assert!(reset.call(&[]).await.unwrap().is_empty());
    assert_eq!(
        read.call(&[]).await.unwrap(),
        [Value::F32(0.0), Value::U32(0)]
    );
    // Wrong arguments are refused naming the member.
    let err = add.call(&[]).await.unwrap_err().to_string();
    assert!(err.contains("Tally.add"), "{err}");

    // A refresh finds the same class and members.
    let before = m.som().classes.clone();
    m.refresh().await.unwrap();
    assert_eq!(m.som().classes, before);
}

#[tokio::test]
async fn pipes_run_from_module_functions_into_class_members_and_back() {
    let n = net().await;
    let mut m = Manager::new(&n.h).await.unwrap();
    m.refresh().await.unwrap();
    let tally = m.define_class(Tally::new(0.0)).await.unwrap();
    let add = FnRef::new("h", tally.member("add").unwrap());
    let (sensor, acc, _) = refs();

    // a.sensor -> h.Tally.add (module to host class), then h.Tally.add's
    // total (f32) -> b.acc (f64, host class to module).
    let into = m
        .connect(&sensor, &add, &[0], &[0], PipeOptions::default())
        .await
        .unwrap();
    assert_eq!(into.route, [0]);
    assert_eq!(
        into.destination.unwrap().function.as_deref(),
        Some("Tally.add")
    );
    let out = m
        .connect(&add, &acc, &[0], &[0], PipeOptions::default())
        .await
        .unwrap();
    assert_eq!(out.route, [0, 1]);

    m.function(&sensor)
        .unwrap()
        .call(&[Value::F32(2.5)])
        .await
        .unwrap();
    wait_state(tally.state(), |s| s.adds == 1).await;
    assert_eq!(tally.state().lock().unwrap().total, 2.5);
    wait_for(&n.acc_seen, |v| v == [2.5]).await;

    m.function(&sensor)
        .unwrap()
        .call(&[Value::F32(1.0)])
        .await
        .unwrap();
    wait_state(tally.state(), |s| s.adds == 2).await;
    wait_for(&n.acc_seen, |v| v == [2.5, 3.5]).await;

    // Another member reads the state the piped calls built.
    assert_eq!(
        m.function(&FnRef::new("h", "Tally.read"))
            .unwrap()
            .call(&[])
            .await
            .unwrap(),
        [Value::F32(3.5), Value::U32(2)]
    );
    // Types are checked against members like any function: u32 -> f32
    // converts only some values, so a strict pipe refuses it.
    let strict = PipeOptions {
        strict: true,
        ..PipeOptions::default()
    };
    let err = m
        .connect(&FnRef::new("b", "text"), &add, &[0], &[0], strict)
        .await
        .unwrap_err();
    assert!(matches!(err, SomError::TypeMismatch(_)), "{err}");
    assert!(err.to_string().contains("Tally.add"), "{err}");
}

#[tokio::test]
async fn pipe_stats_show_overflows_over_the_network() {
    let n = net().await;
    let mut m = Manager::new(&n.h).await.unwrap();
    m.refresh().await.unwrap();
    let (sensor, acc, _) = refs();
    let p = m
        .connect(&sensor, &acc, &[0], &[0], PipeOptions::default())
        .await
        .unwrap();
    assert_eq!(p.slot, 0);
    let fresh = m.pipe_stats(&sensor, 0).await.unwrap();
    assert_eq!(fresh, PipeStats::default());
    // Slot 0 sends from port 2 of a (the sensor's control port is 1): with
    // a stack quota of 0 it is never clear to send, so its queue of
    // HOST_FN_QUEUE (4) datagrams fills and the oldest are dropped.
    let pipe_port = m.som().function(1, "sensor").unwrap().pipe_ports[0];
    assert_eq!(pipe_port, 2);
    let quota = |max: u8| {
        n._a.with_runtime(move |rt, _| rt.set_quota(Owner::Port(pipe_port), max))
    };
    quota(0).await.unwrap().unwrap();
    let call = m.function(&sensor).unwrap();
    for x in 1..=6 {
        call.call(&[Value::F32(x as f32)]).await.unwrap();
    }
    let stats = m.pipe_stats(&sensor, 0).await.unwrap();
    assert_eq!((stats.sent, stats.overflows), (0, 2), "{stats:?}");
    assert_eq!((stats.send_errors, stats.remote_errors), (0, 0));
    assert_eq!(stats.last_remote_error, None);
    // Room again: the next packet to the function flushes the newest four.
    quota(8).await.unwrap().unwrap();
    let stats = m.pipe_stats(&sensor, 0).await.unwrap();
    assert_eq!(stats.overflows, 2);
    wait_for(&n.acc_seen, |v| v == [3.0, 4.0, 5.0, 6.0]).await;
    assert_eq!(m.pipe_stats(&sensor, 0).await.unwrap().sent, 4);
    // An empty slot is refused, naming the function.
    let e = m.pipe_stats(&sensor, 1).await.unwrap_err();
    assert!(
        matches!(
            e,
            SomError::Remote {
                error: ControlError::NoSuchPipe(1),
                ..
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("\"sensor\""), "{e}");
}

#[tokio::test]
async fn acknowledged_pipes_deliver_end_to_end() {
    let n = net().await;
    let mut m = Manager::new(&n.h).await.unwrap();
    m.refresh().await.unwrap();
    let (sensor, acc, _) = refs();
    let options = PipeOptions {
        delivery: PipeDelivery::Acked,
        ..PipeOptions::default()
    };
    let p = m.connect(&sensor, &acc, &[0], &[0], options).await.unwrap();
    assert_eq!(p.delivery, SomDelivery::Acked);
    let call = m.function(&sensor).unwrap();
    for x in [1.0, 2.0, 3.0] {
        call.call(&[Value::F32(x)]).await.unwrap();
    }
    wait_for(&n.acc_seen, |v| v == [1.0, 2.0, 3.0]).await;
    // Every datagram acknowledged, none sent twice.
    let mut stats = m.pipe_stats(&sensor, 0).await.unwrap();
    for _ in 0..100 {
        if stats.acked == 3 {
            break;
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
        stats = m.pipe_stats(&sensor, 0).await.unwrap();
    }
    assert_eq!(
        (stats.sent, stats.acked, stats.retries, stats.failures),
        (3, 3, 0, 0),
        "{stats:?}"
    );
    // The network agrees with the model.
    let before = m.som().pipes.clone();
    m.refresh().await.unwrap();
    assert_eq!(m.som().pipes, before);
    assert_eq!(m.som().pipes[0].delivery, SomDelivery::Acked);
}
