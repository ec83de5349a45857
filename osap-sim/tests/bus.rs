//! Eight steppers on one simulated RS-485 bus behind a hub: the scan finds
//! them through `bus_forward` routes, their clocks settle on the hub's (the
//! bus head's) time, and motion streamed to all eight runs on every one.

use osap_host::netrunner::{scan, Netrunner, ScanOptions, SyncGoal};
use osap_host::som::{FnRef, Manager, Value};
use osap_host::{Host, HostConfig};
use osap_sim::machine::{SimMachine, TimeMode};
use osap_sim::topology::SimSpec;
use std::sync::atomic::Ordering;
use std::time::Duration;

mod common;

const DROPS: usize = 8;

fn topology() -> SimSpec {
    let mut text = String::from(
        "name = \"bus8\"\n[[module]]\nname = \"hub\"\ntype = \"hub\"\n\
         [[link]]\na = \"host\"\nb = \"hub\"\nkind = \"usb\"\n",
    );
    for k in 1..=DROPS {
        text.push_str(&format!(
            "[[module]]\nname = \"d{k}\"\ntype = \"stepper\"\nrate_ppm = {}\n",
            (k as f64 - 4.5) * 20.0
        ));
    }
    let drops: Vec<String> = (1..=DROPS).map(|k| format!("\"d{k}\"")).collect();
    text.push_str(&format!(
        "[[bus]]\nname = \"rs485\"\nhead = \"hub\"\ndrops = [{}]\nbaud = 1000000\n",
        drops.join(", ")
    ));
    SimSpec::parse(&text).unwrap()
}

/// A module's runtime counters and its bus link's, for failure messages.
async fn counters(sim: &SimMachine, name: &str) -> String {
    sim.module(name)
        .unwrap()
        .with_runtime(|rt, _| format!("{:?} {:?}", rt.counters(), rt.link_counters(1)))
        .await
        .unwrap_or_default()
}

/// Virtual time by default: the bus's turns are not stretched by how the
/// host schedules ten module tasks on its cores, and every run is the
/// same (frames fall on tokio's 1 ms ticks). With `OSAP_BUS_REAL_TIME=1`
/// the same runs in real time, frames timed to the µs on the wire thread:
/// the figures docs/performance.md quotes (on an idle machine).
#[test]
fn eight_drops_are_scanned_synced_and_driven() {
    common::on_bus_runtime(run);
}

