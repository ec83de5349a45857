//! A load cell weighing a simulated melt, end to end in virtual time: the
//! host sets up the module's load cell over the network, tares it at
//! rest, streams an extrusion to the module's motor, and reads the force
//! the module's own HX711 driver clocks out of the emulated converter: the
//! melt law's force at that flow, at the converter's 80 samples a second.
//!
//! The extruder: 400 microsteps per mm of 1.75 mm filament; the melt the
//! simulator's default PLA-like one, in a block held at 210 °C (its room).

use osap_host::netrunner::{Netrunner, SyncGoal};
use osap_host::som::{FnRef, Manager, Value};
use osap_host::{Host, HostConfig};
use osap_sim::machine::{virtual_runtime, SimMachine, TimeMode};
use osap_sim::topology::{MeltSpec, SimSpec};
use std::time::Duration;

/// A point every 8 ms: one call per point keeps well ahead of the stream.
const IV: u64 = 8192;
/// Filament speed while extruding, mm/s: 4.81 mm³/s.
const SPEED: f64 = 2.0;

const TOPOLOGY: &str = r#"
name = "extruder"

[[module]]
name = "e"
type = "stepper"
rate_ppm = -20.0

[module.motor]
full_steps_per_unit = 25.0

[[module.io.heater]]
pwm = 0
analog = 0
power_w = 40.0
heat_capacity_j_per_k = 15.0
loss_w_per_k = 0.1
ambient_c = 210.0

[module.io.melt]
flow_k = 8.0
flow_n = 0.6
temp_coeff = 0.02
t_ref = 210.0
response_ms = 60.0
noise_n = 0.1
grip_n = 40.0
data_pin = 2
clock_pin = 3

[[link]]
a = "host"
b = "e"
kind = "usb"
"#;

async fn call(m: &Manager, function: &str, args: &[Value<'static>]) -> Vec<Value<'static>> {
    m.function(&FnRef::new("e", function))
        .unwrap()
        .call(args)
        .await
        .unwrap_or_else(|e| panic!("{function}: {e}"))
}

/// `loadcell_read`: (time, force, raw, samples, taring).
async fn read(m: &Manager) -> (u64, f32, i32, u32, bool) {
    match call(m, "loadcell_read", &[]).await[..] {
        [Value::U64(t), Value::F32(f), Value::I32(r), Value::U32(n), Value::Bool(taring)] => {
            (t, f, r, n, taring)
        }
        ref other => panic!("loadcell_read gave {other:?}"),
    }
}

async fn run() {
    let spec = SimSpec::parse(TOPOLOGY).expect("the topology parses");
    let melt: MeltSpec = spec.modules[0].io.as_ref().unwrap().melt.clone().unwrap();
    let host = Host::start(HostConfig::named("h")).expect("host");
    let sim = SimMachine::start_with(&host, &spec, TimeMode::Virtual)
        .await
        .expect("machine starts");
    let mut m = Manager::new(&host).await.expect("manager");
    m.refresh().await.expect("scan");
    let nr = Netrunner::new(&host).await.unwrap();
    nr.wait_synchronised(&sim.route_to("e").unwrap(), SyncGoal::default())
        .await
        .unwrap();

    call(&m, "loadcell_setup", &[Value::U8(2), Value::U8(3)]).await;
    call(&m, "loadcell_tare", &[Value::U16(40)]).await;
    tokio::time::sleep(Duration::from_millis(600)).await;
    let (_, _, raw, samples, taring) = read(&m).await;
    assert!(!taring, "40 samples at 80 a second are in after 0.6 s");
    assert!((raw - 85_000).abs() < 2_000, "the bridge's offset: {raw}");
    assert!((40..=50).contains(&samples), "{samples} samples in 0.6 s");
    call(
        &m,
        "loadcell_scale",
        &[Value::F32((1.0 / melt.counts_per_newton) as f32)],
    )
    .await;
    let (_, rest, _, _, _) = read(&m).await;
    assert!(rest.abs() < 0.5, "tared: {rest} N at rest");

    // The extruder: 16 microsteps of 25 full steps per mm.
    call(&m, "set_scale", &[Value::F32(25.0)]).await;
    call(&m, "set_microsteps", &[Value::U16(16)]).await;
    call(&m, "set_interval", &[Value::U32(IV as u32)]).await;
    call(&m, "set_enable", &[Value::Bool(true)]).await;
    // Three seconds at SPEED, streamed as it runs, up to 250 ms ahead.
    let now = host.system_time().await.unwrap().as_micros();
    let t0 = (now + 200_000).next_multiple_of(IV);
    let n = 3_000_000 / IV;
    let add = m.function(&FnRef::new("e", "add_point")).unwrap();
    let mut k = 0;
    let mut forces = Vec::new();
    let mut last_time = 0;
    while k < n + 4 {
        let ahead = host.system_time().await.unwrap().as_micros() + 250_000;
        while k < n + 4 && t0 + k * IV < ahead {
            let position = SPEED * (k.min(n) * IV) as f64 / 1e6;
            if let Err(e) = add
                .call(&[Value::U64(t0 + k * IV), Value::F32(position as f32)])
                .await
            {
                let fault = call(&m, "get_fault", &[]).await;
                panic!("point {k}: {e}; fault {fault:?}");
            }
            k += 1;
        }
        let (time, force, _, _, _) = read(&m).await;
        // Settled: from 1 s in (16 τ) to the end of the push.
        if time != last_time && time > t0 + 1_000_000 && time < t0 + n * IV {
            forces.push(f64::from(force));
        }
        last_time = time;
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    // The last points run, and a conversion or two after them.
    while host.system_time().await.unwrap().as_micros() < t0 + (n + 4) * IV + 50_000 {
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    let area = std::f64::consts::PI * 0.875f64.powi(2);
    let law = melt.flow_k * (SPEED * area).powf(melt.flow_n);
    let mean = forces.iter().sum::<f64>() / forces.len() as f64;
    assert!(forces.len() > 120, "{} samples in 2 s", forces.len());
    assert!(
        (mean / law - 1.0).abs() < 0.02,
        "the cell reads {mean:.2} N, the melt law {law:.2} N"
    );
    let stats = sim
        .module("e")
        .unwrap()
        .module()
        .unwrap()
        .lock(|m| m.board().pins().melt().unwrap().stats());
    assert_eq!(stats.slips, 0);
    assert!(
        (stats.pushed_mm - SPEED * (n * IV) as f64 / 1e6).abs() < 0.01,
        "{stats:?}"
    );
    sim.stop().await.unwrap();
}

#[test]
fn a_load_cell_weighs_the_simulated_melt_through_the_modules_own_driver() {
    virtual_runtime()
        .expect("a current-thread runtime")
        .block_on(run());
}
