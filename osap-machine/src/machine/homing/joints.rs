//! Homing an arm (scara, fivebar): its joints, one at a time, in joint
//! space, by the switch sequence cartesian axes home with; then x and y
//! from the joints through the kinematics.
//!
//! The joints stay one at a time: a combined turn of both is no straight
//! line in x and y, and the arm's reach is checked only when homing
//! leaves joint space.

use maxl::blocks::planner::{Limits, Planner, VectorLimits, DEFAULT_CAPACITY};

use super::search::SwitchHoming;
use crate::config::{Direction, Kinematics, MachineFile, JOINT_SEARCH};
use crate::machine::events::MachineEvent;
use crate::machine::{lock_motion, Machine, MachineError, MAX_AXES};

impl Machine {
    /// Homes an arm's two joints (scara, fivebar: x's homing homes the
    /// first joint, y's the second, in the file's homing order; see
    /// [`MachineFile::homed_joint`](crate::config::MachineFile::homed_joint)).
    /// The machine plans in joint space meanwhile (each joint seeks its
    /// switch alone, as a cartesian axis does, in radians), then takes
    /// its machine position from the homed joints through the
    /// kinematics. Both joints count as homed, with x and y, only if both
    /// homed and the pose is one the kinematics reach in the file's
    /// working mode.
    pub async fn home_joints(&self) -> Result<(), MachineError> {
        let cfg = self.config().clone();
        let joints: Vec<String> = cfg
            .homing_order()
            .into_iter()
            .flatten()
            .filter(|a| cfg.homed_joint(a).is_some())
            .map(String::from)
            .collect();
        self.idle().await?;
        self.inner
            .state
            .send_replace(crate::machine::MachineState::Homing);
        let result = match self.enter_joint_space() {
            Ok(()) => {
                let mut result = Ok(());
                for axis in &joints {
                    result = self.home_joint(axis).await;
                    if result.is_err() {
                        break;
                    }
                }
                // Leave joint space however homing ended: a fault's stop
                // replaced the planner in joint coordinates.
                let left = self.leave_joint_space();
                result.and(left)
            }
            Err(e) => Err(e),
        };
        if result.is_ok() {
            let mut homed = self.inner.homed.lock().unwrap_or_else(|e| e.into_inner());
            for axis in &joints {
                if let Some(k) = self.axes().iter().position(|n| n == axis) {
                    homed[k] = true;
                }
            }
            drop(homed);
            for axis in &joints {
                let _ = self
                    .inner
                    .events
                    .send(MachineEvent::Homed { axis: axis.clone() });
            }
        }
        let homing = matches!(
            *self.inner.state.borrow(),
            crate::machine::MachineState::Homing
        );
        if homing {
            self.inner
                .state
                .send_replace(crate::machine::MachineState::Idle);
        }
        result
    }

    /// Plans in the arm's joint space from here on: slots 0 and 1 are
    /// its joints' angles where the motors stand, under a planner whose
    /// joint limits [`joint_planner`] derives. No motor moves.
    fn enter_joint_space(&self) -> Result<(), MachineError> {
        let mut m = lock_motion(&self.inner.motion);
        let motors = m.last_motors.clone();
        m.drive.set_joint_space(true);
        let entered = m
            .drive
            .machine_position(&motors)
            .map_err(MachineError::from)
            .and_then(|q| {
                let mut planner = joint_planner(self.config())?;
                let mut p = [0.0; MAX_AXES];
                p[..q.len()].copy_from_slice(&q);
                planner.set_position(p)?;
                Ok(planner)
            });
        match entered {
            Ok(planner) => {
                m.replace_planner(planner);
                Ok(())
            }
            Err(e) => {
                m.drive.set_joint_space(false);
                Err(e)
            }
        }
    }

