//! Homing switches beyond the soft travel, on simulated modules in virtual
//! time: a job may visit every point of the travel without touching a
//! switch, a move past the travel still crash-stops on the switch, homing
//! puts the machine where its carriage really is to within a microstep,
//! and homing or probing one axis expects a press on its own switch only.

use osap_machine::config::MachineFile;
use osap_machine::job::{from_gcode, from_svg};
use osap_machine::sim::SimOptions;
use osap_machine::{Machine, MachineError, MachineEvent, MachineState};
use osap_sim::machine::virtual_runtime;
use tokio::sync::broadcast;

fn load(name: &str) -> MachineFile {
    MachineFile::load(format!(
        "{}/../examples/machines/{name}.toml",
        env!("CARGO_MANIFEST_DIR")
    ))
    .unwrap()
}

async fn start(cfg: &MachineFile) -> Machine {
    Machine::simulate_with(cfg, SimOptions::VIRTUAL)
        .await
        .unwrap()
}

/// One microstep of motor `motor`, in axis units.
fn microstep(cfg: &MachineFile, motor: &str) -> f64 {
    let m = &cfg.motors[motor];
    1.0 / (m.full_steps_per_unit * f64::from(m.microsteps))
}

/// The limit presses and faults among `events` so far.
fn presses_and_faults(events: &mut broadcast::Receiver<MachineEvent>) -> Vec<MachineEvent> {
    let mut seen = Vec::new();
    while let Ok(e) = events.try_recv() {
        if matches!(
            e,
            MachineEvent::Limit { pressed: true, .. }
                | MachineEvent::Fault { .. }
                | MachineEvent::LinkLost { .. }
        ) {
            seen.push(e);
        }
    }
    seen
}

/// The shipped plotter's travel corners, a G-code part and an SVG drawing
/// that reach them: no switch is touched, since the switches sit 1 mm
/// beyond the travel (the default endstop).
#[test]
fn plotter_jobs_reach_every_corner_of_the_travel_without_a_limit_fault() {
    virtual_runtime().unwrap().block_on(async {
        let cfg = load("plotter");
        let m = start(&cfg).await;
        m.home().await.unwrap();
        let mut events = m.events();
        m.start_recording().await.unwrap();
        let t0 = m.now_us().await.unwrap();

        // A part outline over the whole sheet that returns to X0 Y0.
        let gcode = "G21 G90\nG0 X0 Y0\nG1 X200 Y0 F3000\nG1 X200 Y150\nG1 X0 Y150\n\
                     G1 X0 Y0\nG0 X100 Y75\nG0 X0 Y0\nM30\n";
        let job = osap_machine::gcode::read(gcode).unwrap();
        let part = from_gcode(&cfg, &job, &m.position()).unwrap();
        m.run_program(&part, |_| {}).await.unwrap();
        assert_eq!(m.position(), vec![0.0, 0.0]);

        // A drawing whose frame is the page's edge, the page the sheet.
        let svg = r#"<svg xmlns="http://www.w3.org/2000/svg" width="200mm" height="150mm" viewBox="0 0 200 150">
            <path d="M 0 0 H 200 V 150 H 0 Z M 0 0 L 200 150" fill="none" stroke="black"/>
        </svg>"#;
        let drawing = osap_machine::svg::read(svg, &Default::default()).unwrap();
        let program = from_svg(&cfg, &drawing, 100.0).unwrap();
        m.run_program(&program, |_| {}).await.unwrap();
        m.goto_now([0.0, 0.0], 100.0).await.unwrap();

        let seen = presses_and_faults(&mut events);
        assert!(seen.is_empty(), "{seen:?}");
        assert_eq!(m.state(), MachineState::Idle);
        // The motors really went to every corner, to a step.
        let rec = m.take_recording(t0).await.unwrap();
        let step = microstep(&cfg, "a");
        for [x, y] in [[0.0, 0.0], [200.0, 0.0], [200.0, 150.0], [0.0, 150.0]] {
            let near = rec
                .executed
                .iter()
                .map(|s| (s.pos[0] - x).abs().max((s.pos[1] - y).abs()))
                .fold(f64::INFINITY, f64::min);
            assert!(near <= step, "corner ({x}, {y}): nearest {near} mm");
        }
        // And the carriage stands at the corner the switches are beyond.
        for axis in ["x", "y"] {
            let real = m.sim_axis_position(axis).unwrap();
            assert!(real.abs() <= step, "{axis}: carriage at {real}");
        }
        m.stop().await.unwrap();
    });
}

