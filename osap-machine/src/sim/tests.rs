//! The simulated machines the example machine files derive.

use super::*;
use osap_host::som::Manager;
use osap_host::{Host, HostConfig};
use osap_sim::machine::{virtual_runtime, SimMachine, TimeMode};
use std::path::PathBuf;

fn example(name: &str) -> MachineFile {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../examples/machines")
        .join(name);
    MachineFile::load(path).unwrap()
}

fn parse(text: &str) -> MachineFile {
    MachineFile::parse(text).unwrap()
}

fn err(cfg: &MachineFile) -> (String, String) {
    let e = spec(cfg).unwrap_err();
    (e.key().unwrap_or("").to_string(), e.to_string())
}

/// The module on hub link `k`.
fn on_hub_link(t: &SimSpec, k: usize) -> &str {
    let l = &t.links[t.links_of(HUB)[k]];
    if l.a == HUB {
        &l.b
    } else {
        &l.a
    }
}

/// Where the machine believes it stands at boot (0 in the travel, else
/// min), as the machine layer takes it.
fn believed_boot(cfg: &MachineFile, axis: &str) -> f64 {
    let a = &cfg.axes[axis];
    if a.min <= 0.0 && 0.0 <= a.max {
        0.0
    } else {
        a.min
    }
}

/// What the machine sends each motor (by simulated module name) to go
/// to believed `x, y` on a corexy machine, from believed `p0`.
fn corexy_motors(cfg: &MachineFile, x: f64, y: f64) -> BTreeMap<String, f64> {
    let (x0, y0) = (believed_boot(cfg, "x"), believed_boot(cfg, "y"));
    let q = |x: f64, y: f64| [x + y, x - y];
    let (q, q0) = (q(x, y), q(x0, y0));
    let Kinematics::CoreXy { motors } = &cfg.kinematics else {
        panic!("corexy");
    };
    motors
        .iter()
        .enumerate()
        .map(|(i, m)| {
            let motor = &cfg.motors[m];
            let s = if motor.invert { -1.0 } else { 1.0 };
            // m_i = s_i·q_i(p) − o_i, o_i = s_i·q_i(p0).
            let name = module_name(cfg, &motor.module).unwrap().to_string();
            (name, s * q[i] - s * q0[i])
        })
        .collect()
}

#[test]
fn the_plotter_derives() {
    let cfg = example("plotter.toml");
    let t = spec(&cfg).unwrap();
    assert_eq!(t.name, "plotter");
    let names: Vec<&str> = t.modules.iter().map(|m| m.name.as_str()).collect();
    assert_eq!(names, ["hub", "a", "b", "z"]);
    assert_eq!(t.modules[0].type_name, "hub");
    assert!(t.modules[1..].iter().all(|m| m.type_name == "stepper"));
    // z by route [0, 3]: hub link 3; a and b by name: links 1 and 2.
    assert_eq!(
        [1, 2, 3].map(|k| on_hub_link(&t, k)),
        ["a", "b", "z"],
        "hub links"
    );
    assert_eq!(t.links[0].kind, LinkKind::Usb);
    assert!(t.links[1..]
        .iter()
        .all(|l| l.kind == LinkKind::Uart && l.baud() == UART_BAUD));
    // Motors with the file's scale; the pen's module has I/O.
    for m in ["a", "b"] {
        let spec = &t.modules[t.module_index(m).unwrap()];
        assert_eq!(spec.motor.as_ref().unwrap().full_steps_per_unit, 5.0);
        assert_eq!(spec.motor.as_ref().unwrap().limit_min, None);
    }
    let z = &t.modules[t.module_index("z").unwrap()];
    assert_eq!((z.motor.is_none(), z.io.is_some()), (true, true));
    // Distinct clocks, within ±60 ppm.
    let mut rates: Vec<f64> = t.modules.iter().map(|m| m.rate_ppm).collect();
    assert!(rates.iter().all(|r| r.abs() <= RATE_SPREAD_PPM));
    rates.sort_by(f64::total_cmp);
    rates.dedup();
    assert_eq!(rates.len(), t.modules.len(), "{rates:?}");
    // x homes on a's input, y on b's, both 1 mm below their min (a
    // switch sits past the travel, so the travel's edge is reachable).
    assert_eq!(t.switches.len(), 2);
    assert_eq!(t.switches[0].module, "a");
    assert_eq!(t.switches[1].module, "b");
    assert!(t.switches.iter().all(|s| s.pressed_below && s.at == -1.0));
}

