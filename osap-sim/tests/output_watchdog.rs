//! The output watchdog on a simulated module, end to end in virtual time:
//! a host sets a tool on and goes quiet, and the module puts the tool in
//! its safe state by itself, its timeout after the host's last call, and
//! reports why once the host asks again. The module's own timer sources
//! (`get_fault` on change, as a machine pipes it) do not keep it alive.

use osap_host::som::{FnRef, Manager, Value};
use osap_host::{Host, HostConfig};
use osap_module::fault::FaultKind;
use osap_sim::machine::{virtual_runtime, SimMachine, TimeMode};
use osap_sim::topology::SimSpec;
use pipes_core::control::InputMode;
use std::path::PathBuf;
use std::time::Duration;

/// The plotter's pen servo: 0.05 is pen up, 0.1 pen down.
const PEN_UP: f32 = 0.05;
const PEN_DOWN: f32 = 0.1;
/// The machine file's default `output_watchdog_ms`.
const TIMEOUT_MS: u32 = 500;

async fn run() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("topologies/single-usb.toml");
    let topology = SimSpec::load(path).expect("the shipped topology loads");
    let host = Host::start(HostConfig::named("h")).expect("host");
    let sim = SimMachine::start_with(&host, &topology, TimeMode::Virtual)
        .await
        .expect("machine starts");
    let mut m = Manager::new(&host).await.expect("manager");
    m.refresh().await.expect("scan");
    // A source on the module's own timer, as a machine sets get_fault up.
    m.set_input_mode(&FnRef::new("motor", "get_fault"), InputMode::OnTimer(5_000))
        .await
        .unwrap();
    let f = |name: &str| m.function(&FnRef::new("motor", name)).unwrap();
    f("set_safe_pwm")
        .call(&[Value::U8(0), Value::F32(PEN_UP)])
        .await
        .unwrap();
    f("pwm_write")
        .call(&[Value::U8(0), Value::F32(PEN_DOWN)])
        .await
        .unwrap();
    f("set_output_watchdog")
        .call(&[Value::U32(TIMEOUT_MS)])
        .await
        .unwrap();
    let module = sim.module("motor").unwrap().module().unwrap();
    let pwm0 = || module.lock(|m| m.board().pins().pwm()[0]);
    let down = (PEN_DOWN * 65_535.0 + 0.5) as u16;
    let up = (PEN_UP * 65_535.0 + 0.5) as u16;
    assert_eq!(pwm0(), down);
    // The host goes quiet. 0.4 s on, the pen is still down.
    tokio::time::sleep(Duration::from_millis(400)).await;
    assert_eq!(pwm0(), down, "before the timeout");
    // Past the timeout, the module lifted it by itself.
    tokio::time::sleep(Duration::from_millis(200)).await;
    assert_eq!(pwm0(), up, "after the timeout");
    // The writes on the pin: down, then up once, the timeout after the
    // last call (the watchdog's arming) to within the module's wake-up.
    let writes = module.lock(|m| m.board().pins().pwm_writes().to_vec());
    assert_eq!(
        writes.iter().map(|w| w.duty).collect::<Vec<_>>(),
        [down, up],
        "{writes:?}"
    );
    // What the host hears when it comes back: the watchdog fault, with how
    // long it had been quiet (the arming call's reply left after the module
    // fed the watchdog, so at least the timeout; its wake-up is a tokio
    // timer, 1 ms fine).
    let out = f("get_fault").call(&[]).await.unwrap();
    let [Value::U64(_), Value::U8(code), Value::U32(quiet), Value::U32(count)] = out[..] else {
        panic!("get_fault gave {out:?}")
    };
    eprintln!("the module was quiet for {quiet} µs when its watchdog fired");
    assert_eq!(FaultKind::from_code(code), Some(FaultKind::OutputWatchdog));
    assert_eq!(count, 1);
    let timeout_us = TIMEOUT_MS * 1_000;
    assert!(
        (timeout_us..timeout_us + 1_000).contains(&quiet),
        "quiet for {quiet} µs"
    );
    // That call fed it again: the pen stays up (nothing writes it), and
    // with the host quiet again it fires once more.
    tokio::time::sleep(Duration::from_millis(600)).await;
    assert_eq!(pwm0(), up);
    let out = f("get_fault").call(&[]).await.unwrap();
    assert_eq!(out[3], Value::U32(2), "{out:?}");
    sim.stop().await.unwrap();
}

#[test]
fn a_quiet_host_leaves_no_tool_on() {
    virtual_runtime()
        .expect("a current-thread runtime")
        .block_on(run());
}
