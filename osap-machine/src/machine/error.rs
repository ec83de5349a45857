//! What can go wrong driving a machine, by reason.

use crate::config::ConfigError;
use maxl::blocks::kinematics::KinError;
use maxl::blocks::planner::PlanError;
use osap_host::som::failure::{lookup, Failure};
use osap_host::som::SomError;
use osap_host::HostError;
use osap_module::fault::FaultKind;

/// An error of the [`Machine`](super::Machine) API.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum MachineError {
    /// The machine file is not valid.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The machine file describes something this machine layer cannot
    /// drive; the message names the key and the fix.
    #[error("machine file: {0}")]
    Unsupported(String),
    /// The bed mesh the machine file names could not be read.
    #[error("machine file: {0}")]
    Mesh(#[from] crate::mesh::MeshError),
    /// The host runtime or a link failed.
    #[error(transparent)]
    Host(#[from] HostError),
    /// A request to a module or to the host's functions failed.
    #[error(transparent)]
    Network(#[from] SomError),
    /// A module of `[modules]` is not on the network.
    #[error("modules.{key}: no module {wanted} on the network (found: {found}); check the cables, `osap scan`, or the name set with `osap rename`")]
    ModuleNotFound {
        /// The key in `[modules]`.
        key: String,
        /// What was looked for: a name or a route.
        wanted: String,
        /// The runtimes that were found.
        found: String,
    },
    /// A module of `[modules]` was not found, or is not a module the
    /// machine knows.
    #[error(transparent)]
    Module(#[from] crate::network::FindError),
    /// A module's clock did not settle on the machine's clock.
    #[error("module {module}: its clock did not follow the machine's: {detail}")]
    NotSynchronised {
        /// The module's key.
        module: String,
        /// Why.
        detail: String,
    },
    /// A module refused a setting or a command.
    #[error("module {module}: {function} refused: {reason}")]
    ModuleRefused {
        /// The module's key.
        module: String,
        /// The function called.
        function: String,
        /// The reason, by name.
        reason: String,
    },
    /// A target is outside an axis's soft travel limits.
    #[error("axis {axis}: {value} is outside its travel [{min}, {max}]")]
    OutOfTravel {
        /// The axis.
        axis: String,
        /// The coordinate asked for.
        value: f64,
        /// The soft limit, low end.
        min: f64,
        /// The soft limit, high end.
        max: f64,
    },
    /// A target does not have one coordinate per axis.
    #[error("a target needs {expected} coordinates ({axes}), got {got}")]
    WrongAxisCount {
        /// The machine's axis count.
        expected: usize,
        /// The machine's axes.
        axes: String,
        /// The coordinates given.
        got: usize,
    },
    /// A feed rate that is not finite and positive.
    #[error("feed rate {0} must be finite and positive (units/s)")]
    BadRate(f64),
    /// A move before the axes it needs were homed.
    #[error("axis {0} is not homed: call home() first, or set_position() if you know where it is")]
    NotHomed(String),
    /// The planner refused a move.
    #[error("planner: {0}")]
    Plan(#[from] PlanError),
    /// A position the kinematics cannot reach.
    #[error("kinematics: {0}")]
    Kinematics(#[from] KinError),
    /// The machine stopped on a fault; [`Machine::recover`](super::Machine::recover)
    /// clears it.
    #[error("machine faulted: {0}")]
    Faulted(String),
    /// Homing an axis failed.
    #[error("homing axis {axis}: {reason}")]
    Homing {
        /// The axis.
        axis: String,
        /// Why.
        reason: String,
    },
    /// Probing the bed failed (`[probe]`, `osap level`).
    #[error("probing {point}: {reason}")]
    Probe {
        /// Which probe point, and where.
        point: String,
        /// Why.
        reason: String,
    },
    /// No tool of that name in `[tools]`.
    #[error("no tool {0:?} in [tools]")]
    UnknownTool(String),
    /// No heater of that name in `[heaters]`.
    #[error("no heater {0:?} in [heaters]")]
    UnknownHeater(String),
    /// A heater refused or failed.
    #[error("heater {heater}: {reason}")]
    Heater {
        /// The heater.
        heater: String,
        /// Why.
        reason: String,
    },
    /// The machine file has no `[axes.e.loadcell]`.
    #[error("the machine has no load cell: add [axes.e.loadcell] to its machine file")]
    NoLoadCell,
    /// The load cell failed.
    #[error("load cell: {0}")]
    LoadCell(String),
    /// No axis of that name.
    #[error("no axis {0:?} on this machine")]
    UnknownAxis(String),
    /// A tool setting out of range.
    #[error("tool {tool}: {reason}")]
    Tool {
        /// The tool.
        tool: String,
        /// Why.
        reason: String,
    },
    /// The machine has stopped (its host or simulation is gone).
    #[error("the machine has stopped")]
    Stopped,
    /// A stop did not reach every module: those it did not reach may
    /// still move or keep a tool on.
    #[error("{0}")]
    StopIncomplete(StopReport),
    /// A module's function returned outputs of other types or fewer than
    /// this host expects: its firmware is not one this host knows.
    #[error("module {module}: {function} returned {got}, not {expected}; update its firmware (`osap flash`) or this host")]
    BadOutput {
        /// The module's key.
        module: String,
        /// The function called.
        function: String,
        /// What the host expected, e.g. `(u64, f32)`.
        expected: String,
        /// What came back.
        got: String,
    },
}

/// What a stop reached: every module of the machine file is sent `halt`
/// and every tool on it its off value, all at once, and this says which
/// modules confirmed every call and which could not be reached.
#[derive(Debug, Clone, Default)]
pub struct StopReport {
    /// Why the machine stopped (an emergency stop, a fault's reason, a
    /// halt the script asked for).
    pub reason: String,
    /// The modules (keys of `[modules]`) that confirmed the halt and every
    /// tool off, in key order.
    pub confirmed: Vec<String>,
    /// The modules that did not, with the first error of each, in key
    /// order.
    pub unreachable: Vec<Unreached>,
}

/// A module a stop did not reach, and why.
#[derive(Debug, Clone)]
pub struct Unreached {
    /// The module's key.
    pub module: String,
    /// The call that failed first.
    pub error: std::sync::Arc<MachineError>,
}

impl StopReport {
    /// Whether every module confirmed.
    pub fn is_complete(&self) -> bool {
        self.unreachable.is_empty()
    }

    /// `Ok(self)` if every module confirmed, else
    /// [`MachineError::StopIncomplete`].
    pub fn complete(self) -> Result<StopReport, MachineError> {
        if self.is_complete() {
            Ok(self)
        } else {
            Err(MachineError::StopIncomplete(self))
        }
    }
}

impl PartialEq for StopReport {
    fn eq(&self, other: &Self) -> bool {
        self.reason == other.reason
            && self.confirmed == other.confirmed
            && self.unreachable.len() == other.unreachable.len()
            && self
                .unreachable
                .iter()
                .zip(&other.unreachable)
                .all(|(a, b)| a.module == b.module && a.error.to_string() == b.error.to_string())
    }
}

impl std::fmt::Display for StopReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "stop ({}): ", self.reason)?;
        if self.confirmed.is_empty() {
            f.write_str("no module confirmed")?;
        } else {
            write!(f, "confirmed by {}", self.confirmed.join(", "))?;
        }
        if !self.unreachable.is_empty() {
            let which: Vec<String> = self
                .unreachable
                .iter()
                .map(|u| format!("{} ({})", u.module, u.error))
                .collect();
            write!(
                f,
                "; NOT reached: {}; cut the power of the modules not reached: they may still move or keep a tool on",
                which.join("; ")
            )?;
        }
        Ok(())
    }
}

/// A refusal code by name and reason, from the table the refusing
/// function publishes with its signature (`QueueFull (code 8): the
/// module's queue is full ..`); by number when the table does not name it
/// or there is none.
pub fn refusal_reason(table: Option<&[Failure]>, code: u8) -> String {
    table
        .and_then(|t| lookup(t, code))
        .map_or_else(|| format!("failure code {code}"), |f| f.to_string())
}

/// What a module's fault means, as a predicate of the module ("module y
/// refused a point: ..."): the `get_fault` kind and detail, by name; a
/// refused point's code by number (see [`fault_reason_in`]).
pub fn fault_reason(kind: FaultKind, detail: u32) -> String {
    fault_reason_in(kind, detail, None)
}

/// [`fault_reason`], naming a refused point's code from `point_refusals`,
/// the table the module's `add_point` publishes.
pub fn fault_reason_in(kind: FaultKind, detail: u32, point_refusals: Option<&[Failure]>) -> String {
    match kind {
        FaultKind::None => "reported no fault".into(),
        FaultKind::Refused => {
            let code = u8::try_from(detail).unwrap_or(u8::MAX);
            format!(
                "refused a point: {}",
                refusal_reason(point_refusals, code)
            )
        }
        FaultKind::Backstop => format!(
            "braked on its backstop: its stream ran dry mid-motion, {:.1} ms after its last point (the host fell behind or the link went quiet: more CPU, a longer timer lead, or a faster link)",
            f64::from(detail) / 1e3
        ),
        FaultKind::StepOverrun => format!(
            "was asked to step faster than its step rate ({detail} steps went out late since its motor was enabled): lower the axis's velocity or its microsteps"
        ),
        FaultKind::LimitHit => "had its limit switch pressed".into(),
        FaultKind::OutputWatchdog => format!(
            "put its outputs in their safe state: nothing reached it for {:.0} ms, past its output watchdog (the host stopped or the link went quiet: check the link, or raise [modules.NAME] output_watchdog_ms)",
            f64::from(detail) / 1e3
        ),
        FaultKind::Halted => "was halted (its motor must be cycled: recover())".into(),
        FaultKind::BlockHalt => format!(
            "was halted by its comparator block in slot {detail}: the block's input rose past its threshold (its motor must be cycled: recover())"
        ),
        FaultKind::HeaterRunaway => {
            use osap_module::heater::RunawayReason as R;
            let (index, reason) = osap_module::heater::runaway_parts(detail);
            let why = match reason {
                Some(R::NotHeating) => "not heating: it did not warm by heating_gain_c within check_gain_time_s (a heater cartridge or thermistor out of its block, a broken heater wire, or gains far too low)",
                Some(R::FellFromTarget) => "fell from its target and stayed below it past max_error (a thermistor out of its block, a fan on the heater block, or too little power)",
                Some(R::SensorOpen) => "its thermistor reads open (a broken wire or connector)",
                Some(R::SensorShort) => "its thermistor reads shorted (pinched wires)",
                Some(R::OverTemp) => "it reached max_temp (a stuck MOSFET, or gains far too high)",
                None => "an unknown runaway reason (a newer firmware?)",
            };
            format!("cut its heater {index} off: {why}")
        }
        FaultKind::OverLimit => {
            let which: Vec<&str> = osap_module::fault::over_limit_names(detail).collect();
            let which = match which.len() {
                0 => "its limits".to_string(),
                1 => format!("its {} limit", which[0]),
                _ => format!("its {} limits", which.join(" and ")),
            };
            format!(
                "refused a point past {which} (the module's set_limits; a machine sets them from its axes, [limits] module_margin or [motors.NAME] limits): plan the motion within the limits, or raise them"
            )
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use osap_module::fault::{OVER_ACCELERATION, OVER_JERK, OVER_VELOCITY};

    #[test]
    fn an_over_limit_fault_names_its_limits() {
        assert_eq!(
            fault_reason(FaultKind::OverLimit, OVER_JERK),
            "refused a point past its jerk limit (the module's set_limits; a machine sets them \
             from its axes, [limits] module_margin or [motors.NAME] limits): plan the motion \
             within the limits, or raise them"
        );
        let both = fault_reason(FaultKind::OverLimit, OVER_VELOCITY | OVER_ACCELERATION);
        assert!(
            both.contains("past its velocity and acceleration limit"),
            "{both}"
        );
        assert!(fault_reason(FaultKind::OverLimit, 0).contains("past its limits"));
    }
}
