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
/// Where the nozzle touches the bed, mm, in the first run; each run
/// after moves it 0.0026 mm lower (0.52 ms at SPEED), so the runs meet the
/// cell's 3.1 ms conversion period at six phases.
const TOUCH: f64 = -2.0;
/// Runs per way.
const RUNS: usize = 6;
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
touch_at = TOUCH_AT
stiffness_n_per_unit = 40.0
data_pin = 2
clock_pin = 3
sample_hz = 320.0
noise_n = 0.02

[[module]]
name = "x"
type = "stepper"
rate_ppm = -40.0

[[link]]
a = "host"
b = "z"
kind = "usb"

[[link]]
a = "z"
b = "x"
kind = "uart"
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
    /// From the halt to the x module setting its pin high, the comparator's
    /// event fanned out over a UART hop, µs (reflex only).
    fan_out_us: Option<i64>,
}

impl Stop {
    /// The stop latency: the overtravel at the probing speed, ms.
    fn latency_ms(&self) -> f64 {
        self.overtravel / SPEED * 1e3
    }
}

async fn probe(reflex: bool, touch: f64) -> Stop {
    let topology = TOPOLOGY.replace("TOUCH_AT", &format!("{touch}"));
    let spec = SimSpec::parse(&topology).expect("the topology parses");
    let host = Host::start(HostConfig::named("h")).expect("host");
    let sim = SimMachine::start_with(&host, &spec, TimeMode::Virtual)
        .await
        .expect("machine starts");
    let mut m = Manager::new(&host).await.expect("manager");
    m.refresh().await.expect("scan");
    let nr = Netrunner::new(&host).await.unwrap();
    for module in ["z", "x"] {
        nr.wait_synchronised(&sim.route_to(module).unwrap(), SyncGoal::default())
            .await
            .unwrap();
    }

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
        // The event also fans out to another module: x drives its pin 2
        // to `above` (the pin held by a first call).
        let write = FnRef::new("x", "digital_write");
        m.function(&write)
            .unwrap()
            .call(&[Value::U8(2), Value::Bool(false)])
            .await
            .unwrap();
        let touch = FnRef::new("z", "touch");
        m.connect(&touch, &write, &[1], &[1], PipeOptions::default())
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
    let (halted_at, fault) = match call(&m, "get_fault", &[]).await[..] {
        [Value::U64(time), Value::U8(code), ..] => (time, code),
        ref other => panic!("get_fault gave {other:?}"),
    };
    let x = sim.module("x").unwrap().module().unwrap();
    // Long enough for the event to cross.
    tokio::time::sleep(Duration::from_millis(20)).await;
    let raised = x.lock(|m| {
        let w = m
            .board()
            .pins()
            .writes()
            .iter()
            .rev()
            .find(|w| w.pin == 2)?;
        w.level.then(|| m.time.system_time(w.local).as_micros())
    });
    sim.stop().await.unwrap();
    Stop {
        overtravel: touch - position,
        peak_n,
        fault,
        fan_out_us: raised.map(|t| t as i64 - halted_at as i64),
    }
}

/// The median and the largest of `xs`.
fn median_max(mut xs: Vec<f64>) -> (f64, f64) {
    xs.sort_by(f64::total_cmp);
    (xs[xs.len() / 2], xs[xs.len() - 1])
}

#[test]
fn a_comparator_on_the_module_stops_the_probe_within_a_sample() {
    let mut reflexes = Vec::new();
    let mut hosts = Vec::new();
    for k in 0..RUNS {
        let touch = TOUCH - 0.0026 * k as f64;
        let run = |reflex| {
            virtual_runtime()
                .expect("a current-thread runtime")
                .block_on(probe(reflex, touch))
        };
        reflexes.push(run(true));
        hosts.push(run(false));
    }
    // The threshold is reached 1 N / 40 N/mm = 0.025 mm past the touch
    // (5 ms at 5 mm/s). After that the reflex waits for the next conversion
    // (3.125 ms at most), the driver's next look at its data line (1 ms),
    // `loadcell_read`'s timer (0.25 ms) and the module's next turn to
    // deliver the datagram (1 ms); the stop is measured to a microstep
    // (0.0025 mm, 0.5 ms).
    let to_threshold_ms = f64::from(THRESHOLD) / 40.0 / SPEED * 1e3;
    let after = |runs: &[Stop]| -> Vec<f64> {
        runs.iter()
            .map(|r| r.latency_ms() - to_threshold_ms)
            .collect()
    };
    let (reflex_median, reflex_max) = median_max(after(&reflexes));
    let (host_median, host_max) = median_max(after(&hosts));
    println!(
        "probe stop after the force crossed 1 N, at {SPEED} mm/s, 320 samples/s, {RUNS} phases: \
         reflex median {reflex_median:.2} ms, max {reflex_max:.2} ms (peak force up to {:.2} N); \
         host round trip median {host_median:.2} ms, max {host_max:.2} ms (up to {:.2} N)",
        reflexes.iter().map(|r| r.peak_n).fold(0.0, f64::max),
        hosts.iter().map(|r| r.peak_n).fold(0.0, f64::max),
    );
    let bound = SAMPLE_US / 1e3 + 1.0 + 0.25 + 1.0 + 0.5;
    assert!(
        after(&reflexes).iter().all(|a| *a > 0.0) && reflex_max <= bound,
        "the reflex stopped up to {reflex_max:.2} ms after the force crossed 1 N (bound {bound:.3} ms)"
    );
    assert!(
        host_median > reflex_median,
        "the host's stop ({host_median:.2} ms) is slower than the module's ({reflex_median:.2} ms)"
    );
    for (reflex, host) in reflexes.iter().zip(&hosts) {
        check_faults(reflex, host);
    }
}

/// Each way stopped as it should: the comparator's halt, and the event
/// fanned out; the host's `halt`.
fn check_faults(reflex: &Stop, host: &Stop) {
    assert_eq!(reflex.fault, FaultKind::BlockHalt.code());
    // The same event reached the x module, one UART hop away, as a pipe.
    let fan_out = reflex.fan_out_us.expect("x set its pin on the touch");
    println!("the touch reached module x's pin {fan_out} µs after z halted");
    assert!(
        (0..2_000).contains(&fan_out),
        "x's pin rose {fan_out} µs after z halted"
    );
    assert_eq!(host.fault, FaultKind::Halted.code());
}
