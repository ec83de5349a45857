//! Homing the axes of one order together, on simulated modules in virtual
//! time: the home position does not depend on the search speed (5 to
//! 100 mm/s, to a microstep), CoreXY's x and y search together and each
//! stops at its own switch, and a switch that never closes, one pressed
//! for good, or a fault during the combined search stops every motor and
//! says why.

use osap_machine::config::MachineFile;
use osap_machine::sim::SimOptions;
use osap_machine::{Machine, MachineError, MachineEvent, MachineState};
use osap_sim::machine::{virtual_runtime, Fault};
use std::time::Duration;

fn load(name: &str) -> MachineFile {
    MachineFile::load(format!(
        "{}/../examples/machines/{name}.toml",
        env!("CARGO_MANIFEST_DIR")
    ))
    .unwrap()
}

/// The file's x and y searching at `speed` (mm/s), on one order.
fn searching_at(mut cfg: MachineFile, speed: f64) -> MachineFile {
    for axis in ["x", "y"] {
        let h = cfg.axes.get_mut(axis).unwrap().homing.as_mut().unwrap();
        h.search_speed = speed;
        h.order = 1;
    }
    cfg.validate().unwrap();
    cfg
}

/// One microstep of motor `motor`, in axis units.
fn microstep(cfg: &MachineFile, motor: &str) -> f64 {
    let m = &cfg.motors[motor];
    1.0 / (m.full_steps_per_unit * f64::from(m.microsteps))
}

/// Where the simulated carriage stands on x and y.
fn carriage(m: &Machine) -> [f64; 2] {
    [
        m.sim_axis_position("x").unwrap(),
        m.sim_axis_position("y").unwrap(),
    ]
}

/// The shipped plotter (CoreXY: GT2 belts on 20-tooth pulleys, 16
/// microsteps, 12.5 µm a microstep) homed with x and y searching together
/// at 5 to 100 mm/s: the carriage ends at the same place to within one
/// microstep, and where the machine says it is. Also prints how long
/// homing took (virtual time) and how far the carriage ran past each
/// switch before it stopped.
#[test]
fn the_home_position_is_the_same_at_search_speeds_from_5_to_100_mm_s() {
    virtual_runtime().unwrap().block_on(async {
        let mut homes: Vec<(f64, [f64; 2])> = Vec::new();
        for speed in [5.0, 10.0, 20.0, 50.0, 100.0] {
            let cfg = searching_at(load("plotter"), speed);
            let step = microstep(&cfg, "a");
            let m = Machine::simulate_with(&cfg, SimOptions::VIRTUAL).await.unwrap();
            m.start_recording().await.unwrap();
            let t0 = m.now_us().await.unwrap();
            m.home().await.unwrap();
            let took = (m.now_us().await.unwrap() - t0) as f64 * 1e-6;
            let rec = m.take_recording(t0).await.unwrap();
            let p = m.position();
            let real = carriage(&m);
            for k in 0..2 {
                assert!(
                    (real[k] - p[k]).abs() <= step,
                    "{speed} mm/s, axis {k}: machine {} carriage {}",
                    p[k],
                    real[k]
                );
            }
            // The switches sit at -1 (the default endstop): how far past
            // them the carriage went, as the motors stepped.
            let past: Vec<f64> = (0..2)
                .map(|k| {
                    let low = rec
                        .executed
                        .iter()
                        .map(|s| s.pos[k])
                        .fold(f64::INFINITY, f64::min);
                    -1.0 - low
                })
                .collect();
            println!(
                "search {speed:5.1} mm/s: homed in {took:.2} s; carriage at ({:.5}, {:.5}); past the switches x {:.2} mm, y {:.2} mm",
                real[0], real[1], past[0], past[1]
            );
            homes.push((speed, real));
            m.stop().await.unwrap();
        }
        for k in 0..2 {
            let (lo, hi) = homes
                .iter()
                .map(|h| h.1[k])
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
                    (lo.min(v), hi.max(v))
                });
            let step = microstep(&load("plotter"), "a");
            assert!(
                hi - lo <= step,
                "axis {k}: homes from {lo} to {hi} over the speeds, one microstep {step}: {homes:?}"
            );
        }
    });
}

