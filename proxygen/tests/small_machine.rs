//! The generated proxies compile and work: the proxies of the shipped
//! `small-machine.toml` (checked in under `generated_small_machine/`, kept
//! equal to the generator's output by `golden.rs` and below) are compiled
//! into this test and run against the simulated modules: calls, return
//! values, connect, set_input_mode, and binding refused for a changed
//! signature, a missing device and a wrong type.

mod common;

#[rustfmt::skip]
#[path = "generated_small_machine/mod.rs"]
mod proxies;

// Compile-only: the odd names and types of `data/odd.som.json` make valid Rust.
#[rustfmt::skip]
#[path = "golden/odd/mod.rs"]
mod odd;

use osap_host::som::{HostFunction, Manager, OwnedValue, PipeOptions, Som};
use osap_host::{Host, HostConfig};
use osap_sim::machine::{self, SimMachine};
use pipes_core::control::InputMode;
use pipes_core::{ScalarType, Type};
use proxies::{BindError, Hub, Stepper};
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn proxies_drive_the_simulated_small_machine() {
    let h = Host::start(HostConfig::named("h")).unwrap();
    let topology = machine::load(
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

    // Bind every stepper by name; calls and return values.
    let x = Stepper::bind(&m, "x").unwrap();
    let y = Stepper::bind(&m, "y").unwrap();
    let _z = Stepper::bind(&m, "z").unwrap();
    let hub = Hub::bind(&m, "hub").unwrap();
    assert_eq!(x.runtime(), "x");
    assert!(hub.get_uptime().await.unwrap() > 0);
    let start = x.get_position().await.unwrap();
    assert_eq!(start.position, 0.0);
    let status = x.get_status().await.unwrap();
    assert_eq!((status.points_queued, status.enabled), (0, false));
    // Disabled: the device refuses (failure code 3), and the error says so.
    let refused = x.add_control_point(start.time, 1.0).await.unwrap_err();
    assert!(
        refused.to_string().contains("add_control_point"),
        "{refused}"
    );
    x.set_current(1.0).await.unwrap();
    // A point already due is reached at once.
    x.add_control_point(start.time, 12.5).await.unwrap();
    let now = x.get_position().await.unwrap();
    assert_eq!(now.position, 12.5);
    assert!(now.time >= start.time);
    assert!(x.get_status().await.unwrap().enabled);
    assert!(y.set_current(5.0).await.is_err(), "over the current limit");

    // Connect x.get_position's position to a host function and call it.
    let seen: Arc<Mutex<Vec<Vec<OwnedValue>>>> = Arc::default();
    let s = seen.clone();
    let f32t = Type::Scalar(ScalarType::F32);
    let sink = HostFunction::new("sink", &[("position", f32t)], &[], move |i| {
        s.lock().unwrap().push(i.to_vec());
        Ok(vec![])
    })
    .unwrap();
    let sink = m.define(sink).await.unwrap();
    m.connect(
        x.get_position_ref(),
        &sink,
        &[1],
        &[0],
        PipeOptions::default(),
    )
    .await
    .unwrap();
    x.get_position().await.unwrap();
    let deadline = Instant::now() + Duration::from_secs(5);
    while !seen.lock().unwrap().contains(&vec![OwnedValue::F32(12.5)]) {
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
    // A function gone and one with an input more.
    let mut som = m.som().clone();
    let ri = som.runtime_index("z").unwrap();
    som.runtimes[ri]
        .functions
        .retain(|f| f.name != "set_current");
    som.runtimes[ri].functions[0].inputs.pop();
    let e = Stepper::check(&som, "z").unwrap_err().to_string();
    assert!(
        e.contains("function \"set_current\": not found on the device"),
        "{e}"
    );
    assert!(
        e.contains("function \"add_control_point\": 1 inputs (time: u64) but the proxy expects 2 (time: u64, position: f32)"),
        "{e}"
    );
}
