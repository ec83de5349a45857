//! Homing: find each axis's switch, and re-define the machine position
//! there without moving a motor.
//!
//! Per axis: if the switch is already pressed, move off it; seek toward it
//! at the search speed until its module reports the pressed edge (with the
//! module's own time stamp of the edge); stop within limits; re-define the
//! axis so that where it was at the edge's time is the switch's `endstop`
//! (beyond the soft travel, or at its edge); back off into the travel;
//! seek again at the latch speed for a precise edge; re-define; back off.
//! The machine position at the edge's time comes from the samples the
//! motors were sent, so the host's delay in hearing of the edge does not
//! matter.

use std::sync::Mutex;

use tokio::sync::broadcast;

use super::events::MachineEvent;
use super::{lock_motion, monitor, Machine, MachineError, MAX_AXES};
use crate::config::Direction;

mod joints;

/// How far past the travel a search may go, as a fraction of the travel.
const SEARCH_MARGIN: f64 = 0.1;

/// Marks one module's switch press as expected (homing or probing on it),
/// and no other's; clears the mark when the search ends, however it ends.
pub(super) struct ExpectSwitch<'a>(&'a Mutex<Option<String>>);

impl<'a> ExpectSwitch<'a> {
    /// Marks `module` in `slot` as expected until dropped: a press on its
    /// switch (`expecting`), or its axis's halt by a probe's comparator
    /// (`expecting_halt`).
    pub(super) fn new(slot: &'a Mutex<Option<String>>, module: &str) -> Self {
        *slot.lock().unwrap_or_else(|e| e.into_inner()) = Some(module.to_string());
        ExpectSwitch(slot)
    }
}

impl Drop for ExpectSwitch<'_> {
    fn drop(&mut self) {
        *self.0.lock().unwrap_or_else(|e| e.into_inner()) = None;
    }
}

impl Machine {
    /// Homes every axis that has homing, in the file's order (lower
    /// `order` first; axes of one order one after another, in axis order).
    /// An arm's x and y home its two joints, together, where the first of
    /// them comes in the order ([`Machine::home_joints`]).
    pub async fn home(&self) -> Result<(), MachineError> {
        let order: Vec<String> = self
            .config()
            .homing_order()
            .into_iter()
            .flatten()
            .map(String::from)
            .collect();
        self.home_in_order(&order).await
    }

    /// Homes `order`'s axes one after another; an arm's joints once.
    async fn home_in_order(&self, order: &[String]) -> Result<(), MachineError> {
        let mut joints_homed = false;
        for axis in order {
            if self.config().homed_joint(axis).is_some() {
                if !joints_homed {
                    self.home_joints().await?;
                    joints_homed = true;
                }
                continue;
            }
            self.home_axis(axis).await?;
        }
        Ok(())
    }

    /// Homes the named axes, in the file's homing order.
    pub async fn home_axes(&self, axes: &[&str]) -> Result<(), MachineError> {
        for a in axes {
            let known = self
                .config()
                .axes
                .get(*a)
                .ok_or_else(|| MachineError::UnknownAxis(a.to_string()))?;
            if known.homing.is_none() {
                return Err(MachineError::Homing {
                    axis: a.to_string(),
                    reason: "it has no [axes.NAME] homing".into(),
                });
            }
        }
        // An arm's joints home together: x or y names both.
        let cfg = self.config();
        let arm = axes.iter().any(|a| cfg.homed_joint(a).is_some());
        let order: Vec<String> = cfg
            .homing_order()
            .into_iter()
            .flatten()
            .filter(|a| axes.contains(a) || (arm && cfg.homed_joint(a).is_some()))
            .map(String::from)
            .collect();
        self.home_in_order(&order).await
    }

