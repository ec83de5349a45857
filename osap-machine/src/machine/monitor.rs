//! Host functions that receive what the modules report through pipes:
//! each motor module's status (faults, link loss), refused points, limit
//! switch edges (homing and limit hits), and stepped positions (what the
//! machine executed).
//!
//! Every report is pushed by the module (a pipe from its function, run on
//! the module's own timer), so nothing here polls the network.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

use osap_host::som::{HostFunction, OwnedValue};
use pipes_core::types::{ScalarType, Type};
use tokio::sync::broadcast;

use super::error::stepper_reason;
use super::events::MachineEvent;

/// A limit switch edge, as its module stamped it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LimitEdge {
    /// Synchronized time of the edge, µs.
    pub time: u64,
    /// Pressed (true) or released.
    pub pressed: bool,
    /// Edges the module has seen since boot.
    pub edges: u32,
}

impl LimitEdge {
    /// Whether this is an edge that happened (not the idle state at boot).
    pub fn is_edge(&self) -> bool {
        self.edges > 0 && self.time > 0
    }
}

/// What the monitors share with the machine.
#[derive(Default)]
pub struct Reports {
    /// Per module key: the newest status (mode, faults) and when it came
    /// (host tokio time).
    pub seen: BTreeMap<String, (u8, u32, tokio::time::Instant)>,
    /// Per module key: refused points seen so far.
    pub refused: BTreeMap<String, u32>,
    /// Per module key: the newest limit edge.
    pub limit: BTreeMap<String, LimitEdge>,
    /// Per motor index: stepped positions (synchronized µs, motor units),
    /// while recording.
    pub positions: Option<Vec<Vec<(u64, f64)>>>,
}

/// Shared [`Reports`].
pub type SharedReports = Arc<Mutex<Reports>>;

/// Locks the reports.
pub fn lock(r: &SharedReports) -> std::sync::MutexGuard<'_, Reports> {
    r.lock().unwrap_or_else(|e| e.into_inner())
}

fn t(s: ScalarType) -> Type {
    Type::Scalar(s)
}

/// The stepper mode (`get_status`) of an axis halted by `halt`.
const HALTED: u8 = 4;

/// `machine.status.<key>(mode, queued, enabled, faults)`, fed by the
/// module's `get_status`.
pub fn status(
    key: &str,
    reports: SharedReports,
    events: broadcast::Sender<MachineEvent>,
) -> Result<HostFunction, String> {
    let module = key.to_string();
    HostFunction::new(
        &format!("machine.status.{key}"),
        &[
            ("mode", t(ScalarType::U8)),
            ("queued", t(ScalarType::U16)),
            ("enabled", t(ScalarType::Bool)),
            ("faults", t(ScalarType::U32)),
        ],
        &[],
        move |ins: &[OwnedValue]| {
            let (Some(OwnedValue::U8(mode)), Some(OwnedValue::U32(faults))) =
                (ins.first(), ins.get(3))
            else {
                return Err(1);
            };
            let now = tokio::time::Instant::now();
            let before = lock(&reports)
                .seen
                .insert(module.clone(), (*mode, *faults, now));
            let (was_mode, was_faults) = before.map_or((0, *faults), |b| (b.0, b.1));
            let newly = |m: u8| *mode == m && was_mode != m;
            // A stream that ran dry at rest parks the axis in the backstop
            // mode harmlessly; only one cut off mid-motion counts a fault.
            let reason = if *faults > was_faults {
                Some("its stream ran dry mid-motion and the backstop braked it (the host fell behind: more CPU, a longer timer lead, or a faster link)")
            } else if newly(HALTED) {
                Some("it was halted")
            } else {
                None
            };
            if let Some(reason) = reason {
                let _ = events.send(MachineEvent::Fault {
                    module: module.clone(),
                    reason: reason.into(),
                });
            }
            Ok(Vec::new())
        },
    )
    .map_err(|e| e.to_string())
}

/// `machine.counters.<key>(points, refused, last_refused, filled)`, fed by
/// the module's `get_counters` (on change).
pub fn counters(
    key: &str,
    reports: SharedReports,
    events: broadcast::Sender<MachineEvent>,
) -> Result<HostFunction, String> {
    let module = key.to_string();
    HostFunction::new(
        &format!("machine.counters.{key}"),
        &[
            ("points", t(ScalarType::U32)),
            ("refused", t(ScalarType::U32)),
            ("last_refused", t(ScalarType::U8)),
            ("filled", t(ScalarType::U32)),
        ],
        &[],
        move |ins: &[OwnedValue]| {
            let (Some(OwnedValue::U32(refused)), Some(OwnedValue::U8(code))) =
                (ins.get(1), ins.get(2))
            else {
                return Err(1);
            };
            let mut r = lock(&reports);
            let first = *r.refused.entry(module.clone()).or_insert(*refused);
            if *refused > first {
                r.refused.insert(module.clone(), *refused);
                let _ = events.send(MachineEvent::Refused {
                    module: module.clone(),
                    count: *refused,
                    reason: stepper_reason(*code),
                });
            }
            Ok(Vec::new())
        },
    )
    .map_err(|e| e.to_string())
}

/// `machine.limit.<key>(time, level, edges)`, fed by the module's
/// `read_limit` (on change): each edge with the module's time stamp. The
/// input reads high when released.
pub fn limit(
    key: &str,
    reports: SharedReports,
    edges: broadcast::Sender<(String, LimitEdge)>,
) -> Result<HostFunction, String> {
    let module = key.to_string();
    HostFunction::new(
        &format!("machine.limit.{key}"),
        &[
            ("time", t(ScalarType::U64)),
            ("level", t(ScalarType::Bool)),
            ("edges", t(ScalarType::U32)),
        ],
        &[],
        move |ins: &[OwnedValue]| {
            let (
                Some(OwnedValue::U64(time)),
                Some(OwnedValue::Bool(level)),
                Some(OwnedValue::U32(count)),
            ) = (ins.first(), ins.get(1), ins.get(2))
            else {
                return Err(1);
            };
            let edge = LimitEdge {
                time: *time,
                pressed: !*level,
                edges: *count,
            };
            let before = lock(&reports).limit.insert(module.clone(), edge);
            // The first report is the switch's state when the pipe began;
            // homing still wants it (an edge it may have raced).
            if before.is_none_or(|b| b.edges != edge.edges) {
                let _ = edges.send((module.clone(), edge));
            }
            Ok(Vec::new())
        },
    )
    .map_err(|e| e.to_string())
}

/// `machine.position.<motor>(time, position)`, fed by the module's
/// `get_position` (on change): what the motor stepped, while recording.
pub fn position(motor: &str, index: usize, reports: SharedReports) -> Result<HostFunction, String> {
    HostFunction::new(
        &format!("machine.position.{motor}"),
        &[
            ("time", t(ScalarType::U64)),
            ("position", t(ScalarType::F32)),
        ],
        &[],
        move |ins: &[OwnedValue]| {
            let (Some(OwnedValue::U64(time)), Some(OwnedValue::F32(p))) = (ins.first(), ins.get(1))
            else {
                return Err(1);
            };
            if let Some(all) = &mut lock(&reports).positions {
                if let Some(list) = all.get_mut(index) {
                    if list.last().is_none_or(|l| l.0 < *time) {
                        list.push((*time, f64::from(*p)));
                    }
                }
            }
            Ok(Vec::new())
        },
    )
    .map_err(|e| e.to_string())
}
