//! The machine file: the examples parse and validate, every validation
//! error names its key, and no input panics the parser.

use std::path::PathBuf;

use osap_machine::config::{
    ConfigError, Direction, Kinematics, MachineFile, Output, SteinhartHart, ToolKind,
};
use proptest::prelude::*;

fn example(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../examples/machines")
        .join(name)
}

/// A small valid CoreXY machine the error tests edit.
const BASE: &str = r#"
name = "t"
[modules]
a = { name = "a" }
b = { name = "b" }
z = { route = [0, 3] }
[motors.a]
module = "a"
full_steps_per_unit = 5.0
[motors.b]
module = "b"
full_steps_per_unit = 5.0
[motors.z]
module = "z"
full_steps_per_unit = 25.0
[kinematics]
type = "corexy"
motors = ["a", "b"]
[axes.x]
min = 0.0
max = 200.0
velocity = 300.0
acceleration = 3000.0
jerk = 100000.0
homing = { switch = "a", direction = "min", search_speed = 20.0, latch_speed = 2.0, backoff = 2.0, order = 1 }
[axes.y]
min = 0.0
max = 150.0
velocity = 300.0
acceleration = 3000.0
jerk = 100000.0
[axes.z]
motor = "z"
min = -10.0
max = 0.0
velocity = 10.0
acceleration = 100.0
jerk = 1000.0
[limits]
velocity = 250.0
acceleration = 2500.0
junction_deviation = 0.02
[tools.pen]
kind = "pen"
module = "z"
output = { pwm = 0 }
settle_ms = 150
"#;

fn edited(from: &str, to: &str) -> String {
    assert!(BASE.contains(from), "BASE has no {from:?}");
    BASE.replacen(from, to, 1)
}

fn invalid_key(text: &str) -> (String, String) {
    match MachineFile::parse(text) {
        Err(e @ ConfigError::Invalid { .. }) => (e.key().unwrap().to_string(), e.to_string()),
        other => panic!("expected a validation error, got {other:?}"),
    }
}

#[test]
fn plotter_example_loads() {
    let m = MachineFile::load(example("plotter.toml")).unwrap();
    assert_eq!(m.name, "plotter");
    assert!(matches!(m.kinematics, Kinematics::CoreXy { .. }));
    assert_eq!(m.axis_names(), ["x", "y"]);
    assert!(m.axes["x"].max - m.axes["x"].min >= 200.0);
    assert!(m.axes["y"].max - m.axes["y"].min >= 150.0);
    // A GT2 belt on a 20-tooth pulley at 16 microsteps: 80 per mm.
    assert_eq!(m.motors["a"].full_steps_per_unit, 5.0);
    assert_eq!(m.motors["b"].full_steps_per_unit, 5.0);
    assert_eq!(m.motors["a"].microsteps, 16);
    assert_eq!(m.motor_for_axis("x"), None);
    assert_eq!(m.motors_for_axis("x"), ["a", "b"]);
    assert_eq!(m.tools["pen"].kind, ToolKind::Pen);
    assert_eq!(m.homing_order(), vec![vec!["x", "y"]]);
    let switches = m.switch_placements();
    assert_eq!(switches.len(), 2);
    assert_eq!(switches[0].module, "a");
    assert_eq!(switches[0].direction, Direction::Min);
    // No endstop given: the switch sits 1 mm beyond the soft travel.
    assert_eq!(switches[0].position, -1.0);
    assert_eq!(switches[1].position, -1.0);
    assert_eq!(m.sim.as_ref().unwrap().axes["x"].resonance_hz, 45.0);
}

#[test]
fn mill_example_loads() {
    let m = MachineFile::load(example("mill.toml")).unwrap();
    assert_eq!(m.name, "mill");
    assert_eq!(m.kinematics, Kinematics::Cartesian {});
    assert_eq!(m.axis_names(), ["x", "y", "z"]);
    assert_eq!(m.motor_for_axis("z"), Some("z"));
    assert_eq!(m.motors_for_axis("y"), ["y"]);
    let spindle = &m.tools["spindle"];
    assert_eq!(spindle.kind, ToolKind::Spindle);
    assert_eq!(spindle.output, Output::Pwm(1));
    assert_eq!(spindle.max_rpm, Some(24000.0));
    assert_eq!(m.homing_order(), vec![vec!["z"], vec!["x", "y"]]);
    assert_eq!(m.bed_mesh.as_deref(), Some("mill-mesh.toml".as_ref()));
}

#[test]
fn base_is_valid() {
    let m = MachineFile::parse(BASE).unwrap();
    assert_eq!(m.axis_names(), ["x", "y", "z"]);
    assert_eq!(m.modules["z"].route.as_deref(), Some(&[0u16, 3][..]));
}

