//! `heater_tune` on the simulated printer's hotend (the module's own
//! heater logic on the thermal model of `[sim.heaters.hotend]`, virtual
//! time): the relay test finds gains in the band the block's physics
//! gives, and a thermistor that breaks mid-tune ends it with the heater
//! cut.

use std::time::Instant;

use osap_machine::config::MachineFile;
use osap_machine::heater_tune::{self, TuneOptions, MIN_PEAKS, TUNE_DELTA_C};
use osap_machine::sim::SimOptions;
use osap_machine::{HeaterState, Machine};
use osap_sim::machine::virtual_runtime;

const PRINTER: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../examples/machines/printer.toml"
);

async fn simulate(cfg: &MachineFile) -> Machine {
    Machine::simulate_with(cfg, SimOptions::VIRTUAL)
        .await
        .unwrap()
}

#[test]
fn the_hotends_tuned_gains_heat_it_and_hold_its_target() {
    let wall = Instant::now();
    let cfg = MachineFile::load(PRINTER).unwrap();
    let res = virtual_runtime().unwrap().block_on(async {
        let m = simulate(&cfg).await;
        let start = tokio::time::Instant::now();
        let res = heater_tune::tune(&m, "hotend", &TuneOptions::new(210.0))
            .await
            .unwrap();
        let took = start.elapsed().as_secs_f64();
        // The heater is left off.
        let r = m.heater("hotend").unwrap().read().await.unwrap();
        assert_eq!((r.state, r.power), (HeaterState::Off, 0.0), "{r:?}");
        m.stop().await.unwrap();
        eprintln!(
            "tuned in {took:.0} s of machine time, {:.1} s wall: {res:?}",
            wall.elapsed().as_secs_f64()
        );
        // Heat-up from 25 °C at ≤ 40/13 °C/s (≥ 60 s), then five cycles
        // of about 6.6 s.
        assert!((80.0..160.0).contains(&took), "{took} s");
        res
    });
    assert_eq!(res.peaks.len(), MIN_PEAKS);
    // The relay swings the 5 °C band, plus what the block rises past an
    // edge in a reading's and a call's latency (≤ 0.3 s at ≤ 1.7 °C/s).
    let half = TUNE_DELTA_C / 2.0;
    assert!((half..half + 0.6).contains(&res.amplitude_c), "{res:?}");
    // 5 °C up at (40 − 0.12·182.5)/13 = 1.39 °C/s and down at 1.68 °C/s:
    // 6.6 s, plus the overshoots' time.
    assert!((6.4..8.0).contains(&res.period_s), "{res:?}");
    // Hence kp = 0.6·4·255/(π·a) for a in that band, and ki, kd from Tu.
    let g = res.gains;
    assert!((60.0..78.0).contains(&g.kp), "{g:?}");
    assert!((14.0..25.0).contains(&g.ki), "{g:?}");
    assert!((45.0..80.0).contains(&g.kd), "{g:?}");

    // Holding with gains: `printer_heaters` (the file's gains), and the
    // written gains load back: `osap-cli/tests/heater_tune.rs`. The
    // simulated block has no sensor lag, so a hold test passes with stiff
    // gains too: it could not tell these from worse ones.
    eprintln!("wall time {:.1} s", wall.elapsed().as_secs_f64());
}

#[test]
fn a_thermistor_that_breaks_during_the_tune_ends_it_with_the_heater_cut() {
    let text = std::fs::read_to_string(PRINTER).unwrap().replace(
        "loss_w_per_k = 0.12          # holds 210 °C at about 55 % duty",
        "loss_w_per_k = 0.12\nsensor_fails_at_s = 20.0",
    );
    let cfg = MachineFile::parse(&text).unwrap();
    virtual_runtime().unwrap().block_on(async {
        let m = simulate(&cfg).await;
        let e = heater_tune::tune(&m, "hotend", &TuneOptions::new(210.0))
            .await
            .unwrap_err();
        // The module's fault report or the heater's own state, whichever
        // the test sees first: either names the hotend.
        assert!(e.to_string().contains("hotend"), "{e}");
        let r = m.heater("hotend").unwrap().read().await.unwrap();
        assert_eq!((r.state, r.power), (HeaterState::Faulted, 0.0), "{r:?}");
        let _ = m.stop().await;
    });
}