/// CoreXY x and y on one order search together: both move from the
/// start, each stops at its own switch, and the one still searching goes
/// on alone. Both presses were expected (no fault), and homing takes
/// about as long as the longer axis alone.
#[test]
fn corexy_x_and_y_search_together_and_each_stops_at_its_switch() {
    virtual_runtime().unwrap().block_on(async {
        let cfg = searching_at(load("plotter"), 100.0);
        let m = Machine::simulate_with(&cfg, SimOptions::VIRTUAL)
            .await
            .unwrap();
        let mut events = m.events();
        m.start_recording().await.unwrap();
        let t0 = m.now_us().await.unwrap();
        m.home().await.unwrap();
        let rec = m.take_recording(t0).await.unwrap();
        let mut presses = Vec::new();
        while let Ok(e) = events.try_recv() {
            match e {
                MachineEvent::Limit {
                    module,
                    pressed: true,
                    expected,
                    time,
                } => {
                    assert!(expected, "{module}");
                    presses.push((module, time));
                }
                MachineEvent::Fault { .. } | MachineEvent::LinkLost { .. } => panic!("{e:?}"),
                _ => {}
            }
        }
        // Each switch pressed twice: in the search, y's switch first (from
        // the middle of the sheet, (100, 75), it is nearer); then both in
        // the latch, which starts both axes the same distance off their
        // switches, so the two latch edges come within microseconds of
        // each other, in either order.
        let order: Vec<&str> = presses.iter().map(|p| p.0.as_str()).collect();
        assert_eq!(order.len(), 4, "{presses:?}");
        assert_eq!(order[..2], ["b", "a"], "{presses:?}");
        let mut latch = order[2..].to_vec();
        latch.sort_unstable();
        assert_eq!(latch, ["a", "b"], "{presses:?}");
        // Both axes were moving toward their switches at once: a moment in
        // the first search when x and y both ran at the search speed
        // (10 ms of samples).
        let together = rec.executed.windows(11).any(|w| {
            let v = |k: usize| (w[10].pos[k] - w[0].pos[k]) / (w[10].t - w[0].t);
            (v(0) + 100.0).abs() < 1.0 && (v(1) + 100.0).abs() < 1.0
        });
        assert!(together, "x and y never searched at once");
        // And x went on alone after y's switch: x at speed, y standing.
        let alone = rec.executed.windows(11).any(|w| {
            let v = |k: usize| (w[10].pos[k] - w[0].pos[k]) / (w[10].t - w[0].t);
            (v(0) + 100.0).abs() < 1.0 && v(1).abs() < 1.0
        });
        assert!(alone, "x never searched alone after y's switch");
        assert!(m.is_homed());
        m.stop().await.unwrap();
    });
}

/// y's switch never closes (a broken wire: the simulation has no switch
/// on module b): x homes, y runs its whole search and stops there, and
/// homing fails naming y and its module; nothing counts as homed.
#[test]
fn a_switch_that_never_closes_stops_the_combined_search_and_says_which() {
    virtual_runtime().unwrap().block_on(async {
        let cfg = searching_at(load("plotter"), 100.0);
        let mut spec = osap_machine::sim::spec(&cfg).unwrap();
        spec.switches.retain(|s| s.module != "b");
        let m = Machine::simulate_on(&cfg, &spec, SimOptions::VIRTUAL)
            .await
            .unwrap();
        let start = carriage(&m);
        let e = m.home().await.unwrap_err();
        let MachineError::Homing { axis, reason } = &e else {
            panic!("{e}")
        };
        assert_eq!(axis, "y", "{e}");
        assert!(
            reason.contains("module b was not pressed within 168.0 units"),
            "{e}"
        );
        assert_eq!(m.homed(), [false, false]);
        assert_eq!(m.state(), MachineState::Idle);
        // y went its whole search (150 × 1.1 + 1 + 2 = 168 mm) and no
        // further; everything stands.
        let end = carriage(&m);
        let step = microstep(&cfg, "a");
        assert!(
            (start[1] - end[1] - 168.0).abs() <= step,
            "y from {} to {}",
            start[1],
            end[1]
        );
        tokio::time::sleep(Duration::from_millis(300)).await;
        assert_eq!(carriage(&m), end);
        m.stop().await.unwrap();
    });
}

