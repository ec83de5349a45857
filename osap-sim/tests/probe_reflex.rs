//! Probing by reflex: a nozzle load cell on the z module presses a bed,
//! and the z axis stops either by a comparator block on the module
//! (`loadcell_read` piped into it, `halt` set) or by the host, which reads
//! the cell over the network and calls `halt`. Both run in virtual time on
//! the simulator, the same move and the same cell; the overtravel past the
//! touch, over the probing speed, is each one's stop latency.
//!
//! The z axis: a T8 leadscrew (8 mm a turn: 25 full steps per mm) at 16
//! microsteps, probing down at 5 mm/s. The cell: an HX717 at 320 samples a
//! second, the bed and gantry 40 N/mm; the probe triggers at 1 N.

use osap_host::netrunner::{Netrunner, SyncGoal};
use osap_host::som::{FnRef, Manager, PipeOptions, Value};
use osap_host::{Host, HostConfig};
use osap_module::fault::FaultKind;
use osap_sim::machine::{virtual_runtime, SimMachine, TimeMode};
use osap_sim::topology::SimSpec;
use pipes_core::control::{InputMode, OutputMode};
use std::time::Duration;

/// A point every 16 ms: the whole search fits the module's queue of 64.
const IV: u64 = 16_384;
/// Probing speed, mm/s.
const SPEED: f64 = 5.0;
/// Where the nozzle touches the bed, mm.
const TOUCH: f64 = -2.0;
/// How far the probe searches, mm.
const DEPTH: f64 = 3.0;
/// The trigger force, N.
const THRESHOLD: f32 = 1.0;
/// The cell's conversion period, µs (320 a second).
const SAMPLE_US: f64 = 1e6 / 320.0;

const TOPOLOGY: &str = r#"
name = "probe"

[[module]]
name = "z"
type = "stepper"
rate_ppm = 30.0

[module.motor]
full_steps_per_unit = 25.0

[module.io.contact]
touch_at = -2.0
stiffness_n_per_unit = 40.0
data_pin = 2
clock_pin = 3
sample_hz = 320.0
noise_n = 0.02

[[link]]
a = "host"
b = "z"
kind = "usb"
"#;

