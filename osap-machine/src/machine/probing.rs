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

use std::time::Duration;

use osap_host::som::{FnRef, Manager, PipeOptions, Value};
use pipes_core::control::{InputMode, OutputMode};

use super::homing::ExpectSwitch;
use super::start::call_idempotent;
use super::{lock_motion, monitor, Machine, MachineError, ModuleInfo, MAX_AXES};
use super::{INTERVAL_US, LEAD_US};
use crate::config::{MachineFile, ProbeLoadCell};
use crate::network::modfn::{get_status, loadcell_read, loadcell_scale, loadcell_setup};

/// The name of the comparator block a load-cell probe makes on its module
/// for each search.
pub(crate) const PROBE_BLOCK: &str = "osap_probe";

/// Sets up the probe's load cell (`[probe] loadcell`: pins, scale) during
/// the machine's configure phase.
pub(super) async fn configure_probe_cell(
    cfg: &MachineFile,
    manager: &Manager,
    modules: &std::collections::BTreeMap<String, ModuleInfo>,
) -> Result<(), MachineError> {
    let Some((p, cell)) = cfg.probe.as_ref().and_then(|p| Some((p, p.loadcell?))) else {
        return Ok(());
    };
    let runtime = modules[&p.module].runtime.as_str();
    let setup = loadcell_setup::Inputs {
        data_pin: cell.data_pin,
        clock_pin: cell.clock_pin,
    };
    call_idempotent(manager, runtime, &p.module, setup).await?;
    let scale = loadcell_scale::Inputs {
        newtons_per_count: cell.newtons_per_count as f32,
    };
    call_idempotent(manager, runtime, &p.module, scale).await?;
    Ok(())
}

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
        if let Some(cell) = self
            .config()
            .probe
            .as_ref()
            .filter(|p| p.module == module)
            .and_then(|p| p.loadcell)
        {
            return self
                .probe_down_by_reflex(module, cell, k, depth, rate)
                .await;
        }
        self.idle().await?;
        // A probe press is expected now, on this module alone: not a
        // crash. A press on any other switch still stops the machine.
        let _expect = ExpectSwitch::new(&self.inner.expecting, &[module]);
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

    /// [`probe_down`](Self::probe_down) with a load cell (`[probe]
    /// loadcell`): a comparator block on the probe's module, fed by the
    /// module's own cell, halts z in the module's loop when the force
    /// passes `threshold_n`; the machine then stands where the motors
    /// stopped, which it returns with the time it saw the halt.
    pub(super) async fn probe_down_by_reflex(
        &self,
        module: &str,
        cell: ProbeLoadCell,
        k: usize,
        depth: f64,
        rate: f64,
    ) -> Result<Option<(u64, Vec<f64>)>, MachineError> {
        self.idle().await?;
        self.tare_probe_cell(module).await?;
        let runtime = self.inner.modules[module].runtime.clone();
        let read = FnRef::new(runtime.as_str(), loadcell_read::NAME);
        {
            let mut manager = self.inner.manager.lock().await;
            // A block an interrupted search left starts afresh.
            if manager
                .som()
                .runtimes
                .iter()
                .any(|r| r.record.name == runtime && r.blocks.iter().any(|b| b.name == PROBE_BLOCK))
            {
                manager.delete_block(&runtime, PROBE_BLOCK).await?;
            }
            let threshold = cell.threshold_n as f32;
            manager
                .new_block(
                    &runtime,
                    "comparator",
                    PROBE_BLOCK,
                    &[
                        Value::F32(threshold),
                        Value::F32(0.2 * threshold),
                        Value::Bool(true),
                    ],
                )
                .await?;
            let touch = FnRef::new(runtime.as_str(), PROBE_BLOCK);
            manager
                .connect(&read, &touch, &[0, 1], &[0, 1], PipeOptions::default())
                .await?;
            manager.set_output_mode(&read, OutputMode::OnChange).await?;
            manager
                .set_input_mode(&read, InputMode::OnTimer(250))
                .await?;
        }
        let result = self.search_until_halted(module, k, depth, rate).await;
        // The block goes with its pipe; the cell is read on demand again.
        {
            let mut manager = self.inner.manager.lock().await;
            manager.delete_block(&runtime, PROBE_BLOCK).await?;
            manager.set_input_mode(&read, InputMode::OnAnyFresh).await?;
            manager.set_output_mode(&read, OutputMode::Always).await?;
        }
        result
    }

    /// Streams z down by up to `depth` at `rate` until `module`'s axis
    /// halts (its comparator saw the touch) or the search ends.
    async fn search_until_halted(
        &self,
        module: &str,
        k: usize,
        depth: f64,
        rate: f64,
    ) -> Result<Option<(u64, Vec<f64>)>, MachineError> {
        // The comparator's halt of this module, and the points its halted
        // axis then refuses, end the search: not a crash.
        let _expect = ExpectSwitch::new(&self.inner.expecting_halt, &[module]);
        {
            let mut m = lock_motion(&self.inner.motion);
            let mut to = m.planner.tail();
            to[k] -= depth;
            m.planner.line(to, rate)?;
            m.mark_busy();
        }
        let halted = || async {
            let out = self.call_idempotent(module, get_status::Inputs {}).await?;
            Ok::<bool, MachineError>(matches!(out.first(), Some(Value::U8(4))))
        };
        let touched = loop {
            tokio::select! {
                r = self.idle() => {
                    // The last points may have run before the halt was seen.
                    if halted().await? {
                        break true;
                    }
                    r?;
                    break false;
                }
                () = tokio::time::sleep(Duration::from_millis(2)) => {
                    if halted().await? {
                        break true;
                    }
                }
            }
        };
        if !touched {
            return Ok(None);
        }
        let at = self.now_us().await?;
        // What was planned past the touch is void: the halted axis refused
        // it. The stream pauses, the points in flight land, and the machine
        // stands where the motors stopped (the halt clears as z is enabled
        // again), as a recovery does.
        lock_motion(&self.inner.motion).paused = true;
        tokio::time::sleep(Duration::from_micros(u64::from(LEAD_US + 4 * INTERVAL_US))).await;
        let rearmed = self.rearm_motors(false).await;
        lock_motion(&self.inner.motion).paused = false;
        rearmed?;
        let tail = lock_motion(&self.inner.motion).planner.tail();
        Ok(Some((at, tail[..self.axes().len()].to_vec())))
    }

    /// Zeroes the probe's cell with its tip off the bed, and waits for it.
    async fn tare_probe_cell(&self, module: &str) -> Result<(), MachineError> {
        const SAMPLES: u16 = 16;
        if self.tare_cell(module, SAMPLES).await? {
            return Ok(());
        }
        Err(MachineError::Probe {
            point: "z".into(),
            reason: format!(
                "the probe's load cell did not finish its tare of {SAMPLES} samples: is its converter wired (data and clock pins) and powered?"
            ),
        })
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
