//! Checks that a machine file describes a possible machine: each check
//! names the first offending key and the fix.

use std::collections::{BTreeMap, BTreeSet};

use super::*;

impl MachineFile {
    pub(super) fn validate_modules(&self) -> Result<(), ConfigError> {
        let mut names = BTreeMap::new();
        let mut routes = BTreeMap::new();
        for (key, module) in &self.modules {
            let at = format!("modules.{key}");
            match (&module.name, &module.route) {
                (Some(_), Some(_)) => {
                    return Err(invalid(
                        at,
                        "both name and route are given; keep one of them",
                    ))
                }
                (None, None) => {
                    return Err(invalid(
                        at,
                        "neither name nor route is given; add name = \"...\" (as set by osap rename) or route = [link, ...]",
                    ))
                }
                (Some(name), None) => {
                    if name.trim().is_empty() {
                        return Err(invalid(
                            format!("{at}.name"),
                            "the module name is empty; use the name set by osap rename",
                        ));
                    }
                    if let Some(other) = names.insert(name.as_str(), key.as_str()) {
                        return Err(invalid(
                            format!("{at}.name"),
                            format!(
                                "duplicate module name {name:?}, also used by modules.{other}; each module appears once"
                            ),
                        ));
                    }
                }
                (None, Some(route)) => {
                    if route.is_empty() {
                        return Err(invalid(
                            format!("{at}.route"),
                            "the route is empty; list the link index of each hop from the host",
                        ));
                    }
                    if route.len() > MAX_ROUTE_HOPS {
                        return Err(invalid(
                            format!("{at}.route"),
                            format!(
                                "the route has {} hops, more than {MAX_ROUTE_HOPS}; check the route",
                                route.len()
                            ),
                        ));
                    }
                    if let Some(other) = routes.insert(route.as_slice(), key.as_str()) {
                        return Err(invalid(
                            format!("{at}.route"),
                            format!(
                                "duplicate route {route:?}, also used by modules.{other}; each module appears once"
                            ),
                        ));
                    }
                }
            }
            if let Some(ms) = module.output_watchdog_ms {
                if !OUTPUT_WATCHDOG_MS.contains(&ms) {
                    return Err(invalid(
                        format!("{at}.output_watchdog_ms"),
                        format!(
                            "{ms} ms is outside {} to {} ms; give how long the module may go without hearing from the host before it switches its tools off (default {DEFAULT_OUTPUT_WATCHDOG_MS})",
                            OUTPUT_WATCHDOG_MS.start(),
                            OUTPUT_WATCHDOG_MS.end()
                        ),
                    ));
                }
            }
        }
        Ok(())
    }

    fn module_exists(&self, key: String, module: &str) -> Result<(), ConfigError> {
        if self.modules.contains_key(module) {
            Ok(())
        } else {
            Err(invalid(
                key,
                format!(
                    "module {module:?} is not in [modules]; add it there ({}) or fix the name",
                    known(self.modules.keys())
                ),
            ))
        }
    }

    fn motor_exists(&self, key: String, motor: &str) -> Result<(), ConfigError> {
        if self.motors.contains_key(motor) {
            Ok(())
        } else {
            Err(invalid(
                key,
                format!(
                    "motor {motor:?} is not in [motors]; add it there ({}) or fix the name",
                    known(self.motors.keys())
                ),
            ))
        }
    }

