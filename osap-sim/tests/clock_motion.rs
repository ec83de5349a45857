//! A simulated module tells its clock when motion is queued, so a time
//! step is deferred (slewed) until the axis stands again.

use osap_core::SystemInstant;
use osap_host::{Host, HostConfig};
use osap_sim::machine::{virtual_runtime, SimMachine, TimeMode};
use osap_sim::topology::SimSpec;
use std::path::PathBuf;
use std::time::Duration;

#[test]
fn a_module_with_queued_motion_holds_its_clock_steps() {
    virtual_runtime().unwrap().block_on(async {
        let host = Host::start(HostConfig::named("h")).unwrap();
        let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("topologies/small-machine.toml");
        let topology = SimSpec::load(path).unwrap();
        let sim = SimMachine::start_with(&host, &topology, TimeMode::Virtual)
            .await
            .unwrap();
        tokio::time::sleep(Duration::from_secs(3)).await;
        let x = sim.module("x").unwrap();
        let active = || x.with_runtime(|rt, _| rt.clock().motion_active());
        assert!(!active().await.unwrap(), "an idle axis holds nothing");
        // A 64-point stream starting 300 ms from now.
        let now = x.with_runtime(|rt, now| rt.system_time(now)).await.unwrap();
        x.module().unwrap().lock(|m| {
            m.stepper.set_enable(true);
            let iv = u64::from(m.stepper.interval_us());
            // Points sit on the interval's grid.
            let first = (now.as_micros() + 300_000).div_ceil(iv) * iv;
            for k in 0..64u64 {
                let t = first + k * iv;
                m.stepper
                    .add_point(SystemInstant::from_micros(t), k as f32 * 0.01)
                    .unwrap();
            }
        });
        // Queued, not yet running: the next poll tells the clock.
        tokio::time::sleep(Duration::from_millis(100)).await;
        assert!(active().await.unwrap(), "queued motion not reported");
        let status = x.with_runtime(|rt, _| rt.clock().status()).await.unwrap();
        assert!(status.motion_active);
        // Run out and stopped: steps are allowed again.
        tokio::time::sleep(Duration::from_secs(2)).await;
        assert!(!active().await.unwrap(), "a standing axis still holds");
        assert_eq!(
            x.module().unwrap().lock(|m| m.stepper.counters().refused),
            0
        );
    });
}

#[test]
fn a_jump_of_the_source_under_motion_is_slewed_then_stepped_once_standing() {
    virtual_runtime().unwrap().block_on(async {
        let host = Host::start(HostConfig::named("h")).unwrap();
        let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("topologies/small-machine.toml");
        let topology = SimSpec::load(path).unwrap();
        let sim = SimMachine::start_with(&host, &topology, TimeMode::Virtual)
            .await
            .unwrap();
        tokio::time::sleep(Duration::from_secs(4)).await;
        let (x, hub) = (sim.module("x").unwrap(), sim.module("hub").unwrap());
        let status = || x.with_runtime(|rt, _| rt.clock().status());
        let before = status().await.unwrap();
        // A second of motion: 64 points at the longest interval, from
        // 100 ms on.
        let now = x.with_runtime(|rt, now| rt.system_time(now)).await.unwrap();
        x.module().unwrap().lock(|m| {
            m.stepper.set_enable(true);
            m.stepper.set_interval(16_384).unwrap();
            let iv = u64::from(m.stepper.interval_us());
            let first = (now.as_micros() + 100_000).div_ceil(iv) * iv;
            for k in 0..64u64 {
                m.stepper
                    .add_point(SystemInstant::from_micros(first + k * iv), k as f32 * 0.01)
                    .unwrap();
            }
        });
        // x's source turns into a root running 1 % fast: x's clock, whose
        // rate is clamped to 500 ppm, falls behind by milliseconds.
        hub.with_runtime(|rt, now| {
            let config = osap_core::clock::TimeConfig {
                root: true,
                max_rate_ppm: 10_000.0,
                ..*rt.clock().config()
            };
            rt.clock_mut().set_config(config).unwrap();
            rt.clock_mut().set_rate_ppb(now, 10_000_000);
        })
        .await
        .unwrap();
        tokio::time::sleep(Duration::from_millis(900)).await;
        let moving = status().await.unwrap();
        assert!(moving.motion_active, "{moving:?}");
        assert_eq!(
            moving.stats.jumps, before.stats.jumps,
            "stepped under motion"
        );
        assert!(moving.stats.deferred_steps >= 1, "{moving:?}");
        assert!(moving.offset_ns.abs() > 1_000_000, "{moving:?}");
        // Standing again: the step is taken.
        tokio::time::sleep(Duration::from_secs(2)).await;
        let after = status().await.unwrap();
        assert!(!after.motion_active, "{after:?}");
        assert!(after.stats.jumps > before.stats.jumps, "{after:?}");
    });
}
