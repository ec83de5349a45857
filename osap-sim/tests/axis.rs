//! Simulated MAXL axes over the network: `corexy-plotter.toml` (a hub on USB,
//! axes a, b and z on UARTs). The host streams time-stamped control points
//! to z, which follows them on its own synchronized clock; the executed
//! states are compared with the stream at *true* (host) time, so the error
//! includes the clock sync error, and the endstop's time stamp is checked
//! against where the stream crossed it.

use osap_host::netrunner::{Netrunner, SyncGoal};
use osap_host::som::{FnRef, Manager, OwnedValue};
use osap_host::{Host, HostConfig};
use osap_sim::machine::axis::{AxisMode, Executed};
use osap_sim::machine::{self, SimMachine};
use std::time::Duration;

mod common;
use common::shipped;

const IV: u64 = 2048;

/// Waits until every module of `names` has settled on the host's clock.
async fn synced(host: &Host, machine: &SimMachine, names: &[&str]) {
    let nr = Netrunner::new(host).await.unwrap();
    for name in names {
        let r = machine.route_to(name).unwrap();
        nr.wait_synchronised(&r, SyncGoal::default()).await.unwrap();
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_axis_follows_a_stream_on_synchronized_time() {
    let host = Host::start(HostConfig::named("h")).unwrap();
    let topology = machine::load(shipped("corexy-plotter.toml")).unwrap();
    let machine = SimMachine::start(&host, &topology).await.unwrap();
    let mut m = Manager::new(&host).await.unwrap();
    m.refresh().await.unwrap();
    synced(&host, &machine, &["z"]).await;
    let z = machine.module("z").unwrap();
    let probe = z.axis().unwrap();
    let current = m.function(&FnRef::new("z", "set_current")).unwrap();
    let add = m.function(&FnRef::new("z", "add_point")).unwrap();
    current.call(&[OwnedValue::F32(1.0)]).await.unwrap();

    // From rest at 0: three repeats, 50 steps of -0.08 mm, four holds at -4.
    let now = host.system_time().await.unwrap();
    let t0 = (now + 300_000).next_multiple_of(IV);
    let mut points: Vec<f32> = vec![0.0; 3];
    points.extend((1..=50).map(|k| k as f32 * -0.08));
    points.extend([-4.0; 4]);
    for (k, p) in points.iter().enumerate() {
        let t = t0 + k as u64 * IV;
        add.call(&[OwnedValue::U64(t), OwnedValue::F32(*p)])
            .await
            .unwrap_or_else(|e| panic!("point {k}: {e}"));
    }
    assert!(
        host.system_time().await.unwrap() < t0,
        "the stream fell behind real time"
    );
    let t_end = t0 + points.len() as u64 * IV;
    while host.system_time().await.unwrap() < t_end + 20_000 {
        tokio::time::sleep(Duration::from_millis(20)).await;
    }

    // The planned ramp: -0.08 mm per interval from stamp 2, exact on the
    // spline's straight run (stamps 3..=51).
    let planned = |t: f64| -0.08 * (t - (t0 + 2 * IV) as f64) / IV as f64;
    let ramp = (t0 + 3 * IV) as f64..=(t0 + 51 * IV) as f64;
    let history = probe.history();
    let on_ramp: Vec<&Executed> = history
        .iter()
        .filter(|e| e.mode == AxisMode::Tracking && ramp.contains(&(e.time as f64)))
        .collect();
    assert!(
        on_ramp.len() > 25,
        "only {} samples on the ramp",
        on_ramp.len()
    );
    let speed = 0.08 / (IV as f64 * 1e-6); // mm/s
    let mut worst_believed = 0.0f64;
    let mut worst_true = 0.0f64;
    for e in &on_ramp {
        // Against its own clock: only fixed-point rounding.
        worst_believed = worst_believed.max((e.position - planned(e.time as f64)).abs());
        // Against true time: plus the clock sync error, times the speed.
        let truth = z.host_time_at(e.local) as f64;
        worst_true = worst_true.max((e.position - planned(truth)).abs());
        assert!((e.velocity + speed).abs() < 0.01 * speed, "{e:?}");
    }
    eprintln!(
        "{} samples: worst error {:.2e} mm on the module's clock, {:.2e} mm at true time ({:.0} µs of travel at {speed:.0} mm/s)",
        on_ramp.len(),
        worst_believed,
        worst_true,
        worst_true / speed * 1e6
    );
    // Q16.16 steps at 400 steps/mm: a few 1e-8 mm.
    assert!(worst_believed < 1e-6, "{worst_believed}");
    // Within 400 µs of clock error at this speed (a synchronised module
    // sits within a few tens of µs once settled; this test starts early).
    assert!(worst_true < 400e-6 * speed, "{worst_true}");
    // It came to rest on the last point, cleanly.
    let last = history.last().unwrap();
    assert!((last.position + 4.0).abs() < 1e-4, "{last:?}");
    assert_eq!(last.velocity, 0.0);
    assert_eq!(probe.counters().faults, 0);
    assert_eq!(probe.counters().points, points.len() as u64);

    // The endstop at -2 mm: crossed on the ramp at stamp 2 + 25.
    let endstop = m.function(&FnRef::new("z", "endstop")).unwrap();
    let out = endstop.call(&[]).await.unwrap();
    let (OwnedValue::U64(hit), OwnedValue::U32(count)) = (&out[0], &out[1]) else {
        panic!("endstop returned {out:?}");
    };
    assert_eq!(*count, 1);
    let expected = t0 + 27 * IV;
    assert!(
        hit.abs_diff(expected) <= 1,
        "endstop at {hit}, expected {expected}"
    );
    machine.stop().await.unwrap();
}