#[test]
fn the_laser_derives() {
    let cfg = example("laser.toml");
    let t = spec(&cfg).unwrap();
    let names: Vec<&str> = t.modules.iter().map(|m| m.name.as_str()).collect();
    // By name, in key order head, x, y.
    assert_eq!(names, ["hub", "laser-head", "laser-x", "laser-y"]);
    let spec = |n: &str| &t.modules[t.module_index(n).unwrap()];
    // The laser's module: I/O and no motor; the belts: 5 full steps/mm.
    let head = spec("laser-head");
    assert_eq!((head.motor.is_none(), head.io.is_some()), (true, true));
    for m in ["laser-x", "laser-y"] {
        let motor = spec(m).motor.as_ref().unwrap();
        assert_eq!(motor.full_steps_per_unit, 5.0);
        assert!(spec(m).io.is_none());
    }
    // x and y home on their own modules' inputs, 1 mm below 0.
    assert_eq!(t.switches.len(), 2);
    assert!(t.switches.iter().all(|s| s.pressed_below && s.at == -1.0));
}

#[test]
fn the_mill_derives() {
    let cfg = example("mill.toml");
    let t = spec(&cfg).unwrap();
    let names: Vec<&str> = t.modules.iter().map(|m| m.name.as_str()).collect();
    // By name, in key order x, y, z: hub links 1, 2, 3.
    assert_eq!(names, ["hub", "mill-x", "mill-y", "mill-z"]);
    assert_eq!(
        [1, 2, 3].map(|k| on_hub_link(&t, k)),
        ["mill-x", "mill-y", "mill-z"]
    );
    let spec = |n: &str| &t.modules[t.module_index(n).unwrap()];
    assert_eq!(
        spec("mill-z").motor.as_ref().unwrap().full_steps_per_unit,
        40.0
    );
    assert_eq!(
        spec("mill-x").motor.as_ref().unwrap().full_steps_per_unit,
        40.0
    );
    assert!(spec("mill-z").io.is_some(), "the spindle's module");
    assert!(spec("mill-x").io.is_none());
    // Three switches 1 mm past the max ends, each over its own motor;
    // y's motor is inverted. Starts: the middles of the travels.
    // And the bed probe on z's input (mill.toml's [probe], [sim.bed]).
    assert_eq!(t.switches.len(), 4);
    assert!(t.switches[3].bed.is_some());
    let x = &t.switches[0];
    assert_eq!(
        x,
        &SwitchSpec::new("mill-x", &[("mill-x", 1.0)], 150.0, 301.0, false)
    );
    let y = &t.switches[1];
    assert_eq!(
        y,
        &SwitchSpec::new("mill-y", &[("mill-y", -1.0)], 100.0, 201.0, false)
    );
    let z = &t.switches[2];
    assert_eq!(
        z,
        &SwitchSpec::new("mill-z", &[("mill-z", 1.0)], -40.0, 1.0, false)
    );
    // z (believed at 0, physically at -40) reaches its travel's top
    // when raised 40 mm without a press, and presses 1 mm above it.
    assert!(!z.pressed(|_| 40.0));
    assert!(!z.pressed(|_| 40.99));
    assert!(z.pressed(|_| 41.0));
    // y's motor is inverted: raising y by 101 sends it -101.
    assert!(!y.pressed(|_| -100.0));
    assert!(y.pressed(|_| -101.0));
    assert!(!y.pressed(|_| 101.0));
}

