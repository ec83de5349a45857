//! The load cell on the filament path (`[axes.e.loadcell]`): set up at
//! start, tared and read through [`Machine::loadcell`].

use std::collections::BTreeMap;
use std::time::Duration;

use pipes_core::export::PipesArgs;

use super::start::call_idempotent;
use super::*;
use crate::config::LoadCellKeys;
use crate::network::modfn::{loadcell_read, loadcell_scale, loadcell_setup, loadcell_tare};

/// A load-cell sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoadCellReading {
    /// When the module read it, synchronized µs (0: none yet).
    pub time_us: u64,
    /// The force, N (tared and scaled).
    pub force_n: f64,
    /// The converter's counts.
    pub raw: i32,
    /// Samples read since the machine set it up.
    pub samples: u32,
    /// Whether a tare is under way.
    pub taring: bool,
}

/// The machine's load cell (see [`Machine::loadcell`]).
#[derive(Clone)]
pub struct LoadCell {
    machine: Machine,
}

impl std::fmt::Debug for LoadCell {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LoadCell").finish_non_exhaustive()
    }
}

/// Sets up the load cell on its module (pins, scale), during the
/// machine's configure phase.
pub(super) async fn configure_loadcell(
    cfg: &MachineFile,
    manager: &Manager,
    modules: &BTreeMap<String, ModuleInfo>,
) -> Result<(), MachineError> {
    let Some(l) = loadcell_keys(cfg) else {
        return Ok(());
    };
    let runtime = modules[&l.module].runtime.as_str();
    let module = l.module.as_str();
    let setup = loadcell_setup::Inputs {
        data_pin: l.data_pin,
        clock_pin: l.clock_pin,
    };
    call_idempotent(manager, runtime, module, setup).await?;
    let scale = loadcell_scale::Inputs {
        newtons_per_count: l.newtons_per_count as f32,
    };
    call_idempotent(manager, runtime, module, scale).await?;
    Ok(())
}

fn loadcell_keys(cfg: &MachineFile) -> Option<&LoadCellKeys> {
    cfg.extruder()?.extruder.loadcell.as_ref()
}

impl Machine {
    /// The load cell of `[axes.e.loadcell]`.
    pub fn loadcell(&self) -> Result<LoadCell, MachineError> {
        loadcell_keys(self.config())
            .map(|_| LoadCell {
                machine: self.clone(),
            })
            .ok_or(MachineError::NoLoadCell)
    }
}

impl LoadCell {
    fn module(&self) -> String {
        loadcell_keys(self.machine.config())
            .map(|l| l.module.clone())
            .unwrap_or_default()
    }

    /// The newest sample.
    pub async fn read(&self) -> Result<LoadCellReading, MachineError> {
        let out = self
            .machine
            .call_idempotent(&self.module(), loadcell_read::Inputs {})
            .await?;
        let o = loadcell_read::Outputs::from_values(&out)
            .map_err(|_| MachineError::LoadCell(format!("loadcell_read answered {out:?}")))?;
        Ok(LoadCellReading {
            time_us: o.time,
            force_n: f64::from(o.force),
            raw: o.raw,
            samples: o.samples,
            taring: o.taring,
        })
    }

    /// Takes the mean of the next `samples` samples as zero, and waits
    /// until they are in (an HX711 gives 10 or 80 a second; the wait ends
    /// in an error after `samples / 5` seconds, enough at 10 a second).
    pub async fn tare(&self, samples: u16) -> Result<(), MachineError> {
        self.machine.check_running()?;
        if self.machine.tare_cell(&self.module(), samples).await? {
            return Ok(());
        }
        Err(MachineError::LoadCell(format!(
            "the tare of {samples} samples did not finish: is the converter wired (data and clock pins) and powered?"
        )))
    }
}

impl Machine {
    /// Tares the load cell on `module` with the mean of its next `samples`
    /// samples and waits for them: `false` if they are not in after
    /// `samples / 5 + 1` seconds (enough at 10 samples a second, the
    /// slowest converter).
    pub(super) async fn tare_cell(&self, module: &str, samples: u16) -> Result<bool, MachineError> {
        self.call_idempotent(module, loadcell_tare::Inputs { samples })
            .await?;
        let deadline =
            tokio::time::Instant::now() + Duration::from_secs_f64(f64::from(samples) / 5.0 + 1.0);
        loop {
            let out = self
                .call_idempotent(module, loadcell_read::Inputs {})
                .await?;
            let taring = loadcell_read::Outputs::from_values(&out)
                .map_err(|_| MachineError::LoadCell(format!("loadcell_read answered {out:?}")))?
                .taring;
            if !taring {
                return Ok(true);
            }
            if tokio::time::Instant::now() > deadline {
                return Ok(false);
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }
}
