//! Any travel at any microstepping: a 1 m belt axis at 256 microsteps
//! (1 280 microsteps/mm, 1.28 million over the travel, forty times what a
//! module's track held before positions wrapped) homes and moves to both
//! ends on the simulated modules, exactly, with its steps under the 100 kHz
//! step tick.

use osap_machine::config::MachineFile;
use osap_machine::sim::SimOptions;
use osap_machine::{Machine, MachineEvent};
use osap_sim::machine::virtual_runtime;

/// A 1 m axis on a 20-tooth GT2 pulley (40 mm a turn, 5 full steps/mm)
/// at 256 microsteps: 1 280 microsteps/mm. At 70 mm/s it steps at
/// 89.6 kHz, under the module's 100 kHz step tick.
const LONG_AXIS: &str = r#"
name = "long-axis"

[modules]
x = { name = "long-x" }

[motors.x]
module = "x"
full_steps_per_unit = 5.0
microsteps = 256

[kinematics]
type = "cartesian"

[axes.x]
motor = "x"
min = 0.0
max = 1000.0
velocity = 70.0
acceleration = 1000.0
jerk = 20000.0
homing = { switch = "x", direction = "min", search_speed = 20.0, latch_speed = 2.0, backoff = 2.0 }

[limits]
velocity = 70.0
acceleration = 1000.0
junction_deviation = 0.01
"#;

/// One microstep, mm.
const MICROSTEP: f64 = 1.0 / 1280.0;

#[test]
fn a_one_metre_axis_at_256_microsteps_reaches_both_ends_exactly() {
    let cfg = MachineFile::parse(LONG_AXIS).unwrap();
    virtual_runtime().unwrap().block_on(async {
        let m = Machine::simulate_with(&cfg, SimOptions::VIRTUAL)
            .await
            .unwrap();
        let mut events = m.events();
        m.home().await.unwrap();
        let mut at = Vec::new();
        for target in [1000.0, 0.0, 1000.0] {
            m.goto_now([target], 70.0).await.unwrap();
            m.idle().await.unwrap();
            assert_eq!(m.position(), [target]);
            // Where the carriage really is, from the steps it took: homing
            // puts the machine where the carriage is to within a microstep
            // (tests/switch_edges.rs), and no move adds to that.
            let real = m.sim_axis_position("x").unwrap();
            assert!(
                (real - target).abs() <= MICROSTEP * (1.0 + 1e-6),
                "at {real} for {target}: {} microsteps off",
                (real - target) / MICROSTEP
            );
            at.push(real);
        }
        // Exactly: the far end is 1 280 000 microsteps from the near one,
        // both times.
        assert_eq!(((at[0] - at[1]) / MICROSTEP).round(), 1_280_000.0);
        assert!(((at[0] - at[1]) / MICROSTEP - 1_280_000.0).abs() < 1e-6);
        assert_eq!(at[0], at[2]);
        // The far end is 1.28 million microsteps from the near one: every
        // one of them went out on time.
        let (steps, up, down, late) = m
            .with_sim(|s| {
                s.module("long-x")
                    .and_then(|sm| sm.module())
                    .map(|sm| sm.lock(|mm| mm.stepper.step_counts()))
            })
            .flatten()
            .unwrap();
        assert!(
            up >= 2 * 1_280_000 && down >= 1_280_000,
            "{up} up, {down} down"
        );
        assert_eq!(late, 0, "late steps");
        // The motor read 0 where it booted, mid-travel (500 mm): at the far
        // end its step index is 640 000, far past 32 767 (to the homing's
        // microstep).
        assert!((steps - 640_000).abs() <= 1, "step index {steps}");
        while let Ok(e) = events.try_recv() {
            assert!(
                !matches!(
                    e,
                    MachineEvent::Fault { .. }
                        | MachineEvent::Refused { .. }
                        | MachineEvent::LinkLost { .. }
                ),
                "{e:?}"
            );
        }
        m.stop().await.unwrap();
    });
}
