//! The simulated machine a machine file describes: the
//! [`SimSpec`] `Machine::simulate` starts, derived from
//! the file alone ([`spec`]), so no second file is needed.
//!
//! # Conventions
//!
//! - **Network**: the host –USB– one hub module named `hub` (type `hub`) –
//!   UART at 2 Mbaud – every module of `[modules]`, each of type `stepper`
//!   (the module firmware, which carries the stepper and the I/O
//!   functions). A module is named by its entry's `name` if it has one,
//!   else by its key. A module given by `route = [0, k]` sits on hub link
//!   `k` (1 to 7; hub link 0 is its USB uplink, the host's link 0); modules
//!   given by name take the free hub links in key order from 1. Hub links
//!   left free below the highest one taken hold a placeholder `hub` named
//!   `spare-K` (the hub's links are numbered in the order they are joined).
//!   The hub and modules get distinct clock rate errors spread evenly over
//!   −60..+60 ppm (hub first, then by hub link), so clock sync has work.
//! - **Boards**: a motor's module gets
//!   [`MotorSpec`]`{ full_steps_per_unit: motor.full_steps_per_unit, .. }`
//!   (the machine sets the module's scale and microsteps to match, so its
//!   positions, and the simulated carriage's, are in motor units); a module
//!   a tool is wired to gets a default [`IoSpec`]; others the defaults.
//! - **Where the machine is**: the machine sends motor `i`
//!   `m_i = s_i·q_i(p) − o_i` (`q` the kinematics' inverse: cartesian
//!   `q = ` the axis's coordinate, corexy `q_a = x + y`, `q_b = x − y`;
//!   `s_i = −1` for `invert = true`), with `o_i` such that every motor reads
//!   0 at boot while the machine believes it stands at `p0` (per axis 0 if
//!   `min ≤ 0 ≤ max`, else `min`). The simulated carriage of motor `i`
//!   starts at 0 and follows `m_i`, while the machine physically boots at
//!   the `[sim]` start ([`start_position`]: `[sim.axes.NAME] start`, by
//!   default the middle of the travel, so homing has to find the switch).
//!   So `q_i(p_phys) = q_i(start) + s_i·p_i`, which for these linear
//!   kinematics gives each axis as a linear form of carriage positions
//!   ([`axis_form`]): cartesian `axis = start + s·p_motor`; corexy
//!   `x = start_x + (s_a·p_a + s_b·p_b)/2`,
//!   `y = start_y + (s_a·p_a − s_b·p_b)/2`.
//! - **Switches**: one [`SwitchSpec`] per axis that homes on a switch
//!   ([`MachineFile::switch_placements`]), on the homing `switch` module's
//!   limit input, over that axis's form, pressed at the travel end it homes
//!   to (`direction = "min"`: while the axis is at or below `min`; `"max"`:
//!   at or above `max`). Its edges carry the time of the step that crossed
//!   (see [`osap_sim::machine`]'s switches over several motors).
//! - **Joint switches**: an arm (scara, fivebar) homes its joints
//!   ([`MachineFile::homed_joint`]): x's switch is pressed by the first
//!   joint's angle, y's by the second's, at the homing's `endstop`
//!   (radians), over the joint's form ([`joint_form`]: `q_j = q_j(start)
//!   + s_j·p_j`, exact, since a joint is its motor's own coordinate).

use std::collections::BTreeMap;

use osap_core::netresponder::NAME_MAX;
use osap_sim::machine::MODULE_LINKS;
use osap_sim::topology::{
    BedContact, ContactSpec, HeaterSpec, IoSpec, LinkKind, LinkSpec, ModuleSpec, MotorSpec,
    RotorSpec, SimSpec, SpecError, SpindleSpec, SwitchSpec, HOST,
};

use crate::config::{Direction, Kinematics, MachineFile, Probe};

pub(crate) mod accel;
mod machine;
pub(crate) mod melt;
mod vibration;

pub use machine::{SimOptions, SimStalls, StallSpan};
/// What the simulated melt did ([`Machine::sim_melt`](crate::Machine::sim_melt)), and its law.
pub use osap_sim::{machine::board::melt::MeltStats, topology::MeltSpec};
pub use vibration::vibration;

/// The simulated hub's name.
pub const HUB: &str = "hub";