    async fn home_axis(&self, axis: &str) -> Result<(), MachineError> {
        let fail = |reason: String| MachineError::Homing {
            axis: axis.to_string(),
            reason,
        };
        let cfg = self.config().clone();
        let a = &cfg.axes[axis];
        let homing = a
            .homing
            .as_ref()
            .ok_or_else(|| fail("no homing configured".into()))?;
        if homing.probe {
            self.idle().await?;
            self.inner.state.send_replace(super::MachineState::Homing);
            let result = self.home_axis_on_probe(axis, homing, a).await;
            let homing = matches!(*self.inner.state.borrow(), super::MachineState::Homing);
            if homing {
                self.inner.state.send_replace(super::MachineState::Idle);
            }
            return result;
        }
        let Some(switch) = homing.switch.as_deref() else {
            return Err(fail(
                "stall homing is not supported yet: wire a switch and set `switch`".into(),
            ));
        };
        let k = self
            .axes()
            .iter()
            .position(|n| n == axis)
            .ok_or_else(|| MachineError::UnknownAxis(axis.into()))?;
        self.idle().await?;
        // Only this axis's switch may be pressed now: any other stops.
        let _expect = ExpectSwitch::new(&self.inner.expecting, switch);
        self.inner.state.send_replace(super::MachineState::Homing);
        let result = self.home_axis_inner(axis, k, switch, homing, a).await;
        // Read, then write: a watch borrow held across a send deadlocks.
        let homing = matches!(*self.inner.state.borrow(), super::MachineState::Homing);
        if homing {
            self.inner.state.send_replace(super::MachineState::Idle);
        }
        result
    }

    async fn home_axis_inner(
        &self,
        axis: &str,
        k: usize,
        switch: &str,
        homing: &crate::config::Homing,
        a: &crate::config::Axis,
    ) -> Result<(), MachineError> {
        let fail = |reason: String| MachineError::Homing {
            axis: axis.to_string(),
            reason,
        };
        let (dir, end) = match homing.direction {
            Direction::Min => (-1.0, a.min),
            Direction::Max => (1.0, a.max),
        };
        // Where the switch's edge is: the axis is re-defined so that its
        // position at the edge's time reads this.
        let home = homing.endstop(a);
        let travel = a.max - a.min;
        let pressed = || {
            monitor::lock(&self.inner.reports)
                .limit
                .get(switch)
                .is_some_and(|e| e.pressed)
        };
        if pressed() {
            self.relative(k, -dir * 2.0 * homing.backoff, homing.search_speed)
                .await?;
            if pressed() {
                return Err(fail(format!(
                    "the switch on module {switch} stays pressed after moving {} off it",
                    2.0 * homing.backoff
                )));
            }
        }
        let search = travel * (1.0 + SEARCH_MARGIN) + (home - end).abs() + homing.backoff;
        let at = self
            .seek(k, switch, dir * search, homing.search_speed)
            .await
            .map_err(|e| match e {
                MachineError::Homing { reason, .. } => fail(reason),
                other => other,
            })?;
        self.shift_axis(k, home - at)?;
        // Inside the travel (the file's validation holds it there).
        let off = homing.homed_position(a);
        self.absolute(k, off, homing.search_speed).await?;
        if let Some(latch) = homing.latch_speed {
            let at = self
                .seek(k, switch, dir * 2.0 * homing.backoff, latch)
                .await
                .map_err(|e| match e {
                    MachineError::Homing { reason, .. } => fail(reason),
                    other => other,
                })?;
            self.shift_axis(k, home - at)?;
            self.absolute(k, off, homing.search_speed).await?;
        }
        self.inner.homed.lock().unwrap_or_else(|e| e.into_inner())[k] = true;
        let _ = self.inner.events.send(MachineEvent::Homed {
            axis: axis.to_string(),
        });
        Ok(())
    }

