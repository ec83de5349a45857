//! What was planned and what the motors stepped, kept while recording,
//! and a test signal added to the plan.

use super::*;

impl Machine {
    /// Adds `excitation(stamp)` to the planned machine position at every
    /// control-point stamp from now on (a test signal such as the chirp of
    /// `osap resonance`; the planner does not see it, so keep the
    /// machine at rest meanwhile); `None` removes it.
    pub fn set_excitation(&self, excitation: Option<motion::Excitation>) {
        lock_motion(&self.inner.motion).excitation = excitation;
    }

    /// Starts keeping what was planned and what the motors stepped, for
    /// [`Machine::take_recording`]: each motor's stepped position every
    /// [`RECORD_PERIOD_US`].
    pub async fn start_recording(&self) -> Result<(), MachineError> {
        lock_motion(&self.inner.motion).record = Some(Vec::new());
        let n = lock_motion(&self.inner.motion).drive.motors().len();
        {
            let mut r = monitor::lock(&self.inner.reports);
            r.positions = Some(vec![Vec::new(); n]);
            r.applied = Some(Vec::new());
        }
        self.position_reports(InputMode::OnTimer(RECORD_PERIOD_US))
            .await
    }

    /// Sets the input mode of every motor module's `get_position` source:
    /// on a timer while recording, idle otherwise (or a recorder's timer,
    /// while one samples it).
    pub(super) async fn position_reports(&self, mode: InputMode) -> Result<(), MachineError> {
        let (motors, tool) = {
            let m = lock_motion(&self.inner.motion);
            let tool = m.tool.as_ref().map(|t| t.module.clone());
            (m.drive.motors().to_vec(), tool)
        };
        let mut manager = self.inner.manager.lock().await;
        for m in motors {
            let runtime = &self.inner.modules[&m.module].runtime;
            let f = crate::network::modfn::get_position::on(runtime);
            let mode = self.inner.capture_holds.machine_sets(&f, mode);
            manager.set_input_mode(&f, mode).await?;
        }
        // The streamed tool's output, read back every millisecond: its
        // ramps change every 100 µs.
        if let Some(key) = tool {
            let runtime = &self.inner.modules[&key].runtime;
            let f = crate::network::modfn::level_read::on(runtime);
            let mode = match mode {
                InputMode::OnTimer(_) => InputMode::OnTimer(FAST_PERIOD_US),
                other => other,
            };
            let mode = self.inner.capture_holds.machine_sets(&f, mode);
            manager.set_input_mode(&f, mode).await?;
        }
        Ok(())
    }

    /// Who holds which module function's timer: recorders beside the
    /// machine's own reports.
    #[cfg_attr(not(feature = "capture"), allow(dead_code))]
    pub(crate) fn capture_holds(&self) -> &holds::Holds {
        &self.inner.capture_holds
    }

    /// What was planned and stepped since [`Machine::start_recording`],
    /// from synchronized time `from_us` on, as machine positions: planned
    /// at every stamp, executed read back from the motors' stepped
    /// positions on a 1 kHz grid. Stops recording.
    pub async fn take_recording(
        &self,
        from_us: u64,
    ) -> Result<crate::record::Recording, MachineError> {
        self.position_reports(InputMode::OnAnyFresh).await?;
        let (planned, drive_axes) = {
            let mut m = lock_motion(&self.inner.motion);
            (m.record.take().unwrap_or_default(), m.drive.axes().to_vec())
        };
        let (positions, applied) = {
            let mut r = monitor::lock(&self.inner.reports);
            (
                r.positions.take().unwrap_or_default(),
                r.applied.take().unwrap_or_default(),
            )
        };
        let tool = lock_motion(&self.inner.motion)
            .tool
            .as_ref()
            .map(|t| t.name.clone());
        let n = drive_axes.len();
        let secs = |t: u64| (t as f64 - from_us as f64) * 1e-6;
        let kept = || planned.iter().filter(|s| s.0 >= from_us);
        let unshaped: Vec<crate::record::Sample> = kept()
            .map(|s| crate::record::Sample {
                t: secs(s.0),
                pos: s.2[..n].to_vec(),
            })
            .collect();
        let planned: Vec<crate::record::Sample> = kept()
            .map(|s| crate::record::Sample {
                t: secs(s.0),
                pos: s.1[..n].to_vec(),
            })
            .collect();
        let mut executed = Vec::new();
        let end = positions
            .iter()
            .filter_map(|p| p.last().map(|l| l.0))
            .min()
            .unwrap_or(0);
        if end > from_us && positions.iter().all(|p| !p.is_empty()) {
            let dt = 1e-3;
            let count = ((secs(end) / dt).floor() as usize).saturating_add(1);
            let series: Vec<Vec<f64>> = positions
                .iter()
                .map(|p| {
                    let pts: Vec<(f64, f64)> = p.iter().map(|s| (secs(s.0), s.1)).collect();
                    crate::record::resample_linear(&pts, 0.0, dt, count)
                })
                .collect();
            let m = lock_motion(&self.inner.motion);
            for i in 0..count {
                let motors: Vec<f64> = series.iter().map(|s| s[i]).collect();
                if let Ok(pos) = m.drive.machine_position(&motors) {
                    executed.push(crate::record::Sample {
                        t: i as f64 * dt,
                        pos,
                    });
                }
            }
        }
        // The tool's duty on the executed grid: interpolated between its
        // readbacks (a ramp between two is a ramp).
        let mut tools = Vec::new();
        let mut tool_readbacks = Vec::new();
        if let Some(name) = tool {
            let pts: Vec<(f64, f64)> = applied
                .iter()
                .filter(|a| a.0 >= from_us)
                .map(|a| (secs(a.0), a.1))
                .collect();
            if let Some(last) = executed.last() {
                // The executed grid (1 ms), less any sample the kinematics
                // could not place: pick each sample's own grid point.
                let dt = 1e-3;
                let count = (last.t / dt).round() as usize + 1;
                let grid = crate::record::resample_linear(&pts, 0.0, dt, count);
                let column = executed
                    .iter()
                    .map(|s| grid[((s.t / dt).round() as usize).min(count - 1)])
                    .collect();
                tools.push((name.clone(), column));
            }
            tool_readbacks.push((name, pts));
        }
        Ok(crate::record::Recording {
            axes: drive_axes,
            planned,
            executed,
            unshaped,
            vibration: Vec::new(),
            stalled: Vec::new(),
            tools,
            tool_readbacks,
        })
    }
}