/// Hub links modules can sit on (1 to 7; link 0 is the hub's uplink).
pub const HUB_MODULE_LINKS: usize = MODULE_LINKS - 1;

/// The baud rate of the hub's UARTs to the modules.
pub const UART_BAUD: u32 = 2_000_000;

/// The clock rate errors of the hub and modules spread over ± this, ppm.
pub const RATE_SPREAD_PPM: f64 = 60.0;

/// A machine file the simulation cannot build.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SimError {
    /// The file describes something the simulation does not (yet) do.
    #[error("simulating the machine file: {key}: {message}")]
    Unsupported {
        /// The key path the error is about, e.g. `modules.z.route`.
        key: String,
        /// What is wrong and how to fix it.
        message: String,
    },
    /// The derived spec failed the simulator's own check (a bug here, or
    /// a limit this module does not check first).
    #[error("simulating the machine file: the derived spec is invalid: {0}")]
    Spec(#[source] SpecError),
}

impl SimError {
    /// The key path an [`SimError::Unsupported`] is about.
    pub fn key(&self) -> Option<&str> {
        match self {
            SimError::Unsupported { key, .. } => Some(key),
            SimError::Spec(_) => None,
        }
    }
}

fn unsupported(key: impl Into<String>, message: impl Into<String>) -> SimError {
    SimError::Unsupported {
        key: key.into(),
        message: message.into(),
    }
}

/// Where the simulated machine boots on `axis`, axis units: its
/// `[sim.axes.NAME] start`, else the middle of its travel. `None` for an
/// axis the file does not have.
pub fn start_position(cfg: &MachineFile, axis: &str) -> Option<f64> {
    let a = cfg.axes.get(axis)?;
    let start = cfg
        .sim
        .as_ref()
        .and_then(|s| s.axes.get(axis))
        .and_then(|s| s.start);
    Some(start.unwrap_or((a.min + a.max) / 2.0))
}

/// The simulated module's name of `[modules]` entry `key`: its `name`, else
/// the key. `None` for a key the file does not have.
pub fn module_name<'a>(cfg: &'a MachineFile, key: &'a str) -> Option<&'a str> {
    let m = cfg.modules.get(key)?;
    Some(m.name.as_deref().unwrap_or(key))
}

/// An axis's physical coordinate as a linear form of the simulated
/// carriages' positions: `offset + Σ coef·(carriage of module)`.
#[derive(Debug, Clone, PartialEq)]
pub struct AxisForm {
    /// (simulated module name, coefficient).
    pub terms: Vec<(String, f64)>,
    /// The axis's coordinate with every carriage at 0 (its start).
    pub offset: f64,
}

impl AxisForm {
    /// The axis's coordinate with the carriages at `position(module)`.
    pub fn value(&self, mut position: impl FnMut(&str) -> f64) -> f64 {
        self.offset + self.terms.iter().map(|(m, c)| c * position(m)).sum::<f64>()
    }
}

/// `axis`'s physical coordinate on the simulated machine as a linear form
/// of its motors' carriage positions (see the conventions above): its own
/// motor's, or under corexy both belt motors' for x and y. Scara and
/// fivebar x and y are not linear: an error naming `key`.
pub fn axis_form(cfg: &MachineFile, axis: &str) -> Result<AxisForm, SimError> {
    let key = format!("axes.{axis}");
    let Some(start) = start_position(cfg, axis) else {
        return Err(unsupported(key, "no such axis in [axes]"));
    };
    let motor_term = |motor: &str, coef: f64| -> Result<(String, f64), SimError> {
        let m = cfg.motors.get(motor).ok_or_else(|| {
            unsupported(key.clone(), format!("motor {motor:?} is not in [motors]"))
        })?;
        let name = module_name(cfg, &m.module).ok_or_else(|| {
            unsupported(
                format!("motors.{motor}.module"),
                format!("module {:?} is not in [modules]", m.module),
            )
        })?;
        let sign = if m.invert { -1.0 } else { 1.0 };
        Ok((name.to_string(), sign * coef))
    };
    if let Some(motor) = cfg.motor_for_axis(axis) {
        return Ok(AxisForm {
            terms: vec![motor_term(motor, 1.0)?],
            offset: start,
        });
    }
    match (&cfg.kinematics, axis) {
        (Kinematics::CoreXy { motors }, "x" | "y") if motors.len() == 2 => {
            // x = (q_a + q_b)/2, y = (q_a − q_b)/2, q_i = q_i(start) + s_i·p_i.
            let b = if axis == "x" { 0.5 } else { -0.5 };
            Ok(AxisForm {
                terms: vec![motor_term(&motors[0], 0.5)?, motor_term(&motors[1], b)?],
                offset: start,
            })
        }
        (Kinematics::Scara { .. } | Kinematics::FiveBar { .. }, "x" | "y") => Err(unsupported(
            key,
            format!(
                "{} kinematics are not linear in the motors: x and y have no linear form; an arm's switches sit on its joints (joint_form)",
                cfg.kinematics.type_name()
            ),
        )),
        _ => Err(unsupported(
            format!("{key}.motor"),
            "no motor drives the axis; add motor = \"...\"",
        )),
    }
}