#[test]
fn the_corexy_switches_follow_x_and_y() {
    let cfg = example("plotter.toml");
    let t = spec(&cfg).unwrap();
    let (xs, ys) = (&t.switches[0], &t.switches[1]);
    // The machine believes it boots at (0, 0); it is at the middle,
    // (100, 75). So x reaches its min (0) when the machine believes
    // x = -100, and y its min when it believes y = -75; each switch
    // sits 1 mm past its min.
    let pressed = |s: &SwitchSpec, x: f64, y: f64| {
        let m = corexy_motors(&cfg, x, y);
        s.pressed(|name| m[name])
    };
    let x_at = |x: f64, y: f64| {
        let m = corexy_motors(&cfg, x, y);
        xs.value(|name| m[name])
    };
    for y in [-70.0, -20.0, 0.0, 30.0, 70.0] {
        assert!(!pressed(xs, -100.0, y), "x at 0, y {y}");
        assert!(!pressed(xs, -100.9, y), "x at -0.9, y {y}");
        assert!(pressed(xs, -101.0, y), "x at -1, y {y}");
        assert!(pressed(xs, -102.0, y), "x past -1, y {y}");
        assert!((x_at(-40.0, y) - 60.0).abs() < 1e-9, "physical x");
    }
    // y moving alone never presses x, wherever x stands off its switch;
    // and it presses y at its min whatever x.
    for x in [-99.0, -50.0, 0.0, 99.0] {
        for k in -74..=74 {
            let y = k as f64;
            assert!(!pressed(xs, x, y), "x {x}, y {y}");
            assert!(!pressed(ys, x, y), "x {x}, y {y}");
        }
        assert!(!pressed(ys, x, -75.0), "y at its min, x {x}");
        assert!(pressed(ys, x, -76.0), "y 1 mm past its min, x {x}");
    }
    // b is inverted: its term's sign says so (x = 100 + (a − b)/2).
    assert_eq!(
        xs.terms,
        vec![("a".to_string(), 0.5), ("b".to_string(), -0.5)]
    );
    assert_eq!(
        ys.terms,
        vec![("a".to_string(), 0.5), ("b".to_string(), 0.5)]
    );
    // The same form for any start the [sim] section gives.
    let text = std::fs::read_to_string(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../examples/machines/plotter.toml"),
    )
    .unwrap()
    .replace(
        "[sim.axes.x]\nresonance_hz = 45.0",
        "[sim.axes.x]\nstart = 10.0\nresonance_hz = 45.0",
    );
    let cfg = parse(&text);
    assert_eq!(start_position(&cfg, "x"), Some(10.0));
    let t = spec(&cfg).unwrap();
    assert_eq!(t.switches[0].offset, 10.0);
    let m = corexy_motors(&cfg, -11.0, 50.0);
    assert!(t.switches[0].pressed(|name| m[name]));
    let m = corexy_motors(&cfg, -10.9, 50.0);
    assert!(!t.switches[0].pressed(|name| m[name]));
}

const BASE: &str = r#"
name = "m"
[limits]
velocity = 100.0
acceleration = 1000.0
junction_deviation = 0.02
[motors.x]
module = "x"
full_steps_per_unit = 5.0
[axes.x]
motor = "x"
min = 0.0
max = 100.0
velocity = 50.0
acceleration = 500.0
jerk = 10000.0
"#;

#[test]
fn routes_place_modules_on_hub_links() {
    let cfg = parse(&format!(
        "{BASE}\n[modules]\nx = {{ route = [0, 2] }}\np = {{ name = \"p\" }}\nq = {{ name = \"q\" }}\nr = {{ route = [0, 5] }}\n"
    ));
    let t = spec(&cfg).unwrap();
    // p and q by name take the free links 1 and 3; 4 is held by a
    // placeholder so that r sits on 5.
    assert_eq!(
        [1, 2, 3, 4, 5].map(|k| on_hub_link(&t, k)),
        ["p", "x", "q", "spare-4", "r"]
    );
    assert_eq!(
        t.modules[t.module_index("spare-4").unwrap()].type_name,
        "hub"
    );
    assert!(t.modules[t.module_index("x").unwrap()].motor.is_some());
}

