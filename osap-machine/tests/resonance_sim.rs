//! `osap_machine::resonance` on simulated modules, in virtual time: the
//! chirp shakes the axis, the simulated accelerometer (the module's own
//! `analog_read`, seeing its carriage through `[sim.axes.NAME]`'s
//! mass-spring mode) is recorded on the synchronized clock, and the mode
//! comes out within 2 % of the model's.

use osap_machine::config::MachineFile;
use osap_machine::resonance::analysis::{model_peak_hz, Peak};
use osap_machine::resonance::{self, measure};
use osap_machine::sim::SimOptions;
use osap_machine::Machine;
use osap_sim::machine::virtual_runtime;

/// A one-axis shaker: 80 full steps/mm at 8 microsteps (1.56 µm), 20 000
/// mm/s², an accelerometer on the motor's module.
fn shaker(freq_hz: f64, damping: f64, range: f64) -> MachineFile {
    MachineFile::parse(&format!(
        r#"
name = "shaker"
[modules]
a = {{ name = "a" }}
[motors.a]
module = "a"
full_steps_per_unit = 80.0
microsteps = 8
[kinematics]
type = "cartesian"
[axes.x]
motor = "a"
min = 0.0
max = 25.0
velocity = 150.0
acceleration = 20000.0
jerk = 1000000.0
homing = {{ switch = "a", direction = "min", search_speed = 20.0, latch_speed = 2.0, backoff = 2.0 }}
accelerometer = {{ module = "a", channel = 1, range = {range} }}
[limits]
velocity = 150.0
acceleration = 20000.0
junction_deviation = 0.02
[sim.axes.x]
start = 3.0
resonance_hz = {freq_hz}
damping_ratio = {damping}
"#
    ))
    .unwrap()
}

async fn start(cfg: &MachineFile) -> Machine {
    Machine::simulate_with(cfg, SimOptions::VIRTUAL)
        .await
        .unwrap()
}

/// Measures the shaker at `freq_hz`, `damping`: (fitted natural
/// frequency, measured peak) relative errors against the model's.
async fn measure_shaker(freq_hz: f64, damping: f64) -> (f64, f64) {
    // The accelerometer's range: the chirp's 18 000 mm/s² through the
    // mode's gain (about 1/2ζ), with room.
    let range = 18_000.0 * (0.75 / damping).max(4.0);
    let cfg = shaker(freq_hz, damping, range);
    let m = start(&cfg).await;
    m.home().await.unwrap();
    let r = measure(&m, "x", 4.0).await.unwrap();
    m.stop().await.unwrap();
    let a = &r.analysis;
    let mode = a
        .mode
        .unwrap_or_else(|| panic!("{freq_hz} Hz ζ {damping}: no mode; peak {:?}", a.peak));
    let Peak::Found { freq_hz: peak, .. } = a.peak else {
        panic!("{freq_hz} Hz ζ {damping}: {:?}", a.peak);
    };
    let model_peak = model_peak_hz(freq_hz, damping);
    println!(
        "{freq_hz:6.1} Hz ζ {damping:4.2}: fitted {:7.3} Hz ζ {:.4} gain {:.3}; peak {peak:7.3} Hz (model's {model_peak:7.3}); shaper {:?}",
        mode.freq_hz,
        mode.damping,
        mode.gain,
        a.recommended.map(|s| s.kind().name())
    );
    (mode.freq_hz / freq_hz - 1.0, peak / model_peak - 1.0)
}

fn spread(cases: &[(f64, f64)]) {
    virtual_runtime().unwrap().block_on(async {
        for &(f, z) in cases {
            let (fit, peak) = measure_shaker(f, z).await;
            assert!(
                fit.abs() < 0.02,
                "{f} Hz ζ {z}: fitted off by {:.2} %",
                fit * 100.0
            );
            assert!(
                peak.abs() < 0.02,
                "{f} Hz ζ {z}: peak off by {:.2} %",
                peak * 100.0
            );
        }
    });
}

// A spread over 20, 45, 80, 120 Hz and damping 0.02, 0.1, 0.2 in two
// halves that run side by side (each case is a 7 s virtual run, about 9 s
// of a core); the analysis alone is tested over a wider spread in
// `resonance::analysis`.

#[test]
fn the_mode_comes_out_within_2_percent_over_a_spread_a() {
    spread(&[(20.0, 0.02), (45.0, 0.1), (120.0, 0.2)]);
}

#[test]
fn the_mode_comes_out_within_2_percent_over_a_spread_b() {
    spread(&[(20.0, 0.2), (80.0, 0.02), (120.0, 0.1)]);
}

/// The plotter's y (38 Hz, ζ 0.1, on its CoreXY belt motor b, at 1
/// microstep): within its range; the files are written and `--write`
/// puts a shaper the machine file accepts.
#[test]
fn the_plotter_measures_y_and_writes_its_shaper() {
    let path = format!(
        "{}/../examples/machines/plotter.toml",
        env!("CARGO_MANIFEST_DIR")
    );
    let cfg = MachineFile::load(&path).unwrap();
    virtual_runtime().unwrap().block_on(async {
        let m = start(&cfg).await;
        m.home().await.unwrap();
        let r = measure(&m, "y", 6.0).await.unwrap();
        m.stop().await.unwrap();
        for l in resonance::summary(&r) {
            println!("{l}");
        }
        let mode = r.analysis.mode.expect("a mode");
        assert!((mode.freq_hz / 38.0 - 1.0).abs() < 0.03, "{mode:?}");
        let dir = std::env::temp_dir().join(format!("osap-resonance-{}", std::process::id()));
        let files = resonance::write(&r, &dir).unwrap();
        for f in &files {
            assert!(std::fs::metadata(f).unwrap().len() > 100, "{}", f.display());
        }
        let copy = dir.join("plotter.toml");
        std::fs::copy(&path, &copy).unwrap();
        let shaper = r.analysis.recommended.expect("a shaper");
        resonance::write_shaper(
            &copy,
            "y",
            &shaper,
            Some("osap-resonance-plotter-y-20261129-143502/run.json"),
        )
        .unwrap();
        let back = MachineFile::load(&copy).unwrap();
        let written = back.axes["y"].shaper.as_ref().unwrap();
        assert_eq!(
            written.fitted_from.as_deref(),
            Some("osap-resonance-plotter-y-20261129-143502/run.json")
        );
        let s = written.config().unwrap();
        assert_eq!(s.kind(), shaper.kind());
        assert!((s.freq_hz() - shaper.freq_hz()).abs() < 0.01);
        // Twice: the line is replaced, not added.
        resonance::write_shaper(&copy, "y", &shaper, None).unwrap();
        let text = std::fs::read_to_string(&copy).unwrap();
        assert_eq!(text.matches("shaper =").count(), 1);
        let _ = std::fs::remove_dir_all(&dir);
    });
}

#[test]
fn an_axis_without_accelerometer_or_homing_is_refused() {
    let mut cfg = shaker(40.0, 0.1, 1e5);
    virtual_runtime().unwrap().block_on(async {
        let m = start(&cfg).await;
        let e = measure(&m, "x", 6.0).await.unwrap_err().to_string();
        assert!(e.contains("home"), "{e}");
        m.stop().await.unwrap();
    });
    cfg.axes.get_mut("x").unwrap().accelerometer = None;
    let e = resonance::Plan::for_axis(&cfg, "x", 6.0)
        .unwrap_err()
        .to_string();
    assert!(e.contains("accelerometer ="), "{e}");
}