    pub(super) fn validate_motors(&self) -> Result<(), ConfigError> {
        for (key, motor) in &self.motors {
            let at = format!("motors.{key}");
            self.module_exists(format!("{at}.module"), &motor.module)?;
            positive(
                &format!("{at}.full_steps_per_unit"),
                motor.full_steps_per_unit,
                "full steps per unit of travel, e.g. 5 for a GT2 belt on a 20-tooth pulley (40 mm a turn, 200 steps)",
            )?;
            let m = motor.microsteps;
            if !(1..=256).contains(&m) || !m.is_power_of_two() {
                return Err(invalid(
                    format!("{at}.microsteps"),
                    format!("microsteps {m} is not a power of two from 1 to 256; use e.g. 16"),
                ));
            }
        }
        // Each motor drives exactly one thing.
        let mut users: BTreeMap<&str, String> = BTreeMap::new();
        let mechanism = self
            .kinematics
            .motors()
            .iter()
            .enumerate()
            .map(|(i, m)| (format!("kinematics.motors[{i}]"), m.as_str()));
        let own = self
            .axes
            .iter()
            .filter_map(|(axis, a)| Some((format!("axes.{axis}.motor"), a.motor.as_deref()?)));
        for (at, motor) in mechanism.chain(own) {
            self.motor_exists(at.clone(), motor)?;
            if let Some(other) = users.insert(motor, at.clone()) {
                return Err(invalid(
                    at,
                    format!(
                        "duplicate: motor {motor:?} already drives {other}; give each a motor of its own"
                    ),
                ));
            }
        }
        for key in self.motors.keys() {
            if !users.contains_key(key.as_str()) {
                return Err(invalid(
                    format!("motors.{key}"),
                    "the motor drives nothing; name it in an axis (motor = \"...\") or in kinematics.motors, or remove it",
                ));
            }
        }
        Ok(())
    }

    pub(super) fn validate_kinematics(&self) -> Result<(), ConfigError> {
        let kin = &self.kinematics;
        if let Kinematics::Cartesian {} = kin {
            return Ok(());
        }
        let kind = kin.type_name();
        if kin.motors().len() != 2 {
            return Err(invalid(
                "kinematics.motors",
                format!(
                    "{kind} needs exactly 2 motors (for x and y), found {}; list two motors",
                    kin.motors().len()
                ),
            ));
        }
        for axis in ["x", "y"] {
            match self.axes.get(axis) {
                None => {
                    return Err(invalid(
                        format!("axes.{axis}"),
                        format!("{kind} kinematics drive x and y; add [axes.{axis}]"),
                    ))
                }
                Some(a) if a.motor.is_some() => {
                    return Err(invalid(
                        format!("axes.{axis}.motor"),
                        format!(
                            "{kind} kinematics drive {axis} with kinematics.motors; remove the axis's motor key"
                        ),
                    ))
                }
                Some(_) => {}
            }
        }
        match kin {
            Kinematics::Scara {
                l1, l2, margin_deg, ..
            } => {
                positive("kinematics.l1", *l1, "the shoulder link length")?;
                positive("kinematics.l2", *l2, "the forearm link length")?;
                margin("kinematics.margin_deg", *margin_deg)?;
            }
            Kinematics::FiveBar {
                span,
                l1,
                l2,
                margin_deg,
                ..
            } => {
                positive("kinematics.span", *span, "the distance between the motors")?;
                positive("kinematics.l1", *l1, "the proximal link length")?;
                positive("kinematics.l2", *l2, "the distal link length")?;
                margin("kinematics.margin_deg", *margin_deg)?;
            }
            _ => {}
        }
        Ok(())
    }

    pub(super) fn validate_axes(&self) -> Result<(), ConfigError> {
        for (name, axis) in &self.axes {
            let at = format!("axes.{name}");
            if !AXIS_NAMES.contains(&name.as_str()) {
                return Err(invalid(
                    at,
                    format!("unknown axis; use one of {}", AXIS_NAMES.join(", ")),
                ));
            }
            if axis.motor.is_none() && !is_mechanism_axis(&self.kinematics, name) {
                return Err(invalid(
                    format!("{at}.motor"),
                    format!(
                        "no motor drives the axis under {} kinematics; add motor = \"...\" ({})",
                        self.kinematics.type_name(),
                        known(self.motors.keys())
                    ),
                ));
            }
            self.validate_axis_kind(name, axis)?;
            if axis.kind == AxisKind::Extruder {
                positive(&format!("{at}.velocity"), axis.velocity, "mm/s")?;
                positive(&format!("{at}.acceleration"), axis.acceleration, "mm/s²")?;
                positive(&format!("{at}.jerk"), axis.jerk, "mm/s³")?;
                continue;
            }
            for (key, v) in [("min", axis.min), ("max", axis.max)] {
                if v.is_nan() {
                    return Err(invalid(
                        format!("{at}.{key}"),
                        format!(
                            "missing: give the soft travel's {} end (units)",
                            if key == "min" { "low" } else { "high" }
                        ),
                    ));
                }
            }
            finite(&format!("{at}.min"), axis.min)?;
            finite(&format!("{at}.max"), axis.max)?;
            if axis.min >= axis.max {
                return Err(invalid(
                    at,
                    format!(
                        "min {} must be below max {}; swap them or fix the travel",
                        axis.min, axis.max
                    ),
                ));
            }
            positive(&format!("{at}.velocity"), axis.velocity, "units/s")?;
            positive(&format!("{at}.acceleration"), axis.acceleration, "units/s²")?;
            positive(&format!("{at}.jerk"), axis.jerk, "units/s³")?;
            if let Some(homing) = &axis.homing {
                self.validate_homing(&format!("{at}.homing"), axis, homing)?;
            }
        }
        Ok(())
    }

