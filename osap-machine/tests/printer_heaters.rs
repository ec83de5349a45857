//! The printer's heaters on simulated modules that run the firmware's own
//! heater logic: set up from the machine file, heated to a target and held
//! there by the module's PID, and cut by the module when their thermistor
//! breaks, which stops the machine naming the heater.

use osap_machine::config::MachineFile;
use osap_machine::sim::SimOptions;
use osap_machine::{HeaterState, Machine, MachineError, MachineState};
use osap_sim::machine::virtual_runtime;

fn printer() -> MachineFile {
    MachineFile::load(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/machines/printer.toml"
    ))
    .unwrap()
}

async fn simulate(cfg: &MachineFile) -> Machine {
    Machine::simulate_with(cfg, SimOptions::VIRTUAL)
        .await
        .unwrap()
}

#[test]
fn the_hotend_heats_to_its_target_and_holds_it() {
    virtual_runtime().unwrap().block_on(async {
        let m = simulate(&printer()).await;
        let h = m.heater("hotend").unwrap();
        let r = h.read().await.unwrap();
        assert!((r.celsius - 25.0).abs() < 1.0, "{r:?}");
        assert_eq!(r.state, HeaterState::Off);
        h.set_target(210.0).await.unwrap();
        let took = h.wait_for_target().await.unwrap().as_secs_f64();
        // 40 W into 13 J/K: 185 K take at least 60 s at full power.
        assert!((60.0..150.0).contains(&took), "{took} s");
        tokio::time::sleep(std::time::Duration::from_secs(30)).await;
        let r = h.read().await.unwrap();
        assert!((r.celsius - 210.0).abs() < 2.0, "{r:?}");
        assert_eq!(r.state, HeaterState::Holding);
        // It holds 210 °C at about 0.12 × 185 = 22 W of 40.
        assert!((r.power - 0.555).abs() < 0.1, "{r:?}");
        m.stop().await.unwrap();
    });
}

#[test]
fn a_broken_thermistor_cuts_the_heater_and_stops_the_machine_naming_it() {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/machines/printer.toml"
    ))
    .unwrap()
    .replace(
        "loss_w_per_k = 0.12          # holds 210 °C at about 55 % duty",
        "loss_w_per_k = 0.12\nsensor_fails_at_s = 20.0",
    );
    let cfg = MachineFile::parse(&text).unwrap();
    assert_eq!(
        cfg.sim.as_ref().unwrap().heaters["hotend"].sensor_fails_at_s,
        Some(20.0)
    );
    virtual_runtime().unwrap().block_on(async {
        let m = simulate(&cfg).await;
        let h = m.heater("hotend").unwrap();
        h.set_target(210.0).await.unwrap();
        let e = h.wait_for_target().await.unwrap_err();
        assert!(matches!(e, MachineError::Faulted(_)), "{e}");
        let MachineState::Faulted(reason) = m.state() else {
            panic!("{:?}", m.state());
        };
        assert!(
            reason.contains("heater hotend") && reason.contains("thermistor reads open"),
            "{reason}"
        );
        // The module cut it: no power, latched.
        let r = h.read().await.unwrap();
        assert_eq!((r.state, r.power), (HeaterState::Faulted, 0.0), "{r:?}");
        let _ = m.stop().await;
    });
}

/// Pressure advance on the simulated printer (K = 0.04 s, smooth time
/// 0.04 s): while the toolhead cruises, the extruder stands K·v ahead of
/// its nominal position; at rest it is exactly where the G-code says.
#[test]
fn the_extruder_runs_ahead_by_k_times_its_velocity_and_ends_where_it_should() {
    virtual_runtime().unwrap().block_on(async {
        let cfg = printer();
        let m = simulate(&cfg).await;
        m.set_position([10.0, 10.0, 1.0, 0.0]).unwrap();
        m.start_recording().await.unwrap();
        let t0 = m.now_us().await.unwrap();
        // 100 mm of x at 100 mm/s laying 3.4 mm of filament.
        m.goto_via_queue([110.0, 10.0, 1.0, 3.4], 100.0)
            .await
            .unwrap();
        m.idle().await.unwrap();
        let rec = m.take_recording(t0).await.unwrap();
        assert_eq!(rec.axes, ["x", "y", "z", "e"]);
        let mut cruising = 0;
        for s in &rec.planned {
            let nominal = (s.pos[0] - 10.0) * 0.034;
            if (40.0..80.0).contains(&s.pos[0]) {
                // 0.04 s × 3.4 mm/s.
                assert!((s.pos[3] - nominal - 0.136).abs() < 1e-6, "{s:?}");
                cruising += 1;
            }
        }
        assert!(cruising > 100, "{cruising} samples while cruising");
        let end = rec.planned.last().unwrap();
        assert!((end.pos[3] - 3.4).abs() < 1e-9, "{end:?}");
        let done = rec.executed.last().unwrap();
        // Within a microstep (1/400 mm) where the motor stepped to.
        assert!((done.pos[3] - 3.4).abs() <= 0.0025, "{done:?}");
        m.stop().await.unwrap();
    });
}
