//! Outputs with a safe state, kept by the modules themselves.
//!
//! When a machine starts (and when [`Machine::recover`](super::Machine::recover)
//! sets a lost module up again), it gives each tool's output its safe
//! value on the tool's module (`set_safe_pwm` with the tool's `off_duty`,
//! `set_safe_digital` low) and arms every module's output watchdog
//! (`set_output_watchdog` with `[modules.NAME] output_watchdog_ms`). A
//! module whose upstream stays quiet that long puts its outputs to their
//! safe values by itself, and its `halt` does the same: a dead host or a
//! cut cable cannot leave a spindle, laser or pen on.
//!
//! A spindle's tachometer (`[tools.NAME] tach`) is set up on its module
//! at the same time (`tach_setup`), so its speed is measured from the
//! start.
//!
//! While the machine runs, a task per module calls its `get_status`
//! four times per watchdog time, so even a module that no stream reaches
//! (a tool's) hears from the host often enough.

use std::collections::BTreeMap;
use std::time::Duration;

use osap_host::som::{FnRef, FunctionHandle, Manager, SomError};

use super::{som_refusal, MachineError, ModuleInfo};
use crate::config::{MachineFile, Output};
use crate::network::modfn::{
    get_status, set_output_watchdog, set_safe_digital, set_safe_pwm, tach_setup, ModuleCall,
};

/// How many times per output watchdog time the host calls each module.
pub(super) const FEEDS_PER_WATCHDOG: u32 = 4;

/// Module function `C` for setting outputs up, or an error naming what
/// the module lacks.
fn setup_function<C: ModuleCall>(
    manager: &Manager,
    key: &str,
    runtime: &str,
    why: &str,
) -> Result<FunctionHandle, MachineError> {
    let function = C::NAME;
    manager
        .function(&FnRef::new(runtime, function))
        .map_err(|e| match e {
            SomError::NoSuchFunction(_) => MachineError::Unsupported(format!(
                "modules.{key}: the module has no {function}, so {why}; update its firmware (`osap flash`)"
            )),
            other => MachineError::Network(other),
        })
}

/// Gives module `key`'s tool outputs their safe values (from the machine
/// file's tools) and arms its output watchdog. A module with a tool must
/// offer both; one without tools is armed if it can be.
pub(super) async fn arm_module(
    cfg: &MachineFile,
    manager: &Manager,
    key: &str,
    runtime: &str,
) -> Result<(), MachineError> {
    let tools: Vec<_> = cfg.tools.iter().filter(|(_, t)| t.module == key).collect();
    for (name, tool) in &tools {
        let why = format!("tool {name} would stay on if the host went quiet");
        let (function, args) = match tool.output {
            Output::Pwm(channel) => {
                let safe = set_safe_pwm::Inputs {
                    channel,
                    duty: tool.off_duty as f32,
                };
                let f = setup_function::<set_safe_pwm::Inputs>(manager, key, runtime, &why)?;
                (f, safe.values())
            }
            Output::Digital(pin) => {
                let safe = set_safe_digital::Inputs { pin, level: false };
                let f = setup_function::<set_safe_digital::Inputs>(manager, key, runtime, &why)?;
                (f, safe.values())
            }
        };
        function
            .call_idempotent(&args)
            .await
            .map_err(|e| som_refusal(key, &function.function().function, e))?;
        // A spindle's tachometer counts on its module from the start.
        if let Some(tach) = tool.tach {
            let why = format!("spindle {name}'s speed could not be measured");
            let f = setup_function::<tach_setup::Inputs>(manager, key, runtime, &why)?;
            let args = tach_setup::Inputs {
                pin: tach.pin,
                pulses_per_rev: tach.pulses_per_rev,
            };
            f.call_idempotent(&args.values())
                .await
                .map_err(|e| som_refusal(key, tach_setup::NAME, e))?;
        }
    }
    let watchdog = match setup_function::<set_output_watchdog::Inputs>(
        manager,
        key,
        runtime,
        "its outputs would stay as they are if the host went quiet",
    ) {
        Ok(h) => h,
        Err(MachineError::Unsupported(_)) if tools.is_empty() => return Ok(()),
        Err(e) => return Err(e),
    };
    let ms = cfg.modules[key].output_watchdog_ms();
    watchdog
        .call_idempotent(&set_output_watchdog::Inputs { timeout_ms: ms }.values())
        .await
        .map_err(|e| som_refusal(key, set_output_watchdog::NAME, e))?;
    Ok(())
}

/// [`arm_module`] for every module of the machine file.
pub(super) async fn arm_all(
    cfg: &MachineFile,
    manager: &Manager,
    modules: &BTreeMap<String, ModuleInfo>,
) -> Result<(), MachineError> {
    for (key, m) in modules {
        arm_module(cfg, manager, key, &m.runtime).await?;
    }
    Ok(())
}

/// Starts a task per module that calls its `get_status` every
/// `output_watchdog_ms / FEEDS_PER_WATCHDOG`, keeping its output watchdog
/// fed while the machine runs (the tasks end when their handles are
/// aborted, with the machine). A lost request is not retried: the next
/// call comes a period later, so two lost in a row still leave the module
/// fed within its watchdog time; a module that stops answering is found
/// by its silent status reports.
pub(super) fn keep_fed(
    cfg: &MachineFile,
    manager: &Manager,
    modules: &BTreeMap<String, ModuleInfo>,
) -> Result<Vec<tokio::task::JoinHandle<()>>, MachineError> {
    let mut tasks = Vec::new();
    for (key, m) in modules {
        let period = Duration::from_millis(u64::from(cfg.modules[key].output_watchdog_ms()))
            / FEEDS_PER_WATCHDOG;
        // A call waits for its reply at most a period: one lost request
        // delays the next call by no more than that.
        let h = manager
            .function(&get_status::on(&m.runtime))?
            .with_timeout(period);
        let key = key.clone();
        tasks.push(tokio::spawn(async move {
            let mut every = tokio::time::interval(period);
            every.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            loop {
                every.tick().await;
                if let Err(e) = h.call(&[]).await {
                    tracing::debug!("feeding module {key}'s output watchdog: {e}");
                }
            }
        }));
    }
    Ok(tasks)
}
