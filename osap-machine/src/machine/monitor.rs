//! Host functions that receive what the modules report through pipes:
//! each module's faults (`get_fault`), each motor module's status (link
//! loss) and refused points, limit switch edges (homing and limit hits),
//! and stepped positions (what the machine executed).
//!
//! Every report is pushed by the module (a pipe from its function, run on
//! the module's own timer), so nothing here polls the network. Each
//! monitor takes its module function's outputs as they are declared
//! ([`crate::network::modfn`]): its inputs are named and typed as they
//! are, and the pipe into it connects them by name.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

use osap_host::som::failure::FailureTable;
use osap_host::som::{HostFnError, HostFunction};
use tokio::sync::broadcast;

use super::error::{fault_reason_in, refusal_reason};
use super::events::{FaultKind, MachineEvent};
use super::MachineError;
use crate::network::modfn::{
    get_counters, get_fault, get_position, get_status, level_read, read_limit,
};

/// Failure code of a fault monitor given a fault code this host does not
/// know (a newer firmware's): the report is refused, not misread.
pub const UNKNOWN_FAULT_KIND: u8 = 2;

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
    /// Per module key: the fault count of its newest `get_fault` report.
    pub faults: BTreeMap<String, u32>,
    /// Per module key: the newest limit edge.
    pub limit: BTreeMap<String, LimitEdge>,
    /// Per motor index: stepped positions (synchronized µs, motor units),
    /// while recording.
    pub positions: Option<Vec<Vec<(u64, f64)>>>,
    /// The streamed tool's output as its module drives it (synchronized
    /// µs, PWM duty), while recording.
    pub applied: Option<Vec<(u64, f64)>>,
    /// Per module key: the synchronized time spans (µs, both ends
    /// included) of the machine's own latest `halt`s of it, oldest first
    /// (at most [`OWN_HALTS_KEPT`]). A `Halted` fault stamped within one is
    /// the machine's own stop, which the stop's
    /// [`StopReport`](super::error::StopReport) reports, not a fault; its
    /// report may come after a later stop began.
    pub own_halts: BTreeMap<String, Vec<(u64, u64)>>,
    /// Per module key: the failure table its `add_point` publishes, which
    /// names the point refusals its faults and counters report by code.
    pub point_refusals: BTreeMap<String, FailureTable>,
}

impl std::fmt::Debug for Reports {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Its parts are tasks, locks and buffers: the name says enough.
        f.debug_struct("Reports").finish_non_exhaustive()
    }
}

/// How many of the machine's own halts of a module are remembered.
pub const OWN_HALTS_KEPT: usize = 4;

impl Reports {
    /// What point refusal `code` of module `key` means, by the module's
    /// own table.
    fn refusal(&self, key: &str, code: u8) -> String {
        refusal_reason(self.point_refusals.get(key).map(|t| &t[..]), code)
    }

    /// Whether module `key`'s `Halted` fault stamped `time` is the
    /// machine's own halt.
    pub fn is_own_halt(&self, key: &str, time: u64) -> bool {
        self.own_halts
            .get(key)
            .is_some_and(|spans| spans.iter().any(|(from, to)| (*from..=*to).contains(&time)))
    }

    /// Notes the machine's own halt of module `key` from synchronized time
    /// `from` (µs) on, until [`end_own_halt`](Self::end_own_halt).
    pub fn begin_own_halt(&mut self, key: &str, from: u64) {
        let spans = self.own_halts.entry(key.to_string()).or_default();
        if spans.len() == OWN_HALTS_KEPT {
            spans.remove(0);
        }
        spans.push((from, u64::MAX));
    }

    /// Ends module `key`'s own halt begun at `from`, at `to`.
    pub fn end_own_halt(&mut self, key: &str, from: u64, to: u64) {
        if let Some(span) = self
            .own_halts
            .get_mut(key)
            .and_then(|spans| spans.iter_mut().rev().find(|s| s.0 == from))
        {
            span.1 = to;
        }
    }

    /// Takes `refused`, module `key`'s refused-point count, as reported:
    /// `true` if it counts refusals the machine has not heard of. The
    /// first report is the baseline; a count below the baseline means the
    /// module restarted (counting from 0 again), so every refusal it
    /// counts is new.
    pub fn take_refused(&mut self, key: &str, refused: u32) -> bool {
        match self.refused.insert(key.to_string(), refused) {
            None => false,
            Some(before) if refused < before => refused > 0,
            Some(before) => refused > before,
        }
    }

