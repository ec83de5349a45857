//! Stops: every stop reaches every module at once.
//!
//! Each stop sends every module of the machine file its `halt` and every
//! tool its off value (`off_duty` on a PWM output, low on a digital pin),
//! all concurrently and each with the retried call (both are safe to
//! repeat), and goes on past any error: the [`StopReport`] says which
//! modules confirmed and which could not be reached, and every stop sends
//! it as [`MachineEvent::Stop`].
//!
//! - An emergency stop ([`Machine::emergency_stop`], a limit switch pressed
//!   outside homing) sends everything at once: the modules stop stepping
//!   where they are.
//! - A controlled stop (a fault, a lost module, [`Machine::halt`],
//!   [`Machine::stop`]) switches the tools off at once, lets the planner
//!   bring every axis to rest within its limits, then sends the halts.
//!
//! The machine's own halts are not faults: the fault monitor leaves out a
//! `Halted` fault stamped while the machine was halting that module
//! ([`monitor::Reports::own_halts`]). After [`Machine::halt`] and
//! [`Machine::recover`], the motors are set up again and the host reads
//! where each motor's steps put it ([`Machine::rearm_motors`]) before the
//! next stream starts.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Duration;

use osap_host::som::{FunctionHandle, Value};
use tokio::task::JoinSet;

use crate::network::modfn::{digital_write, get_position, halt, pwm_write, set_enable};

use super::error::{StopReport, Unreached};
use super::events::MachineEvent;
use super::{lock_motion, monitor, som_refusal, Machine, MachineError, MachineState, MAX_AXES};
use super::{INTERVAL_US, LEAD_US};
use crate::config::Output;

/// Where a module's clock may be off the host's while it stamps its halt,
/// µs: a module's clock follows within 200 µs before motion starts.
const HALT_STAMP_MARGIN_US: u64 = 1_000;

/// What the calls of one stop did, per module key: `None` while every
/// call to it was confirmed, else its first error.
type Outcomes = BTreeMap<String, Option<MachineError>>;

fn merge(into: &mut Outcomes, module: String, result: Result<(), MachineError>) {
    let entry = into.entry(module).or_insert(None);
    if let (None, Err(e)) = (&entry, result) {
        *entry = Some(e);
    }
}

impl Machine {
    /// Stops every motor at once and switches every tool off (each
    /// module's `halt`, no deceleration: an emergency stop) and marks the
    /// machine faulted; [`Machine::recover`] powers the motors up again.
    /// The report says which modules confirmed; a module that could not
    /// be reached makes it [`MachineError::StopIncomplete`].
    pub async fn emergency_stop(&self) -> Result<StopReport, MachineError> {
        self.emergency_stop_as("emergency stop".into())
            .await
            .complete()
    }

    /// [`Machine::emergency_stop`] for `reason`.
    pub(super) async fn emergency_stop_as(&self, reason: String) -> StopReport {
        self.fault(reason.clone());
        let (tools, halts) = tokio::join!(self.tools_off(), self.halt_modules());
        self.pause_motion();
        self.report_stop(reason, [tools, halts])
    }

    /// A controlled stop: every tool goes off at once, every axis
    /// decelerates within its limits along the path and queued moves are
    /// dropped; then every module is halted. Returns once stopped, with the
    /// motors set up again where they stand so that moves resume. A module
    /// the halt could not reach faults the machine
    /// ([`MachineError::StopIncomplete`]).
    pub async fn halt(&self) -> Result<StopReport, MachineError> {
        let (tools, ()) = tokio::join!(self.tools_off(), self.come_to_rest());
        let halts = self.halt_modules().await;
        let report = self.report_stop("halt".into(), [tools, halts]);
        if !report.is_complete() {
            self.fault(report.to_string());
            return report.complete();
        }
        if matches!(*self.inner.state.borrow(), MachineState::Faulted(_)) {
            // A fault meanwhile: the machine stays stopped until recover().
            return Ok(report);
        }
        lock_motion(&self.inner.motion).paused = true;
        let result = self.rearm_motors(false).await;
        lock_motion(&self.inner.motion).paused = false;
        result?;
        Ok(report)
    }

