//! The module firmware's limits over the network: a simulated stepper
//! (osap-module's logic on a simulated board) is given limits with
//! `set_limits`, and a control point past its jerk limit is refused. The
//! host hears the refusal by name (`OverLimit (code 11)`) and reads the
//! fault with `get_fault`: kind `OverLimit`, its detail naming the jerk
//! limit. The stream then goes on from its last accepted point.

use osap_host::som::{FnRef, Manager, Value};
use osap_host::{Host, HostConfig};
use osap_module::fault::{FaultKind, OVER_JERK};
use osap_module::stepper::StepperError;
use osap_sim::machine::SimMachine;
use osap_sim::topology::{LinkKind, LinkSpec, ModuleSpec, SimSpec, HOST};

/// The module's default interval, µs.
const IV: u64 = 2048;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_point_past_a_limit_is_refused_by_name_and_reported_as_a_fault() {
    let host = Host::start(HostConfig::named("h")).unwrap();
    let topology = SimSpec::new("limits")
        .with_module(ModuleSpec::new("motor", "stepper"))
        .with_link(LinkSpec::new(HOST, "motor", LinkKind::Usb));
    let sim = SimMachine::start(&host, &topology).await.unwrap();
    let mut m = Manager::new(&host).await.unwrap();
    m.refresh().await.unwrap();
    let f = |name: &str| m.function(&FnRef::new("motor", name)).unwrap();
    let (set_enable, set_limits, add_point) = (f("set_enable"), f("set_limits"), f("add_point"));
    let (get_position, get_fault, get_counters) =
        (f("get_position"), f("get_fault"), f("get_counters"));

    set_enable.call(&[Value::Bool(true)]).await.unwrap();
    // A bad value is refused by name too.
    let e = set_limits
        .call(&[
            Value::F32(100.0),
            Value::F32(f32::NAN),
            Value::F32(200_000.0),
        ])
        .await
        .unwrap_err()
        .to_string();
    assert!(e.contains("BadValue (code 10)"), "{e}");
    // 100 mm/s, 2 000 mm/s², 200 000 mm/s³: a jerk of J·Δt³ = 0.0017 mm
    // per interval³.
    set_limits
        .call(&[
            Value::F32(100.0),
            Value::F32(2_000.0),
            Value::F32(200_000.0),
        ])
        .await
        .unwrap();
    let jd = 200_000.0 * (IV as f64 * 1e-6).powi(3);

    // A stream far ahead of the module's clock, at rest where it stands.
    let here = get_position.call(&[]).await.unwrap();
    let Some(Value::U64(now)) = here.first() else {
        panic!("{here:?}")
    };
    let t0 = (now + 2_000_000).next_multiple_of(IV);
    let point = |k: u64, p: f64| [Value::U64(t0 + k * IV), Value::F32(p as f32)];
    for k in 0..3 {
        add_point.call(&point(k, 0.0)).await.unwrap();
    }
    // A jump of 1.5 J·Δt³ from rest: past the jerk limit.
    let e = add_point
        .call(&point(3, 1.5 * jd))
        .await
        .unwrap_err()
        .to_string();
    let code = StepperError::OverLimit.code();
    assert!(
        e.contains("add_point") && e.contains(&format!("OverLimit (code {code}): ")),
        "{e}"
    );
    assert!(e.contains("velocity, acceleration or jerk limit"), "{e}");
    let fault = get_fault.call(&[]).await.unwrap();
    match fault.as_slice() {
        [Value::U64(time), Value::U8(kind), Value::U32(detail), Value::U32(count)] => {
            assert!(*time > 0);
            assert_eq!(FaultKind::from_code(*kind), Some(FaultKind::OverLimit));
            assert_eq!(*detail, OVER_JERK, "the jerk limit");
            assert_eq!(*count, 1);
        }
        other => panic!("{other:?}"),
    }
    // The stream goes on from its last accepted point.
    add_point.call(&point(3, 0.5 * jd)).await.unwrap();
    let counters = get_counters.call(&[]).await.unwrap();
    assert_eq!(
        counters[..3],
        [Value::U32(4), Value::U32(1), Value::U8(code)]
    );
    sim.stop().await.unwrap();
}