/// An arm's joint `j` (0 or 1 of `[kinematics] motors`) on the simulated
/// machine as a linear form of its motor's carriage: `q_j = q_j(start) +
/// s_j·p_j`, with `q(start)` the kinematics' inverse of the `[sim]` start
/// (see the conventions above). An error naming the kinematics when the
/// machine has no arm or the start is out of its reach.
pub fn joint_form(cfg: &MachineFile, j: usize) -> Result<AxisForm, SimError> {
    let key = "kinematics";
    let motor = cfg
        .kinematics
        .motors()
        .get(j)
        .ok_or_else(|| unsupported(key, format!("the kinematics have no joint {j}")))?;
    let mechanism = crate::machine::drive::mechanism(cfg)
        .map_err(|e| unsupported(key, e.to_string()))?
        .ok_or_else(|| unsupported(key, "cartesian kinematics have no joints"))?;
    let (Some(x), Some(y)) = (start_position(cfg, "x"), start_position(cfg, "y")) else {
        return Err(unsupported(key, "an arm needs axes x and y"));
    };
    let q = mechanism
        .inverse_xy(nalgebra::Vector2::new(x, y))
        .map_err(|e| {
            unsupported(
                "sim.axes",
                format!("the simulated arm's start ({x}, {y}) is out of its reach: {e}; give [sim.axes.x] and [sim.axes.y] start within it"),
            )
        })?;
    let m = cfg
        .motors
        .get(motor)
        .ok_or_else(|| unsupported(key, format!("motor {motor:?} is not in [motors]")))?;
    let name = module_name(cfg, &m.module).ok_or_else(|| {
        unsupported(
            format!("motors.{motor}.module"),
            format!("module {:?} is not in [modules]", m.module),
        )
    })?;
    let sign = if m.invert { -1.0 } else { 1.0 };
    Ok(AxisForm {
        terms: vec![(name.to_string(), sign)],
        offset: q[j],
    })
}

