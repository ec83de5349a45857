//! A spindle's measured speed (`[tools.NAME] tach`): setting a speed
//! waits until the module's tachometer measures it, and a running
//! spindle whose speed falls below its stall fraction faults the machine.
//!
//! The measuring is the module's (`tach_setup`, `tach_read`: the board
//! counts the pulses, the module's logic turns whole pulse periods into
//! rpm); the host reads it every [`SPEED_POLL`] while it waits and every
//! [`STALL_POLL`] while the spindle runs. A stall is a fault like a
//! module's: the controlled stop halts motion, halts every module and
//! switches every tool (the spindle too) off, and the machine reports it
//! until it recovers.

use std::sync::Arc;
use std::time::Duration;

use pipes_core::export::PipesArgs;

use super::tool::Tool;
use super::{Machine, MachineError};
use crate::config::Tach;
use crate::network::modfn::tach_read;

/// How often the measured speed is read while waiting for it.
pub const SPEED_POLL: Duration = Duration::from_millis(10);

/// How often a running spindle's speed is read for a stall.
pub const STALL_POLL: Duration = Duration::from_millis(25);

/// A spindle at its speed ([`Tool::await_speed`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpeedReached {
    /// The speed commanded, rpm.
    pub target: f64,
    /// The speed measured when the wait ended, rpm.
    pub rpm: f64,
    /// When the module measured it, synchronized µs.
    pub time_us: u64,
    /// How long the wait took.
    pub waited: Duration,
}

impl Tool {
    /// The spindle's tachometer, if it has one.
    pub fn tach(&self) -> Option<Tach> {
        self.machine().config().tools[self.name()].tach
    }

    /// The speed its module's tachometer measured last: (synchronized µs
    /// of the measurement, rpm). An error for a tool without a `tach`.
    pub async fn measured_rpm(&self) -> Result<(u64, f64), MachineError> {
        let module = &self.machine().config().tools[self.name()].module;
        if self.tach().is_none() {
            return Err(MachineError::Tool {
                tool: self.name().into(),
                reason:
                    "it has no tachometer: give its [tools] entry tach = { pin, pulses_per_rev }"
                        .into(),
            });
        }
        let out = self
            .machine()
            .call_idempotent(module, tach_read::Inputs {})
            .await?;
        let o = tach_read::Outputs::from_values(&out).map_err(|_| MachineError::BadOutput {
            module: module.clone(),
            function: tach_read::NAME.into(),
            expected: "(time: u64, rpm: f32)".into(),
            got: format!("{out:?}"),
        })?;
        Ok((o.time, f64::from(o.rpm)))
    }

    /// The speed the tool's level commands, rpm.
    fn commanded_rpm(&self) -> f64 {
        let t = &self.machine().config().tools[self.name()];
        self.level() * t.max_rpm.unwrap_or(0.0)
    }

    /// Waits until the measured speed is within the tachometer's
    /// tolerance of the commanded one (of `max_rpm` when stopping), then
    /// watches the running spindle for a stall. Past the tachometer's
    /// `timeout_s` the machine faults (the spindle and every tool off) and
    /// the error says what was measured.
    pub async fn await_speed(&self) -> Result<SpeedReached, MachineError> {
        let Some(tach) = self.tach() else {
            return Err(MachineError::Tool {
                tool: self.name().into(),
                reason: "it has no tachometer to wait for".into(),
            });
        };
        let max = self.machine().config().tools[self.name()]
            .max_rpm
            .unwrap_or(0.0);
        let target = self.commanded_rpm();
        let band = tach.tolerance * if target > 0.0 { target } else { max };
        let generation = self.generation();
        let start = tokio::time::Instant::now();
        let deadline = start + Duration::from_secs_f64(tach.timeout_s);
        loop {
            let (time_us, rpm) = self.measured_rpm().await?;
            if (rpm - target).abs() <= band {
                if target > 0.0 {
                    self.watch_for_stall(tach, target, generation);
                }
                return Ok(SpeedReached {
                    target,
                    rpm,
                    time_us,
                    waited: start.elapsed(),
                });
            }
            if tokio::time::Instant::now() >= deadline {
                let reason = format!(
                    "spindle {} did not reach {target:.0} rpm within {} s (tach timeout_s): it measures {rpm:.0} rpm; check the drive, its wiring and the tachometer",
                    self.name(),
                    tach.timeout_s
                );
                self.machine().fault_and_stop(reason.clone());
                return Err(MachineError::Tool {
                    tool: self.name().into(),
                    reason,
                });
            }
            tokio::time::sleep(SPEED_POLL).await;
        }
    }

    /// The tool's change counter (see `ToolState::generation`).
    fn generation(&self) -> u64 {
        self.machine()
            .inner
            .tools
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .get(self.name())
            .map_or(0, |s| s.generation)
    }

    /// Reads the spindle's speed every [`STALL_POLL`] while its level is
    /// still the one that commanded `target` (change `generation`): below
    /// the tachometer's `stall_fraction` of it, the spindle stalled, and
    /// the machine faults. Ends with the machine or the level.
    fn watch_for_stall(&self, tach: Tach, target: f64, generation: u64) {
        let weak = Arc::downgrade(&self.machine().inner);
        let name = self.name().to_string();
        tokio::spawn(async move {
            let floor = tach.stall_fraction * target;
            loop {
                tokio::time::sleep(STALL_POLL).await;
                let Some(inner) = weak.upgrade() else { return };
                let machine = Machine { inner };
                let Ok(tool) = machine.tool(&name) else {
                    return;
                };
                if tool.generation() != generation {
                    return;
                }
                // A read that fails (a lost module) is the link monitor's
                // to report; the watch goes on.
                let Ok((_, rpm)) = tool.measured_rpm().await else {
                    continue;
                };
                if tool.generation() != generation {
                    return;
                }
                if rpm < floor {
                    machine.fault_and_stop(format!(
                        "spindle {name} stalled: it measures {rpm:.0} rpm, below {} of the {target:.0} rpm commanded; the machine stopped and switched its tools off",
                        tach.stall_fraction
                    ));
                    return;
                }
            }
        });
    }
}