    /// An extruder is axis `e` and only it; its keys are refused
    /// elsewhere, and checked there.
    fn validate_axis_kind(&self, name: &str, axis: &Axis) -> Result<(), ConfigError> {
        let at = format!("axes.{name}");
        let extruder = axis.kind == AxisKind::Extruder;
        if extruder != (name == "e") {
            return Err(invalid(
                format!("{at}.kind"),
                if extruder {
                    "only axis e may be an extruder; name it [axes.e]".to_string()
                } else {
                    "axis e is the extruder; add kind = \"extruder\" (and its filament_diameter)"
                        .to_string()
                },
            ));
        }
        if !extruder {
            if let Some(key) = axis.extruder.given().next() {
                return Err(invalid(
                    format!("{at}.{key}"),
                    "an extruder's key on an axis that is not one; remove it, or move it to [axes.e]",
                ));
            }
            return Ok(());
        }
        if !(axis.min.is_infinite() && axis.max.is_infinite()) {
            return Err(invalid(at, "an extruder has no travel; remove min and max"));
        }
        if axis.homing.is_some() {
            return Err(invalid(
                format!("{at}.homing"),
                "an extruder does not home; remove its homing",
            ));
        }
        let e = &axis.extruder;
        match e.filament_diameter {
            None => {
                return Err(invalid(
                    format!("{at}.filament_diameter"),
                    "missing: give the filament's diameter in mm (1.75 or 2.85)",
                ))
            }
            Some(d) if !(d.is_finite() && (0.5..=5.0).contains(&d)) => {
                return Err(invalid(
                    format!("{at}.filament_diameter"),
                    format!("{d} mm is not a filament diameter; use 1.75 or 2.85"),
                ))
            }
            _ => {}
        }
        let keys = [
            (
                "max_volumetric_speed",
                e.max_volumetric_speed,
                "mm³/s, e.g. 15 for a V6-class hotend",
            ),
            (
                "max_force_n",
                e.max_force_n,
                "N, e.g. 40 for a geared extruder",
            ),
            (
                "instantaneous_corner_velocity",
                e.instantaneous_corner_velocity,
                "mm/s, e.g. 1",
            ),
            (
                "retract_length",
                e.retract_length,
                "mm, e.g. 0.8 for a direct drive",
            ),
            ("retract_speed", e.retract_speed, "mm/s, e.g. 35"),
        ];
        for (key, v, hint) in keys {
            if let Some(v) = v {
                positive(&format!("{at}.{key}"), v, hint)?;
            }
        }
        if let Some(k) = e.pressure_advance {
            if !(k.is_finite() && (0.0..=1.0).contains(&k)) {
                return Err(invalid(
                    format!("{at}.pressure_advance"),
                    format!("{k} s is outside 0 to 1 s; typical values are 0.02–0.1 for a direct drive, up to 1 for a Bowden tube"),
                ));
            }
        }
        if let Some(t) = e.smooth_time {
            if !(t.is_finite() && t > 0.0 && t <= 0.2) {
                return Err(invalid(
                    format!("{at}.smooth_time"),
                    format!("{t} s is outside (0, 0.2] s; Klipper's default is 0.040"),
                ));
            }
        }
        super::extruder::validate_rheo(self, &at, e)
    }

