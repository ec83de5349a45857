//! Heaters: set up on their modules at start, set and read by name, and
//! waited on. The control loop and runaway protection run on the module
//! (`osap_module::heater`); the host sets targets, reads temperatures and
//! stops the machine on a heater's fault like any other.

use std::time::Duration;

use pipes_core::export::PipesArgs;

use super::start::call_idempotent;
use super::*;
use crate::config::Heater as HeaterConfig;
use crate::network::modfn::{
    heater_gains, heater_limits, heater_output, heater_power, heater_read, heater_runaway,
    heater_sensor, heater_target,
};

/// How often a wait reads the heater's temperature.
const WAIT_POLL: Duration = Duration::from_millis(100);
/// How close to its target a heater must read for a wait to end, °C.
pub const WAIT_WINDOW_C: f64 = 1.5;

/// A heater's state as its module reports it (`heater_read`'s code).
pub use osap_module::heater::HeaterState;

/// One reading of a heater.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeaterReading {
    /// When the module read it, synchronized µs (0: no reading yet).
    pub time_us: u64,
    /// The temperature, °C.
    pub celsius: f64,
    /// The target, °C (0: off).
    pub target: f64,
    /// The duty it drives, 0–1.
    pub power: f64,
    /// Its state.
    pub state: HeaterState,
}

/// A heater of the machine (see [`Machine::heater`]).
#[derive(Clone)]
pub struct Heater {
    machine: Machine,
    name: String,
    index: u8,
}

impl std::fmt::Debug for Heater {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Heater")
            .field("name", &self.name)
            .finish_non_exhaustive()
    }
}

/// The heater's index on its module: its place among that module's
/// heaters in name order (a module runs two).
pub fn heater_index(cfg: &MachineFile, name: &str) -> Option<u8> {
    let module = &cfg.heaters.get(name)?.module;
    let k = cfg
        .heaters
        .iter()
        .filter(|(_, h)| &h.module == module)
        .position(|(n, _)| n == name)?;
    u8::try_from(k).ok()
}

/// Sets up every heater on its module (off, then sensor, output, limits,
/// gains and runaway protection), during the machine's configure phase.
pub(super) async fn configure_heaters(
    cfg: &MachineFile,
    manager: &Manager,
    modules: &BTreeMap<String, ModuleInfo>,
) -> Result<(), MachineError> {
    for (name, h) in &cfg.heaters {
        let index = heater_index(cfg, name).unwrap_or(0);
        let runtime = modules[&h.module].runtime.as_str();
        configure_heater(manager, runtime, name, index, h).await?;
    }
    Ok(())
}

async fn configure_heater(
    manager: &Manager,
    runtime: &str,
    name: &str,
    index: u8,
    h: &HeaterConfig,
) -> Result<(), MachineError> {
    let module = h.module.as_str();
    let off = heater_target::Inputs {
        index,
        celsius: 0.0,
    };
    call_idempotent(manager, runtime, module, off).await?;
    let s = &h.sensor;
    // The file was checked when it was read.
    let curve = s.curve().map_err(|(k, why)| {
        MachineError::Config(crate::config::ConfigError::Invalid {
            file: None,
            key: format!("heaters.{name}.sensor.{k}"),
            message: why,
        })
    })?;
    let call = heater_sensor::Inputs {
        index,
        analog: s.analog,
        a: curve.a as f32,
        b: curve.b as f32,
        c: curve.c as f32,
        pullup_ohms: s.pullup_ohms as f32,
    };
    call_idempotent(manager, runtime, module, call).await?;
    let call = heater_output::Inputs {
        index,
        pwm: h.pwm(),
        max_power: h.max_power as f32,
    };
    call_idempotent(manager, runtime, module, call).await?;
    let call = heater_limits::Inputs {
        index,
        min_temp: h.min_temp as f32,
        max_temp: h.max_temp as f32,
    };
    call_idempotent(manager, runtime, module, call).await?;
    let call = heater_gains::Inputs {
        index,
        kp: h.kp as f32,
        ki: h.ki as f32,
        kd: h.kd as f32,
    };
    call_idempotent(manager, runtime, module, call).await?;
    let r = h.runaway(name);
    let call = heater_runaway::Inputs {
        index,
        hysteresis_c: r.hysteresis_c as f32,
        max_error: r.max_error as f32,
        heating_gain_c: r.heating_gain_c as f32,
        check_gain_time_s: r.check_gain_time_s.unwrap_or(20.0) as f32,
    };
    call_idempotent(manager, runtime, module, call).await?;
    Ok(())
}