#[test]
fn min_above_max_names_the_axis_and_the_fix() {
    let (key, msg) = invalid_key(&edited("min = 0.0\nmax = 200.0", "min = 10.0\nmax = 5.0"));
    assert_eq!(key, "axes.x");
    assert_eq!(
        msg,
        "machine file: axes.x: min 10 must be below max 5; swap them or fix the travel"
    );
}

#[test]
fn load_names_the_file() {
    let dir = std::env::temp_dir().join(format!("osap-machine-config-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("plotter.toml");
    std::fs::write(
        &path,
        edited("min = 0.0\nmax = 200.0", "min = 10.0\nmax = 5.0"),
    )
    .unwrap();
    let msg = MachineFile::load(&path).unwrap_err().to_string();
    assert!(
        msg.starts_with("machine file ")
            && msg.ends_with(
                "plotter.toml: axes.x: min 10 must be below max 5; swap them or fix the travel"
            ),
        "{msg}"
    );
    let missing = MachineFile::load(dir.join("none.toml")).unwrap_err();
    assert!(matches!(missing, ConfigError::Io { .. }));
    assert!(missing.to_string().contains("none.toml"));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn unknown_key_is_a_parse_error_with_its_line() {
    let text = BASE.replace(
        "[motors.a]\nmodule = \"a\"",
        "[motors.a]\nmodule = \"a\"\ninvrt = true",
    );
    let err = MachineFile::parse(&text).unwrap_err();
    let ConfigError::Parse { line, message, .. } = &err else {
        panic!("expected a parse error, got {err:?}");
    };
    let expected = text.lines().position(|l| l.starts_with("invrt")).unwrap() + 1;
    assert_eq!(*line, Some(expected));
    assert!(message.contains("invrt"), "{message}");
    assert!(
        err.to_string().contains(&format!("line {expected}")),
        "{err}"
    );
}

#[test]
fn unknown_kinematics_type_is_a_parse_error() {
    let err = MachineFile::parse(&edited("type = \"corexy\"", "type = \"delta\"")).unwrap_err();
    assert!(matches!(err, ConfigError::Parse { .. }), "{err:?}");
    assert!(err.to_string().contains("delta"), "{err}");
}

#[test]
fn unknown_axis() {
    let (key, msg) = invalid_key(&edited("[axes.z]", "[axes.q]"));
    assert_eq!(key, "axes.q");
    assert!(msg.contains("unknown axis; use one of x, y, z"), "{msg}");
}

#[test]
fn missing_module_in_motor_tool_and_homing() {
    let (key, msg) = invalid_key(&edited("module = \"b\"", "module = \"bb\""));
    assert_eq!(key, "motors.b.module");
    assert!(msg.contains("\"bb\" is not in [modules]"), "{msg}");
    let (key, _) = invalid_key(&edited(
        "kind = \"pen\"\nmodule = \"z\"",
        "kind = \"pen\"\nmodule = \"q\"",
    ));
    assert_eq!(key, "tools.pen.module");
    let (key, _) = invalid_key(&edited("switch = \"a\"", "switch = \"nope\""));
    assert_eq!(key, "axes.x.homing.switch");
}

/// A module steps at most once per 10 µs tick: 100 000 microsteps/s.
#[test]
fn step_rates_past_the_step_tick_are_refused_with_the_fix() {
    // z on a T8 screw (25 full steps/mm) at 256 microsteps: 6 400 per mm,
    // so 10 mm/s needs 64 000 microsteps/s (fine) and 20 mm/s 128 000.
    let ok = edited(
        "full_steps_per_unit = 25.0",
        "full_steps_per_unit = 25.0\nmicrosteps = 256",
    );
    MachineFile::parse(&ok).unwrap();
    let fast = ok.replacen("velocity = 10.0", "velocity = 20.0", 1);
    let (key, msg) = invalid_key(&fast);
    assert_eq!(key, "motors.z");
    assert!(msg.contains("needs 128000 microsteps/s"), "{msg}");
    assert!(
        msg.contains("lower axes.z.velocity to at most 15.6"),
        "{msg}"
    );
    assert!(msg.contains("or set motors.z.microsteps to 128"), "{msg}");
    // A CoreXY belt moves at up to √2 × the toolhead's speed: 250 mm/s at
    // 80 microsteps/mm is 28 284/s; at 256 microsteps (1 280/mm) 452 548/s.
    let belts = edited(
        "module = \"a\"\nfull_steps_per_unit = 5.0",
        "module = \"a\"\nfull_steps_per_unit = 5.0\nmicrosteps = 256",
    );
    let (key, msg) = invalid_key(&belts);
    assert_eq!(key, "motors.a");
    assert!(msg.contains("limits.velocity 353.6 needs"), "{msg}");
    assert!(msg.contains("set motors.a.microsteps to 32"), "{msg}");
}

#[test]
fn missing_motor() {
    let (key, msg) = invalid_key(&edited("motor = \"z\"", "motor = \"w\""));
    assert_eq!(key, "axes.z.motor");
    assert!(msg.contains("\"w\" is not in [motors]"), "{msg}");
}

#[test]
fn non_positive_steps() {
    let (key, msg) = invalid_key(&edited(
        "full_steps_per_unit = 25.0",
        "full_steps_per_unit = 0.0",
    ));
    assert_eq!(key, "motors.z.full_steps_per_unit");
    assert!(msg.contains("must be positive"), "{msg}");
    let (key, _) = invalid_key(&edited(
        "full_steps_per_unit = 25.0",
        "full_steps_per_unit = -3.0",
    ));
    assert_eq!(key, "motors.z.full_steps_per_unit");
    let (key, _) = invalid_key(&edited(
        "full_steps_per_unit = 25.0",
        "full_steps_per_unit = nan",
    ));
    assert_eq!(key, "motors.z.full_steps_per_unit");
}

#[test]
fn microsteps_must_be_a_power_of_two() {
    let text = edited(
        "full_steps_per_unit = 25.0",
        "full_steps_per_unit = 25.0\nmicrosteps = 12",
    );
    assert_eq!(invalid_key(&text).0, "motors.z.microsteps");
    let text = edited(
        "full_steps_per_unit = 25.0",
        "full_steps_per_unit = 25.0\nmicrosteps = 512",
    );
    assert_eq!(invalid_key(&text).0, "motors.z.microsteps");
}

#[test]
fn non_positive_limits() {
    assert_eq!(
        invalid_key(&edited(
            "junction_deviation = 0.02",
            "junction_deviation = 0.0"
        ))
        .0,
        "limits.junction_deviation"
    );
    assert_eq!(
        invalid_key(&edited("velocity = 250.0", "velocity = -1.0")).0,
        "limits.velocity"
    );
    assert_eq!(
        invalid_key(&edited("jerk = 1000.0", "jerk = 0.0")).0,
        "axes.z.jerk"
    );
    assert_eq!(
        invalid_key(&edited("acceleration = 100.0", "acceleration = inf")).0,
        "axes.z.acceleration"
    );
}

#[test]
fn mechanisms_need_two_motors_on_x_and_y() {
    let (key, msg) = invalid_key(&edited("motors = [\"a\", \"b\"]", "motors = [\"a\"]"));
    assert_eq!(key, "kinematics.motors");
    assert!(msg.contains("corexy needs exactly 2 motors"), "{msg}");
    // x may not also name a motor.
    let (key, _) = invalid_key(&edited("[axes.x]\n", "[axes.x]\nmotor = \"z\"\n"));
    assert_eq!(key, "axes.x.motor");
}

#[test]
fn cartesian_axes_need_their_own_motor() {
    let (key, msg) = invalid_key(&edited(
        "type = \"corexy\"\nmotors = [\"a\", \"b\"]",
        "type = \"cartesian\"",
    ));
    // a and b now drive nothing; the first complaint is about them or x.
    assert!(key == "motors.a" || key == "axes.x.motor", "{key}: {msg}");
}

#[test]
fn duplicate_motor_use_and_modules() {
    let (key, msg) = invalid_key(&edited(
        "motors = [\"a\", \"b\"]",
        "motors = [\"a\", \"a\"]",
    ));
    assert_eq!(key, "kinematics.motors[1]");
    assert!(msg.contains("duplicate"), "{msg}");
    let (key, msg) = invalid_key(&edited("b = { name = \"b\" }", "b = { name = \"a\" }"));
    assert_eq!(key, "modules.b.name");
    assert!(msg.contains("duplicate module name"), "{msg}");
    let text = edited(
        "settle_ms = 150",
        "settle_ms = 150\n[tools.laser]\nkind = \"laser\"\nmodule = \"z\"\noutput = { pwm = 0 }",
    );
    let (key, msg) = invalid_key(&text);
    assert_eq!(key, "tools.pen.output");
    assert!(msg.contains("duplicate"), "{msg}");
}

#[test]
fn module_needs_exactly_one_of_name_and_route() {
    assert_eq!(
        invalid_key(&edited(
            "z = { route = [0, 3] }",
            "z = { name = \"z\", route = [0, 3] }"
        ))
        .0,
        "modules.z"
    );
    assert_eq!(
        invalid_key(&edited("z = { route = [0, 3] }", "z = {}")).0,
        "modules.z"
    );
    assert_eq!(
        invalid_key(&edited("z = { route = [0, 3] }", "z = { route = [] }")).0,
        "modules.z.route"
    );
}

#[test]
fn homing_checks() {
    assert_eq!(
        invalid_key(&edited("latch_speed = 2.0, ", "")).0,
        "axes.x.homing.latch_speed"
    );
    assert_eq!(
        invalid_key(&edited("search_speed = 20.0", "search_speed = 2000.0")).0,
        "axes.x.homing.search_speed"
    );
    assert_eq!(
        invalid_key(&edited("backoff = 2.0", "backoff = 500.0")).0,
        "axes.x.homing.backoff"
    );
    assert_eq!(
        invalid_key(&edited("switch = \"a\"", "switch = \"a\", stall = \"a\"")).0,
        "axes.x.homing"
    );
    // Stall homing names a motor and needs no latch speed.
    let m = MachineFile::parse(&edited(
        "switch = \"a\", direction = \"min\", search_speed = 20.0, latch_speed = 2.0",
        "stall = \"a\", direction = \"max\", search_speed = 20.0",
    ))
    .unwrap();
    assert!(m.switch_placements().is_empty());
}

#[test]
fn the_endstop_lies_beyond_the_travel_and_the_backoff_comes_back_inside() {
    // Default: 1 mm beyond the homed end; homing leaves the axis at
    // endstop + backoff.
    let m = MachineFile::parse(BASE).unwrap();
    let x = &m.axes["x"];
    let homing = x.homing.as_ref().unwrap();
    assert_eq!(homing.endstop(x), -1.0);
    assert_eq!(homing.homed_position(x), 1.0);
    // An explicit endstop, at the edge or beyond, is where the switch sits.
    for endstop in ["0.0", "-1.5"] {
        let m = MachineFile::parse(&edited(
            "backoff = 2.0,",
            &format!("backoff = 2.0, endstop = {endstop},"),
        ))
        .unwrap();
        assert_eq!(
            m.switch_placements()[0].position,
            endstop.parse::<f64>().unwrap()
        );
    }
    // Inside the travel: a job would press it.
    let (key, msg) = invalid_key(&edited("backoff = 2.0,", "backoff = 2.0, endstop = 0.5,"));
    assert_eq!(key, "axes.x.homing.endstop");
    assert!(msg.contains("inside the travel [0, 200]"), "{msg}");
    assert!(msg.contains("at or beyond min = 0"), "{msg}");
    let (key, _) = invalid_key(&edited("backoff = 2.0,", "backoff = 2.0, endstop = nan,"));
    assert_eq!(key, "axes.x.homing.endstop");
    // Homing to max: the endstop must lie at or above max.
    let (key, msg) = invalid_key(&edited(
        "direction = \"min\", search_speed = 20.0, latch_speed = 2.0, backoff = 2.0,",
        "direction = \"max\", search_speed = 20.0, latch_speed = 2.0, backoff = 2.0, endstop = 199.0,",
    ));
    assert_eq!(key, "axes.x.homing.endstop");
    assert!(msg.contains("at or beyond max = 200"), "{msg}");
    // A backoff that stays outside the travel (0.5 mm from a switch 1 mm
    // out), or one that crosses it.
    for backoff in ["0.5", "0.0", "201.5"] {
        let (key, msg) = invalid_key(&edited("backoff = 2.0", &format!("backoff = {backoff}")));
        assert_eq!(key, "axes.x.homing.backoff");
        assert!(msg.contains("from 1 to 201"), "{msg}");
    }
    // Exactly back to the edge is inside.
    let m = MachineFile::parse(&edited("backoff = 2.0", "backoff = 1.0")).unwrap();
    let x = &m.axes["x"];
    assert_eq!(x.homing.as_ref().unwrap().homed_position(x), 0.0);
}

#[test]
fn tool_output_range() {
    assert_eq!(
        invalid_key(&edited("output = { pwm = 0 }", "output = { pwm = 2 }")).0,
        "tools.pen.output.pwm"
    );
    assert_eq!(
        invalid_key(&edited("output = { pwm = 0 }", "output = { digital = 4 }")).0,
        "tools.pen.output.digital"
    );
    let m =
        MachineFile::parse(&edited("output = { pwm = 0 }", "output = { digital = 3 }")).unwrap();
    assert_eq!(m.tools["pen"].output, Output::Digital(3));
    assert!(MachineFile::parse(&edited(
        "output = { pwm = 0 }",
        "output = { pwm = 0, digital = 1 }"
    ))
    .is_err());
    assert_eq!(
        invalid_key(&edited(
            "settle_ms = 150",
            "settle_ms = 150\nmax_rpm = 1000.0"
        ))
        .0,
        "tools.pen.max_rpm"
    );
}

#[test]
fn sim_section() {
    let text = format!("{BASE}\n[sim.axes.x]\nresonance_hz = 40.0\ndamping_ratio = 0.1\n");
    let m = MachineFile::parse(&text).unwrap();
    assert_eq!(m.sim.unwrap().axes["x"].damping_ratio, 0.1);
    let text = format!("{BASE}\n[sim.axes.a]\nresonance_hz = 40.0\ndamping_ratio = 0.1\n");
    assert_eq!(invalid_key(&text).0, "sim.axes.a");
    let text = format!("{BASE}\n[sim.axes.x]\nresonance_hz = 0.0\ndamping_ratio = 0.1\n");
    assert_eq!(invalid_key(&text).0, "sim.axes.x.resonance_hz");
    let text =
        format!("{BASE}\n[sim.axes.x]\nresonance_hz = 40.0\ndamping_ratio = 0.1\nmass = 2\n");
    assert!(matches!(
        MachineFile::parse(&text),
        Err(ConfigError::Parse { .. })
    ));
}

#[test]
fn scara_and_fivebar() {
    let scara = edited(
        "type = \"corexy\"",
        "type = \"scara\"\nl1 = 100.0\nl2 = 80.0\nelbow = \"right\"",
    );
    // An arm's x homing homes its first joint, in radians: the switch's
    // angle is needed, and the second joint (y's homing) homes too.
    assert_eq!(invalid_key(&scara).0, "axes.x.homing.endstop");
    let joint = scara.replace("backoff = 2.0", "backoff = 0.1, endstop = -1.0");
    assert_eq!(invalid_key(&joint).0, "axes.y.homing");
    assert_eq!(
        invalid_key(&scara.replace("backoff = 2.0", "backoff = 4.0, endstop = -1.0")).0,
        "axes.x.homing.backoff"
    );
    let homing = "homing = { switch = \"a\", direction = \"min\", search_speed = 20.0, latch_speed = 2.0, backoff = 2.0, order = 1 }\n";
    assert!(scara.contains(homing));
    let scara = scara.replace(homing, "");
    let m = MachineFile::parse(&scara).unwrap();
    assert!(matches!(m.kinematics, Kinematics::Scara { margin_deg, .. } if margin_deg == 5.0));
    assert_eq!(
        invalid_key(&scara.replace("l2 = 80.0", "l2 = 0.0")).0,
        "kinematics.l2"
    );
    // A scara without its link lengths does not parse.
    assert!(matches!(
        MachineFile::parse(&edited("type = \"corexy\"", "type = \"scara\"")),
        Err(ConfigError::Parse { .. })
    ));
    let fivebar = edited(
        "type = \"corexy\"",
        "type = \"fivebar\"\nspan = 50.0\nl1 = 100.0\nl2 = 120.0\nleft_elbow = \"left\"\nright_elbow = \"right\"\ntool = \"left\"\nmargin_deg = 3.0",
    );
    let fivebar = fivebar.replace(homing, "");
    MachineFile::parse(&fivebar).unwrap();
    assert_eq!(
        invalid_key(&fivebar.replace("margin_deg = 3.0", "margin_deg = 95.0")).0,
        "kinematics.margin_deg"
    );
    // corexy takes no link lengths.
    assert!(matches!(
        MachineFile::parse(&edited("type = \"corexy\"", "type = \"corexy\"\nl1 = 1.0")),
        Err(ConfigError::Parse { .. })
    ));
}

proptest! {
    #[test]
    fn arbitrary_text_never_panics(text in "\\PC*") {
        let _ = MachineFile::parse(&text);
    }

    #[test]
    fn toml_ish_text_never_panics(
        lines in prop::collection::vec(
            prop_oneof![
                Just("name = \"m\"".to_string()),
                Just("[limits]".to_string()),
                Just("[kinematics]".to_string()),
                Just("type = \"corexy\"".to_string()),
                Just("type = \"scara\"".to_string()),
                Just("motors = [\"a\", \"b\"]".to_string()),
                "\\[(axes|motors|modules|tools|sim\\.axes)\\.[a-z]\\]",
                "[a-z_]{1,12} = -?[0-9]{1,4}(\\.[0-9]{1,3})?",
                "[a-z_]{1,12} = \"[a-z]{0,3}\"",
                "[a-z]{1,3} = \\{ (name|route|pwm|digital|switch) = (\\[[0-9, ]{0,6}\\]|\"[a-z]\"|[0-9]) \\}",
                "(velocity|acceleration|jerk|min|max|junction_deviation|full_steps_per_unit) = -?[0-9e.+-]{1,8}",
                "\\PC{0,20}",
            ],
            0..40,
        ),
    ) {
        let _ = MachineFile::parse(&lines.join("\n"));
    }

    #[test]
    fn mutated_examples_never_panic(cut in 0usize..4000, insert in "\\PC{0,8}") {
        for file in ["plotter.toml", "mill.toml"] {
            let text = std::fs::read_to_string(example(file)).unwrap();
            let mut at = cut.min(text.len());
            while !text.is_char_boundary(at) {
                at -= 1;
            }
            let mutated = format!("{}{}{}", &text[..at], insert, &text[at..]);
            let _ = MachineFile::parse(&mutated);
            let _ = MachineFile::parse(&text[..at]);
        }
    }
}

#[test]
fn deep_nesting_is_an_error_not_a_crash() {
    for text in [
        format!("a = {}", "[".repeat(100_000)),
        format!("a = {}", "{ b = ".repeat(100_000)),
        "[a.".repeat(50_000),
    ] {
        assert!(matches!(
            MachineFile::parse(&text),
            Err(ConfigError::Parse { .. })
        ));
    }
}

#[test]
fn parse_errors_quote_the_line() {
    let text = "name = \"x\"\n[limits]\nvelocity = 1.0\n";
    let msg = MachineFile::parse(text).unwrap_err().to_string();
    assert_eq!(
        msg,
        "machine file, line 2: missing field `acceleration` (at `[limits]`)"
    );
}

#[test]
fn cartesian_takes_no_mechanism_keys() {
    let mill = std::fs::read_to_string(example("mill.toml")).unwrap();
    let text = mill.replace("type = \"cartesian\"", "type = \"cartesian\"\nl1 = 3.0");
    assert!(
        matches!(MachineFile::parse(&text), Err(ConfigError::Parse { .. })),
        "{:?}",
        MachineFile::parse(&text)
    );
}

#[test]
fn firmware_limits_are_validated_with_their_key() {
    let margin = edited(
        "junction_deviation = 0.02",
        "junction_deviation = 0.02\nmodule_margin = 0.5",
    );
    let (key, msg) = invalid_key(&margin);
    assert_eq!(key, "limits.module_margin");
    assert!(msg.contains("at least 1"), "{msg}");
    let off = edited(
        "junction_deviation = 0.02",
        "junction_deviation = 0.02\nmodule_margin = 0.0",
    );
    assert_eq!(MachineFile::parse(&off).unwrap().limits.module_margin, 0.0);
    assert_eq!(MachineFile::parse(BASE).unwrap().limits.module_margin, 1.5);
    let own = edited(
        "[motors.b]\nmodule = \"b\"\nfull_steps_per_unit = 5.0",
        "[motors.b]\nmodule = \"b\"\nfull_steps_per_unit = 5.0\nlimits = { velocity = 400.0, acceleration = -1.0 }",
    );
    let (key, _) = invalid_key(&own);
    assert_eq!(key, "motors.b.limits.acceleration");
    let good = own.replace("acceleration = -1.0", "acceleration = 9000.0");
    let m = MachineFile::parse(&good).unwrap();
    let l = m.motors["b"].limits.unwrap();
    assert_eq!((l.velocity, l.acceleration, l.jerk), (400.0, 9000.0, 0.0));
}

#[test]
fn stop_settings_are_validated_with_their_key() {
    // The output watchdog: default 500 ms, within 100..=10 000 ms.
    let m = MachineFile::parse(BASE).unwrap();
    assert_eq!(m.modules["z"].output_watchdog_ms(), 500);
    assert_eq!(m.limits.max_late_steps, 0);
    let short = edited(
        "z = { route = [0, 3] }",
        "z = { route = [0, 3], output_watchdog_ms = 20 }",
    );
    let (key, msg) = invalid_key(&short);
    assert_eq!(key, "modules.z.output_watchdog_ms");
    assert!(msg.contains("20 ms is outside 100 to 10000 ms"), "{msg}");
    let off = short.replace("output_watchdog_ms = 20", "output_watchdog_ms = 0");
    assert_eq!(invalid_key(&off).0, "modules.z.output_watchdog_ms");
    let good = short.replace("output_watchdog_ms = 20", "output_watchdog_ms = 250");
    assert_eq!(
        MachineFile::parse(&good).unwrap().modules["z"].output_watchdog_ms(),
        250
    );
    // Late steps: a count, default 0; a negative one is not a count.
    let late = edited(
        "junction_deviation = 0.02",
        "junction_deviation = 0.02\nmax_late_steps = 4",
    );
    assert_eq!(MachineFile::parse(&late).unwrap().limits.max_late_steps, 4);
    let negative = late.replace("max_late_steps = 4", "max_late_steps = -1");
    assert!(
        matches!(
            MachineFile::parse(&negative),
            Err(ConfigError::Parse { .. })
        ),
        "{:?}",
        MachineFile::parse(&negative)
    );
}

#[test]
fn printer_example_loads() {
    let m = MachineFile::load(example("printer.toml")).unwrap();
    assert_eq!(m.axis_names(), ["x", "y", "z", "e"]);
    assert_eq!(m.toolhead_axes(), 3);
    let e = m.extruder().unwrap();
    assert!(e.min.is_infinite() && e.max.is_infinite());
    assert_eq!(e.extruder.filament_diameter, Some(1.75));
    // 400 microsteps per mm on z (T8) and on the extruder.
    for k in ["z", "e"] {
        let mo = &m.motors[k];
        assert_eq!(mo.full_steps_per_unit * f64::from(mo.microsteps), 400.0);
    }
    assert_eq!(m.heaters.len(), 2);
    assert_eq!(
        m.heaters["bed"].runaway("bed").check_gain_time_s,
        Some(60.0)
    );
    assert_eq!(
        m.heaters["hotend"].runaway("hotend").check_gain_time_s,
        Some(20.0)
    );
}

#[test]
fn extruder_keys_are_checked_with_their_key() {
    let text = std::fs::read_to_string(example("printer.toml")).unwrap();
    let bad = |from: &str, to: &str| {
        assert!(text.contains(from), "{from}");
        match MachineFile::parse(&text.replacen(from, to, 1)) {
            Err(ConfigError::Invalid { key, message, .. }) => (key, message),
            other => panic!("{from} -> {to}: {other:?}"),
        }
    };
    let (key, _) = bad("filament_diameter = 1.75", "filament_diameter = 17.5");
    assert_eq!(key, "axes.e.filament_diameter");
    let (key, msg) = bad("kind = \"extruder\"\n", "");
    assert_eq!(key, "axes.e.kind", "{msg}");
    let (key, msg) = bad(
        "velocity = 10.0\n",
        "velocity = 10.0\npressure_advance = 0.05\n",
    );
    assert_eq!(key, "axes.z.pressure_advance", "{msg}");
    let (key, msg) = bad(
        "kind = \"extruder\"\n",
        "kind = \"extruder\"\nmin = 0.0\nmax = 10.0\n",
    );
    assert_eq!(key, "axes.e", "{msg}");
    let (key, _) = bad("pressure_advance = 0.04", "pressure_advance = 2.0");
    assert_eq!(key, "axes.e.pressure_advance");
    // A typo in the flattened extruder keys is still refused.
    assert!(matches!(
        MachineFile::parse(&text.replacen("smooth_time = 0.04", "smoth_time = 0.04", 1)),
        Err(ConfigError::Parse { .. })
    ));
    // Heaters.
    let (key, _) = bad("max_temp = 290.0", "max_temp = 600.0");
    assert_eq!(key, "heaters.hotend.max_temp");
    let (key, _) = bad("output = { pwm = 1 }", "output = { pwm = 0 }");
    assert_eq!(key, "heaters.hotend.output");
    let (key, _) = bad("[sim.heaters.bed]", "[sim.heaters.chamber]");
    assert_eq!(key, "sim.heaters.chamber");
    let (key, _) = bad("kp = 21.5", "kp = -1.0");
    assert_eq!(key, "heaters.hotend.kp");
    // Thermistors: a name not catalogued (the message lists those that
    // are), two curves at once, a table that is no thermistor, a pullup.
    let (key, msg) = bad("\"ATC Semitec 104GT-2\"", "\"Semitec 104GT\"");
    assert_eq!(key, "heaters.hotend.sensor.thermistor");
    assert!(msg.contains("EPCOS 100K B57560G104F"), "{msg}");
    let (key, msg) = bad(
        "thermistor = \"ATC Semitec 104GT-2\"",
        "thermistor = \"ATC Semitec 104GT-2\", beta = 4267.0",
    );
    assert_eq!(key, "heaters.hotend.sensor.thermistor", "{msg}");
    let (key, msg) = bad(
        "thermistor = \"ATC Semitec 104GT-2\"",
        "points = [[25.0, 100000.0], [150.0, 1641.9]]",
    );
    assert_eq!(key, "heaters.hotend.sensor.points");
    assert!(msg.contains("at least 3"), "{msg}");
    let (key, msg) = bad(
        "thermistor = \"ATC Semitec 104GT-2\"",
        "points = [[100000.0, 25.0], [1641.9, 150.0], [226.15, 250.0]]",
    );
    assert_eq!(key, "heaters.hotend.sensor.points");
    assert!(msg.contains("[°C, Ω]"), "{msg}");
    let (key, _) = bad("pullup_ohms = 4700.0", "pullup_ohms = 0.0");
    assert_eq!(key, "heaters.hotend.sensor.pullup_ohms");
    let (key, _) = bad(
        "sensor = { analog = 0, beta = 3950.0 }",
        "sensor = { analog = 0, beta = -3950.0 }",
    );
    assert_eq!(key, "heaters.bed.sensor.beta");
}

#[test]
fn load_cell_model_and_simulated_melt_keys_are_checked_with_their_key() {
    let text = std::fs::read_to_string(example("printer.toml")).unwrap();
    let bad = |from: &str, to: &str| {
        assert!(text.contains(from), "{from}");
        match MachineFile::parse(&text.replacen(from, to, 1)) {
            Err(ConfigError::Invalid { key, message, .. }) => (key, message),
            other => panic!("{from} -> {to}: {other:?}"),
        }
    };
    let printer = MachineFile::parse(&text).unwrap();
    let e = printer.extruder().unwrap();
    assert_eq!(e.extruder.loadcell.as_ref().unwrap().clock_pin, 3);
    let melt = printer.sim.as_ref().unwrap().axes["e"].melt.unwrap();
    assert_eq!((melt.flow_k, melt.response_ms), (8.0, 45.0));
    let (key, _) = bad("data_pin = 2", "data_pin = 4");
    assert_eq!(key, "axes.e.loadcell.data_pin");
    let (key, _) = bad("data_pin = 2", "data_pin = 3");
    assert_eq!(key, "axes.e.loadcell.clock_pin");
    let (key, msg) = bad("newtons_per_count = 0.0005", "newtons_per_count = 0.0");
    assert_eq!(key, "axes.e.loadcell.newtons_per_count");
    assert!(msg.contains("known weight"), "{msg}");
    let (key, _) = bad(
        "[axes.e.loadcell]\nmodule = \"e\"",
        "[axes.e.loadcell]\nmodule = \"q\"",
    );
    assert_eq!(key, "axes.e.loadcell.module");
    // The simulated melt: every key or none, physical values, a grip.
    let (key, msg) = bad("response_ms = 45.0\n", "");
    assert_eq!(key, "sim.axes.e.response_ms", "{msg}");
    let (key, _) = bad("flow_n = 0.6", "flow_n = 2.0");
    assert_eq!(key, "sim.axes.e.flow_n");
    let (key, _) = bad("max_force_n = 40.0 ", "");
    assert_eq!(key, "axes.e.max_force_n");
    let (key, msg) = bad("[sim.axes.z]\nstart = 10.0", "[sim.axes.z]\nstart = 10.0\nflow_k = 1.0\nflow_n = 0.5\ntemp_coeff = 0.0\nt_ref = 200.0\nresponse_ms = 10.0");
    assert_eq!(key, "sim.axes.z.flow_k", "{msg}");
    // A fitted model: positive values, an ordered range.
    let model = "retract_speed = 35.0\n\n[axes.e.model]\nflow_k = 8.0\nflow_n = 0.6\ntemp_coeff = 0.02\nt_ref = 210.0\nresponse_ms = 45.0\ntemp_range = [195.0, 235.0]\n";
    let with_model = text.replacen("retract_speed = 35.0\n", model, 1);
    let m = MachineFile::parse(&with_model).unwrap();
    assert_eq!(
        m.extruder()
            .unwrap()
            .extruder
            .model
            .as_ref()
            .unwrap()
            .temp_range,
        [195.0, 235.0]
    );
    let bad_model = with_model.replacen(
        "temp_range = [195.0, 235.0]",
        "temp_range = [235.0, 195.0]",
        1,
    );
    match MachineFile::parse(&bad_model) {
        Err(ConfigError::Invalid { key, .. }) => assert_eq!(key, "axes.e.model.temp_range"),
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_thermistor_is_named_given_as_beta_or_as_points_and_each_is_its_curve() {
    let text = std::fs::read_to_string(example("printer.toml")).unwrap();
    let hotend = |sensor: &str| {
        let t = text.replacen(
            "sensor = { analog = 0, thermistor = \"ATC Semitec 104GT-2\", pullup_ohms = 4700.0 }",
            sensor,
            1,
        );
        MachineFile::parse(&t).unwrap().heaters["hotend"]
            .sensor
            .curve()
            .unwrap()
    };
    // The catalogued 104GT-2 is the curve through its three datasheet
    // points, and so are those points given as a table.
    let named = hotend("sensor = { analog = 0, thermistor = \"ATC Semitec 104GT-2\" }");
    let table = hotend(
        "sensor = { analog = 0, points = [[20.0, 126800.0], [150.0, 1360.0], [300.0, 80.65]] }",
    );
    for (t, r) in [(20.0, 126_800.0), (150.0, 1_360.0), (300.0, 80.65)] {
        assert!((named.celsius(r) - t).abs() < 1e-6);
        assert!((table.celsius(r) - t).abs() < 1e-6);
    }
    // Nothing given: the common 100 kΩ β 3950.
    let plain = hotend("sensor = { analog = 0 }");
    assert_eq!(plain, SteinhartHart::from_beta(3950.0, 100_000.0));
    assert!((plain.celsius(100_000.0) - 25.0).abs() < 1e-9);
    // β 4267, the 104GT-2's own nominal β, reads 300 °C several degrees
    // off the datasheet's curve: the reason to name the thermistor.
    let beta = hotend("sensor = { analog = 0, beta = 4267.0 }");
    let off = beta.celsius(80.65) - 300.0;
    assert!(off.abs() > 3.0, "{off}");
}