    /// Stops the machine: a controlled stop and every module halted, every
    /// tool off, then the motors are left powered where they stand; a
    /// simulated machine (whatever runs underneath) is shut down.
    pub async fn stop(self) -> Result<StopReport, MachineError> {
        self.await_stops().await;
        let (tools, ()) = tokio::join!(self.tools_off(), self.come_to_rest());
        let halts = self.halt_modules().await;
        self.pause_motion();
        let report = self.report_stop("the machine stops".into(), [tools, halts]);
        self.inner.state.send_replace(MachineState::Stopped);
        let underneath = self
            .inner
            .underneath
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .take();
        if let Some(u) = underneath {
            u.stop().await?;
        }
        report.complete()
    }

    /// Marks the machine faulted (a controlled stop) and, on its first
    /// fault, switches every tool off at once and halts every module once
    /// the axes have come to rest (in a task [`Machine::recover`] waits
    /// for).
    pub(super) fn fault_and_stop(&self, reason: String) {
        if !self.fault(reason.clone()) {
            return;
        }
        let machine = self.clone();
        let task = tokio::spawn(async move {
            let (tools, ()) = tokio::join!(machine.tools_off(), machine.come_to_rest());
            let halts = machine.halt_modules().await;
            machine.pause_motion();
            machine.report_stop(reason, [tools, halts]);
        });
        self.inner
            .stops
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push(task);
    }

    /// Sends no more points: the modules stand halted, and would refuse
    /// them until [`Machine::recover`] sets them up again (and resumes).
    fn pause_motion(&self) {
        lock_motion(&self.inner.motion).paused = true;
    }

    /// Waits for the stops that faults started to end.
    pub(super) async fn await_stops(&self) {
        let tasks: Vec<_> = self
            .inner
            .stops
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .drain(..)
            .collect();
        for t in tasks {
            if let Err(e) = t.await {
                // The stop's own report went out before any panic could;
                // a task that did not end is worth a log line.
                tracing::error!("a stop's task ended abnormally: {e}");
            }
        }
    }

    /// Halts the planner and waits until every axis has come to rest:
    /// the planner idle and its last points run on the modules. Bounded by
    /// the slowest stop the machine file allows (a host whose motion
    /// stopped sampling never reports rest; the halts go out anyway).
    async fn come_to_rest(&self) {
        {
            let mut m = lock_motion(&self.inner.motion);
            let _ = m.halt();
            if m.paused {
                // No point is sent: the motors stand (a stop before this
                // one halted them).
                return;
            }
            m.mark_busy();
        }
        let bound = self.stop_bound();
        let mut status = self.inner.status.clone();
        let rest = tokio::time::timeout(bound, async {
            loop {
                let s = *status.borrow_and_update();
                if lock_motion(&self.inner.motion).is_idle() && !s.busy {
                    return Some(s.rest_stamp);
                }
                if status.changed().await.is_err() {
                    return None;
                }
            }
        })
        .await;
        let Ok(Some(rest)) = rest else {
            tracing::warn!(
                "the axes did not report rest within {bound:?}: halting every module anyway"
            );
            return;
        };
        // A module runs a point two intervals after its stamp.
        let done = rest + 2 * u64::from(INTERVAL_US);
        if let Ok(now) = self.now_us().await {
            if done > now {
                tokio::time::sleep(Duration::from_micros(done - now)).await;
            }
        }
    }

    /// The longest a controlled stop can take: the slowest axis from its
    /// top speed to rest, twice, with the timer's lead, and a second more.
    fn stop_bound(&self) -> Duration {
        let cfg = &self.inner.cfg;
        let slowest = cfg
            .axes
            .values()
            .map(|a| a.velocity / a.acceleration)
            .filter(|t| t.is_finite())
            .fold(0.0, f64::max);
        Duration::from_secs_f64(2.0 * slowest + f64::from(LEAD_US) * 1e-6 + 1.0)
    }

