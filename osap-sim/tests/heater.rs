//! A heater on a simulated module, end to end in virtual time: the host
//! configures it through the module's functions and sets a target, the
//! module's own PID heats the simulated block to it and holds it, and
//! when the block's thermistor breaks the module cuts the heater by itself
//! and reports the sensor-open fault.
//!
//! The block is a hotend: a 40 W cartridge, 15 J/K, losing 0.1 W/K to a
//! 25 °C room, read by a 100 kΩ β 3950 thermistor on a 4.7 kΩ pullup.

use osap_host::som::{FnRef, Manager, Value};
use osap_host::{Host, HostConfig};
use osap_module::fault::FaultKind;
use osap_module::heater::{runaway_detail, HeaterState, RunawayReason};
use osap_sim::machine::{virtual_runtime, SimMachine, TimeMode};
use osap_sim::topology::SimSpec;
use std::time::Duration;

/// The heater's index on the module.
const HEATER: u8 = 0;
/// The thermistor breaks this long after the module boots.
const FAILS_AT_S: f64 = 200.0;

const TOPOLOGY: &str = r#"
name = "hotend"

[[module]]
name = "tool"
type = "stepper"
rate_ppm = 35.0

[[module.io.heater]]
pwm = 0
analog = 0
power_w = 40.0
heat_capacity_j_per_k = 15.0
loss_w_per_k = 0.1
sensor_fails_at_s = 200.0

[[link]]
a = "host"
b = "tool"
kind = "usb"
"#;

async fn run() {
    let topology = SimSpec::parse(TOPOLOGY).expect("the topology parses");
    let host = Host::start(HostConfig::named("h")).expect("host");
    let sim = SimMachine::start_with(&host, &topology, TimeMode::Virtual)
        .await
        .expect("machine starts");
    let mut m = Manager::new(&host).await.expect("manager");
    m.refresh().await.expect("scan");
    let f = |name: &str| m.function(&FnRef::new("tool", name)).unwrap();
    // The thermistor's curve: β 3950 through 100 kΩ at 25 °C.
    let t = osap_module::heater::Thermistor::from_beta(3950.0, 100_000.0, 4_700.0);
    f("heater_sensor")
        .call(&[
            Value::U8(HEATER),
            Value::U8(0),
            Value::F32(t.a),
            Value::F32(t.b),
            Value::F32(t.c),
            Value::F32(t.pullup_ohms),
        ])
        .await
        .unwrap();
    f("heater_output")
        .call(&[Value::U8(HEATER), Value::U8(0), Value::F32(1.0)])
        .await
        .unwrap();
    f("heater_limits")
        .call(&[Value::U8(HEATER), Value::F32(0.0), Value::F32(280.0)])
        .await
        .unwrap();
    // Klipper's example gains for such a hotend.
    f("heater_gains")
        .call(&[
            Value::U8(HEATER),
            Value::F32(22.2),
            Value::F32(1.08),
            Value::F32(114.0),
        ])
        .await
        .unwrap();
    f("heater_target")
        .call(&[Value::U8(HEATER), Value::F32(200.0)])
        .await
        .unwrap();
    let module = sim.module("tool").unwrap().module().unwrap();
    let block = || {
        module.lock(|m| {
            let pins = m.board().pins();
            (
                pins.heaters()[0].temperature(pins.secs_since_boot()),
                pins.pwm()[0],
            )
        })
    };
    // At full power the block takes 85 s to reach 198 °C; past its
    // overshoot (under 2 °C), from 150 s on, it holds within 1 °C until its
    // thermistor breaks at 200 s.
    tokio::time::sleep(Duration::from_secs(150)).await;
    let mut band = (f64::MAX, f64::MIN);
    while module.lock(|m| m.board().pins().secs_since_boot()) < FAILS_AT_S - 1.0 {
        let (t, pwm) = block();
        assert!(pwm > 0, "heating");
        band = (band.0.min(t), band.1.max(t));
        tokio::time::sleep(Duration::from_millis(500)).await;
    }
    assert!(band.0 > 199.0 && band.1 < 201.0, "held within {band:?}");
    let out = f("heater_read").call(&[Value::U8(HEATER)]).await.unwrap();
    let [Value::U64(time), Value::F32(temp), Value::F32(target), Value::F32(power), Value::U8(state)] =
        out[..]
    else {
        panic!("heater_read gave {out:?}")
    };
    assert!(time > 0);
    assert!((temp - 200.0).abs() < 2.0, "{temp}");
    assert_eq!((target, state), (200.0, HeaterState::Holding as u8));
    assert!(power > 0.2 && power < 0.7, "{power}");
    // The thermistor breaks: within a control period (100 ms) and the
    // module's wake-up, the heater is off.
    tokio::time::sleep(Duration::from_millis(1_000 + 150)).await;
    let (_, pwm) = block();
    assert_eq!(pwm, 0, "cut");
    let writes = module.lock(|m| m.board().pins().pwm_writes().to_vec());
    let cut = writes.iter().rposition(|w| w.duty != 0).unwrap() + 1;
    let cut_at = writes[cut].local.as_micros() as f64 * 1e-6;
    // When the sensor failed, on the module's (drifting) clock.
    let failed_at = module.lock(|m| {
        let clock = m.board().clock();
        let at = clock.boot() + Duration::from_secs_f64(FAILS_AT_S);
        clock.local_at(at).as_micros() as f64 * 1e-6
    });
    let after = cut_at - failed_at;
    assert!(
        (0.0..0.11).contains(&after),
        "cut {after} s after the sensor failed"
    );
    let out = f("get_fault").call(&[]).await.unwrap();
    let [Value::U64(_), Value::U8(code), Value::U32(detail), Value::U32(_)] = out[..] else {
        panic!("get_fault gave {out:?}")
    };
    assert_eq!(FaultKind::from_code(code), Some(FaultKind::HeaterRunaway));
    assert_eq!(detail, runaway_detail(0, RunawayReason::SensorOpen));
    // Latched off: a new target is refused until the sensor reads sane.
    let refused = f("heater_target")
        .call(&[Value::U8(HEATER), Value::F32(200.0)])
        .await
        .unwrap_err();
    assert!(refused.to_string().contains("Faulted"), "{refused}");
    let refused = f("heater_clear")
        .call(&[Value::U8(HEATER)])
        .await
        .unwrap_err();
    assert!(refused.to_string().contains("SensorFault"), "{refused}");
    tokio::time::sleep(Duration::from_secs(5)).await;
    assert_eq!(block().1, 0, "still off");
    sim.stop().await.unwrap();
}