/// A move past the travel into the switch (the machine told a wrong
/// position, so the soft limits pass it) still crash-stops at the switch.
#[test]
fn a_move_past_the_travel_into_the_switch_still_crash_stops() {
    virtual_runtime().unwrap().block_on(async {
        let cfg = load("plotter");
        let m = start(&cfg).await;
        m.home().await.unwrap();
        m.goto_now([0.0, 75.0], 100.0).await.unwrap();
        let mut events = m.events();
        // Wrong: the carriage is at x = 0, so going to x = 0 from a
        // believed 3 drives it 3 mm out, through the switch at -1.
        m.set_position([3.0, 75.0]).unwrap();
        m.goto_via_queue([0.0, 75.0], 50.0).await.unwrap();
        let e = m.idle().await.unwrap_err();
        assert!(
            matches!(&e, MachineError::Faulted(r) if r.contains("limit switch on module a")),
            "{e}"
        );
        let hit = presses_and_faults(&mut events).into_iter().any(|e| {
            matches!(&e, MachineEvent::Limit { module, pressed: true, expected: false, .. } if module == "a")
        });
        assert!(hit);
        // Stopped at the switch (1 mm past the edge), not 3 mm out: within
        // the stopping distance machine_sim.rs allows a crash stop (1 mm).
        let real = m.sim_axis_position("x").unwrap();
        assert!(real <= -1.0 && real > -2.0, "x stopped at {real}");
        m.recover().await.unwrap();
        let e = m.goto_now([100.0, 75.0], 50.0).await.unwrap_err();
        assert!(matches!(e, MachineError::NotHomed(_)), "{e}");
        m.stop().await.unwrap();
    });
}

/// After homing, the machine's position is the carriage's to within one
/// microstep, homing to min (plotter x and y, CoreXY; xylophone x) and to
/// max (xylophone y).
#[test]
fn homing_puts_the_machine_where_the_carriage_is_to_a_microstep() {
    virtual_runtime().unwrap().block_on(async {
        for (name, motors) in [("plotter", ["a", "b"]), ("xylophone", ["x", "y"])] {
            let cfg = load(name);
            let m = start(&cfg).await;
            m.home().await.unwrap();
            let p = m.position();
            for (k, axis) in ["x", "y"].iter().enumerate() {
                let a = &cfg.axes[*axis];
                let homing = a.homing.as_ref().unwrap();
                assert_eq!(p[k], homing.homed_position(a), "{name} {axis}");
                let real = m.sim_axis_position(axis).unwrap();
                let step = microstep(&cfg, motors[k]);
                println!(
                    "{name} {axis} ({:?}): machine {} carriage {real} ({:.2} microsteps)",
                    homing.direction,
                    p[k],
                    (real - p[k]) / step
                );
                assert!(
                    (real - p[k]).abs() <= step,
                    "{name} {axis}: machine {} carriage {real}, one microstep {step}",
                    p[k]
                );
            }
            m.stop().await.unwrap();
        }
    });
}

/// While y homes, only y's switch may be pressed: a press on x's stops the
/// machine.
#[test]
fn homing_one_axis_expects_only_its_own_switch() {
    virtual_runtime().unwrap().block_on(async {
        let cfg = load("plotter");
        let m = start(&cfg).await;
        m.home_axes(&["x"]).await.unwrap();
        let mut events = m.events();
        let other = async {
            // y's search from mid-travel takes 1.5 s at 50 mm/s: 0.5 s in,
            // it is still seeking.
            tokio::time::sleep(std::time::Duration::from_millis(500)).await;
            assert_eq!(m.state(), MachineState::Homing);
            assert!(m.sim_press_limit("a"));
        };
        let (homed, ()) = tokio::join!(m.home_axes(&["y"]), other);
        let e = homed.unwrap_err();
        assert!(
            matches!(&e, MachineError::Faulted(r) if r.contains("limit switch on module a")),
            "{e}"
        );
        let hit = presses_and_faults(&mut events).into_iter().any(|e| {
            matches!(&e, MachineEvent::Limit { module, pressed: true, expected: false, .. } if module == "a")
        });
        assert!(hit);
        assert!(matches!(m.state(), MachineState::Faulted(_)));
        m.stop().await.unwrap();
    });
}

/// While z probes the bed, only the probe's switch may be pressed: a press
/// on x's homing switch stops the machine.
#[test]
fn probing_expects_only_the_probe() {
    virtual_runtime().unwrap().block_on(async {
        let mut cfg = load("mill");
        cfg.bed_mesh = None;
        let m = start(&cfg).await;
        // The simulated carriage starts mid-travel: say so.
        m.set_position([150.0, 100.0, -40.0]).unwrap();
        let other = async {
            // The bed is 30 mm down at 2 mm/s: 0.5 s in, it is still
            // searching.
            tokio::time::sleep(std::time::Duration::from_millis(500)).await;
            assert!(m.sim_press_limit("x"));
        };
        let (probed, ()) = tokio::join!(m.probe_down("z", 35.0, 2.0), other);
        let e = probed.unwrap_err();
        assert!(
            matches!(&e, MachineError::Faulted(r) if r.contains("limit switch on module x")),
            "{e}"
        );
        m.stop().await.unwrap();
    });
}
