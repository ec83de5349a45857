//! Probing the bed: a z search on a probe input, and changing the bed mesh
//! the machine follows. The flow that probes a grid is in the `level` module.
//!
//! A probe is a switch on a module's limit input (`[probe] module`). Like a
//! homing switch, its press reaches the host as an edge stamped with the
//! module's own time; the machine position at that time comes from the
//! samples the motors were sent, so the host's delay in hearing of the
//! edge does not matter.

use maxl::blocks::bedlevel::BedMesh;
use tokio::sync::broadcast;

use super::homing::ExpectSwitch;
use super::{lock_motion, monitor, Machine, MachineError, MAX_AXES};

impl Machine {
    /// Whether the switch on `module`'s limit input reads pressed (as last
    /// reported).
    pub fn switch_pressed(&self, module: &str) -> bool {
        monitor::lock(&self.inner.reports)
            .limit
            .get(module)
            .is_some_and(|e| e.pressed)
    }

    /// Moves the z axis down by up to `depth` at `rate` until the switch on
    /// `module`'s limit input is pressed, then stops (a controlled stop).
    /// Returns the edge's synchronized time (µs, the module's stamp) and
    /// the machine position (axis order) then, or
    /// `None` when the search ran its whole depth untriggered (the axis
    /// then stands at its end). The switch must be one the machine watches
    /// (a homing switch or `[probe] module`).
    pub async fn probe_down(
        &self,
        module: &str,
        depth: f64,
        rate: f64,
    ) -> Result<Option<(u64, Vec<f64>)>, MachineError> {
        if !(depth.is_finite() && depth > 0.0) {
            return Err(MachineError::Probe {
                point: "z".into(),
                reason: format!("search depth {depth} must be positive"),
            });
        }
        if !(rate.is_finite() && rate > 0.0) {
            return Err(MachineError::BadRate(rate));
        }
        let k = self
            .axes()
            .iter()
            .position(|a| a == "z")
            .ok_or_else(|| MachineError::UnknownAxis("z".into()))?;
        self.idle().await?;
        // A probe press is expected now, on this module alone: not a
        // crash. A press on any other switch still stops the machine.
        let _expect = ExpectSwitch::new(&self.inner.expecting, module);
        let mut edges = self.inner.limit_edges.subscribe();
        let since = self.now_us().await?;
        {
            let mut m = lock_motion(&self.inner.motion);
            let mut to = m.planner.tail();
            to[k] -= depth;
            m.planner.line(to, rate)?;
            m.mark_busy();
        }
        let edge = loop {
            tokio::select! {
                e = edges.recv() => match e {
                    Ok((from, edge)) if from == module && edge.pressed && edge.time >= since => break edge,
                    Ok(_) | Err(broadcast::error::RecvError::Lagged(_)) => continue,
                    Err(broadcast::error::RecvError::Closed) => return Err(MachineError::Stopped),
                },
                r = self.idle() => {
                    r?;
                    return Ok(None);
                }
            }
        };
        self.stop_motion().await?;
        let m = lock_motion(&self.inner.motion);
        let at = m
            .position_at(edge.time)
            .ok_or_else(|| MachineError::Probe {
                point: "z".into(),
                reason: format!(
                    "the probe's edge time {} µs is outside the recent motion; are the module clocks synchronized?",
                    edge.time
                ),
            })?;
        Ok(Some((edge.time, at)))
    }

    /// The bed mesh the machine follows, if any.
    pub fn bed_mesh(&self) -> Option<BedMesh> {
        lock_motion(&self.inner.motion).drive.mesh().cloned()
    }

    /// Follows `mesh` from now on (`None`: a flat bed). No motor moves: the
    /// machine's z where it stands is re-read through the new mesh, so the
    /// homed coordinates stay true. Waits for the queue to finish first.
    pub async fn set_bed_mesh(&self, mesh: Option<BedMesh>) -> Result<(), MachineError> {
        if mesh.is_some() && (self.axes().len() < 3 || self.axes()[..3] != ["x", "y", "z"]) {
            return Err(MachineError::Unsupported(format!(
                "bed_mesh: a bed mesh needs axes x, y and z; this machine has {}",
                self.axes().join(", ")
            )));
        }
        self.idle().await?;
        let mut m = lock_motion(&self.inner.motion);
        let old = m.drive.mesh().cloned();
        m.drive.set_mesh(mesh);
        let motors = m.last_motors.clone();
        let p = match m.drive.machine_position(&motors) {
            Ok(p) => p,
            Err(e) => {
                m.drive.set_mesh(old);
                return Err(e.into());
            }
        };
        let mut p3 = [0.0; MAX_AXES];
        p3[..p.len()].copy_from_slice(&p);
        m.set_position(p3)?;
        Ok(())
    }
}