/// The simulated machine `cfg` describes (see the module docs for the
/// conventions): a hub on the host's USB, every module of `[modules]` on a
/// hub UART, motors, I/O and one switch over motors per axis homed on a
/// switch. Validated; errors name the key and the fix.
pub fn spec(cfg: &MachineFile) -> Result<SimSpec, SimError> {
    // Names.
    let mut names: BTreeMap<&str, String> = BTreeMap::new();
    for key in cfg.modules.keys() {
        let Some(name) = module_name(cfg, key) else {
            continue;
        };
        let at = if cfg.modules[key].name.is_some() {
            format!("modules.{key}.name")
        } else {
            format!("modules.{key}")
        };
        if name == HUB || name == HOST {
            return Err(unsupported(
                at,
                format!(
                    "the name {name:?} is the simulated {}'s; rename the module",
                    if name == HUB { "hub" } else { "host runtime" }
                ),
            ));
        }
        if name.len() > NAME_MAX {
            return Err(unsupported(
                at,
                format!(
                    "the module name {name:?} is {} bytes long; a module's name is at most {NAME_MAX} bytes",
                    name.len()
                ),
            ));
        }
        if let Some(other) = names.insert(name, key.clone()) {
            return Err(unsupported(
                at,
                format!(
                    "module {other:?} already has the name {name:?} in simulation (a module given by route is named by its key); give the modules distinct names"
                ),
            ));
        }
    }

    // Hub links: routes first, then the rest in key order.
    let mut slots: Vec<Option<&str>> = vec![None; HUB_MODULE_LINKS + 1];
    for (key, m) in &cfg.modules {
        let Some(route) = &m.route else { continue };
        let at = format!("modules.{key}.route");
        let k = match route.as_slice() {
            [0, k] if (1..=HUB_MODULE_LINKS as u16).contains(k) => usize::from(*k),
            _ => {
                return Err(unsupported(
                    at,
                    format!(
                        "route {route:?} cannot be simulated: the simulated machine has its modules on one hub on the host's link 0, so a route is [0, k] with k the hub link, 1 to {HUB_MODULE_LINKS}; use e.g. route = [0, 1], or name the module instead"
                    ),
                ))
            }
        };
        if let Some(other) = slots[k] {
            return Err(unsupported(
                at,
                format!("hub link {k} is already modules.{other}'s; give each module its own link"),
            ));
        }
        slots[k] = Some(key);
    }
    let by_name = cfg.modules.iter().filter(|(_, m)| m.route.is_none());
    let mut free = 1..;
    for (key, _) in by_name {
        let Some(k) = free
            .by_ref()
            .find(|&k| k > HUB_MODULE_LINKS || slots[k].is_none())
        else {
            unreachable!("an unbounded range");
        };
        if k > HUB_MODULE_LINKS {
            return Err(unsupported(
                "modules",
                format!(
                    "{} modules: the simulated hub has {HUB_MODULE_LINKS} links for modules; simulate fewer modules",
                    cfg.modules.len()
                ),
            ));
        }
        slots[k] = Some(key);
    }
    let used = slots.iter().rposition(Option::is_some).unwrap_or(0);

    // Motors and tools.
    let mut motor_of: BTreeMap<&str, &str> = BTreeMap::new();
    for (key, motor) in &cfg.motors {
        if let Some(other) = motor_of.insert(&motor.module, key) {
            return Err(unsupported(
                format!("motors.{key}.module"),
                format!(
                    "module {:?} already drives motor {other:?}; a simulated module has one motor: put each motor on its own module",
                    motor.module
                ),
            ));
        }
    }

    // Runtimes: the hub, then the modules by hub link; rates spread.
    let count = used + 1;
    let rate = |i: usize| {
        if count < 2 {
            0.0
        } else {
            -RATE_SPREAD_PPM + 2.0 * RATE_SPREAD_PPM * i as f64 / (count - 1) as f64
        }
    };
    // The load each modelled motor feels (kinematics linear in the motors;
    // arms simulate their motors without stalls).
    let loads = crate::machine::motor_accel::reflected_inertia(cfg).unwrap_or_default();
    let mut t = SimSpec::new(&cfg.name)
        .with_module(ModuleSpec::new(HUB, "hub").with_rate_ppm(rate(0)))
        .with_link(LinkSpec::new(HOST, HUB, LinkKind::Usb));
    for (k, slot) in slots.iter().enumerate().take(used + 1).skip(1) {
        let (name, spec) = match slot {
            None => {
                let mut name = format!("spare-{k}");
                while names.contains_key(name.as_str()) {
                    name.push('_');
                }
                (name.clone(), ModuleSpec::new(&name, "hub"))
            }
            Some(key) => {
                let name = module_name(cfg, key).unwrap_or(key).to_string();
                let mut spec = ModuleSpec::new(&name, "stepper");
                if let Some((motor_key, motor)) = motor_of.get(key).map(|m| (*m, &cfg.motors[*m])) {
                    // A motor with datasheet values stalls as it would.
                    let rotor = motor.model.map(|keys| RotorSpec {
                        model: keys.model(),
                        load_inertia_kgm2: loads
                            .iter()
                            .find(|(n, _)| n == motor_key)
                            .map_or(0.0, |l| l.1),
                        damping_ratio: 0.3,
                    });
                    spec = spec.with_motor(MotorSpec {
                        full_steps_per_unit: motor.full_steps_per_unit,
                        rotor,
                        ..MotorSpec::default()
                    });
                }
                if cfg.tools.values().any(|tool| tool.module == *key) {
                    spec = spec.with_io(IoSpec::default());
                }
                // A spindle with a tachometer: its motor and drive.
                if let Some(spindle) = sim_spindle(cfg, key)? {
                    let mut io = spec.io.clone().unwrap_or_default();
                    io.spindle = Some(spindle);
                    spec = spec.with_io(io);
                }
                // The heaters on this module, each with its thermal model.
                for (hname, h) in cfg.heaters.iter().filter(|(_, h)| h.module == *key) {
                    let Some(model) = cfg.sim.as_ref().and_then(|s| s.heaters.get(hname)) else {
                        return Err(unsupported(
                            format!("heaters.{hname}"),
                            format!("a simulated heater needs its thermal model: add [sim.heaters.{hname}] with power_w, heat_capacity_j_per_k and loss_w_per_k"),
                        ));
                    };
                    let mut io = spec.io.clone().unwrap_or_default();
                    io.heaters.push(HeaterSpec {
                        pwm: h.pwm(),
                        analog: h.sensor.analog,
                        // The simulated thermistor is the one the file
                        // names (the file was checked when read).
                        beta: 3950.0,
                        r25_ohms: 100_000.0,
                        steinhart_hart: h.sensor.curve().ok().map(|c| [c.a, c.b, c.c]),
                        pullup_ohms: h.sensor.pullup_ohms,
                        power_w: model.power_w,
                        heat_capacity_j_per_k: model.heat_capacity_j_per_k,
                        loss_w_per_k: model.loss_w_per_k,
                        ambient_c: model.ambient_c,
                        sensor_fails_at_s: model.sensor_fails_at_s,
                    });
                    spec = spec.with_io(io);
                }
                // The extruder's melt and its load cell.
                if let Some(melt) = melt::sim_melt(cfg, key).map_err(|(k, m)| unsupported(k, m))? {
                    let mut io = spec.io.clone().unwrap_or_default();
                    io.melt = Some(melt);
                    spec = spec.with_io(io);
                }
                // A nozzle load cell the probe's module weighs the bed with.
                if let Some(contact) = probe_contact(cfg, key)? {
                    let mut io = spec.io.clone().unwrap_or_default();
                    io.contact = Some(contact);
                    spec = spec.with_io(io);
                }
                // An accelerometer of `osap resonance` on this module.
                if let Some(accel) =
                    accel::sim_accel(cfg, key).map_err(|(k, m)| unsupported(k, m))?
                {
                    let mut io = spec.io.clone().unwrap_or_default();
                    io.accel = Some(accel);
                    spec = spec.with_io(io);
                }
                (name, spec)
            }
        };
        t = t
            .with_module(spec.with_rate_ppm(rate(k)))
            .with_link(LinkSpec {
                baud: Some(UART_BAUD),
                ..LinkSpec::new(HUB, &name, LinkKind::Uart)
            });
    }

    // Switches.
    for placement in cfg.switch_placements() {
        let form = match placement.joint {
            Some(j) => joint_form(cfg, j),
            None => axis_form(cfg, placement.axis),
        }
        .map_err(|e| match e {
            SimError::Unsupported { message, .. } => {
                unsupported(format!("axes.{}.homing.switch", placement.axis), message)
            }
            other => other,
        })?;
        let Some(module) = module_name(cfg, placement.module) else {
            return Err(unsupported(
                format!("axes.{}.homing.switch", placement.axis),
                format!("module {:?} is not in [modules]", placement.module),
            ));
        };
        t = t.with_switch(SwitchSpec {
            module: module.to_string(),
            terms: form.terms,
            offset: form.offset,
            at: placement.position,
            pressed_below: placement.direction == Direction::Min,
            bed: None,
        });
    }

    // The bed probe: pressed while its tip is at or below the bed.
    let bed = cfg.sim.as_ref().and_then(|s| s.bed.as_ref());
    // (A load-cell probe is the probe module's contact, above.)
    if let (Some(probe @ Probe { loadcell: None, .. }), Some(bed)) = (&cfg.probe, bed) {
        let (surface, Some(module)) = (*bed, module_name(cfg, &probe.module)) else {
            return Err(unsupported(
                "probe",
                "a simulated probe needs its module in [modules]",
            ));
        };
        let [ox, oy, oz] = probe.offset;
        let (x, y, z) = (
            axis_form(cfg, "x")?,
            axis_form(cfg, "y")?,
            axis_form(cfg, "z")?,
        );
        t = t.with_switch(SwitchSpec {
            module: module.to_string(),
            terms: z.terms,
            offset: z.offset + oz,
            at: 0.0,
            pressed_below: true,
            bed: Some(BedContact {
                x_terms: x.terms,
                x_offset: x.offset + ox,
                y_terms: y.terms,
                y_offset: y.offset + oy,
                surface,
            }),
        });
    }

    t.validate().map_err(SimError::Spec)?;
    Ok(t)
}

