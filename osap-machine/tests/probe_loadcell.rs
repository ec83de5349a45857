//! A load-cell probe (`[probe] loadcell`) on the simulated mill, in virtual
//! time: `probe_down` makes a comparator on the z module that halts z in
//! the module's own loop when the nozzle presses the bed, finds the bed
//! where it is to the comparator's threshold and stop, leaves the machine
//! running where the motors stopped, and takes its block away again.

use osap_machine::config::MachineFile;
use osap_machine::sim::SimOptions;
use osap_machine::{Machine, MachineState};
use osap_sim::machine::virtual_runtime;

/// The mill with a flat bed at z = -70 and a load cell on the z module:
/// 1 N trips it, the bed and gantry push back 40 N/mm in the simulator.
fn mill_with_loadcell_probe() -> MachineFile {
    let path = format!(
        "{}/../examples/machines/mill.toml",
        env!("CARGO_MANIFEST_DIR")
    );
    let text = std::fs::read_to_string(path).unwrap();
    let text = text
        .replace("tilt_x = 0.001 ", "tilt_x = 0.0 ")
        .replace("tilt_y = -0.0015 ", "tilt_y = 0.0 ")
        .replace("warp = 0.15 ", "warp = 0.0 ")
        .replace(
            "travel_speed = 40.0 ",
            "loadcell = { data_pin = 2, clock_pin = 3, newtons_per_count = 0.0005 }\ntravel_speed = 40.0 ",
        );
    let mut cfg = MachineFile::parse(&text).unwrap();
    assert!(cfg.probe.as_ref().unwrap().loadcell.is_some());
    cfg.bed_mesh = None;
    // z at 16 microsteps (the file's 8 is coarser than a mill is built).
    cfg.motors.get_mut("z").unwrap().microsteps = 16;
    cfg.validate().unwrap();
    cfg
}

#[test]
fn a_load_cell_probe_stops_z_by_reflex_and_the_machine_goes_on() {
    virtual_runtime().unwrap().block_on(async {
        let cfg = mill_with_loadcell_probe();
        let m = Machine::simulate_with(&cfg, SimOptions::VIRTUAL)
            .await
            .unwrap();
        // The simulated carriage starts mid-travel: say so.
        m.set_position([150.0, 100.0, -40.0]).unwrap();
        m.goto_now([150.0, 100.0, -67.0], 10.0).await.unwrap();
        m.idle().await.unwrap();

        let (_, at) = m
            .probe_down("z", 7.0, 2.0)
            .await
            .unwrap()
            .expect("it touched");
        // 1 N is 0.025 mm into a 40 N/mm bed; the comparator then stops z
        // within 6 ms (docs/pipes.md §7), 0.012 mm at 2 mm/s, to a
        // microstep.
        let z = at[2];
        let step =
            1.0 / (cfg.motors["z"].full_steps_per_unit * f64::from(cfg.motors["z"].microsteps));
        assert!(
            z <= -70.025 + step && z >= -70.025 - 0.012 - step,
            "the probe stopped at z = {z:.4} over a bed at -70"
        );
        assert_eq!(
            m.state(),
            MachineState::Idle,
            "an expected halt is no fault"
        );
        // The machine stands where its motors do and moves on.
        m.goto_now([150.0, 100.0, -67.0], 10.0).await.unwrap();
        m.idle().await.unwrap();
        assert!((m.position()[2] + 67.0).abs() < 1e-9);
        // The comparator went with its search.
        let manager = m.manager().lock().await;
        assert!(manager.som().runtimes.iter().all(|r| r.blocks.is_empty()));
        drop(manager);
        // A second search finds the same bed.
        let (_, again) = m
            .probe_down("z", 7.0, 2.0)
            .await
            .unwrap()
            .expect("it touched");
        // Two searches differ by where the touch falls in the cell's
        // conversion period: within the stop window above.
        assert!(
            (again[2] - z).abs() <= 0.012 + step,
            "{} then {z}",
            again[2]
        );
        m.stop().await.unwrap();
    });
}

