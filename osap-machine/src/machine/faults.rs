//! What the machine does on a fault: a controlled stop, every module
//! halted and every tool off, and which faults stop it at all.

use super::*;

impl Machine {
    /// Halts the machine and marks it faulted on every fault, limit hit
    /// outside homing, or lost module.
    pub(super) fn spawn_fault_handler(&self) {
        let weak = Arc::downgrade(&self.inner);
        let mut rx = self.inner.events.subscribe();
        let mut edges = self.inner.limit_edges.subscribe();
        tokio::spawn(async move {
            loop {
                let (reason, crash) = tokio::select! {
                    e = rx.recv() => match e {
                        Ok(MachineEvent::Fault { module, kind, detail, reason, .. }) => {
                            let Some(inner) = weak.upgrade() else { return };
                            if !stops_motion(&inner, &module, kind, detail) {
                                continue;
                            }
                            let machine = Machine { inner };
                            let heater = (kind == events::FaultKind::HeaterRunaway)
                                .then(|| machine.heater_name(&module, (detail & 0xff) as u8))
                                .flatten();
                            match heater {
                                Some(name) => (format!("heater {name}: module {module} {reason}"), false),
                                None => (format!("module {module} {reason}"), false),
                            }
                        }
                        Ok(MachineEvent::LinkLost { module }) => {
                            let Some(inner) = weak.upgrade() else { return };
                            inner.lost.lock().unwrap_or_else(|e| e.into_inner()).insert(module.clone());
                            (format!("module {module} stopped answering"), false)
                        }
                        Ok(_) | Err(broadcast::error::RecvError::Lagged(_)) => continue,
                        Err(broadcast::error::RecvError::Closed) => return,
                    },
                    e = edges.recv() => match e {
                        Ok((module, edge)) => {
                            if !edge.is_edge() {
                                // The switch's state when its pipe began.
                                continue;
                            }
                            let Some(inner) = weak.upgrade() else { return };
                            let expected = inner
                                .expecting
                                .lock()
                                .unwrap_or_else(|e| e.into_inner())
                                .contains(&module);
                            let _ = inner.events.send(MachineEvent::Limit {
                                module: module.clone(),
                                time: edge.time,
                                pressed: edge.pressed,
                                expected,
                            });
                            if expected || !edge.pressed {
                                continue;
                            }
                            (format!("limit switch on module {module} pressed outside homing: every motor stopped at once; home again"), true)
                        }
                        Err(broadcast::error::RecvError::Lagged(_)) => continue,
                        Err(broadcast::error::RecvError::Closed) => return,
                    },
                };
                let Some(inner) = weak.upgrade() else { return };
                let machine = Machine { inner };
                if crash {
                    // The points already sent run a lead ahead: only the
                    // modules can stop at once. Where the axes are is then
                    // known only to a step count, not to the switch: re-home.
                    // The report goes out as an event, and to the log.
                    machine.emergency_stop_as(reason).await;
                    machine
                        .inner
                        .homed
                        .lock()
                        .unwrap_or_else(|e| e.into_inner())
                        .iter_mut()
                        .zip(machine.homing_axes())
                        .for_each(|(h, homes)| *h = !homes);
                } else {
                    machine.fault_and_stop(reason);
                }
            }
        });
    }

    /// Stops motion (a controlled stop) and marks the machine faulted;
    /// `true` if this is its first fault. The first fault is the one the
    /// machine reports until it recovers: what follows (refusals behind a
    /// stopped axis) is its consequence. [`Machine::fault_and_stop`] also
    /// halts every module and switches every tool off.
    pub(super) fn fault(&self, reason: String) -> bool {
        {
            let mut m = lock_motion(&self.inner.motion);
            let _ = m.halt();
            m.mark_busy();
        }
        if matches!(*self.inner.state.borrow(), MachineState::Faulted(_)) {
            tracing::debug!("machine faulted again: {reason}");
            return false;
        }
        tracing::warn!("machine faulted: {reason}");
        let state = MachineState::Faulted(reason);
        self.inner.state.send_replace(state.clone());
        let _ = self.inner.events.send(MachineEvent::State(state));
        true
    }

    /// Whether module `module`'s fault of `kind` with `detail` (a
    /// [`MachineEvent::Fault`]) stops this machine: every fault does but
    /// late steps within `[limits] max_late_steps` and a refusal for a
    /// motor the machine file leaves disabled.
    pub fn fault_stops(&self, module: &str, kind: events::FaultKind, detail: u32) -> bool {
        stops_motion(&self.inner, module, kind, detail)
    }
}

/// Whether a module's fault stops the machine: every kind but late steps
/// within `[limits] max_late_steps`, and a refusal for a disabled motor
/// only when the machine file enables a motor of that module.
pub(super) fn stops_motion(
    inner: &Inner,
    module: &str,
    kind: events::FaultKind,
    detail: u32,
) -> bool {
    use events::FaultKind as K;
    use osap_module::stepper::StepperError as E;
    let code = |e: E| u32::from(e.code());
    let halt_expected = inner
        .expecting_halt
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .iter()
        .any(|m| m == module);
    match kind {
        K::None => false,
        // A load-cell probe's comparator halting z ends its search; the
        // points streamed past the touch are refused as halted.
        K::BlockHalt if halt_expected => false,
        K::Refused if halt_expected && detail == code(E::Faulted) => false,
        // Late steps stall a real motor: more than the file allows stop.
        K::StepOverrun => detail > inner.cfg.limits.max_late_steps,
        K::Refused if detail == code(E::Disabled) => lock_motion(&inner.motion)
            .drive
            .motors()
            .iter()
            .any(|m| m.module == module && m.enable),
        K::Refused
        | K::Backstop
        | K::LimitHit
        | K::Halted
        | K::OverLimit
        | K::OutputWatchdog
        | K::HeaterRunaway
        | K::BlockHalt => true,
    }
}