async fn run(mode: TimeMode) {
    let host = Host::start(HostConfig::named("h")).unwrap();
    let sim = SimMachine::start_with(&host, &topology(), mode)
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(500)).await;

    // Scan: the hub's bus link reports its drops; each is walked into.
    let report = scan(&host, &ScanOptions::default()).await.unwrap();
    let stats = sim.bus_stats(0).unwrap();
    assert!(
        report.failures.is_empty(),
        "{} collisions; {:?}",
        stats.collisions.load(Ordering::Relaxed),
        report.failures
    );
    let map = report.map;
    for k in 1..=DROPS {
        let r = map
            .runtimes
            .iter()
            .find(|r| r.name == format!("d{k}"))
            .unwrap_or_else(|| panic!("d{k} not found:\n{}", map.tree()));
        assert_eq!(r.route_drops.last(), Some(&Some(k as u8)), "{r:?}");
        assert_eq!(
            r.route(),
            sim.route_to(&format!("d{k}"))
                .unwrap()
                .with_mtu(r.route_mtu)
        );
    }
    assert!(
        map.tree().contains("via rs485_bus link 1 drop 8: d8"),
        "{}",
        map.tree()
    );

    // Clock sync through the bus head.
    let nr = Netrunner::new(&host).await.unwrap();
    for k in 1..=DROPS {
        let route = sim.route_to(&format!("d{k}")).unwrap();
        nr.wait_synchronised(&route, SyncGoal::default())
            .await
            .unwrap_or_else(|e| panic!("d{k} did not settle: {e}"));
    }

    // Motion to all eight over the bus.
    let mut m = Manager::new(&host).await.unwrap();
    m.refresh().await.unwrap();
    let now = host.system_time().await.unwrap().as_micros();
    let iv = 2048u64;
    let t0 = (now + 3_000_000).next_multiple_of(iv);
    for k in 1..=DROPS {
        let name = format!("d{k}");
        m.function(&FnRef::new(&name, "set_enable"))
            .unwrap()
            .call(&[Value::Bool(true)])
            .await
            .unwrap();
    }
    // Each drop's 24 points stream from its own task, all eight at once
    // (as a host pipelines a move): the calls contend for the bus's turns.
    // The stream ramps to TARGET and holds there for its last 4 points.
    const TARGET: f64 = 2.0;
    let points: Vec<f32> = (0..24).map(|i| (i.min(20) as f32) * 0.1).collect();
    assert_eq!(f64::from(*points.last().unwrap()), TARGET);
    let frames0 = sim.bus_stats(0).unwrap().frames.load(Ordering::Relaxed);
    let bytes0 = sim.bus_stats(0).unwrap().bytes.load(Ordering::Relaxed);
    let started = tokio::time::Instant::now();
    let mut tasks = Vec::new();
    for k in 1..=DROPS {
        let add = m
            .function(&FnRef::new(format!("d{k}"), "add_point"))
            .unwrap();
        let points = points.clone();
        tasks.push(tokio::spawn(async move {
            let mut latencies = Vec::new();
            for (i, p) in points.iter().enumerate() {
                let sent = tokio::time::Instant::now();
                add.call(&[Value::U64(t0 + i as u64 * iv), Value::F32(*p)])
                    .await
                    .map_err(|e| format!("d{k} point {i}: {e}"))?;
                latencies.push(sent.elapsed());
            }
            Ok::<_, String>(latencies)
        }));
    }
    let mut per_drop = Vec::new();
    for task in tasks {
        match task.await.unwrap() {
            Ok(latencies) => per_drop.push(latencies),
            Err(e) => panic!(
                "{e}\nhub: {}\nd1: {}",
                counters(&sim, "hub").await,
                counters(&sim, "d1").await
            ),
        }
    }
    let elapsed = started.elapsed();
    let frames = sim.bus_stats(0).unwrap().frames.load(Ordering::Relaxed) - frames0;
    let bytes = sim.bus_stats(0).unwrap().bytes.load(Ordering::Relaxed) - bytes0;
    let calls = (DROPS * points.len()) as f64;
    let worst = per_drop.iter().flatten().max().unwrap();
    let means: Vec<f64> = per_drop
        .iter()
        .map(|l| l.iter().map(Duration::as_secs_f64).sum::<f64>() / l.len() as f64 * 1e3)
        .collect();
    let (lo, hi) = means
        .iter()
        .fold((f64::MAX, 0f64), |(lo, hi), &m| (lo.min(m), hi.max(m)));
    println!(
        "bus8 motion: {calls} calls in {:.0} ms ({:.0} calls/s); bus {frames} frames, \
         {bytes} bytes ({:.1}% of 1 Mbit/s); call latency mean per drop {lo:.1}..{hi:.1} ms, \
         worst {:.1} ms",
        elapsed.as_secs_f64() * 1e3,
        calls / elapsed.as_secs_f64(),
        bytes as f64 * 10.0 / elapsed.as_secs_f64() / 1e6 * 100.0,
        worst.as_secs_f64() * 1e3,
    );
    // Fair turns: no drop's calls take much longer than another's.
    assert!(hi <= 2.0 * lo + 2.0, "unfair: {means:?}");
    assert!(*worst < Duration::from_millis(100), "worst {worst:?}");
    let end = t0 + points.len() as u64 * iv + 200_000;
    let wait = end.saturating_sub(host.system_time().await.unwrap().as_micros());
    tokio::time::sleep(Duration::from_micros(wait)).await;
    for k in 1..=DROPS {
        let module = sim.module(&format!("d{k}")).unwrap().module().unwrap();
        let (refused, position, steps_per_unit) = module.lock(|m| {
            (
                m.stepper.counters().refused,
                m.board().motor().position(),
                m.stepper.steps_per_unit(),
            )
        });
        assert_eq!(refused, 0, "d{k} refused points");
        // The carriage stands at the stream's end to within one step (the
        // step generator rounds to the nearest; 1/80 unit at the module's
        // 80 full steps per unit and 1 microstep): every point arrived and
        // ran, on time.
        let step = 1.0 / f64::from(steps_per_unit);
        assert!(
            (position - TARGET).abs() <= step,
            "d{k} stands at {position}, not within a step ({step}) of {TARGET}"
        );
    }
    let stats = sim.bus_stats(0).unwrap();
    assert_eq!(stats.collisions.load(Ordering::Relaxed), 0);
    assert!(stats.frames.load(Ordering::Relaxed) > 0);
}