    /// Forgets what module `key` counted (its refused points and faults):
    /// the next reports are its new baselines. For a module that may have
    /// rebooted, when the machine sets it up again.
    pub fn reset_baselines(&mut self, key: &str) {
        self.refused.remove(key);
        self.faults.remove(key);
    }
}

/// Shared [`Reports`].
pub type SharedReports = Arc<Mutex<Reports>>;

/// Locks the reports.
pub fn lock(r: &SharedReports) -> std::sync::MutexGuard<'_, Reports> {
    r.lock().unwrap_or_else(|e| e.into_inner())
}

/// `machine.status.<key>(mode, queued, enabled, faults)`, fed by the
/// module's `get_status` (its inputs are `get_status`'s outputs): each
/// report says the module still answers (the watchdog's link-loss check).
/// Faults come through [`fault`].
pub fn status(key: &str, reports: SharedReports) -> Result<HostFunction, MachineError> {
    let module = key.to_string();
    Ok(HostFunction::typed(
        &format!("machine.status.{key}"),
        move |s: get_status::Outputs| {
            let now = tokio::time::Instant::now();
            lock(&reports)
                .seen
                .insert(module.clone(), (s.mode, s.faults, now));
            Ok::<(), HostFnError>(())
        },
    )?)
}

/// `machine.fault.<key>(time, code, detail, count)`, fed by the module's
/// `get_fault` (on change): each new fault becomes a
/// [`MachineEvent::Fault`]. The first report is the count the machine
/// started with. A limit press is left to the limit monitor when homing
/// watches the module's switch (`limit_watched`).
pub fn fault(
    key: &str,
    limit_watched: bool,
    reports: SharedReports,
    events: broadcast::Sender<MachineEvent>,
) -> Result<HostFunction, MachineError> {
    let module = key.to_string();
    Ok(HostFunction::typed(
        &format!("machine.fault.{key}"),
        move |f: get_fault::Outputs| {
            let before = lock(&reports).faults.insert(module.clone(), f.count);
            // A count that moved either way is news (a module that restarted
            // counts from 0 again).
            if before.is_none_or(|b| b == f.count) {
                return Ok(());
            }
            let Some(kind) = FaultKind::from_code(f.code) else {
                return Err(HostFnError::new(UNKNOWN_FAULT_KIND));
            };
            if kind == FaultKind::None
                || (kind == FaultKind::LimitHit && limit_watched)
                || (kind == FaultKind::Halted && lock(&reports).is_own_halt(&module, f.time))
            {
                return Ok(());
            }
            let refusals = lock(&reports).point_refusals.get(&module).cloned();
            let _ = events.send(MachineEvent::Fault {
                module: module.clone(),
                kind,
                detail: f.detail,
                time: f.time,
                reason: fault_reason_in(kind, f.detail, refusals.as_deref()),
            });
            Ok(())
        },
    )?)
}

/// `machine.counters.<key>(points, refused, last_refused, filled)`, fed by
/// the module's `get_counters` (on change).
pub fn counters(
    key: &str,
    reports: SharedReports,
    events: broadcast::Sender<MachineEvent>,
) -> Result<HostFunction, MachineError> {
    let module = key.to_string();
    Ok(HostFunction::typed(
        &format!("machine.counters.{key}"),
        move |c: get_counters::Outputs| {
            let mut r = lock(&reports);
            if r.take_refused(&module, c.refused) {
                let reason = r.refusal(&module, c.last_refused);
                drop(r);
                let _ = events.send(MachineEvent::Refused {
                    module: module.clone(),
                    count: c.refused,
                    reason,
                });
            }
            Ok::<(), HostFnError>(())
        },
    )?)
}