    /// Plans in machine coordinates again, from where the joints stand
    /// (the kinematics' forward map). An error when that pose is not one
    /// the kinematics' inverse returns to (out of reach, too near a
    /// singularity, or in the other working mode): moves from it would
    /// jump, so the arm stays unhomed.
    fn leave_joint_space(&self) -> Result<(), MachineError> {
        let mut m = lock_motion(&self.inner.motion);
        let motors = m.last_motors.clone();
        let q = m
            .drive
            .machine_position(&motors)
            .map(|q| format!("({:.4}, {:.4}) rad", q[0], q.get(1).copied().unwrap_or(0.0)))
            .unwrap_or_else(|e| format!("unknown ({e})"));
        m.drive.set_joint_space(false);
        let fail = |reason: String| MachineError::Homing {
            axis: "x, y".into(),
            reason,
        };
        let p = m.drive.machine_position(&motors)?;
        let back = m.drive.motor_positions(&p).map_err(|e| {
            fail(format!(
                "the arm stands at joints {q}, at ({:.3}, {:.3}), which the kinematics refuse: {e}; place the switches (endstop, backoff) so homing ends inside the arm's reach",
                p[0], p[1]
            ))
        });
        let mut planner = crate::machine::motion::machine_planner(self.config())?;
        let mut p6 = [0.0; MAX_AXES];
        p6[..p.len()].copy_from_slice(&p);
        planner.set_position(p6)?;
        m.replace_planner(planner);
        let back = back?;
        // A joint a microradian off is the other working mode, not rounding.
        if let Some((i, (a, b))) = motors
            .iter()
            .zip(&back)
            .enumerate()
            .find(|(_, (a, b))| (*a - *b).abs() > 1e-6)
        {
            return Err(fail(format!(
                "motor {} stands at {a:.6} but the kinematics put ({:.3}, {:.3}) at {b:.6}: the homed pose is in another working mode than the file's; place the switches so homing ends in it",
                m.drive.motors()[i].name,
                p[0],
                p[1]
            )));
        }
        Ok(())
    }

    /// Homes one arm joint on its switch, in joint space (slot `k` of the
    /// axis is the joint's angle, radians), alone: the switch sequence of
    /// a cartesian axis ([`SwitchHoming`]).
    async fn home_joint(&self, axis: &str) -> Result<(), MachineError> {
        let fail = |reason: String| MachineError::Homing {
            axis: axis.to_string(),
            reason,
        };
        let cfg = self.config().clone();
        let homing = cfg.axes[axis]
            .homing
            .as_ref()
            .ok_or_else(|| fail("no homing configured".into()))?;
        let (Some(switch), Some(home)) = (homing.switch.as_deref(), homing.endstop) else {
            return Err(fail(
                "an arm's joint homes on a switch at its endstop (radians)".into(),
            ));
        };
        let k = self
            .axes()
            .iter()
            .position(|n| n == axis)
            .ok_or_else(|| MachineError::UnknownAxis(axis.into()))?;
        let dir = match homing.direction {
            Direction::Min => -1.0,
            Direction::Max => 1.0,
        };
        let joint = SwitchHoming {
            axis: axis.to_string(),
            k,
            switch: switch.to_string(),
            dir,
            search: JOINT_SEARCH + homing.backoff,
            home,
            off: home - dir * homing.backoff,
            backoff: homing.backoff,
            search_speed: homing.search_speed,
            latch_speed: homing.latch_speed,
            unit: "rad",
        };
        self.home_on_switches(std::slice::from_ref(&joint)).await
    }
}

/// The planner an arm homes its joints with: slots 0 and 1 in radians,
/// at up to the joints' fastest homing speed, accelerating at most as
/// fast as turns the tool at full reach (`l1 + l2`) at the slower of x's
/// and y's accelerations (mm/s² over mm: rad/s²); the other axes keep
/// their own limits and stand still.
pub(crate) fn joint_planner(cfg: &MachineFile) -> Result<Planner<MAX_AXES>, MachineError> {
    let reach = match &cfg.kinematics {
        Kinematics::Scara { l1, l2, .. } | Kinematics::FiveBar { l1, l2, .. } => l1 + l2,
        other => {
            return Err(MachineError::Unsupported(format!(
                "{} kinematics have no joints to home",
                other.type_name()
            )))
        }
    };
    let names = cfg.axis_names();
    let mut vel = [1.0; MAX_AXES];
    let mut acc = [1.0; MAX_AXES];
    for (k, name) in names.iter().enumerate().take(MAX_AXES) {
        vel[k] = cfg.axes[*name].velocity;
        acc[k] = cfg.axes[*name].acceleration;
    }
    let speed = ["x", "y"]
        .iter()
        .filter_map(|a| cfg.axes.get(*a)?.homing.as_ref())
        .map(|h| h.search_speed)
        .fold(0.0, f64::max);
    let accel = ["x", "y"]
        .iter()
        .filter_map(|a| cfg.axes.get(*a))
        .map(|a| a.acceleration)
        .fold(cfg.limits.acceleration, f64::min)
        / reach;
    for k in 0..2 {
        vel[k] = speed;
        acc[k] = accel;
    }
    let limits = Limits::new(vel, acc, cfg.limits.junction_deviation)?;
    let vector = VectorLimits::new(speed, accel)?.with_path_axes(cfg.toolhead_axes());
    Ok(Planner::with_vector_limits(
        limits,
        vector,
        DEFAULT_CAPACITY,
    )?)
}