#[test]
fn a_simulated_hotend_heats_holds_and_is_cut_when_its_thermistor_breaks() {
    virtual_runtime()
        .expect("a current-thread runtime")
        .block_on(run());
}

#[test]
fn heater_specs_out_of_range_are_refused_naming_the_key() {
    let bad = |from: &str, to: &str| {
        let text = TOPOLOGY.replacen(from, to, 1);
        SimSpec::parse(&text).unwrap_err().to_string()
    };
    let e = bad("pwm = 0", "pwm = 2");
    assert!(
        e.contains("[[module.io.heater]] pwm 2 does not exist"),
        "{e}"
    );
    let e = bad(
        "heat_capacity_j_per_k = 15.0",
        "heat_capacity_j_per_k = 0.0",
    );
    assert!(
        e.contains("heat_capacity_j_per_k 0 must be finite and positive"),
        "{e}"
    );
    let e = bad("sensor_fails_at_s = 200.0", "sensor_fails_at_s = -1.0");
    assert!(e.contains("sensor_fails_at_s -1"), "{e}");
    let second = "[[module.io.heater]]\npwm = 1\nanalog = 0\npower_w = 200.0\n\
                  heat_capacity_j_per_k = 400.0\nloss_w_per_k = 0.8\n\n[[link]]";
    let e = bad("[[link]]", second);
    assert!(e.contains("analog 0 already reads another heater"), "{e}");
    let e = bad("power_w = 40.0", "power_w = 40.0\nwatts = 3");
    assert!(e.contains("watts"), "{e}");
    // A bed on the other output and input is fine.
    let bed = second.replace("analog = 0", "analog = 1");
    let spec = SimSpec::parse(&TOPOLOGY.replacen("[[link]]", &bed, 1)).unwrap();
    assert_eq!(spec.modules[0].io.as_ref().unwrap().heaters.len(), 2);
}