    /// Sends every tool its off value at once: each tool's module, with the
    /// retried call.
    async fn tools_off(&self) -> Outcomes {
        let mut calls = JoinSet::new();
        for (name, tool) in &self.inner.cfg.tools {
            let (output, off_duty) = (tool.output, tool.off_duty as f32);
            let machine = self.clone();
            let (name, module) = (name.clone(), tool.module.clone());
            calls.spawn(async move {
                let r = match output {
                    Output::Pwm(channel) => {
                        let off = pwm_write::Inputs {
                            channel,
                            duty: off_duty,
                        };
                        machine.call_idempotent(&module, off).await
                    }
                    Output::Digital(pin) => {
                        let off = digital_write::Inputs { pin, level: false };
                        machine.call_idempotent(&module, off).await
                    }
                };
                if r.is_ok() {
                    machine.tool_is_off(&name);
                }
                (module, r.map(|_| ()))
            });
        }
        let mut out = Outcomes::new();
        while let Some(done) = calls.join_next().await {
            match done {
                Ok((module, r)) => merge(&mut out, module, r),
                Err(e) => tracing::error!("a tool-off call's task ended abnormally: {e}"),
            }
        }
        out
    }

    /// Sends `halt` to every module of the machine file that has one, at
    /// once, with the retried call, noting each as the machine's own halt
    /// (see [`monitor::Reports::own_halts`]).
    async fn halt_modules(&self) -> Outcomes {
        let mut out = Outcomes::new();
        let mut handles: Vec<(String, FunctionHandle)> = Vec::new();
        {
            let manager = self.inner.manager.lock().await;
            for (key, m) in &self.inner.modules {
                match manager.function(&halt::on(&m.runtime)) {
                    Ok(h) => handles.push((key.clone(), h)),
                    // A module without `halt` (no motor) has only its tools
                    // to stop.
                    Err(osap_host::som::SomError::NoSuchFunction(_)) => {}
                    Err(e) => merge(&mut out, key.clone(), Err(MachineError::Network(e))),
                }
            }
        }
        let mut calls = JoinSet::new();
        for (key, h) in handles {
            let machine = self.clone();
            calls.spawn(async move {
                // Without the synchronized time (the host is going), no
                // halt is taken for the machine's own: it stops as a fault.
                let from = machine.now_us().await.ok();
                let start = from.map(|t| t.saturating_sub(HALT_STAMP_MARGIN_US));
                if let Some(start) = start {
                    monitor::lock(&machine.inner.reports).begin_own_halt(&key, start);
                }
                let r = h
                    .call_idempotent(&[])
                    .await
                    .map(|_| ())
                    .map_err(|e| som_refusal(&key, halt::NAME, e));
                if let Some(start) = start {
                    let to = machine.now_us().await.unwrap_or(start);
                    let to = to.saturating_add(HALT_STAMP_MARGIN_US);
                    monitor::lock(&machine.inner.reports).end_own_halt(&key, start, to);
                }
                (key, r)
            });
        }
        while let Some(done) = calls.join_next().await {
            match done {
                Ok((key, r)) => merge(&mut out, key, r),
                Err(e) => tracing::error!("a halt call's task ended abnormally: {e}"),
            }
        }
        out
    }

    /// The report of a stop from what its calls did; sent as
    /// [`MachineEvent::Stop`] and logged.
    fn report_stop(&self, reason: String, parts: [Outcomes; 2]) -> StopReport {
        let mut all = Outcomes::new();
        for part in parts {
            for (module, outcome) in part {
                merge(&mut all, module, outcome.map_or(Ok(()), Err));
            }
        }
        let mut report = StopReport {
            reason,
            ..StopReport::default()
        };
        for (module, outcome) in all {
            match outcome {
                None => report.confirmed.push(module),
                Some(error) => report.unreachable.push(Unreached {
                    module,
                    error: Arc::new(error),
                }),
            }
        }
        if report.is_complete() {
            tracing::info!("{report}");
        } else {
            tracing::error!("{report}");
        }
        let _ = self.inner.events.send(MachineEvent::Stop(report.clone()));
        report
    }