#[test]
fn bad_files_are_refused_naming_the_key() {
    for route in ["[1, 2]", "[0]", "[0, 0]", "[0, 8]", "[0, 1, 2]"] {
        let cfg = parse(&format!("{BASE}\n[modules]\nx = {{ route = {route} }}\n"));
        let (key, message) = err(&cfg);
        assert_eq!(key, "modules.x.route", "{route}: {message}");
        assert!(message.contains("[0, k]"), "{message}");
    }
    // The hub's name is taken.
    let cfg = parse(&format!("{BASE}\n[modules]\nx = {{ name = \"hub\" }}\n"));
    assert_eq!(err(&cfg).0, "modules.x.name");
    // A route module is named by its key, which another module's name
    // may clash with.
    let cfg = parse(&format!(
        "{BASE}\n[modules]\nx = {{ route = [0, 1] }}\ny = {{ name = \"x\" }}\n"
    ));
    let (key, message) = err(&cfg);
    assert!(key.starts_with("modules."), "{key}: {message}");
    // More modules than the hub has links.
    let many: String = (0..8)
        .map(|i| format!("m{i} = {{ name = \"m{i}\" }}\n"))
        .collect();
    let cfg = parse(&format!(
        "{BASE}\n[modules]\nx = {{ name = \"x\" }}\n{many}"
    ));
    assert_eq!(err(&cfg).0, "modules");
    // Every microstep setting the file allows is simulated (1 to 256).
    let cfg = parse(
        &format!("{BASE}\n[modules]\nx = {{ name = \"x\" }}\n").replace(
            "full_steps_per_unit = 5.0",
            "full_steps_per_unit = 5.0\nmicrosteps = 256",
        ),
    );
    assert_eq!(spec(&cfg).unwrap().modules.len(), 2);
    // A scara homes its joints on switches pressed by the joints' angles.
    let scara = r#"
name = "arm"
[limits]
velocity = 100.0
acceleration = 1000.0
junction_deviation = 0.02
[modules]
s = { name = "s" }
e = { name = "e" }
[motors.s]
module = "s"
full_steps_per_unit = 100.0
[motors.e]
module = "e"
full_steps_per_unit = 100.0
invert = true
[kinematics]
type = "scara"
motors = ["s", "e"]
l1 = 100.0
l2 = 100.0
elbow = "left"
[axes.x]
min = 10.0
max = 150.0
velocity = 50.0
acceleration = 500.0
jerk = 10000.0
homing = { switch = "s", direction = "min", endstop = -1.0, search_speed = 0.5, latch_speed = 0.05, backoff = 0.1 }
[axes.y]
min = 10.0
max = 150.0
velocity = 50.0
acceleration = 500.0
jerk = 10000.0
homing = { switch = "e", direction = "max", endstop = -0.2, search_speed = 0.5, latch_speed = 0.05, backoff = 0.1 }
"#;
    let cfg = parse(scara);
    let t = spec(&cfg).unwrap();
    assert_eq!(t.switches.len(), 2);
    // The joints at the sim's start (the travel's middle, (80, 80)).
    let q = crate::machine::drive::mechanism(&cfg)
        .unwrap()
        .unwrap()
        .inverse_xy(nalgebra::Vector2::new(80.0, 80.0))
        .unwrap();
    let (s, e) = (&t.switches[0], &t.switches[1]);
    assert_eq!(s.terms, vec![("s".to_string(), 1.0)]);
    assert_eq!(e.terms, vec![("e".to_string(), -1.0)]);
    assert!((s.offset - q[0]).abs() < 1e-12 && (e.offset - q[1]).abs() < 1e-12);
    assert_eq!((s.at, s.pressed_below), (-1.0, true));
    assert_eq!((e.at, e.pressed_below), (-0.2, false));
    // Its homing is in radians, at an angle the file must give, and homes
    // both joints.
    let no_endstop = scara.replace("endstop = -1.0, ", "");
    let e = MachineFile::parse(&no_endstop).unwrap_err();
    assert_eq!(e.key(), Some("axes.x.homing.endstop"), "{e}");
    let one_joint = scara.replace(
        "homing = { switch = \"e\", direction = \"max\", endstop = -0.2, search_speed = 0.5, latch_speed = 0.05, backoff = 0.1 }\n",
        "",
    );
    let e = MachineFile::parse(&one_joint).unwrap_err();
    assert_eq!(e.key(), Some("axes.y.homing"), "{e}");
    // Without homing a scara arm simulates without switches.
    let none = one_joint.replace(
        "homing = { switch = \"s\", direction = \"min\", endstop = -1.0, search_speed = 0.5, latch_speed = 0.05, backoff = 0.1 }\n",
        "",
    );
    assert!(spec(&parse(&none)).unwrap().switches.is_empty());
}

