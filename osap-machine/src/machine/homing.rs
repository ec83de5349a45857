//! Homing: find each axis's switch, and re-define the machine position
//! there without moving a motor.
//!
//! Axes home in the file's `order`, lower first; the switch-homed axes of
//! one order home together ([`search`]): if a switch is already pressed,
//! its axis moves off it; every axis seeks toward its switch at its own
//! search speed until its module reports the pressed edge (with the
//! module's own time stamp of the edge), and stops there while the others
//! go on; each axis is re-defined so that where it was at its edge's time
//! is its switch's `endstop` (beyond the soft travel, or at its edge); the
//! axes back off into the travel, seek again at their latch speeds for a
//! precise edge, are re-defined, and back off. The machine position at
//! an edge's time comes from the samples the motors were sent, so the
//! host's delay in hearing of the edge does not matter, nor does the
//! search speed.

use std::sync::Mutex;

use super::events::MachineEvent;
use super::{Machine, MachineError};
use crate::config::Direction;

mod joints;
mod search;

use search::SwitchHoming;

/// How far past the travel a search may go, as a fraction of the travel.
const SEARCH_MARGIN: f64 = 0.1;

/// Marks some modules' switch presses as expected (homing or probing on
/// them), and no other's; clears the mark when the search ends, however
/// it ends.
pub(super) struct ExpectSwitch<'a>(&'a Mutex<Vec<String>>);

impl<'a> ExpectSwitch<'a> {
    /// Marks `modules` in `slot` as expected until dropped: a press on
    /// their switches (`expecting`), or their axis's halt by a probe's
    /// comparator (`expecting_halt`).
    pub(super) fn new(slot: &'a Mutex<Vec<String>>, modules: &[&str]) -> Self {
        *slot.lock().unwrap_or_else(|e| e.into_inner()) =
            modules.iter().map(|m| m.to_string()).collect();
        ExpectSwitch(slot)
    }
}

impl Drop for ExpectSwitch<'_> {
    fn drop(&mut self) {
        self.0.lock().unwrap_or_else(|e| e.into_inner()).clear();
    }
}

/// How one axis of a homing order homes.
enum Way<'a> {
    /// On a switch, together with the order's other switch axes.
    Switch(SwitchHoming),
    /// Down onto the bed with the probe's load cell, alone.
    Probe(&'a str),
    /// An arm's joint: the arm's joints home on their own.
    Joint,
}

impl Machine {
    /// Homes every axis that has homing, in the file's order: lower
    /// `order` first; the axes of one order that home on switches home
    /// together, each stopping at its own switch (then any that home on
    /// the probe, one after another). An arm's x and y home its two
    /// joints, where the first of them comes in the order
    /// ([`Machine::home_joints`]).
    pub async fn home(&self) -> Result<(), MachineError> {
        let groups: Vec<Vec<String>> = self
            .config()
            .homing_order()
            .into_iter()
            .map(|g| g.into_iter().map(String::from).collect())
            .collect();
        self.home_in_order(&groups).await
    }

    /// Homes `groups` one after another (each an order's axes); an arm's
    /// joints once.
    async fn home_in_order(&self, groups: &[Vec<String>]) -> Result<(), MachineError> {
        let mut joints_homed = false;
        for group in groups {
            // Every axis's way first: a group that cannot home moves none.
            let ways = group
                .iter()
                .map(|axis| self.way_of(axis))
                .collect::<Result<Vec<_>, _>>()?;
            if ways.iter().any(|w| matches!(w, Way::Joint)) && !joints_homed {
                self.home_joints().await?;
                joints_homed = true;
            }
            let together: Vec<SwitchHoming> = ways
                .iter()
                .filter_map(|w| match w {
                    Way::Switch(h) => Some(h.clone()),
                    _ => None,
                })
                .collect();
            if !together.is_empty() {
                self.home_together(&together).await?;
            }
            for w in &ways {
                if let Way::Probe(axis) = w {
                    self.home_axis_on_probe(axis).await?;
                }
            }
        }
        Ok(())
    }

