//! The SCARA drawing arm (examples/machines/scara.toml) on simulated
//! modules, in virtual time: it homes its two joints on switches pressed
//! by the joints' angles, then draws the shipped SVG end to end, and the
//! pen's path (the motors' stepped positions through the arm's forward
//! kinematics) follows the planned path.

use maxl::blocks::kinematics::{Planar, Scara, Side};
use nalgebra::Vector2;
use osap_machine::config::{Kinematics, MachineFile};
use osap_machine::job::from_svg;
use osap_machine::sim::{joint_form, SimOptions};
use osap_machine::svg::{self, SvgOptions};
use osap_machine::{Machine, MachineEvent};
use osap_sim::machine::virtual_runtime;

fn scara() -> MachineFile {
    MachineFile::load(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/machines/scara.toml"
    ))
    .unwrap()
}

/// The arm's kinematics, built here from the file's numbers (not by the
/// machine), to check the machine against.
fn arm(cfg: &MachineFile) -> Scara {
    let Kinematics::Scara {
        l1, l2, margin_deg, ..
    } = cfg.kinematics
    else {
        panic!("not a scara");
    };
    Scara::new(l1, l2, Side::Right, margin_deg.to_radians()).unwrap()
}

/// Where the simulated pen really is: each joint's angle from its motor's
/// stepped carriage (the simulator's, not the machine's belief), through
/// the arm's forward kinematics.
fn real_pen(m: &Machine, cfg: &MachineFile) -> [f64; 2] {
    let q: Vec<f64> = (0..2)
        .map(|j| {
            let form = joint_form(cfg, j).unwrap();
            m.with_sim(|s| {
                form.value(|module| {
                    s.module(module)
                        .and_then(|sm| sm.module())
                        .map_or(f64::NAN, |sm| sm.lock(|mm| mm.board().motor().position()))
                })
            })
            .unwrap()
        })
        .collect();
    let p = arm(cfg).forward_xy(Vector2::new(q[0], q[1])).unwrap();
    [p.x, p.y]
}

/// One shoulder microstep at the arm's full reach, mm: the resolution the
/// pen can be placed to.
fn microstep_at_reach(cfg: &MachineFile) -> f64 {
    let motor = &cfg.motors["shoulder"];
    400.0 / (motor.full_steps_per_unit * f64::from(motor.microsteps))
}

#[test]
fn the_scara_arm_homes_its_joints_and_draws_the_svg() {
    virtual_runtime().unwrap().block_on(async {
        let cfg = scara();
        let m = Machine::simulate_with(
            &cfg,
            SimOptions::VIRTUAL,
        )
        .await
        .unwrap();
        let mut events = m.events();
        assert!(!m.is_homed());
        m.home().await.unwrap();
        assert!(m.is_homed());
        // Homing leaves the joints backed off their switches: a = -0.70 +
        // 0.15, b = 2.80 - 0.15, and the machine position is that pose's.
        let expect = arm(&cfg).forward_xy(Vector2::new(-0.55, 2.65)).unwrap();
        let p = m.position();
        assert!(
            (p[0] - expect.x).abs() < 1e-6 && (p[1] - expect.y).abs() < 1e-6,
            "{p:?} vs {expect:?}"
        );
        // Where the pen really is: within the latch's edge (a step at
        // 0.03 rad/s) and a microstep of where the machine believes.
        let real = real_pen(&m, &cfg);
        let off = ((real[0] - p[0]).powi(2) + (real[1] - p[1]).powi(2)).sqrt();
        let step = microstep_at_reach(&cfg);
        eprintln!("homed: believed {p:?}, real {real:?}: {off:.4} mm apart (a microstep at reach {step:.4} mm)");
        assert!(off < step, "{off} mm");

        // The shipped drawing (160 × 120 mm), its page's corner at (-80,
        // 150): x -75..75, y 155..265, inside the table.
        let text = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../examples/jobs/drawing.svg"
        ))
        .unwrap();
        let drawing = svg::read(
            &text,
            &SvgOptions {
                offset: [-80.0, 150.0],
                ..SvgOptions::default()
            },
        )
        .unwrap();
        let program = from_svg(&cfg, &drawing, 60.0).unwrap();
        m.start_recording().await.unwrap();
        let t0 = m.now_us().await.unwrap();
        let started = tokio::time::Instant::now();
        m.run_program(&program, |_| {}).await.unwrap();
        m.idle().await.unwrap();
        let took = started.elapsed().as_secs_f64();
        let rec = m.take_recording(t0).await.unwrap();
        assert!(rec.executed.len() > 1000, "{}", rec.executed.len());
        // Every point of the drawing was reached by the pen.
        let reached = |pt: &[f64; 2]| {
            rec.executed
                .iter()
                .map(|s| ((s.pos[0] - pt[0]).powi(2) + (s.pos[1] - pt[1]).powi(2)).sqrt())
                .fold(f64::INFINITY, f64::min)
        };
        let worst_point = drawing
            .polylines
            .iter()
            .flatten()
            .map(reached)
            .fold(0.0, f64::max);
        let errors = rec.following_error();
        eprintln!(
            "drawing.svg on the scara: {took:.1} s, following error {errors:?}, every drawing point within {worst_point:.4} mm of the pen's path"
        );
        for (axis, err) in &errors {
            // The stepped joints through the kinematics against the plan:
            // within a shoulder microstep at full reach (0.079 mm).
            assert!(*err < step, "{axis}: {err} mm");
        }
        // The path passes every point of the drawing within that too.
        assert!(worst_point < step, "{worst_point} mm");
        // At the end the pen really is where the machine says.
        let p = m.position();
        let real = real_pen(&m, &cfg);
        let off = ((real[0] - p[0]).powi(2) + (real[1] - p[1]).powi(2)).sqrt();
        assert!(off < step, "end: {p:?} vs {real:?}");
        while let Ok(e) = events.try_recv() {
            assert!(!matches!(e, MachineEvent::Fault { .. }), "{e:?}");
        }
        m.stop().await.unwrap();
    });
}

/// An elbow switch on the wrong side of straight: homing turns the elbow
/// through the stretched pose and ends it in the other working mode than
/// the file's (`elbow = "right"`, b > 0), where the kinematics would put
/// the same pen position at other joint angles. Homing says so, and the
/// arm stays unhomed (moves are refused) rather than jump.
#[test]
fn an_arm_homed_into_its_other_working_mode_stays_unhomed() {
    virtual_runtime().unwrap().block_on(async {
        let text = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../examples/machines/scara.toml"
        ))
        .unwrap();
        let wrong = text.replace(
            "direction = \"max\", endstop = 2.80",
            "direction = \"min\", endstop = -2.80",
        );
        assert_ne!(wrong, text);
        let cfg = MachineFile::parse(&wrong).unwrap();
        let m = Machine::simulate_with(
            &cfg,
            SimOptions::VIRTUAL,
        )
        .await
        .unwrap();
        let e = m.home().await.unwrap_err();
        assert!(
            matches!(&e, osap_machine::MachineError::Homing { reason, .. } if reason.contains("another working mode")),
            "{e}"
        );
        assert!(!m.is_homed());
        let e = m.goto_via_queue([0.0, 200.0], 50.0).await.unwrap_err();
        assert!(matches!(e, osap_machine::MachineError::NotHomed(_)), "{e}");
        m.stop().await.unwrap();
    });
}
