//! The simulated winch end to end in virtual time: the modules' torque
//! mode over the network, commuting from the simulated encoders, holds the
//! mass against gravity; the output watchdog ends the torque when the host
//! goes quiet and the motors hold the mass where it is; a module whose
//! motor has no encoder refuses the mode.

use osap_host::som::{FnRef, Manager, SomError, Value};
use osap_host::{Host, HostConfig};
use osap_module::fault::FaultKind;
use osap_module::stepper::{Mode, StepperError};
use osap_sim::machine::{virtual_runtime, SimMachine, TimeMode};
use osap_sim::topology::SimSpec;
use pipes_core::control::ControlError;
use std::path::PathBuf;
use std::time::Duration;

const CABLES: [&str; 4] = ["tl", "tr", "br", "bl"];
const WATCHDOG_MS: u32 = 50;

fn topology(name: &str) -> SimSpec {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("topologies")
        .join(name);
    SimSpec::load(path).expect("the shipped topology loads")
}

async fn call(
    m: &Manager,
    module: &str,
    function: &str,
    args: &[Value<'static>],
) -> Vec<Value<'static>> {
    m.function(&FnRef::new(module, function))
        .unwrap()
        .call(args)
        .await
        .unwrap_or_else(|e| panic!("{module}.{function}: {e}"))
}

fn mode(status: &[Value<'_>]) -> u8 {
    match status.first() {
        Some(Value::U8(mode)) => *mode,
        other => panic!("get_status answered {other:?}"),
    }
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

async fn held_then_watched() {
    let spec = topology("winch.toml");
    let host = Host::start(HostConfig::named("h")).expect("host");
    let sim = SimMachine::start_with(&host, &spec, TimeMode::Virtual)
        .await
        .expect("machine starts");
    let mut m = Manager::new(&host).await.expect("manager");
    m.refresh().await.expect("scan");
    let plant = sim.winch().expect("a winch").clone();
    let start = plant.now().position();
    for name in CABLES {
        call(&m, name, "set_enable", &[Value::Bool(true)]).await;
    }
    // Gravity held open loop: the tensions that hold 1 kg at the centre of
    // the square (top cables 6.94 N more than the bottom ones' 3 N), as
    // fractions of 0.45 N·m on 12 mm spools; a positive torque pays out.
    let top = -(3.0 + 9.81 / 2f64.sqrt()) * 0.012 / 0.45;
    let bottom = -3.0 * 0.012 / 0.45;
    for (name, f) in CABLES.into_iter().zip([top, top, bottom, bottom]) {
        call(&m, name, "set_torque", &[Value::F32(f as f32)]).await;
    }
    for name in CABLES {
        let status = call(&m, name, "get_status", &[]).await;
        assert_eq!(mode(&status), Mode::Torque as u8, "{name}");
    }
    // Held by torque alone for 0.3 s, fed by the host: the mass stays
    // within a few mm (friction and the commutation's lag are all that
    // differ from statics).
    call(&m, "tl", "set_output_watchdog", &[Value::U32(WATCHDOG_MS)]).await;
    for _ in 0..30 {
        tokio::time::sleep(Duration::from_millis(10)).await;
        call(&m, "tl", "get_position", &[]).await;
    }
    let torqued = plant.now().position();
    assert!(dist(torqued, start) < 3e-3, "{start:?} → {torqued:?}");
    // get_position is the shaft: the top-left cable paid out (mm) as the
    // simulated spool turned.
    let out = call(&m, "tl", "get_position", &[]).await;
    let Some(Value::F32(paid_steps)) = out.get(1) else {
        panic!("{out:?}");
    };
    let lengths = plant.now().lengths();
    // Its length at boot: from its anchor to where the mass hung then (it
    // sagged since, the brakes holding the spools). The default scale: 80
    // full steps per unit; 200 full steps a turn of a 12 mm spool.
    let l0 = dist([0.0, 1.0], [0.5, 0.5]);
    let turn = 2.0 * std::f64::consts::PI * 0.012;
    let paid = f64::from(*paid_steps) * 80.0 / 200.0 * turn;
    assert!(paid < -0.5e-3, "the cable was reeled in: {paid}");
    // Within two encoder counts.
    assert!(
        (l0 + paid - lengths[0]).abs() < 2.0 * turn / 16_384.0,
        "{} vs {}",
        l0 + paid,
        lengths[0]
    );
    // The host goes quiet: past its timeout tl's watchdog ends its torque,
    // and its motor holds where it stands.
    tokio::time::sleep(Duration::from_millis(u64::from(WATCHDOG_MS) + 20)).await;
    let status = call(&m, "tl", "get_status", &[]).await;
    assert_eq!(mode(&status), Mode::Idle as u8);
    let fault = call(&m, "tl", "get_fault", &[]).await;
    assert_eq!(
        fault.get(1),
        Some(&Value::U8(FaultKind::OutputWatchdog.code()))
    );
    // Every motor ends its torque (the others by call) and holds: the mass
    // stays where it was.
    for name in CABLES {
        call(&m, name, "torque_off", &[]).await;
    }
    let held = plant.now().position();
    tokio::time::sleep(Duration::from_millis(500)).await;
    let after = plant.now().position();
    assert!(dist(held, after) < 0.5e-3, "{held:?} → {after:?}");
    // Points are welcome again, where the shaft stood.
    let status = call(&m, "br", "get_status", &[]).await;
    assert_eq!(mode(&status), Mode::Idle as u8);
}

#[test]
fn torque_holds_the_mass_and_the_watchdog_ends_it_with_the_motors_holding() {
    virtual_runtime().unwrap().block_on(held_then_watched());
}

async fn refused_without_encoder() {
    let spec = topology("single-usb.toml");
    let host = Host::start(HostConfig::named("h")).expect("host");
    let _sim = SimMachine::start_with(&host, &spec, TimeMode::Virtual)
        .await
        .expect("machine starts");
    let mut m = Manager::new(&host).await.expect("manager");
    m.refresh().await.expect("scan");
    call(&m, "motor", "set_enable", &[Value::Bool(true)]).await;
    let e = m
        .function(&FnRef::new("motor", "set_torque"))
        .unwrap()
        .call(&[Value::F32(0.1)])
        .await
        .unwrap_err();
    match &e {
        SomError::Remote {
            error: ControlError::CallFailed(code),
            ..
        } => assert_eq!(code.code(), StepperError::Unsupported.code(), "{e}"),
        other => panic!("{other}"),
    }
    assert!(e.to_string().contains("Unsupported"), "{e}");
}

#[test]
fn a_motor_without_an_encoder_refuses_the_torque_mode() {
    virtual_runtime()
        .unwrap()
        .block_on(refused_without_encoder());
}