    /// Homes the named axes, in the file's homing order (the named axes
    /// of one order together).
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
        let groups: Vec<Vec<String>> = cfg
            .homing_order()
            .into_iter()
            .map(|g| {
                g.into_iter()
                    .filter(|a| axes.contains(a) || (arm && cfg.homed_joint(a).is_some()))
                    .map(String::from)
                    .collect::<Vec<_>>()
            })
            .filter(|g| !g.is_empty())
            .collect();
        self.home_in_order(&groups).await
    }

    /// How `axis` homes; an error, before anything moves, for an axis that
    /// cannot.
    fn way_of<'a>(&self, axis: &'a str) -> Result<Way<'a>, MachineError> {
        let fail = |reason: String| MachineError::Homing {
            axis: axis.to_string(),
            reason,
        };
        if self.config().homed_joint(axis).is_some() {
            return Ok(Way::Joint);
        }
        let a = self
            .config()
            .axes
            .get(axis)
            .ok_or_else(|| MachineError::UnknownAxis(axis.into()))?;
        let homing = a
            .homing
            .as_ref()
            .ok_or_else(|| fail("no homing configured".into()))?;
        if homing.probe {
            return Ok(Way::Probe(axis));
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
        let (dir, end) = match homing.direction {
            Direction::Min => (-1.0, a.min),
            Direction::Max => (1.0, a.max),
        };
        // Where the switch's edge is: the axis is re-defined so that its
        // position at the edge's time reads this.
        let home = homing.endstop(a);
        let travel = a.max - a.min;
        Ok(Way::Switch(SwitchHoming {
            axis: axis.to_string(),
            k,
            switch: switch.to_string(),
            dir,
            search: travel * (1.0 + SEARCH_MARGIN) + (home - end).abs() + homing.backoff,
            home,
            // Inside the travel (the file's validation holds it there).
            off: homing.homed_position(a),
            backoff: homing.backoff,
            search_speed: homing.search_speed,
            latch_speed: homing.latch_speed,
            unit: "units",
        }))
    }

    /// Homes `group`'s axes on their switches, together; marks them homed
    /// only if every one of them homed.
    async fn home_together(&self, group: &[SwitchHoming]) -> Result<(), MachineError> {
        self.idle().await?;
        self.inner.state.send_replace(super::MachineState::Homing);
        let result = self.home_on_switches(group).await;
        if result.is_ok() {
            let mut homed = self.inner.homed.lock().unwrap_or_else(|e| e.into_inner());
            for h in group {
                homed[h.k] = true;
            }
            drop(homed);
            for h in group {
                let _ = self.inner.events.send(MachineEvent::Homed {
                    axis: h.axis.clone(),
                });
            }
        }
        // Read, then write: a watch borrow held across a send deadlocks.
        let homing = matches!(*self.inner.state.borrow(), super::MachineState::Homing);
        if homing {
            self.inner.state.send_replace(super::MachineState::Idle);
        }
        result
    }

    /// Homes z down onto the bed with the probe's load cell: the touch is
    /// `endstop`, then z backs off to its homed position.
    async fn home_axis_on_probe(&self, axis: &str) -> Result<(), MachineError> {
        self.idle().await?;
        self.inner.state.send_replace(super::MachineState::Homing);
        let result = self.probe_home(axis).await;
        let homing = matches!(*self.inner.state.borrow(), super::MachineState::Homing);
        if homing {
            self.inner.state.send_replace(super::MachineState::Idle);
        }
        result
    }

    /// [`home_axis_on_probe`](Self::home_axis_on_probe)'s search, with the
    /// machine homing.
    async fn probe_home(&self, axis: &str) -> Result<(), MachineError> {
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
        let a = &cfg.axes[axis];
        let homing = a
            .homing
            .as_ref()
            .ok_or_else(|| fail("no homing configured".into()))?;
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
        self.shift_slots(&[(k, homing.endstop(a) - at[k])])?;
        self.move_slots(&[(
            k,
            search::Target::To(homing.homed_position(a)),
            homing.search_speed,
        )])
        .await?;
        self.inner.homed.lock().unwrap_or_else(|e| e.into_inner())[k] = true;
        let _ = self.inner.events.send(MachineEvent::Homed {
            axis: axis.to_string(),
        });
        Ok(())
    }
}
