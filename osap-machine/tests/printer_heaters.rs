//! The printer's heaters on simulated modules that run the firmware's own
//! heater logic: set up from the machine file, heated to a target and held
//! there by the module's PID, and cut by the module when their thermistor
//! breaks, which stops the machine naming the heater.

use osap_machine::config::MachineFile;
use osap_machine::sim::SimOptions;
use osap_machine::{HeaterState, Machine, MachineError, MachineState};
use osap_sim::machine::{virtual_runtime, TimeMode};

fn printer() -> MachineFile {
    MachineFile::load(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/machines/printer.toml"
    ))
    .unwrap()
}

async fn simulate(cfg: &MachineFile) -> Machine {
    Machine::simulate_with(
        cfg,
        SimOptions {
            time: TimeMode::Virtual,
        },
    )
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
