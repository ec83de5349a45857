//! The switch homing sequence, one for a cartesian order's axes and an
//! arm's joints: the slots of a group seek their switches together, each
//! at its own speed, and each stops at its own switch's edge.
//!
//! The planner moves every slot of a line together, so "stops at its own
//! edge while the others go on" is done in legs: all open slots go
//! straight toward their switches; at the first edge the line stops (a
//! controlled stop), the slot whose switch closed is done (its coordinate
//! at the edge's time is taken from the samples sent), and the rest go on
//! in a new line from where they stand. On CoreXY, where both motors move
//! for either axis, the lines are in machine coordinates: once x has its
//! edge, y goes on alone and x stands (both motors still turn).

use tokio::sync::broadcast;

use super::ExpectSwitch;
use crate::machine::{lock_motion, monitor, Machine, MachineError, MAX_AXES};

/// One planner slot homing on its switch, in the slot's units (an axis's,
/// or radians for an arm's joint).
#[derive(Debug, Clone)]
pub(super) struct SwitchHoming {
    /// The axis's name, for errors and the `Homed` event.
    pub(super) axis: String,
    /// The planner slot.
    pub(super) k: usize,
    /// The module whose limit input is the switch.
    pub(super) switch: String,
    /// Toward the switch: −1 (homing to min) or +1 (to max).
    pub(super) dir: f64,
    /// How far the first search goes before the switch counts as broken.
    pub(super) search: f64,
    /// The slot's coordinate at the switch's edge (`endstop`).
    pub(super) home: f64,
    /// Where homing leaves the slot, off the switch.
    pub(super) off: f64,
    /// The back-off distance (the latch search goes twice it).
    pub(super) backoff: f64,
    /// The first search's speed, and the speed of the moves between.
    pub(super) search_speed: f64,
    /// The second, slow search's speed, if there is one.
    pub(super) latch_speed: Option<f64>,
    /// The slot's unit, for messages.
    pub(super) unit: &'static str,
}

impl SwitchHoming {
    fn fail(&self, reason: String) -> MachineError {
        MachineError::Homing {
            axis: self.axis.clone(),
            reason,
        }
    }
}

/// Where a move takes a slot.
#[derive(Debug, Clone, Copy)]
pub(super) enum Target {
    /// To exactly this coordinate (not `here + (value − here)`, which
    /// rounds).
    To(f64),
    /// By this much from where the queue ends.
    By(f64),
}

/// One slot's part of a combined search.
struct Seek<'a> {
    h: &'a SwitchHoming,
    distance: f64,
    speed: f64,
}

/// How close to the end of its distance a slot counts as having run it
/// all: far under a microstep (rounding of `speed × time`).
const AT_END: f64 = 1e-6;

impl Machine {
    /// Homes `group`'s slots on their switches, together (the machine
    /// homing, the planner's slots as the group's units). Every switch of
    /// the group may be pressed meanwhile, and no other.
    pub(super) async fn home_on_switches(
        &self,
        group: &[SwitchHoming],
    ) -> Result<(), MachineError> {
        let modules: Vec<&str> = group.iter().map(|h| h.switch.as_str()).collect();
        let _expect = ExpectSwitch::new(&self.inner.expecting, &modules);
        // Off a switch pressed already: its press would be no edge.
        let pressed: Vec<&SwitchHoming> = group
            .iter()
            .filter(|h| self.switch_pressed(&h.switch))
            .collect();
        if !pressed.is_empty() {
            let moves: Vec<_> = pressed
                .iter()
                .map(|h| (h.k, Target::By(-h.dir * 2.0 * h.backoff), h.search_speed))
                .collect();
            self.move_slots(&moves).await?;
            if let Some(h) = pressed.iter().find(|h| self.switch_pressed(&h.switch)) {
                return Err(h.fail(format!(
                    "the switch on module {} stays pressed after moving {} {} off it",
                    h.switch,
                    2.0 * h.backoff,
                    h.unit
                )));
            }
        }
        let seeks: Vec<Seek> = group
            .iter()
            .map(|h| Seek {
                h,
                distance: h.search,
                speed: h.search_speed,
            })
            .collect();
        self.search_and_back_off(&seeks).await?;
        let latching: Vec<Seek> = group
            .iter()
            .filter_map(|h| {
                Some(Seek {
                    h,
                    distance: 2.0 * h.backoff,
                    speed: h.latch_speed?,
                })
            })
            .collect();
        if !latching.is_empty() {
            self.search_and_back_off(&latching).await?;
        }
        Ok(())
    }

