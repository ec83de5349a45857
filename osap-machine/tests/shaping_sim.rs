//! Input shaping on the simulated plotter, in virtual time: with the
//! shapers `osap resonance` recommends in the file, homing ends where it
//! ends unshaped, every move is shaped (the motors follow the plan a
//! fixed lag behind at constant speed), `idle()` returns with the
//! carriages where they were sent, and re-defining the position moves no
//! motor.

use osap_machine::config::{AxisShaper, MachineFile};
use osap_machine::sim::SimOptions;
use osap_machine::Machine;
use osap_sim::machine::virtual_runtime;

/// One microstep of the plotter's belts, mm.
const MICROSTEP: f64 = 1.0 / 80.0;

fn plotter(shaped: bool) -> MachineFile {
    let mut cfg = MachineFile::load(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/machines/plotter.toml"
    ))
    .unwrap();
    if shaped {
        // What `osap resonance --write` wrote for the simulated modes.
        for (axis, hz, zeta) in [("x", 44.87, 0.08), ("y", 38.03, 0.1)] {
            cfg.axes.get_mut(axis).unwrap().shaper = Some(AxisShaper {
                kind: "zvd".into(),
                freq_hz: hz,
                damping: zeta,
                fitted_from: None,
            });
        }
    }
    cfg.validate().unwrap();
    cfg
}

async fn start(cfg: &MachineFile) -> Machine {
    Machine::simulate_with(cfg, SimOptions::VIRTUAL)
        .await
        .unwrap()
}

fn carriages(m: &Machine) -> [f64; 2] {
    [
        m.sim_axis_position("x").unwrap(),
        m.sim_axis_position("y").unwrap(),
    ]
}

#[test]
fn shaped_moves_home_follow_and_rest_where_sent() {
    virtual_runtime().unwrap().block_on(async {
        // Unshaped homing, for reference.
        let m = start(&plotter(false)).await;
        m.home().await.unwrap();
        let plain_home = carriages(&m);
        m.stop().await.unwrap();

        let m = start(&plotter(true)).await;
        m.home().await.unwrap();
        let home = carriages(&m);
        for k in 0..2 {
            assert!(
                (home[k] - plain_home[k]).abs() <= MICROSTEP,
                "homed at {home:?}, unshaped at {plain_home:?}"
            );
        }

        // A long move at 200 mm/s: shaped, and at rest where sent once
        // idle() returns.
        m.start_recording().await.unwrap();
        let t0 = m.now_us().await.unwrap();
        m.goto_now([150.0, 101.0], 200.0).await.unwrap();
        let at = carriages(&m);
        let rec = m.take_recording(t0).await.unwrap();
        // The carriages (their physical positions, from their steps)
        // moved exactly what was asked since homing ended at (1, 1).
        for (k, moved) in [149.0, 100.0].iter().enumerate() {
            assert!(
                (at[k] - home[k] - moved).abs() <= MICROSTEP,
                "axis {k}: {home:?} then {at:?}"
            );
        }
        assert_eq!(rec.unshaped.len(), rec.planned.len());
        // Cruising (|v| constant), the motors follow the plan exactly one
        // lag behind: the shapers' common lag is the larger impulse
        // centroid, y's ZVD at 38.03 Hz, ζ 0.1 (amplitudes 0.334, 0.488,
        // 0.178 at 0, 13.2 and 26.4 ms): 11.1 ms.
        let lag = {
            let c = osap_machine::machine::motion::shapers(&plotter(true)).unwrap();
            maxl::blocks::shaper::InputShaper::new(c).lag_s()
        };
        assert!((lag - 0.01114).abs() < 0.0001, "lag {lag}");
        // Before the recording or after it: where it starts or ends.
        let x_at = |samples: &[osap_machine::record::Sample], t: f64| -> f64 {
            let i = samples.partition_point(|s| s.t <= t);
            match (i.checked_sub(1).map(|j| &samples[j]), samples.get(i)) {
                (Some(a), Some(b)) => a.pos[0] + (b.pos[0] - a.pos[0]) * (t - a.t) / (b.t - a.t),
                (Some(a), None) => a.pos[0],
                (None, _) => samples[0].pos[0],
            }
        };
        let mut checked = 0;
        let mut largest_gap: f64 = 0.0;
        for s in &rec.planned[10..rec.planned.len() - 10] {
            let plan = x_at(&rec.unshaped, s.t);
            largest_gap = largest_gap.max((s.pos[0] - plan).abs());
            // Mid-cruise: the plan's x at t − lag (linear in time there).
            let earlier = x_at(&rec.unshaped, s.t - lag);
            let v = (x_at(&rec.unshaped, s.t + 0.01) - x_at(&rec.unshaped, s.t - 0.05)) / 0.06;
            if (v.abs() - v_cruise_x()).abs() < 1e-6 {
                assert!(
                    (s.pos[0] - earlier).abs() < 1e-6,
                    "{}: {} vs {earlier}",
                    s.t,
                    s.pos[0]
                );
                checked += 1;
            }
        }
        assert!(checked > 100, "{checked} cruise samples");
        // The shaped position trails the plan by v·lag: 2 mm.
        assert!(largest_gap > 1.5, "{largest_gap}");

        // Re-defining where the machine is moves nothing, and the next
        // move starts there.
        m.set_position([0.0, 0.0]).unwrap();
        m.goto_now([10.0, 0.0], 50.0).await.unwrap();
        let after = carriages(&m);
        assert!(
            (after[0] - at[0] - 10.0).abs() <= MICROSTEP && (after[1] - at[1]).abs() <= MICROSTEP,
            "{at:?} then {after:?}"
        );
        m.stop().await.unwrap();
    });
}

/// The x velocity of the move to (150, 101) from the home (1, 1) while it
/// cruises at 200 mm/s: 200 · 149/√(149² + 100²).
fn v_cruise_x() -> f64 {
    200.0 * 149.0 / (149.0f64.powi(2) + 100.0f64.powi(2)).sqrt()
}
