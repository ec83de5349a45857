//! The generated proxies compile and work: the proxies of the shipped
//! `small-machine.toml` (checked in under `generated_small_machine/`, kept
//! equal to the generator's output by `golden.rs` and below) are compiled
//! into this test and run against the simulated modules (each runs the
//! module firmware's functions): calls, return values, failure codes,
//! connect, set_input_mode, and binding refused for a changed signature, a
//! missing device and a wrong type.

mod common;

// Generated for a user's crate, where its items are public API.
#[rustfmt::skip]
#[allow(unreachable_pub)]
#[path = "generated_small_machine/mod.rs"]
mod proxies;

// Compile-only: the odd names and types of `data/odd.som.json` make valid Rust.
#[rustfmt::skip]
#[allow(unreachable_pub)]
#[path = "golden/odd/mod.rs"]
mod odd;

use osap_host::som::{HostFunction, Manager, PipeOptions, Som, Value};
use osap_host::{Host, HostConfig};
use osap_sim::machine::SimMachine;
use osap_sim::topology::SimSpec;
use pipes_core::control::InputMode;
use pipes_core::{ScalarType, Type};
use proxies::{BindError, Stepper, DEVICES};
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn proxies_drive_the_simulated_small_machine() {
    let h = Host::start(HostConfig::named("h")).unwrap();
    let topology = SimSpec::load(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../osap-sim/topologies/small-machine.toml"),
    )
    .unwrap();
    let _machine = SimMachine::start(&h, &topology).await.unwrap();
    let mut m = Manager::new(&h).await.unwrap();
    let report = m.refresh().await.unwrap();
    assert!(report.scan_failures.is_empty() && report.function_failures.is_empty());

    // The live machine generates exactly the proxies compiled in here.
    let data = common::tests_dir("data/small-machine.som.json");
    if common::bless() {
        std::fs::write(&data, m.som().to_json() + "\n").unwrap();
    }
    let files = proxygen::generate(m.som(), &proxygen::Options::default()).unwrap();
    common::golden(&common::tests_dir("generated_small_machine"), &files);
    // One proxy serves every module: they all run the module firmware. The
    // hub has no functions, so no proxy.
    assert_eq!(
        DEVICES,
        [("stepper", "0.1.0", &["x", "y", "z", "tool"][..])]
    );

    // Bind every stepper by name; calls and return values.
    let x = Stepper::bind(&m, "x").unwrap();
    let y = Stepper::bind(&m, "y").unwrap();
    let _z = Stepper::bind(&m, "z").unwrap();
    let _tool = Stepper::bind(&m, "tool").unwrap();
    assert_eq!(x.runtime(), "x");
    let start = x.get_position().await.unwrap();
    assert_eq!(start.position, 0.0);
    let status = x.get_status().await.unwrap();
    assert_eq!(
        (status.mode, status.queued, status.enabled, status.faults),
        (0, 0, false, 0)
    );
    // Disabled: the device refuses (failure code 6), and the error says
    // so by name, with the fix.
    let t = (start.time + 5_000_000).next_multiple_of(2048);
    let refused = x.add_point(t, 0.0).await.unwrap_err().to_string();
    assert!(
        refused.contains("add_point")
            && refused.contains("Disabled (code 6): the motor is disabled: enable it"),
        "{refused}"
    );
    x.set_enable(true).await.unwrap();
    let status = x.get_status().await.unwrap();
    assert_eq!((status.mode, status.enabled), (1, true));
    // A stream's first point, where the axis stands, on the interval grid.
    x.add_point(t, 0.0).await.unwrap();
    assert_eq!(x.get_status().await.unwrap().queued, 1);
    let counters = x.get_counters().await.unwrap();
    assert_eq!(
        (counters.points, counters.refused, counters.last_refused),
        (1, 1, 6)
    );
    // The simulated driver sets 1 to 256 microsteps, powers of two (48:
    // code 10, a bad value).
    let e = y.set_microsteps(48).await.unwrap_err().to_string();
    assert!(
        e.contains("set_microsteps") && e.contains("BadValue (code 10)"),
        "{e}"
    );
    y.set_microsteps(256).await.unwrap();
    let limit = x.read_limit().await.unwrap();
    assert_eq!((limit.time, limit.level, limit.edges), (0, true, 0));
    assert!(x.digital_read(9).await.is_err(), "no pin 9");
    assert_eq!(x.analog_read(0).await.unwrap().value, 0.0);

    // Connect x.get_status's points queued to a host function and call it.
    let seen: Arc<Mutex<Vec<Vec<Value<'static>>>>> = Arc::default();
    let s = seen.clone();
    let u16t = Type::Scalar(ScalarType::U16);
    let sink = HostFunction::new("sink", &[("queued", u16t)], &[], move |i| {
        s.lock().unwrap().push(i.to_vec());
        Ok(vec![])
    })
    .unwrap();
    let sink = m.define(sink).await.unwrap();
    m.connect(
        x.get_status_ref(),
        &sink,
        &[1],
        &[0],
        PipeOptions::default(),
    )
    .await
    .unwrap();
    x.get_status().await.unwrap();
    let deadline = Instant::now() + Duration::from_secs(5);
    while !seen.lock().unwrap().contains(&vec![Value::U16(1)]) {
        assert!(Instant::now() < deadline, "the pipe never delivered");
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
    m.set_input_mode(y.get_status_ref(), InputMode::OnAllFresh)
        .await
        .unwrap();
    assert_eq!(y.get_status_handle().function().runtime, "y");

    // A changed signature (new firmware, old proxies) fails validation.
    let mut som: Som = m.som().clone();
    let ri = som.runtime_index("x").unwrap();
    let f = som.runtimes[ri]
        .functions
        .iter_mut()
        .find(|f| f.name == "get_position")
        .unwrap();
    f.outputs[1].type_name = "f64".into();
    som.runtimes[ri].record.version = "0.2.0".into();
    let e = Stepper::check(&som, "x").unwrap_err();
    assert!(matches!(e, BindError::Mismatch { .. }));
    assert_eq!(
        e.to_string(),
        "runtime \"x\" (stepper 0.2.0) does not match its proxy (generated from stepper 0.1.0; \
         regenerate the proxies): function \"get_position\": output 1 is `position: f64` but the \
         proxy expects `position: f32`"
    );
    Stepper::check(&som, "y").unwrap();
    let e = Stepper::check(m.som(), "w").unwrap_err();
    assert_eq!(
        e.to_string(),
        "cannot bind the stepper proxy to runtime \"w\": no runtime has this name (is the device missing?)"
    );
    let e = Stepper::bind(&m, "hub").unwrap_err();
    assert_eq!(
        e.to_string(),
        "runtime \"hub\" is a \"hub\", not a \"stepper\": bind another proxy"
    );
    // A function gone and one with an input less.
    let mut som = m.som().clone();
    let ri = som.runtime_index("z").unwrap();
    som.runtimes[ri]
        .functions
        .retain(|f| f.name != "set_enable");
    let add = &mut som.runtimes[ri].functions[0];
    assert_eq!(add.name, "add_point");
    add.inputs.pop();
    let e = Stepper::check(&som, "z").unwrap_err().to_string();
    assert!(
        e.contains("function \"set_enable\": not found on the device"),
        "{e}"
    );
    assert!(
        e.contains("function \"add_point\": 1 inputs (time: u64) but the proxy expects 2 (time: u64, position: f32)"),
        "{e}"
    );
}