/// `osap level`'s flow (`level::level`) probes the whole grid by reflex:
/// over a flat bed, every point reads the same height to the probe's
/// repeatability, and the fitted mesh is flat.
#[test]
fn levelling_with_a_load_cell_probe_finds_a_flat_bed_flat() {
    virtual_runtime().unwrap().block_on(async {
        let cfg = mill_with_loadcell_probe();
        let m = Machine::simulate_with(&cfg, SimOptions::VIRTUAL)
            .await
            .unwrap();
        m.home().await.unwrap();
        let levelled = osap_machine::level::level(&m, |_, _| {}).await.unwrap();
        let [nx, ny] = cfg.probe.as_ref().unwrap().grid;
        assert_eq!(levelled.points.len(), nx * ny);
        let step =
            1.0 / (cfg.motors["z"].full_steps_per_unit * f64::from(cfg.motors["z"].microsteps));
        for p in &levelled.points {
            assert!(
                p.z <= -70.025 + step && p.z >= -70.025 - 0.012 - step,
                "point ({}, {}) at z = {:.4} over a bed at -70",
                p.ix,
                p.iy,
                p.z
            );
        }
        assert!(levelled.stats.rms < 0.01, "{:?}", levelled.stats);
        assert_eq!(m.state(), MachineState::Idle);
        m.stop().await.unwrap();
    });
}

/// A load cell the file cannot have is refused, naming the key.
#[test]
fn a_wrong_load_cell_is_refused_by_key() {
    let path = format!(
        "{}/../examples/machines/mill.toml",
        env!("CARGO_MANIFEST_DIR")
    );
    let text = std::fs::read_to_string(path).unwrap();
    let with = |cell: &str| {
        MachineFile::parse(&text.replace(
            "travel_speed = 40.0 ",
            &format!("loadcell = {cell}\ntravel_speed = 40.0 "),
        ))
        .unwrap_err()
        .to_string()
    };
    let e = with("{ data_pin = 9, clock_pin = 3, newtons_per_count = 0.0005 }");
    assert!(
        e.contains("probe.loadcell.data_pin") && e.contains("pins 0 to 3"),
        "{e}"
    );
    let e = with("{ data_pin = 2, clock_pin = 2, newtons_per_count = 0.0005 }");
    assert!(e.contains("probe.loadcell.clock_pin"), "{e}");
    let e = with("{ data_pin = 2, clock_pin = 3, newtons_per_count = 0.0005, threshold_n = -1.0 }");
    assert!(e.contains("probe.loadcell.threshold_n"), "{e}");
}

/// z homes down onto the bed with the load cell (`probe = true`): the
/// touch becomes the bed's z, and a probe afterwards finds the bed there.
#[test]
fn z_homes_on_the_bed_with_the_load_cell() {
    virtual_runtime().unwrap().block_on(async {
        let mut cfg = mill_with_loadcell_probe();
        let homing = cfg.axes.get_mut("z").unwrap().homing.as_mut().unwrap();
        homing.switch = None;
        homing.latch_speed = None;
        homing.probe = true;
        homing.direction = osap_machine::config::Direction::Min;
        homing.endstop = Some(-70.0);
        homing.search_speed = 5.0;
        homing.backoff = 3.0;
        // x and y first: z comes down over the bed.
        homing.order = 3;
        cfg.validate().unwrap();
        let m = Machine::simulate_with(&cfg, SimOptions::VIRTUAL)
            .await
            .unwrap();
        m.home().await.unwrap();
        assert!(m.homed().iter().all(|h| *h));
        assert!((m.position()[2] + 67.0).abs() < 1e-9, "{:?}", m.position());
        // The touch at 5 mm/s reads -70; a probe at 2 mm/s stops a little
        // sooner past the threshold: within 0.02 mm of it.
        let (_, at) = m
            .probe_down("z", 7.0, 2.0)
            .await
            .unwrap()
            .expect("it touched");
        assert!(
            (at[2] + 70.0).abs() < 0.02,
            "the bed after homing is at {}",
            at[2]
        );
        m.stop().await.unwrap();
    });
}
