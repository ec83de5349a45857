//! Tools: a spindle, pen or laser on a module's PWM or digital output.

use std::time::Duration;

use super::{Machine, MachineError};
use crate::config::Output;
use crate::network::modfn::{digital_write, pwm_write};

/// What the machine remembers of a tool.
#[derive(Debug, Default, Clone)]
pub(crate) struct ToolState {
    /// The level set last (0 off, 1 full).
    pub(super) level: f64,
    /// When the tool will have settled after the last change.
    ready_at: Option<tokio::time::Instant>,
    /// Bumped on every change of level: a spindle's stall watch ends when
    /// the level it watches is no longer the tool's.
    pub(super) generation: u64,
}

/// A tool of the machine (see [`Machine::tool`]).
#[derive(Clone)]
pub struct Tool {
    machine: Machine,
    name: String,
}

impl std::fmt::Debug for Tool {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Its parts are tasks, locks and buffers: the name says enough.
        f.debug_struct("Tool").finish_non_exhaustive()
    }
}

impl Machine {
    /// The tool `name` of `[tools]`.
    pub fn tool(&self, name: &str) -> Result<Tool, MachineError> {
        if !self.config().tools.contains_key(name) {
            return Err(MachineError::UnknownTool(name.into()));
        }
        Ok(Tool {
            machine: self.clone(),
            name: name.into(),
        })
    }

    /// Notes that a stop switched tool `name` off.
    pub(super) fn tool_is_off(&self, name: &str) {
        let mut tools = self.inner.tools.lock().unwrap_or_else(|e| e.into_inner());
        let s = tools.entry(name.to_string()).or_default();
        s.level = 0.0;
        s.ready_at = None;
        s.generation += 1;
    }

    /// The streamed tool does `cmd` from the next segment queued on (from
    /// where the queue ends), or at once if nothing is queued: a job's
    /// tool command on the path (see [`super::tool_track`]).
    pub fn tool_command(&self, cmd: super::tool_track::ToolCommand) {
        let mut m = super::motion::lock(&self.inner.motion);
        let mark = m.planner.stats().queued_total;
        if let Some(t) = &mut m.tool {
            t.command(mark, cmd);
        }
    }

    /// Notes the level a job left tool `name` at.
    pub(crate) fn note_tool_level(&self, name: &str, level: f64) {
        let mut tools = self.inner.tools.lock().unwrap_or_else(|e| e.into_inner());
        tools.entry(name.to_string()).or_default().level = level;
    }

    /// The first tool of a kind (pen, spindle, laser), if any.
    pub fn tool_of_kind(&self, kind: crate::config::ToolKind) -> Option<Tool> {
        let name = self
            .config()
            .tools
            .iter()
            .find(|(_, t)| t.kind == kind)?
            .0
            .clone();
        self.tool(&name).ok()
    }
}

impl Tool {
    /// The tool's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Sets the tool's level now: 0 off, 1 on (full speed or power), and
    /// between for PWM tools; a digital output is on for any level > 0.
    /// The tool is ready [`Tool::await_ready`] after its settle time, or,
    /// for a spindle with a tachometer, once its measured speed is there.
    pub async fn set(&self, level: f64) -> Result<(), MachineError> {
        if !(level.is_finite() && (0.0..=1.0).contains(&level)) {
            return Err(MachineError::Tool {
                tool: self.name.clone(),
                reason: format!("level {level} must be within 0..=1"),
            });
        }
        let t = &self.machine.config().tools[&self.name];
        // A streamed tool's stream takes the level from its next point on;
        // the write below sets it now (and drops the points its module had
        // queued).
        if let Some(track) = &mut super::motion::lock(&self.machine.inner.motion).tool {
            if track.name == self.name {
                track.set_now(level);
            }
        }
        match t.output {
            Output::Pwm(channel) => {
                let duty = t.off_duty + level * (t.on_duty - t.off_duty);
                let duty = duty as f32;
                self.machine
                    .call_module(&t.module, pwm_write::Inputs { channel, duty })
                    .await?;
            }
            Output::Digital(pin) => {
                let level = level > 0.0;
                self.machine
                    .call_module(&t.module, digital_write::Inputs { pin, level })
                    .await?;
            }
        }
        let settle = Duration::from_millis(u64::from(t.settle_ms));
        let mut tools = self
            .machine
            .inner
            .tools
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        let s = tools.entry(self.name.clone()).or_default();
        s.level = level;
        s.ready_at = Some(tokio::time::Instant::now() + settle);
        s.generation += 1;
        Ok(())
    }

    /// Full on (pen down, full power, full speed).
    pub async fn on(&self) -> Result<(), MachineError> {
        self.set(1.0).await
    }

    /// Off (pen up).
    pub async fn off(&self) -> Result<(), MachineError> {
        self.set(0.0).await
    }

    /// The machine it belongs to.
    pub(super) fn machine(&self) -> &Machine {
        &self.machine
    }

    /// A spindle at `rpm` (scaled by its `max_rpm`). With a tachometer,
    /// [`Tool::await_ready`] then waits for the measured speed.
    pub async fn set_rpm(&self, rpm: f64) -> Result<(), MachineError> {
        let t = &self.machine.config().tools[&self.name];
        let Some(max) = t.max_rpm else {
            return Err(MachineError::Tool {
                tool: self.name.clone(),
                reason: "no max_rpm in its [tools] entry: give one to set speeds in rpm".into(),
            });
        };
        if !(rpm.is_finite() && (0.0..=max).contains(&rpm)) {
            return Err(MachineError::Tool {
                tool: self.name.clone(),
                reason: format!("{rpm} rpm is outside 0..={max}"),
            });
        }
        self.set(rpm / max).await
    }

    /// The level set last.
    pub fn level(&self) -> f64 {
        self.machine
            .inner
            .tools
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .get(&self.name)
            .map_or(0.0, |s| s.level)
    }

    /// Waits until the tool has settled after its last change (a spindle
    /// at speed, a pen down), by its `settle_ms`; a spindle with a
    /// tachometer until its measured speed is within its tolerance
    /// ([`Tool::await_speed`]), which also starts watching it for a stall.
    pub async fn await_ready(&self) -> Result<(), MachineError> {
        if self.tach().is_some() {
            return self.await_speed().await.map(|_| ());
        }
        let at = self
            .machine
            .inner
            .tools
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .get(&self.name)
            .and_then(|s| s.ready_at);
        if let Some(at) = at {
            tokio::time::sleep_until(at).await;
        }
        Ok(())
    }
}