#[test]
fn sim_axes_take_a_start_and_an_optional_resonance() {
    let with = |extra: &str| {
        MachineFile::parse(&format!(
            "{BASE}\n[modules]\nx = {{ name = \"x\" }}\n{extra}"
        ))
    };
    let cfg = with("[sim.axes.x]\nstart = 20.0\n").unwrap();
    let axis = &cfg.sim.as_ref().unwrap().axes["x"];
    assert_eq!((axis.start, axis.resonance()), (Some(20.0), None));
    assert_eq!(start_position(&cfg, "x"), Some(20.0));
    let cfg = with("[sim.axes.x]\nresonance_hz = 40.0\ndamping_ratio = 0.1\n").unwrap();
    assert_eq!(
        cfg.sim.as_ref().unwrap().axes["x"].resonance(),
        Some((40.0, 0.1))
    );
    assert_eq!(start_position(&cfg, "x"), Some(50.0), "the middle");
    for (extra, key) in [
        ("[sim.axes.x]\nstart = 120.0\n", "sim.axes.x.start"),
        ("[sim.axes.x]\nstart = -1.0\n", "sim.axes.x.start"),
        (
            "[sim.axes.x]\nresonance_hz = 40.0\n",
            "sim.axes.x.damping_ratio",
        ),
        (
            "[sim.axes.x]\ndamping_ratio = 0.1\n",
            "sim.axes.x.resonance_hz",
        ),
    ] {
        let e = with(extra).unwrap_err();
        assert_eq!(e.key(), Some(key), "{extra}: {e}");
    }
}

#[test]
fn the_plotter_starts_and_a_scan_finds_every_module() {
    let cfg = example("plotter.toml");
    let t = spec(&cfg).unwrap();
    virtual_runtime().unwrap().block_on(async {
        let host = Host::start(HostConfig::named("machine")).unwrap();
        let sim = SimMachine::start_with(&host, &t, TimeMode::Virtual)
            .await
            .unwrap();
        let mut m = Manager::new(&host).await.unwrap();
        let report = m.refresh().await.unwrap();
        assert!(
            report.scan_failures.is_empty(),
            "{:?}",
            report.scan_failures
        );
        let som = m.som();
        let mut found: Vec<&str> = som.runtimes[1..]
            .iter()
            .map(|r| r.record.name.as_str())
            .collect();
        found.sort();
        assert_eq!(found, ["a", "b", "hub", "z"]);
        // The route in the file reaches z.
        let z = som.walk(0, &[0, 3]).unwrap();
        assert_eq!(som.runtimes[z].record.name, "z");
        // Every switch reads released at boot: the carriage starts in
        // the middle of the travel.
        for name in ["a", "b"] {
            let module = sim.module(name).unwrap().module().unwrap();
            assert!(module.lock(|m| m.limit.level), "{name} released");
        }
        sim.stop().await.unwrap();
    });
}

/// One spec, two simulators: the spec a machine file derives, which the
/// real-time machines run above, also runs in the discrete-event
/// simulator, node for node and link for link, and its clocks converge
/// there as on the machines.
#[test]
fn a_machine_files_spec_runs_in_the_discrete_event_simulator() {
    let cfg = example("mill.toml");
    let spec = spec(&cfg).unwrap();
    let network = osap_sim::Network::from_spec(&spec).unwrap();
    let names: Vec<&str> = network.nodes.iter().map(|n| n.name.as_str()).collect();
    let expected: Vec<&str> = std::iter::once(HOST)
        .chain(spec.modules.iter().map(|m| m.name.as_str()))
        .collect();
    assert_eq!(names, expected);
    assert_eq!(network.links.len(), spec.links.len());
    let outcome = osap_sim::Scenario::from_spec(&spec)
        .unwrap()
        .seconds(5.0)
        .run()
        .unwrap();
    let metrics = &outcome.metrics;
    assert_eq!(metrics.node_count(), spec.modules.len() + 1);
    assert!(metrics.all_tiered_time(255).is_some(), "not tiered");
    let converged = metrics.worst_convergence_time(50.0);
    assert!(
        converged.is_some_and(|s| s < 4.0),
        "within 50 µs after {converged:?} s"
    );
}