    /// `probe = true`: z homes down onto the bed with the probe's load
    /// cell.
    fn validate_probe_homing(
        &self,
        at: &str,
        axis: &Axis,
        homing: &Homing,
    ) -> Result<(), ConfigError> {
        if homing.switch.is_some() || homing.stall.is_some() {
            return Err(invalid(
                at,
                "probe homing takes no switch or stall; keep one way of homing",
            ));
        }
        if at != "axes.z.homing" || homing.direction != Direction::Min {
            return Err(invalid(
                at,
                "probe homing is z's, downwards onto the bed: direction = \"min\"",
            ));
        }
        if self.probe.as_ref().and_then(|p| p.loadcell).is_none() {
            return Err(invalid(
                format!("{at}.probe"),
                "probe homing presses the bed with [probe]'s load cell: give [probe] a loadcell",
            ));
        }
        let Some(bed) = homing.endstop else {
            return Err(invalid(
                format!("{at}.endstop"),
                "probe homing needs endstop: the z of the bed's surface",
            ));
        };
        if !(bed.is_finite() && (axis.min..=axis.max).contains(&bed)) {
            return Err(invalid(
                format!("{at}.endstop"),
                format!(
                    "the bed's z {bed} must lie within z's travel [{}, {}]",
                    axis.min, axis.max
                ),
            ));
        }
        positive(
            &format!("{at}.search_speed"),
            homing.search_speed,
            "units/s",
        )?;
        if homing.search_speed > axis.velocity {
            return Err(invalid(
                format!("{at}.search_speed"),
                format!(
                    "search speed {} is above the axis velocity {}; lower it",
                    homing.search_speed, axis.velocity
                ),
            ));
        }
        Ok(())
    }

    pub(super) fn validate_homing(
        &self,
        at: &str,
        axis: &Axis,
        homing: &Homing,
    ) -> Result<(), ConfigError> {
        if homing.probe {
            return self.validate_probe_homing(at, axis, homing);
        }
        match (&homing.switch, &homing.stall) {
            (Some(_), Some(_)) => {
                return Err(invalid(
                    at,
                    "both switch and stall are given; keep one of them",
                ))
            }
            (None, None) => {
                return Err(invalid(
                    at,
                    "neither switch nor stall is given; add switch = \"<module>\" (its limit input) or stall = \"<motor>\"",
                ))
            }
            (Some(module), None) => {
                self.module_exists(format!("{at}.switch"), module)?;
                match homing.latch_speed {
                    None => {
                        return Err(invalid(
                            format!("{at}.latch_speed"),
                            "switch homing needs a latch speed; add latch_speed (slower than search_speed)",
                        ))
                    }
                    Some(latch) => {
                        positive(&format!("{at}.latch_speed"), latch, "units/s")?;
                        if latch > homing.search_speed {
                            return Err(invalid(
                                format!("{at}.latch_speed"),
                                format!(
                                    "latch speed {latch} is above search speed {}; make the latch the slower approach",
                                    homing.search_speed
                                ),
                            ));
                        }
                    }
                }
            }
            (None, Some(motor)) => {
                self.motor_exists(format!("{at}.stall"), motor)?;
                if let Some(latch) = homing.latch_speed {
                    positive(&format!("{at}.latch_speed"), latch, "units/s")?;
                }
            }
        }
        positive(
            &format!("{at}.search_speed"),
            homing.search_speed,
            "units/s",
        )?;
        if let Some(joint) = at
            .strip_prefix("axes.")
            .and_then(|a| a.strip_suffix(".homing"))
            .and_then(|a| self.homed_joint(a))
        {
            return self.validate_joint_homing(at, joint, homing);
        }
        if homing.search_speed > axis.velocity {
            return Err(invalid(
                format!("{at}.search_speed"),
                format!(
                    "search speed {} is above the axis velocity {}; lower it",
                    homing.search_speed, axis.velocity
                ),
            ));
        }
        finite(&format!("{at}.backoff"), homing.backoff)?;
        if homing.backoff < 0.0 {
            return Err(invalid(
                format!("{at}.backoff"),
                format!(
                    "backoff {} is negative; give the distance to move away, e.g. 2",
                    homing.backoff
                ),
            ));
        }
        self.validate_endstop(at, axis, homing)
    }

