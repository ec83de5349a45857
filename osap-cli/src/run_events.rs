//! What `osap run` heard from the machine while a job ran: every event,
//! taken as it comes (so the stream does not lag behind a long job), sorted
//! into faults that stop the machine, faults this machine file lets pass,
//! refusals and stop reports. A lagged stream is itself an error: the list
//! is then incomplete.

use std::collections::BTreeMap;

use osap_machine::machine::events::FaultKind;
use osap_machine::{MachineEvent, StopReport};
use tokio::sync::{broadcast, oneshot};

/// Whether a module's fault (module, kind, detail) stops the machine
/// ([`osap_machine::Machine::fault_stops`]).
pub(crate) type Stops = Box<dyn Fn(&str, FaultKind, u32) -> bool + Send>;

/// The events of a run, sorted.
#[derive(Debug, Default)]
pub(crate) struct Heard {
    /// Faults that stop the machine, in order: the first of each module
    /// and kind.
    pub stopping: Vec<String>,
    /// Faults the machine file lets pass (late steps within
    /// `max_late_steps`, a disabled motor's refusals): the latest of each
    /// module and kind.
    pub passed: Vec<String>,
    /// Which line of `stopping` or `passed` holds each module and kind
    /// (`None` for a lost link).
    lines: BTreeMap<(String, Option<u8>, bool), usize>,
    /// Per module: refused points so far and the latest reason.
    pub refusals: BTreeMap<String, (u32, String)>,
    /// The stops' reports.
    pub stops: Vec<StopReport>,
    /// Events lost because the stream lagged.
    pub missed: u64,
}

impl Heard {
    /// Adds `line` for `module` and `kind`: the first of a stopping fault
    /// stays (it is the cause), the latest of one that passed replaces the
    /// one before (a running count).
    fn note(&mut self, module: String, kind: Option<u8>, stops: bool, line: String) {
        let list = if stops {
            &mut self.stopping
        } else {
            &mut self.passed
        };
        match self.lines.get(&(module.clone(), kind, stops)) {
            Some(_) if stops => {}
            Some(&i) => list[i] = line,
            None => {
                self.lines.insert((module, kind, stops), list.len());
                list.push(line);
            }
        }
    }

    /// Sorts one event in.
    pub(crate) fn take(&mut self, stops: &Stops, e: MachineEvent) {
        match e {
            MachineEvent::Fault {
                module,
                kind,
                detail,
                reason,
                ..
            } => {
                let line = format!("module {module} {reason}");
                let stop = stops(&module, kind, detail);
                self.note(module, Some(kind.code()), stop, line);
            }
            MachineEvent::LinkLost { module } => {
                let line = format!("module {module} stopped answering");
                self.note(module, None, true, line);
            }
            MachineEvent::Limit {
                module,
                pressed: true,
                expected: false,
                ..
            } => {
                let line = format!("module {module}: limit switch pressed outside homing");
                self.note(module, Some(FaultKind::LimitHit.code()), true, line);
            }
            MachineEvent::Refused {
                module,
                count,
                reason,
            } => {
                // The newest count per module says it all.
                self.refusals.insert(module, (count, reason));
            }
            MachineEvent::Stop(report) => self.stops.push(report),
            _ => {}
        }
    }

    /// Whether anything heard stopped the machine, or a stop did not reach
    /// every module.
    pub(crate) fn stopped(&self) -> bool {
        !self.stopping.is_empty() || self.stops.iter().any(|s| !s.is_complete())
    }
}

/// Takes every event from `events` until `done` fires, then what is
/// already queued.
pub(crate) async fn collect(
    mut events: broadcast::Receiver<MachineEvent>,
    stops: Stops,
    mut done: oneshot::Receiver<()>,
) -> Heard {
    let mut heard = Heard::default();
    loop {
        tokio::select! {
            e = events.recv() => match e {
                Ok(e) => heard.take(&stops, e),
                Err(broadcast::error::RecvError::Lagged(n)) => heard.missed += n,
                Err(broadcast::error::RecvError::Closed) => return heard,
            },
            _ = &mut done => break,
        }
    }
    loop {
        match events.try_recv() {
            Ok(e) => heard.take(&stops, e),
            Err(broadcast::error::TryRecvError::Lagged(n)) => heard.missed += n,
            Err(_) => return heard,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn late_steps_stop_past(bound: u32) -> Stops {
        Box::new(move |_, kind, detail| kind != FaultKind::StepOverrun || detail > bound)
    }

    fn late(module: &str, detail: u32) -> MachineEvent {
        MachineEvent::Fault {
            module: module.into(),
            kind: FaultKind::StepOverrun,
            detail,
            time: 1,
            reason: format!("sent {detail} steps late"),
        }
    }

    #[test]
    fn faults_are_sorted_by_whether_they_stop_the_machine() {
        let mut h = Heard::default();
        let stops = late_steps_stop_past(2);
        h.take(&stops, late("a", 1));
        h.take(&stops, late("a", 2));
        assert_eq!(h.passed, ["module a sent 2 steps late"], "the latest count");
        assert!(!h.stopped());
        h.take(&stops, late("a", 3));
        h.take(&stops, late("a", 7));
        h.take(&stops, MachineEvent::LinkLost { module: "z".into() });
        assert_eq!(
            h.stopping,
            ["module a sent 3 steps late", "module z stopped answering"],
            "the first, which stopped the machine"
        );
        assert!(h.stopped());
    }

    #[tokio::test]
    async fn a_lagged_stream_is_counted_as_missed() {
        let (tx, rx) = broadcast::channel(4);
        let (done_tx, done) = oneshot::channel();
        for i in 0..10 {
            tx.send(late("a", i)).unwrap();
        }
        done_tx.send(()).unwrap();
        let h = collect(rx, late_steps_stop_past(100), done).await;
        // Four kept, six lost: the list says so instead of "none".
        assert_eq!(h.missed, 6);
        assert_eq!(h.passed.len(), 4);
    }
}