/// x's switch reads pressed at start and stays pressed when x moves off
/// it (a switch stuck closed: the simulation's closes anywhere below
/// x = 150, and the carriage starts at 100): homing moves x off by twice
/// the backoff, stops, and fails naming x; y did not search.
#[test]
fn a_switch_that_stays_pressed_stops_homing_before_the_search() {
    virtual_runtime().unwrap().block_on(async {
        let cfg = searching_at(load("plotter"), 100.0);
        let mut spec = osap_machine::sim::spec(&cfg).unwrap();
        for s in spec.switches.iter_mut().filter(|s| s.module == "a") {
            s.at = 150.0;
        }
        let m = Machine::simulate_on(&cfg, &spec, SimOptions::VIRTUAL)
            .await
            .unwrap();
        assert!(m.switch_pressed("a"));
        let start = carriage(&m);
        let e = m.home().await.unwrap_err();
        let MachineError::Homing { axis, reason } = &e else {
            panic!("{e}")
        };
        assert_eq!(axis, "x", "{e}");
        assert!(
            reason.contains("module a stays pressed after moving 4 units off it"),
            "{e}"
        );
        assert_eq!(m.homed(), [false, false]);
        assert_eq!(m.state(), MachineState::Idle);
        let end = carriage(&m);
        let step = microstep(&cfg, "a");
        assert!((end[0] - start[0] - 4.0).abs() <= step, "{start:?} {end:?}");
        assert!((end[1] - start[1]).abs() <= step, "{start:?} {end:?}");
        m.stop().await.unwrap();
    });
}

/// During the mill's combined x-y search, z's switch (z homed first, and
/// stands off it) is pressed: a crash. Every motor stops at once, the
/// machine is faulted, and homing fails with the reason.
#[test]
fn a_crash_during_the_combined_search_stops_every_motor() {
    virtual_runtime().unwrap().block_on(async {
        let cfg = load("mill");
        let m = Machine::simulate_with(&cfg, SimOptions::VIRTUAL)
            .await
            .unwrap();
        let mut events = m.events();
        let mut stops = m.events();
        let crash = async {
            loop {
                if let Ok(MachineEvent::Homed { axis }) = events.recv().await {
                    if axis == "z" {
                        break;
                    }
                }
            }
            // x and y search from the middle of the table: 0.3 s in,
            // both still move.
            tokio::time::sleep(Duration::from_millis(300)).await;
            assert_eq!(m.state(), MachineState::Homing);
            assert!(m.sim_press_limit("z"));
        };
        let (homed, ()) = tokio::join!(m.home(), crash);
        let e = homed.unwrap_err();
        assert!(
            matches!(&e, MachineError::Faulted(r) if r.contains("limit switch on module z")),
            "{e}"
        );
        assert!(matches!(m.state(), MachineState::Faulted(_)));
        // The emergency stop's report: every module halted (the motors
        // stand where they are).
        let report = loop {
            if let Ok(MachineEvent::Stop(report)) = stops.recv().await {
                break report;
            }
        };
        assert!(report.unreachable.is_empty(), "{report}");
        let at = [
            m.sim_axis_position("x").unwrap(),
            m.sim_axis_position("y").unwrap(),
        ];
        tokio::time::sleep(Duration::from_millis(300)).await;
        assert_eq!(
            [
                m.sim_axis_position("x").unwrap(),
                m.sim_axis_position("y").unwrap()
            ],
            at
        );
        // The crash un-homes every axis (z too): where they stand is known
        // only to a step count now.
        assert_eq!(m.homed(), [false, false, false]);
        m.stop().await.unwrap();
    });
}

/// Module b stops answering during the plotter's combined search: the
/// machine faults (every other module halted), and homing fails with the
/// reason.
#[test]
fn a_module_lost_during_the_combined_search_faults_the_machine() {
    virtual_runtime().unwrap().block_on(async {
        let cfg = searching_at(load("plotter"), 20.0);
        let m = Machine::simulate_with(&cfg, SimOptions::VIRTUAL)
            .await
            .unwrap();
        let lose = async {
            // From the middle of the sheet at 20 mm/s: seconds of search.
            tokio::time::sleep(Duration::from_millis(500)).await;
            assert_eq!(m.state(), MachineState::Homing);
            let faults = m.with_sim(|s| s.injector()).unwrap();
            faults.inject(&Fault::Freeze("b".into())).await.unwrap();
        };
        let (homed, ()) = tokio::join!(m.home(), lose);
        let e = homed.unwrap_err();
        assert!(
            matches!(&e, MachineError::Faulted(r) if r.contains("module b")),
            "{e}"
        );
        assert!(matches!(m.state(), MachineState::Faulted(_)));
        assert_eq!(m.homed(), [false, false]);
        let _ = m.stop().await;
    });
}