    /// An arm's joint homing ([`MachineFile::homed_joint`]): in radians,
    /// with the switch's angle given, a backoff within half a turn, and
    /// the other joint homed on a switch too (an arm's pose needs both).
    fn validate_joint_homing(
        &self,
        at: &str,
        joint: usize,
        homing: &Homing,
    ) -> Result<(), ConfigError> {
        let Some(endstop) = homing.endstop else {
            return Err(invalid(
                format!("{at}.endstop"),
                format!(
                    "an arm's {} homes joint {joint} ({}): give endstop, the joint's angle in radians where its switch closes",
                    self.kinematics.type_name(),
                    self.kinematics.motors().get(joint).map_or("?", String::as_str)
                ),
            ));
        };
        finite(&format!("{at}.endstop"), endstop)?;
        if !(homing.backoff > 0.0 && homing.backoff < std::f64::consts::PI) {
            return Err(invalid(
                format!("{at}.backoff"),
                format!(
                    "backoff {} rad must be above 0 and below half a turn (π); e.g. 0.1",
                    homing.backoff
                ),
            ));
        }
        let other = if joint == 0 { "y" } else { "x" };
        if self.homed_joint(other).is_none() {
            return Err(invalid(
                format!("axes.{other}.homing"),
                format!(
                    "{} kinematics home both joints (x's homing the first, y's the second); give axes.{other} switch homing too",
                    self.kinematics.type_name()
                ),
            ));
        }
        Ok(())
    }

    /// The endstop lies beyond the soft travel (or at its edge) on the
    /// homed side, and the backoff brings the axis from it back inside.
    pub(super) fn validate_endstop(
        &self,
        at: &str,
        axis: &Axis,
        homing: &Homing,
    ) -> Result<(), ConfigError> {
        let endstop = homing.endstop(axis);
        if let Some(given) = homing.endstop {
            finite(&format!("{at}.endstop"), given)?;
        }
        let (end, side, past) = match homing.direction {
            Direction::Min => (axis.min, "min", endstop > axis.min),
            Direction::Max => (axis.max, "max", endstop < axis.max),
        };
        if past {
            return Err(invalid(
                format!("{at}.endstop"),
                format!(
                    "endstop {endstop} lies inside the travel [{}, {}]: a job would press the switch; put it at or beyond {side} = {end} (default {ENDSTOP_BEYOND} beyond)",
                    axis.min, axis.max
                ),
            ));
        }
        let homed = homing.homed_position(axis);
        if homed < axis.min || homed > axis.max {
            let need = (endstop - end).abs();
            return Err(invalid(
                format!("{at}.backoff"),
                format!(
                    "backoff {} from the endstop {endstop} leaves the axis at {homed}, outside the travel [{}, {}]; give a backoff from {need} to {}",
                    homing.backoff,
                    axis.min,
                    axis.max,
                    need + (axis.max - axis.min)
                ),
            ));
        }
        Ok(())
    }

    pub(super) fn validate_limits(&self) -> Result<(), ConfigError> {
        let l = &self.limits;
        positive("limits.velocity", l.velocity, "units/s")?;
        positive("limits.acceleration", l.acceleration, "units/s²")?;
        positive(
            "limits.junction_deviation",
            l.junction_deviation,
            "units, e.g. 0.02",
        )?;
        let r = l.minimum_cruise_ratio;
        if !(r.is_finite() && (0.0..1.0).contains(&r)) {
            return Err(invalid(
                "limits.minimum_cruise_ratio",
                format!("{r} must be in [0, 1), e.g. 0.5"),
            ));
        }
        if let Some(j) = l.jerk {
            positive("limits.jerk", j, "units/s³, e.g. 100000")?;
            if l.profile != super::ProfileKind::Scurve {
                return Err(invalid(
                    "limits.jerk",
                    "the toolhead's jerk only bounds jerk-limited profiles: add profile = \"scurve\", or remove jerk",
                ));
            }
        }
        let m = l.module_margin;
        if !(m.is_finite() && (m == 0.0 || m >= 1.0)) {
            return Err(invalid(
                "limits.module_margin",
                format!("{m} must be 0 (firmware limits off) or at least 1, e.g. 1.5"),
            ));
        }
        for (name, motor) in &self.motors {
            if let Some(ml) = &motor.limits {
                let at = format!("motors.{name}.limits");
                positive(&format!("{at}.velocity"), ml.velocity, "motor units/s")?;
                positive(
                    &format!("{at}.acceleration"),
                    ml.acceleration,
                    "motor units/s²",
                )?;
                if !(ml.jerk.is_finite() && ml.jerk >= 0.0) {
                    return Err(invalid(
                        format!("{at}.jerk"),
                        format!("{} must be 0 (unchecked) or positive", ml.jerk),
                    ));
                }
            }
        }
        Ok(())
    }