async fn call(m: &Manager, function: &str, args: &[Value<'static>]) -> Vec<Value<'static>> {
    m.function(&FnRef::new("z", function))
        .unwrap()
        .call(args)
        .await
        .unwrap_or_else(|e| panic!("{function}: {e}"))
}

/// What one probe did.
#[derive(Debug)]
struct Stop {
    /// How far past the touch the carriage stopped, mm.
    overtravel: f64,
    /// The largest force on the cell, N.
    peak_n: f64,
    /// The module's latest fault kind.
    fault: u8,
}

impl Stop {
    /// The stop latency: the overtravel at the probing speed, ms.
    fn latency_ms(&self) -> f64 {
        self.overtravel / SPEED * 1e3
    }
}

async fn probe(reflex: bool) -> Stop {
    let spec = SimSpec::parse(TOPOLOGY).expect("the topology parses");
    let host = Host::start(HostConfig::named("h")).expect("host");
    let sim = SimMachine::start_with(&host, &spec, TimeMode::Virtual)
        .await
        .expect("machine starts");
    let mut m = Manager::new(&host).await.expect("manager");
    m.refresh().await.expect("scan");
    let nr = Netrunner::new(&host).await.unwrap();
    nr.wait_synchronised(&sim.route_to("z").unwrap(), SyncGoal::default())
        .await
        .unwrap();

    call(&m, "loadcell_setup", &[Value::U8(2), Value::U8(3)]).await;
    call(&m, "loadcell_scale", &[Value::F32(1.0 / 2000.0)]).await;
    call(&m, "loadcell_tare", &[Value::U16(16)]).await;
    tokio::time::sleep(Duration::from_millis(100)).await;
    call(&m, "set_scale", &[Value::F32(25.0)]).await;
    call(&m, "set_microsteps", &[Value::U16(16)]).await;
    call(&m, "set_interval", &[Value::U32(IV as u32)]).await;

    let read = FnRef::new("z", "loadcell_read");
    if reflex {
        // The cell's samples, as they come, into a comparator that halts z.
        m.new_block(
            "z",
            "comparator",
            "touch",
            &[Value::F32(THRESHOLD), Value::F32(0.2), Value::Bool(true)],
        )
        .await
        .unwrap();
        m.connect(
            &read,
            &FnRef::new("z", "touch"),
            &[0, 1],
            &[0, 1],
            PipeOptions::default(),
        )
        .await
        .unwrap();
        m.set_output_mode(&read, OutputMode::OnChange)
            .await
            .unwrap();
        m.set_input_mode(&read, InputMode::OnTimer(250))
            .await
            .unwrap();
    }
    call(&m, "set_enable", &[Value::Bool(true)]).await;

    // Down 3 mm at SPEED, every point queued before the move starts (so
    // the module's latest fault is what stopped it, not a refusal after).
    let now = host.system_time().await.unwrap().as_micros();
    let t0 = (now + 300_000).next_multiple_of(IV);
    let n = (DEPTH / SPEED * 1e6) as u64 / IV + 1;
    let add = m.function(&FnRef::new("z", "add_point")).unwrap();
    for k in 0..=n {
        let position = -SPEED * (k.min(n - 1) * IV) as f64 / 1e6;
        add.call(&[Value::U64(t0 + k * IV), Value::F32(position as f32)])
            .await
            .unwrap_or_else(|e| panic!("point {k}: {e}"));
    }
    assert!(
        host.system_time().await.unwrap().as_micros() < t0,
        "queued in time"
    );
    let loadcell = m.function(&read).unwrap();
    let halt = m.function(&FnRef::new("z", "halt")).unwrap();
    let status = m.function(&FnRef::new("z", "get_status")).unwrap();
    loop {
        if !reflex {
            // The host's way: read the cell, halt on the threshold.
            let out = loadcell.call(&[]).await.unwrap();
            if matches!(out.get(1), Some(Value::F32(f)) if *f > THRESHOLD) {
                halt.call(&[]).await.unwrap();
            }
        }
        if matches!(status.call(&[]).await.unwrap().first(), Some(Value::U8(4))) {
            break;
        }
        let now = host.system_time().await.unwrap().as_micros();
        assert!(
            now < t0 + n * IV + 100_000,
            "the probe ran its whole depth untriggered"
        );
    }
    let module = sim.module("z").unwrap().module().unwrap();
    let (position, peak_n) = module.lock(|m| {
        let b = m.board();
        (
            b.motor().position(),
            b.pins().contact().unwrap().peak_force(),
        )
    });
    let fault = match call(&m, "get_fault", &[]).await[..] {
        [_, Value::U8(code), ..] => code,
        ref other => panic!("get_fault gave {other:?}"),
    };
    sim.stop().await.unwrap();
    Stop {
        overtravel: TOUCH - position,
        peak_n,
        fault,
    }
}

#[test]
fn a_comparator_on_the_module_stops_the_probe_within_a_sample() {
    let rt = virtual_runtime().expect("a current-thread runtime");
    let reflex = rt.block_on(probe(true));
    let rt = virtual_runtime().expect("a current-thread runtime");
    let host = rt.block_on(probe(false));
    println!(
        "probe stop latency at {SPEED} mm/s, 320 samples/s: reflex {:.2} ms ({:.4} mm past the \
         touch, peak {:.2} N), host round trip {:.2} ms ({:.4} mm, peak {:.2} N)",
        reflex.latency_ms(),
        reflex.overtravel,
        reflex.peak_n,
        host.latency_ms(),
        host.overtravel,
        host.peak_n
    );
    // The threshold is reached 1 N / 40 N/mm = 0.025 mm past the touch
    // (5 ms at 5 mm/s); the comparator then halts within the sample that
    // shows it, a conversion period plus the module's loop and the 250 µs
    // the cell is read on.
    let to_threshold_ms = f64::from(THRESHOLD) / 40.0 / SPEED * 1e3;
    let reflex_after = reflex.latency_ms() - to_threshold_ms;
    assert!(
        reflex_after > 0.0 && reflex_after < SAMPLE_US / 1e3 + 1.5,
        "the reflex stopped {reflex_after:.2} ms after the force crossed 1 N"
    );
    assert_eq!(reflex.fault, FaultKind::BlockHalt.code());
    assert_eq!(host.fault, FaultKind::Halted.code());
    assert!(
        host.latency_ms() > reflex.latency_ms(),
        "the host's stop ({:.2} ms) is slower than the module's ({:.2} ms)",
        host.latency_ms(),
        reflex.latency_ms()
    );
}