    /// Seeks every switch of `seeks`, re-defines each slot so that its
    /// coordinate at its edge's time is its `home`, and moves them all
    /// to `off`.
    async fn search_and_back_off(&self, seeks: &[Seek<'_>]) -> Result<(), MachineError> {
        let at = self.seek_switches(seeks).await?;
        let shifts: Vec<(usize, f64)> = seeks
            .iter()
            .zip(&at)
            .map(|(s, at)| (s.h.k, s.h.home - at))
            .collect();
        self.shift_slots(&shifts)?;
        let moves: Vec<_> = seeks
            .iter()
            .map(|s| (s.h.k, Target::To(s.h.off), s.h.search_speed))
            .collect();
        self.move_slots(&moves).await
    }

    /// Moves the slots of `seeks` together, each toward its switch at its
    /// speed, until every switch has been pressed. A slot whose switch is
    /// pressed stops there (the others stop with it, then go on without
    /// it); its coordinate at its edge's time (the module's stamp) is
    /// returned, in `seeks`' order. A slot that runs its whole distance
    /// unpressed fails the search, with every slot standing.
    async fn seek_switches(&self, seeks: &[Seek<'_>]) -> Result<Vec<f64>, MachineError> {
        let mut edges = self.inner.limit_edges.subscribe();
        let since = self.now_us().await?;
        let mut at: Vec<Option<f64>> = vec![None; seeks.len()];
        let mut left: Vec<f64> = seeks.iter().map(|s| s.distance).collect();
        loop {
            let open: Vec<usize> = (0..seeks.len()).filter(|&i| at[i].is_none()).collect();
            if open.is_empty() {
                break;
            }
            // This leg: each open slot at its speed, until the first of
            // them has gone its whole distance.
            let time = open
                .iter()
                .map(|&i| left[i] / seeks[i].speed)
                .fold(f64::INFINITY, f64::min);
            let from = {
                let mut m = lock_motion(&self.inner.motion);
                let from = m.planner.tail();
                let mut to = from;
                for &i in &open {
                    let s = &seeks[i];
                    to[s.h.k] += s.h.dir * s.speed * time;
                }
                let speeds: Vec<(usize, f64)> = open
                    .iter()
                    .map(|&i| (seeks[i].h.k, seeks[i].speed))
                    .collect();
                let path = path_axes(m.planner.vector_limits().path_axes);
                if let Some(feed) = feed_for(&from, &to, &speeds, path) {
                    m.planner.line(to, feed)?;
                    m.mark_busy();
                }
                from
            };
            let edge = loop {
                tokio::select! {
                    biased;
                    e = edges.recv() => match e {
                        Ok((module, edge))
                            if edge.pressed
                                && edge.time >= since
                                && open.iter().any(|&i| seeks[i].h.switch == module) =>
                        {
                            break Some((module, edge.time));
                        }
                        Ok(_) | Err(broadcast::error::RecvError::Lagged(_)) => continue,
                        Err(broadcast::error::RecvError::Closed) => return Err(MachineError::Stopped),
                    },
                    r = self.idle() => {
                        r?;
                        break None;
                    }
                }
            };
            let heard = edge.is_some();
            if heard {
                self.stop_motion().await?;
            }
            // Every press heard by now, and the switches' last reports:
            // two switches may close within one stop, and a receiver that
            // lagged missed edges the reports still hold.
            let mut presses: Vec<(String, u64)> = edge.into_iter().collect();
            loop {
                match edges.try_recv() {
                    Ok((module, e)) if e.pressed && e.time >= since => {
                        presses.push((module, e.time))
                    }
                    Ok(_) | Err(broadcast::error::TryRecvError::Lagged(_)) => continue,
                    Err(_) => break,
                }
            }
            {
                let r = monitor::lock(&self.inner.reports);
                for &i in &open {
                    let switch = &seeks[i].h.switch;
                    if let Some(e) = r.limit.get(switch).filter(|e| e.pressed && e.time >= since) {
                        presses.push((switch.clone(), e.time));
                    }
                }
            }
            // A switch's first press is its edge.
            presses.sort_by_key(|p| p.1);
            let m = lock_motion(&self.inner.motion);
            let mut latched = false;
            for (module, time) in presses {
                for &i in &open {
                    if seeks[i].h.switch != module || at[i].is_some() {
                        continue;
                    }
                    let p = m.position_at(time).ok_or_else(|| {
                        seeks[i].h.fail(format!(
                            "the switch's edge time {time} µs is outside the recent motion; are the module clocks synchronized?"
                        ))
                    })?;
                    at[i] = Some(p[seeks[i].h.k]);
                    latched = true;
                }
            }
            let here = m.planner.tail();
            drop(m);
            for &i in &open {
                let k = seeks[i].h.k;
                left[i] -= (here[k] - from[k]).abs();
            }
            if !heard {
                // The leg ran to its end: the slot it ended for had its
                // whole distance, unpressed.
                let ran_out = open
                    .iter()
                    .copied()
                    .filter(|&i| at[i].is_none())
                    .min_by(|&a, &b| left[a].total_cmp(&left[b]));
                if let Some(i) = ran_out {
                    if left[i] <= AT_END || !latched {
                        let s = &seeks[i];
                        return Err(s.h.fail(format!(
                            "the switch on module {} was not pressed within {:.1} {}; check its wiring and the homing direction",
                            s.h.switch, s.distance, s.h.unit
                        )));
                    }
                }
            }
        }
        Ok(at.into_iter().flatten().collect())
    }

    /// Moves slots together in one straight line, each to its target and
    /// none faster than its own speed (the slowest sets the line's time),
    /// and waits until they stand. No travel check: homing works before
    /// the travel is known.
    pub(super) async fn move_slots(
        &self,
        moves: &[(usize, Target, f64)],
    ) -> Result<(), MachineError> {
        {
            let mut m = lock_motion(&self.inner.motion);
            let from = m.planner.tail();
            let mut to = from;
            for &(k, target, _) in moves {
                to[k] = match target {
                    Target::To(v) => v,
                    Target::By(d) => from[k] + d,
                };
            }
            let speeds: Vec<(usize, f64)> = moves.iter().map(|&(k, _, v)| (k, v)).collect();
            let path = path_axes(m.planner.vector_limits().path_axes);
            if let Some(feed) = feed_for(&from, &to, &speeds, path) {
                m.planner.line(to, feed)?;
                m.mark_busy();
            }
        }
        self.idle().await
    }

    /// Adds each `(slot, delta)` to its slot's coordinate, without moving.
    pub(super) fn shift_slots(&self, deltas: &[(usize, f64)]) -> Result<(), MachineError> {
        let mut m = lock_motion(&self.inner.motion);
        let n = m.drive.axes().len();
        let mut p = m.planner.tail();
        for &(k, delta) in deltas {
            p[k] += delta;
        }
        let motors = m.last_motors.clone();
        m.drive.rebase(&p[..n], &motors)?;
        let mut p3 = [0.0; MAX_AXES];
        p3[..n].copy_from_slice(&p[..n]);
        m.set_position(p3)?;
        Ok(())
    }
}

/// How many leading slots carry the planner's path (its vector limits'
/// `path_axes`; 0: all).
fn path_axes(k: usize) -> usize {
    match k {
        0 => MAX_AXES,
        k => k.min(MAX_AXES),
    }
}

/// The planner feed for a straight line from `from` to `to` that moves
/// each slot of `speeds` at most at its speed: the line takes as long as
/// its slowest slot needs, and the planner's feed is along the path slots
/// (the first `path`) when any of them moves, else along all. `None` for
/// a line that does not move.
fn feed_for(
    from: &[f64; MAX_AXES],
    to: &[f64; MAX_AXES],
    speeds: &[(usize, f64)],
    path: usize,
) -> Option<f64> {
    let time = speeds
        .iter()
        .map(|&(k, v)| (to[k] - from[k]).abs() / v)
        .fold(0.0, f64::max);
    let length = |slots: std::ops::Range<usize>| {
        slots.map(|k| (to[k] - from[k]).powi(2)).sum::<f64>().sqrt()
    };
    let on_path = length(0..path);
    let length = if on_path > 1e-9 {
        on_path
    } else {
        length(0..MAX_AXES)
    };
    (time > 0.0 && length > 1e-9).then(|| length / time)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_combined_line_moves_each_slot_at_its_own_speed() {
        let from = [0.0; MAX_AXES];
        let mut to = from;
        to[0] = -110.0;
        to[1] = -55.0;
        // x at 100/s, y at 50/s: 1.1 s for both, along a path of
        // √(110² + 55²) = 122.98.
        let feed = feed_for(&from, &to, &[(0, 100.0), (1, 50.0)], 3).unwrap();
        assert!((feed - 122.983_738_762_3 / 1.1).abs() < 1e-9, "{feed}");
        // The slower slot sets the time: y at 100/s would need 0.55 s, x
        // 1.1 s at 100/s.
        let feed = feed_for(&from, &to, &[(0, 100.0), (1, 100.0)], 3).unwrap();
        assert!((feed - 122.983_738_762_3 / 1.1).abs() < 1e-9, "{feed}");
        // Off the path slots (an extruder, slot 3 of 3 path slots): along
        // all.
        let mut e = from;
        e[3] = 5.0;
        assert_eq!(feed_for(&from, &e, &[(3, 2.0)], 3), Some(2.0));
        assert_eq!(feed_for(&from, &from, &[(0, 2.0)], 3), None);
    }
}