    /// Homes z down onto the bed with the probe's load cell: the touch is
    /// `endstop`, then z backs off to its homed position.
    async fn home_axis_on_probe(
        &self,
        axis: &str,
        homing: &crate::config::Homing,
        a: &crate::config::Axis,
    ) -> Result<(), MachineError> {
        let fail = |reason: String| MachineError::Homing {
            axis: axis.to_string(),
            reason,
        };
        let k = self
            .axes()
            .iter()
            .position(|n| n == axis)
            .ok_or_else(|| MachineError::UnknownAxis(axis.into()))?;
        let cfg = self.config().clone();
        let Some((module, cell)) = cfg
            .probe
            .as_ref()
            .and_then(|p| Some((p.module.clone(), p.loadcell?)))
        else {
            return Err(fail("probe homing needs [probe] with a loadcell".into()));
        };
        let travel = a.max - a.min;
        let search = travel * (1.0 + SEARCH_MARGIN) + homing.backoff;
        let Some((_, at)) = self
            .probe_down_by_reflex(&module, cell, k, search, homing.search_speed)
            .await?
        else {
            return Err(fail(format!(
                "the probe's load cell never reached {} N in {search:.1} of search: is the bed under the tip, and the cell wired?",
                cell.threshold_n
            )));
        };
        self.shift_axis(k, homing.endstop(a) - at[k])?;
        self.absolute(k, homing.homed_position(a), homing.search_speed)
            .await?;
        self.inner.homed.lock().unwrap_or_else(|e| e.into_inner())[k] = true;
        let _ = self.inner.events.send(MachineEvent::Homed {
            axis: axis.to_string(),
        });
        Ok(())
    }

    /// Moves axis slot `k` to exactly `value` (not `here + (value −
    /// here)`, which rounds) and waits until it stands.
    async fn absolute(&self, k: usize, value: f64, rate: f64) -> Result<(), MachineError> {
        self.move_axis(k, |_| value, rate).await
    }

    /// Moves axis slot `k` by `delta` (no travel check: homing works
    /// before the travel is known) and waits until it stands.
    async fn relative(&self, k: usize, delta: f64, rate: f64) -> Result<(), MachineError> {
        self.move_axis(k, |here| here + delta, rate).await
    }

    /// Moves axis slot `k` from where it stands to `to(here)`, and waits
    /// until it stands.
    async fn move_axis(
        &self,
        k: usize,
        to: impl FnOnce(f64) -> f64,
        rate: f64,
    ) -> Result<(), MachineError> {
        {
            let mut m = lock_motion(&self.inner.motion);
            let mut target = m.planner.tail();
            target[k] = to(target[k]);
            m.planner.line(target, rate)?;
            m.mark_busy();
        }
        self.idle().await
    }

    /// Moves axis slot `k` by up to `delta` at `rate` until module
    /// `switch` reports its switch pressed; stops and returns the axis's
    /// coordinate at the edge's time.
    async fn seek(
        &self,
        k: usize,
        switch: &str,
        delta: f64,
        rate: f64,
    ) -> Result<f64, MachineError> {
        let mut edges = self.inner.limit_edges.subscribe();
        let since = self.now_us().await?;
        {
            let mut m = lock_motion(&self.inner.motion);
            let mut to = m.planner.tail();
            to[k] += delta;
            m.planner.line(to, rate)?;
            m.mark_busy();
        }
        let edge = loop {
            tokio::select! {
                e = edges.recv() => match e {
                    Ok((module, edge)) if module == switch && edge.pressed && edge.time >= since => break edge,
                    Ok(_) | Err(broadcast::error::RecvError::Lagged(_)) => continue,
                    Err(broadcast::error::RecvError::Closed) => return Err(MachineError::Stopped),
                },
                r = self.idle() => {
                    r?;
                    return Err(MachineError::Homing {
                        axis: String::new(),
                        reason: format!(
                            "the switch on module {switch} was not pressed within {:.1} units; check its wiring and the homing direction",
                            delta.abs()
                        ),
                    });
                }
            }
        };
        self.stop_motion().await?;
        let m = lock_motion(&self.inner.motion);
        let at = m.position_at(edge.time).ok_or_else(|| MachineError::Homing {
            axis: String::new(),
            reason: format!(
                "the switch's edge time {} µs is outside the recent motion; are the module clocks synchronized?",
                edge.time
            ),
        })?;
        Ok(at[k])
    }

    /// Adds `delta` to axis slot `k`'s coordinate, without moving.
    fn shift_axis(&self, k: usize, delta: f64) -> Result<(), MachineError> {
        let mut m = lock_motion(&self.inner.motion);
        let n = m.drive.axes().len();
        let mut p = m.planner.tail();
        p[k] += delta;
        let motors = m.last_motors.clone();
        m.drive.rebase(&p[..n], &motors)?;
        let mut p3 = [0.0; MAX_AXES];
        p3[..n].copy_from_slice(&p[..n]);
        m.set_position(p3)?;
        Ok(())
    }
}