/// The simulated spindle of `key`'s module: its spindle tool with a
/// `tach`, driven by its PWM output at `duty × max_rpm / on_duty` (the
/// drive's full scale), with the motor and drive of
/// `[sim.spindles.NAME]`.
fn sim_spindle(cfg: &MachineFile, key: &str) -> Result<Option<SpindleSpec>, SimError> {
    let Some((name, tool, tach)) = cfg
        .tools
        .iter()
        .filter(|(_, t)| t.module == key)
        .find_map(|(n, t)| Some((n, t, t.tach?)))
    else {
        return Ok(None);
    };
    let Some(model) = cfg.sim.as_ref().and_then(|s| s.spindles.get(name)) else {
        return Err(unsupported(
            format!("tools.{name}.tach"),
            format!("a simulated spindle with a tachometer needs its motor and drive: add [sim.spindles.{name}] with inertia_kgm2, max_torque_nm and time_constant_s"),
        ));
    };
    let (crate::config::Output::Pwm(pwm), Some(max_rpm)) = (tool.output, tool.max_rpm) else {
        return Err(unsupported(
            format!("tools.{name}.output"),
            "a simulated spindle's drive is commanded by a PWM output: give output = { pwm = N } and max_rpm",
        ));
    };
    if tool.off_duty != 0.0 || tool.on_duty <= 0.0 {
        return Err(unsupported(
            format!("tools.{name}.off_duty"),
            "a simulated spindle's drive stands at 0 duty and scales with it: keep off_duty = 0 and on_duty above 0",
        ));
    }
    Ok(Some(SpindleSpec {
        pwm,
        max_rpm: max_rpm / tool.on_duty,
        tach_pin: tach.pin,
        pulses_per_rev: tach.pulses_per_rev,
        inertia_kgm2: model.inertia_kgm2,
        max_torque_nm: model.max_torque_nm,
        time_constant_s: model.time_constant_s,
        drag_nm: model.drag_nm,
    }))
}