impl Machine {
    /// The heater `name` of `[heaters]`.
    pub fn heater(&self, name: &str) -> Result<Heater, MachineError> {
        let index = heater_index(self.config(), name)
            .ok_or_else(|| MachineError::UnknownHeater(name.into()))?;
        Ok(Heater {
            machine: self.clone(),
            name: name.into(),
            index,
        })
    }

    /// Every heater, in name order.
    pub fn heaters(&self) -> Vec<Heater> {
        self.config()
            .heaters
            .keys()
            .filter_map(|n| self.heater(n).ok())
            .collect()
    }

    /// The heater on module `module` at `index`, by name.
    pub(super) fn heater_name(&self, module: &str, index: u8) -> Option<String> {
        let cfg = self.config();
        cfg.heaters
            .iter()
            .filter(|(_, h)| h.module == module)
            .nth(usize::from(index))
            .map(|(n, _)| n.clone())
    }
}

impl Heater {
    /// The heater's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    fn config(&self) -> &HeaterConfig {
        &self.machine.config().heaters[&self.name]
    }

    /// Holds `celsius` from now on (0: off). Refused past the heater's
    /// `max_temp`, and by the module while the heater is faulted.
    pub async fn set_target(&self, celsius: f64) -> Result<(), MachineError> {
        let h = self.config();
        if !(celsius == 0.0 || (celsius >= h.min_temp && celsius < h.max_temp)) {
            return Err(MachineError::Heater {
                heater: self.name.clone(),
                reason: format!(
                    "target {celsius} °C is outside its min_temp {} to max_temp {} °C",
                    h.min_temp, h.max_temp
                ),
            });
        }
        self.machine.check_running()?;
        let call = heater_target::Inputs {
            index: self.index,
            celsius: celsius as f32,
        };
        self.machine.call_idempotent(&h.module, call).await?;
        Ok(())
    }

    /// Drives the heater open loop at `duty` (0–1, within its
    /// `max_power`), for autotuning; the module's protection still holds.
    pub async fn set_power(&self, duty: f64) -> Result<(), MachineError> {
        self.machine.check_running()?;
        let call = heater_power::Inputs {
            index: self.index,
            duty: duty as f32,
        };
        self.machine
            .call_idempotent(&self.config().module, call)
            .await?;
        Ok(())
    }

    /// Reads the heater.
    pub async fn read(&self) -> Result<HeaterReading, MachineError> {
        let call = heater_read::Inputs { index: self.index };
        let out = self
            .machine
            .call_idempotent(&self.config().module, call)
            .await?;
        let bad = || MachineError::Heater {
            heater: self.name.clone(),
            reason: format!("heater_read answered {out:?}"),
        };
        let o = heater_read::Outputs::from_values(&out).map_err(|_| bad())?;
        Ok(HeaterReading {
            time_us: o.time,
            celsius: f64::from(o.temp),
            target: f64::from(o.target),
            power: f64::from(o.power),
            // A code this host does not know is taken as the worst.
            state: HeaterState::from_code(o.state).unwrap_or(HeaterState::Faulted),
        })
    }

    /// Waits until the heater reads within [`WAIT_WINDOW_C`] of its
    /// target, and returns how long that took. A heater that faults, a
    /// machine that stops, or a wait past the heater's `wait_timeout_s`
    /// ends it with an error (the timeout is a fault: the machine stops).
    pub async fn wait_for_target(&self) -> Result<Duration, MachineError> {
        let start = tokio::time::Instant::now();
        let timeout = Duration::from_secs_f64(self.config().wait_timeout_s);
        loop {
            self.machine.check_running()?;
            let r = self.read().await?;
            if r.state == HeaterState::Faulted {
                // Its module's fault report stops the machine too; the
                // first fault is the one it keeps.
                let reason = format!(
                    "heater {}: its module cut it off (runaway protection) while waiting for {:.1} °C",
                    self.name, r.target
                );
                self.machine.fault_and_stop(reason.clone());
                return Err(MachineError::Faulted(reason));
            }
            if r.target == 0.0 || (r.celsius - r.target).abs() <= WAIT_WINDOW_C {
                return Ok(start.elapsed());
            }
            if start.elapsed() > timeout {
                let reason = format!(
                    "heater {} did not reach {:.1} °C within its wait_timeout_s {:.0} s (it reads {:.1} °C)",
                    self.name, r.target, timeout.as_secs_f64(), r.celsius
                );
                self.machine.fault_and_stop(reason.clone());
                return Err(MachineError::Faulted(reason));
            }
            tokio::time::sleep(WAIT_POLL).await;
        }
    }
}