    pub(super) fn validate_tools(&self) -> Result<(), ConfigError> {
        let mut outputs: BTreeMap<(&str, Output), &str> = BTreeMap::new();
        for (key, tool) in &self.tools {
            let at = format!("tools.{key}");
            self.module_exists(format!("{at}.module"), &tool.module)?;
            match tool.output {
                Output::Pwm(channel) if channel >= PWM_CHANNELS => {
                    return Err(invalid(
                        format!("{at}.output.pwm"),
                        format!(
                            "PWM channel {channel} does not exist; a module has channels 0 to {}",
                            PWM_CHANNELS - 1
                        ),
                    ))
                }
                Output::Digital(pin) if pin >= DIGITAL_PINS => {
                    return Err(invalid(
                        format!("{at}.output.digital"),
                        format!(
                            "digital pin {pin} does not exist; a module has pins 0 to {}",
                            DIGITAL_PINS - 1
                        ),
                    ))
                }
                _ => {}
            }
            if let Some(other) = outputs.insert((tool.module.as_str(), tool.output), key) {
                return Err(invalid(
                    format!("{at}.output"),
                    format!(
                        "duplicate: tools.{other} already uses this output of module {:?}; wire each tool to its own output",
                        tool.module
                    ),
                ));
            }
            for (name, duty) in [("on_duty", tool.on_duty), ("off_duty", tool.off_duty)] {
                if !(0.0..=1.0).contains(&duty) {
                    return Err(invalid(
                        format!("{at}.{name}"),
                        format!("duty {duty} is outside 0 to 1; give a fraction of full duty"),
                    ));
                }
            }
            if let Some(rpm) = tool.max_rpm {
                if tool.kind != ToolKind::Spindle {
                    return Err(invalid(
                        format!("{at}.max_rpm"),
                        "max_rpm is for spindles only; remove it or set kind = \"spindle\"",
                    ));
                }
                positive(&format!("{at}.max_rpm"), rpm, "rpm")?;
            }
            if tool.dynamic && !tool.streamed() {
                return Err(invalid(
                    format!("{at}.dynamic"),
                    "dynamic power is for a laser on a PWM output; remove it, or set kind = \"laser\" and output = { pwm = N }",
                ));
            }
            if let Some(s) = tool.s_max {
                if tool.kind != ToolKind::Laser {
                    return Err(invalid(
                        format!("{at}.s_max"),
                        "s_max is for lasers only (a spindle's S is rpm: give max_rpm); remove it or set kind = \"laser\"",
                    ));
                }
                positive(&format!("{at}.s_max"), s, "(the S word at full power)")?;
            }
        }
        Ok(())
    }