/// The contact a `[probe] loadcell` presses on `key`'s module: the bed of
/// `[sim.bed]` (flat) under the tip the module's own carriage moves.
fn probe_contact(cfg: &MachineFile, key: &str) -> Result<Option<ContactSpec>, SimError> {
    let Some((probe, cell)) = cfg
        .probe
        .as_ref()
        .and_then(|p| Some((p, p.loadcell?)))
        .filter(|(p, _)| p.module == key)
    else {
        return Ok(None);
    };
    let Some(bed) = cfg.sim.as_ref().and_then(|s| s.bed.as_ref()) else {
        return Ok(None);
    };
    if bed.tilt_x != 0.0 || bed.tilt_y != 0.0 || bed.warp != 0.0 {
        return Err(unsupported(
            "probe.loadcell",
            "a simulated load-cell probe presses a flat bed: set [sim.bed] tilt_x, tilt_y and warp to 0",
        ));
    }
    let z = axis_form(cfg, "z")?;
    let name = module_name(cfg, key).unwrap_or(key);
    let [(module, coef)] = z.terms.as_slice() else {
        return Err(unsupported(
            "probe.loadcell",
            "a simulated load-cell probe weighs the z axis its module drives alone",
        ));
    };
    if module != name || *coef == 0.0 {
        return Err(unsupported(
            "probe.loadcell",
            format!("a simulated load-cell probe weighs z: put it on z's module, not {key:?}"),
        ));
    }
    // The tip is at coef·p + offset + offset_z; it touches at the bed's z.
    let touch_at = (bed.z - z.offset - probe.offset[2]) / coef;
    Ok(Some(ContactSpec {
        touch_at,
        pressing_below: *coef > 0.0,
        stiffness_n_per_unit: 40.0,
        data_pin: cell.data_pin,
        clock_pin: cell.clock_pin,
        sample_hz: 320.0,
        counts_per_newton: 1.0 / cell.newtons_per_count,
        offset_counts: 85_000.0,
        noise_n: 0.02,
        seed: 0,
    }))
}

#[cfg(test)]
mod tests;