/// One row of a heater log: synchronized time and each heater's reading.
#[derive(Debug, Clone, PartialEq)]
pub struct HeaterRow {
    /// When the row was read, synchronized µs.
    pub time_us: u64,
    /// Each heater's reading, in [`Machine::heaters`] order.
    pub readings: Vec<HeaterReading>,
}

/// Heaters read at a fixed period in the background (see
/// [`Machine::log_heaters`]); [`HeaterLog::finish`] ends it.
#[derive(Debug)]
pub struct HeaterLog {
    names: Vec<String>,
    task: tokio::task::JoinHandle<Vec<HeaterRow>>,
    stop: tokio::sync::watch::Sender<bool>,
}

impl Machine {
    /// Reads every heater each `period` from now until
    /// [`HeaterLog::finish`]: what `osap run` writes to heaters.csv. A row
    /// with a failed reading is left out.
    pub fn log_heaters(&self, period: Duration) -> HeaterLog {
        let heaters = self.heaters();
        let names = heaters.iter().map(|h| h.name().to_string()).collect();
        let (stop, mut stopped) = tokio::sync::watch::channel(false);
        let machine = self.clone();
        let task = tokio::spawn(async move {
            let mut rows = Vec::new();
            let mut tick = tokio::time::interval(period);
            tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            loop {
                // The last row is read when the log is finished.
                let last = tokio::select! {
                    _ = tick.tick() => false,
                    _ = stopped.changed() => true,
                };
                // A row a read misses (a lost reply) is left out; the
                // log goes on through a fault, to show the heaters off.
                let Ok(time_us) = machine.now_us().await else {
                    continue;
                };
                let mut readings = Vec::with_capacity(heaters.len());
                for h in &heaters {
                    if let Ok(r) = h.read().await {
                        readings.push(r);
                    }
                }
                if readings.len() == heaters.len() {
                    rows.push(HeaterRow { time_us, readings });
                }
                if last {
                    return rows;
                }
            }
        });
        HeaterLog { names, task, stop }
    }
}

impl HeaterLog {
    /// The heaters' names, in column order.
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// Takes a last row, ends the log and returns its rows.
    pub async fn finish(self) -> Vec<HeaterRow> {
        let _ = self.stop.send(true);
        self.task.await.unwrap_or_default()
    }
}

/// Writes `rows` as CSV with the header `t,NAME,NAME_target,NAME_power,..`
/// (t in s after `t0_us`; °C, °C, duty 0–1).
pub fn write_heaters_csv(
    path: &std::path::Path,
    names: &[String],
    rows: &[HeaterRow],
    t0_us: u64,
) -> std::io::Result<()> {
    use std::fmt::Write as _;
    let mut text = String::from("t");
    for n in names {
        let _ = write!(text, ",{n},{n}_target,{n}_power");
    }
    text.push('\n');
    for r in rows {
        let t = (r.time_us as f64 - t0_us as f64) * 1e-6;
        let _ = write!(text, "{t:.4}");
        for h in &r.readings {
            let _ = write!(text, ",{:.2},{:.1},{:.4}", h.celsius, h.target, h.power);
        }
        text.push('\n');
    }
    std::fs::write(path, text)
}
