//! Motors that stall, on the simulated mill with its motors' datasheet
//! values (NEMA 23, 1.26 N·m, 2.8 A, 0.9 Ω, 2.5 mH, 300 g·cm², on 24 V, 5 mm
//! screws) and a 20 kg gantry on y: a constant acceleration beyond what the
//! motor can give stalls it (steps lost, reported), one within it does
//! not, and planning from the motor model (`[limits] model = "motors"`,
//! margin 0.7) never stalls while using the torque the motor has at low
//! speed.
//!
//! Shuttling y 40 mm at 50 mm/s, a constant acceleration stalls the y
//! motor between 14 000 and 20 000 mm/s² (one stall, 14 391 full steps
//! lost at 20 000): what sets it is the torque at low speed (23 500 mm/s²
//! at rest, without margin). Near 50 mm/s the motor has a fifth of its
//! holding torque, but the ramp spends too little time there for the
//! rotor to fall two full steps behind.

use osap_machine::config::{MachineFile, MotorModelKeys, PlannerModel};
use osap_machine::sim::SimOptions;
use osap_machine::Machine;
use osap_sim::machine::{virtual_runtime, TimeMode};

const NEMA23: MotorModelKeys = MotorModelKeys {
    holding_torque_nm: 1.26,
    rated_current_a: 2.8,
    resistance_ohm: 0.9,
    inductance_mh: 2.5,
    supply_v: 24.0,
    rotor_inertia_gcm2: 300.0,
    steps_per_rev: 200.0,
};

/// The mill with motor models and masses; every acceleration `accel`
/// (mm/s²), planned from the motors when `motors`.
fn mill(accel: f64, motors: bool) -> MachineFile {
    let mut cfg = MachineFile::load(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/machines/mill.toml"
    ))
    .unwrap();
    for m in cfg.motors.values_mut() {
        m.model = Some(NEMA23);
    }
    for (axis, kg) in [("x", 12.0), ("y", 20.0), ("z", 4.0)] {
        let a = cfg.axes.get_mut(axis).unwrap();
        a.acceleration = accel;
        a.moving_mass_kg = Some(kg);
    }
    cfg.limits.acceleration = accel;
    if motors {
        cfg.limits.model = Some(PlannerModel::Motors);
    }
    cfg.validate().unwrap();
    cfg
}

/// Back and forth along y, 40 mm at 50 mm/s (where the motor has a fifth
/// of its holding torque), ten times; returns (seconds, stalls, full
/// steps lost).
async fn shuttle(cfg: &MachineFile) -> (f64, usize, f64) {
    let m = Machine::simulate_with(
        cfg,
        SimOptions {
            time: TimeMode::Virtual,
        },
    )
    .await
    .unwrap();
    m.set_position([150.0, 100.0, -10.0]).unwrap();
    let t0 = tokio::time::Instant::now();
    for k in 0..10 {
        let y = if k % 2 == 0 { 140.0 } else { 100.0 };
        m.goto_via_queue([150.0, y, -10.0], 50.0).await.unwrap();
    }
    m.idle().await.unwrap();
    let s = t0.elapsed().as_secs_f64();
    let stalls = m.sim_stalls();
    m.stop().await.unwrap();
    let y = stalls.iter().find(|s| s.motor == "y").unwrap();
    (s, y.stalls, y.lost_full_steps)
}

#[test]
fn constant_acceleration_past_the_torque_stalls_and_the_motor_model_does_not() {
    virtual_runtime().unwrap().block_on(async {
        let (t_slow, stalls, _) = shuttle(&mill(3000.0, false)).await;
        assert_eq!(stalls, 0, "3000 mm/s² stalled");
        let (_, stalls, _) = shuttle(&mill(14_000.0, false)).await;
        assert_eq!(stalls, 0, "14 000 mm/s² stalled");
        let (_, stalls, lost) = shuttle(&mill(20_000.0, false)).await;
        assert!(
            stalls > 0 && lost > 1000.0,
            "20 000 mm/s²: {stalls} stalls, {lost} steps lost"
        );
        // The model, with a 0.7 margin, plans up to 16 000 mm/s² at rest
        // and 3000 at 50 mm/s.
        let (t_model, stalls, _) = shuttle(&mill(30_000.0, true)).await;
        assert_eq!(stalls, 0, "the motor model stalled");
        eprintln!("shuttle: constant 3000 mm/s² {t_slow:.3} s, motor model {t_model:.3} s");
        assert!(t_model < t_slow, "{t_model} vs {t_slow}");
    });
}