    /// Sets every motor's module up to run again after a stop and takes
    /// the machine to be where the motors' steps put them: powers each
    /// motor as the machine file says (off first when `cycle`, which a
    /// module needs after its backstop), reads its stepped position
    /// (`get_position`), all motors at once, then starts a fresh planner
    /// there with the same feed override. Run with the motion paused, so
    /// the next stream starts where each motor stands.
    pub(super) async fn rearm_motors(&self, cycle: bool) -> Result<(), MachineError> {
        let motors: Vec<_> = lock_motion(&self.inner.motion).drive.motors().to_vec();
        let mut calls = JoinSet::new();
        for (i, motor) in motors.iter().enumerate() {
            let machine = self.clone();
            let (module, enable) = (motor.module.clone(), motor.enable);
            calls.spawn(async move {
                let r = async {
                    if cycle {
                        let off = set_enable::Inputs { on: false };
                        machine.call_idempotent(&module, off).await?;
                    }
                    let on = set_enable::Inputs { on: enable };
                    machine.call_idempotent(&module, on).await?;
                    let out = machine
                        .call_idempotent(&module, get_position::Inputs {})
                        .await?;
                    stepped_position(&module, &out)
                }
                .await;
                (i, r)
            });
        }
        let mut at = vec![f64::NAN; motors.len()];
        let mut first_error = None;
        while let Some(done) = calls.join_next().await {
            match done {
                Ok((i, Ok(p))) => at[i] = p,
                Ok((_, Err(e))) => {
                    first_error.get_or_insert(e);
                }
                Err(e) => {
                    first_error.get_or_insert(MachineError::Unsupported(format!(
                        "setting a motor up again ended abnormally: {e}"
                    )));
                }
            }
        }
        if let Some(e) = first_error {
            return Err(e);
        }
        let mut m = lock_motion(&self.inner.motion);
        let p = m.drive.machine_position(&at)?;
        // Whatever was planned is void: a fresh planner, where the motors
        // stand, with the same feed override.
        let scale = m.planner.feed_scale();
        let mut planner = super::motion::machine_planner(&self.inner.cfg)?;
        planner.set_feed_scale(scale)?;
        let mut p3 = [0.0; MAX_AXES];
        p3[..p.len()].copy_from_slice(&p);
        planner.set_position(p3)?;
        m.replace_planner(planner);
        m.last_motors = at;
        m.error = None;
        Ok(())
    }
}

/// The position of module `module`'s `get_position` outputs `(time: u64,
/// position: f32)`; outputs of other types, or a position that is not a
/// number, are an error (never a position of 0).
pub(super) fn stepped_position(module: &str, out: &[Value<'static>]) -> Result<f64, MachineError> {
    match out {
        [Value::U64(_), Value::F32(p)] if p.is_finite() => Ok(f64::from(*p)),
        _ => Err(MachineError::BadOutput {
            module: module.into(),
            function: "get_position".into(),
            expected: "(time: u64, position: f32), a finite position".into(),
            got: format!("{out:?}"),
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_missing_or_mistyped_position_is_an_error_not_zero() {
        let good = [Value::U64(7), Value::F32(-12.5)];
        assert_eq!(stepped_position("a", &good).unwrap(), -12.5);
        for bad in [
            vec![],
            vec![Value::U64(7)],
            vec![Value::U64(7), Value::F64(-12.5)],
            vec![Value::U64(7), Value::I32(3)],
            vec![Value::U64(7), Value::F32(f32::NAN)],
            vec![Value::U64(7), Value::F32(1.0), Value::F32(2.0)],
        ] {
            let e = stepped_position("a", &bad).unwrap_err();
            assert!(
                matches!(&e, MachineError::BadOutput { module, function, .. } if module == "a" && function == "get_position"),
                "{bad:?}: {e}"
            );
            assert!(e.to_string().contains("update its firmware"), "{e}");
        }
    }
}