    pub(super) fn validate_sim(&self) -> Result<(), ConfigError> {
        let Some(sim) = &self.sim else {
            return Ok(());
        };
        for (name, axis) in &sim.axes {
            let at = format!("sim.axes.{name}");
            let Some(travel) = self.axes.get(name) else {
                return Err(invalid(
                    at,
                    format!(
                        "unknown axis; simulate one of the machine's axes ({})",
                        known(self.axes.keys())
                    ),
                ));
            };
            if let Some(start) = axis.start {
                finite(&format!("{at}.start"), start)?;
                if !(travel.min..=travel.max).contains(&start) {
                    return Err(invalid(
                        format!("{at}.start"),
                        format!(
                            "start {start} is outside the axis's travel [{}, {}]; give a position within it, or leave start out for the middle of the travel",
                            travel.min, travel.max
                        ),
                    ));
                }
            }
            super::extruder::validate_sim_melt(self, &at, name, axis)?;
            match axis.given {
                [false, false] => continue,
                [true, false] => {
                    return Err(invalid(
                        format!("{at}.damping_ratio"),
                        "resonance_hz is given without damping_ratio; give both (e.g. damping_ratio = 0.1) or neither",
                    ))
                }
                [false, true] => {
                    return Err(invalid(
                        format!("{at}.resonance_hz"),
                        "damping_ratio is given without resonance_hz; give both (e.g. resonance_hz = 40) or neither",
                    ))
                }
                [true, true] => {}
            }
            positive(&format!("{at}.resonance_hz"), axis.resonance_hz, "Hz")?;
            finite(&format!("{at}.damping_ratio"), axis.damping_ratio)?;
            if axis.damping_ratio < 0.0 {
                return Err(invalid(
                    format!("{at}.damping_ratio"),
                    format!(
                        "damping ratio {} is negative; use 0 (undamped) or more, e.g. 0.1",
                        axis.damping_ratio
                    ),
                ));
            }
        }
        for (name, h) in &sim.heaters {
            let at = format!("sim.heaters.{name}");
            if !self.heaters.contains_key(name) {
                return Err(invalid(
                    at,
                    format!("no heater {name:?} in [heaters] to simulate; fix the name or remove the section"),
                ));
            }
            positive(
                &format!("{at}.heat_capacity_j_per_k"),
                h.heat_capacity_j_per_k,
                "J/K, about 15 for a hotend, 400 for a bed",
            )?;
            for (k, v) in [("power_w", h.power_w), ("loss_w_per_k", h.loss_w_per_k)] {
                if !(v.is_finite() && v >= 0.0) {
                    return Err(invalid(format!("{at}.{k}"), format!("{v} must be ≥ 0")));
                }
            }
            finite(&format!("{at}.ambient_c"), h.ambient_c)?;
            if let Some(t) = h.sensor_fails_at_s {
                positive(&format!("{at}.sensor_fails_at_s"), t, "s after boot")?;
            }
        }
        Ok(())
    }
}

pub(super) fn is_mechanism_axis(kin: &Kinematics, axis: &str) -> bool {
    !matches!(kin, Kinematics::Cartesian {}) && (axis == "x" || axis == "y")
}

fn known<'a>(names: impl Iterator<Item = &'a String>) -> String {
    let names: BTreeSet<&str> = names.map(String::as_str).collect();
    if names.is_empty() {
        "none defined yet".to_string()
    } else {
        format!(
            "defined: {}",
            names.into_iter().collect::<Vec<_>>().join(", ")
        )
    }
}

fn finite(key: &str, value: f64) -> Result<(), ConfigError> {
    if value.is_finite() {
        Ok(())
    } else {
        Err(invalid(
            key,
            format!("{value} is not a finite number; give a number"),
        ))
    }
}

pub(super) fn positive(key: &str, value: f64, what: &str) -> Result<(), ConfigError> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(invalid(
            key,
            format!("{value} must be positive; give a positive value ({what})"),
        ))
    }
}

/// `value` finite and within `lo..=hi`.
pub(super) fn finite_in(key: &str, value: f64, lo: f64, hi: f64) -> Result<(), ConfigError> {
    if value.is_finite() && (lo..=hi).contains(&value) {
        Ok(())
    } else {
        Err(invalid(
            key,
            format!("{value} is outside {lo} to {hi}; give a value within it"),
        ))
    }
}

fn margin(key: &str, value: f64) -> Result<(), ConfigError> {
    if value.is_finite() && (0.0..90.0).contains(&value) {
        Ok(())
    } else {
        Err(invalid(
            key,
            format!("margin {value}° is outside 0 to 90; use a few degrees, e.g. 5"),
        ))
    }
}