/// `machine.limit.<key>(time, level, edges)`, fed by the module's
/// `read_limit` (on change): each edge with the module's time stamp. The
/// input reads high when released.
pub fn limit(
    key: &str,
    reports: SharedReports,
    edges: broadcast::Sender<(String, LimitEdge)>,
) -> Result<HostFunction, MachineError> {
    let module = key.to_string();
    Ok(HostFunction::typed(
        &format!("machine.limit.{key}"),
        move |l: read_limit::Outputs| {
            let edge = LimitEdge {
                time: l.time,
                pressed: !l.level,
                edges: l.edges,
            };
            let before = lock(&reports).limit.insert(module.clone(), edge);
            // The first report is the switch's state when the pipe began;
            // homing still wants it (an edge it may have raced).
            if before.is_none_or(|b| b.edges != edge.edges) {
                let _ = edges.send((module.clone(), edge));
            }
            Ok::<(), HostFnError>(())
        },
    )?)
}

/// `machine.position.<motor>(time, position)`, fed by the module's
/// `get_position` (on change): what the motor stepped, while recording.
pub fn position(
    motor: &str,
    index: usize,
    reports: SharedReports,
) -> Result<HostFunction, MachineError> {
    Ok(HostFunction::typed(
        &format!("machine.position.{motor}"),
        move |p: get_position::Outputs| {
            if let Some(all) = &mut lock(&reports).positions {
                if let Some(list) = all.get_mut(index) {
                    if list.last().is_none_or(|l| l.0 < p.time) {
                        list.push((p.time, f64::from(p.position)));
                    }
                }
            }
            Ok::<(), HostFnError>(())
        },
    )?)
}

/// `machine.applied.<tool>(time, pwm0, pwm1, pins)`, fed by the tool
/// module's `level_read` (on change): the duty its PWM output `channel`
/// drives, while recording.
pub fn applied(
    tool: &str,
    channel: u8,
    reports: SharedReports,
) -> Result<HostFunction, MachineError> {
    Ok(HostFunction::typed(
        &format!("machine.applied.{tool}"),
        move |r: level_read::Outputs| {
            if let Some(list) = &mut lock(&reports).applied {
                let duty = if channel == 0 { r.pwm0 } else { r.pwm1 };
                if list.last().is_none_or(|l| l.0 < r.time) {
                    list.push((r.time, f64::from(duty)));
                }
            }
            Ok::<(), HostFnError>(())
        },
    )?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_refusal_baseline_starts_again_when_a_module_restarts() {
        let mut r = Reports::default();
        // The first report is the baseline: 3 refusals from before.
        assert!(!r.take_refused("b", 3));
        assert!(!r.take_refused("b", 3));
        assert!(r.take_refused("b", 4));
        // Module b reboots and counts from 0: its first refusals are news,
        // though fewer than the 4 counted before.
        assert!(!r.take_refused("b", 0));
        assert!(r.take_refused("b", 1));
        assert!(r.take_refused("b", 2));
        // A reboot seen only after it refused again: still news.
        assert!(r.take_refused("b", 1));
        // Set up again after a loss: the next report is the baseline.
        r.reset_baselines("b");
        assert!(!r.take_refused("b", 7));
        assert!(r.take_refused("b", 8));
        // Other modules keep theirs.
        assert!(!r.take_refused("a", 5));
        r.reset_baselines("b");
        assert!(r.take_refused("a", 6));
    }

    #[test]
    fn only_a_halt_within_the_machines_own_spans_is_its_own() {
        let mut r = Reports::default();
        assert!(!r.is_own_halt("a", 1_000));
        r.begin_own_halt("a", 1_000);
        assert!(r.is_own_halt("a", 9_000_000), "open until it ends");
        r.end_own_halt("a", 1_000, 2_000);
        assert!(r.is_own_halt("a", 1_000));
        assert!(r.is_own_halt("a", 2_000));
        assert!(!r.is_own_halt("a", 999));
        assert!(!r.is_own_halt("a", 2_001));
        assert!(!r.is_own_halt("b", 1_500));
        // A later stop keeps the earlier span: its report may come late.
        r.begin_own_halt("a", 5_000);
        r.end_own_halt("a", 5_000, 6_000);
        assert!(r.is_own_halt("a", 1_500) && r.is_own_halt("a", 5_500));
        assert!(!r.is_own_halt("a", 3_000));
        for k in 0..OWN_HALTS_KEPT as u64 {
            r.begin_own_halt("a", 10_000 * (k + 1));
        }
        assert!(!r.is_own_halt("a", 1_500), "only the latest are kept");
    }
}
