//! Heater autotune: PID gains from a relay test (`osap heater-tune`),
//! Klipper's `PID_CALIBRATE` (its `ControlAutoTune`) on a heater of the
//! machine file.
//!
//! # The test ([`tune`])
//!
//! The host drives the heater open loop ([`crate::Heater::set_power`]; the
//! module's sensor, `max_temp` and watchdog checks still guard it) as a
//! relay with hysteresis: full `max_power` until it reads at or above the
//! target, then nothing until it reads at or below `target −`
//! [`TUNE_DELTA_C`], and so on. It reads the heater every [`POLL`] and
//! takes each new reading at the module's own time (the synchronized
//! clock). The peaks are recorded as Klipper records them ([`Relay`]):
//! every switch of the relay records the extreme since the last one, and
//! the test ends once the heater is off with [`MIN_PEAKS`] recorded. The
//! heater is turned off at the end, on every error, and on a timeout.
//!
//! # The gains ([`Relay::result`], [`ziegler_nichols`])
//!
//! For every peak from the fifth on, the cycle is the time from the peak
//! two before it. The median cycle is taken; its peak-to-peak swing gives
//! the amplitude `a = |ΔT|/2` and its cycle the period `Tu`. Åström and
//! Hägglund's relay estimate of the ultimate gain is `Ku = 4·max_power /
//! (π·a)`, and Ziegler–Nichols gives `Ti = Tu/2`, `Td = Tu/8`,
//! `kp = 0.6·Ku·255`, `ki = kp/Ti`, `kd = kp·Td`: Klipper's units
//! ([`osap_module::heater::PID_PARAM_BASE`]), as `[heaters.NAME]` takes
//! them.
//!
//! # Writing them ([`write_gains`])
//!
//! `kp`, `ki` and `kd` of `[heaters.NAME]` are replaced in place, each on
//! its own line, keeping the file's comments and order; the file is parsed
//! and validated before it is written.

use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::config::MachineFile;
use crate::{HeaterState, Machine, MachineError, MachineState};

/// The relay's hysteresis: it heats again at `target −` this, °C
/// (Klipper's `TUNE_PID_DELTA`).
pub const TUNE_DELTA_C: f64 = 5.0;
/// How many peaks the test records before it ends (Klipper's 12: the
/// start, the heat-up's low, then five highs and five lows).
pub const MIN_PEAKS: usize = 12;
/// How often the host reads the heater and sets the relay.
pub const POLL: Duration = Duration::from_millis(100);
/// How long a test may take unless told otherwise.
pub const DEFAULT_TIMEOUT: Duration = Duration::from_secs(20 * 60);
/// Klipper's PID scale (a gain of `kp` is `kp/255` of full duty per °C).
const PID_PARAM_BASE: f64 = osap_module::heater::PID_PARAM_BASE as f64;

/// Why a test failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TuneError {
    /// The machine refused or failed (a stop, a fault, a lost link).
    #[error(transparent)]
    Machine(#[from] MachineError),
    /// The test cannot run as asked (the message says why and what to
    /// change).
    #[error("{0}")]
    Refused(String),
    /// The module cut the heater (its runaway protection) during the test.
    #[error("heater {heater}: its module cut it off (runaway protection: sensor or max_temp) at {celsius:.1} °C during the autotune")]
    Faulted {
        /// The heater.
        heater: String,
        /// Its last reading, °C.
        celsius: f64,
    },
    /// The test did not record its peaks in time.
    #[error("heater {heater}: {peaks} of {MIN_PEAKS} peaks after {:.0} s (it reads {celsius:.1} °C); a heater that cannot reach its target, or a slow one, needs a lower target or a longer timeout", .timeout.as_secs_f64())]
    Timeout {
        /// The heater.
        heater: String,
        /// Peaks recorded.
        peaks: usize,
        /// Its last reading, °C.
        celsius: f64,
        /// The timeout.
        timeout: Duration,
    },
    /// The machine file could not be read or written.
    #[error("{}: {source}", .path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
}

/// PID gains in Klipper's units (`[heaters.NAME]` `kp`, `ki`, `kd`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gains {
    /// Proportional gain.
    pub kp: f64,
    /// Integral gain, per s.
    pub ki: f64,
    /// Derivative gain, s.
    pub kd: f64,
}

/// Ziegler–Nichols gains from a relay oscillation of `amplitude_c` (half
/// its peak-to-peak swing, °C) and period `period_s` driven at
/// `max_power` (Klipper's `calc_pid`).
pub fn ziegler_nichols(max_power: f64, amplitude_c: f64, period_s: f64) -> Gains {
    let ku = 4.0 * max_power / (std::f64::consts::PI * amplitude_c);
    let ti = 0.5 * period_s;
    let td = 0.125 * period_s;
    let kp = 0.6 * ku * PID_PARAM_BASE;
    Gains {
        kp,
        ki: kp / ti,
        kd: kp * td,
    }
}

/// A recorded peak: the extreme between two switches of the relay.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Peak {
    /// The temperature, °C.
    pub celsius: f64,
    /// When, s (on the clock of the readings).
    pub time_s: f64,
}

/// A finished test's outcome.
#[derive(Debug, Clone, PartialEq)]
pub struct TuneResult {
    /// The gains.
    pub gains: Gains,
    /// The oscillation's amplitude the gains came from (half its
    /// peak-to-peak swing), °C.
    pub amplitude_c: f64,
    /// Its period, s.
    pub period_s: f64,
    /// Every peak recorded, in order (the first two are the start and the
    /// heat-up's low; then highs and lows alternate).
    pub peaks: Vec<Peak>,
    /// The relay's target, °C.
    pub target_c: f64,
    /// The duty it heated at.
    pub max_power: f64,
}

/// The relay and its peak recorder, sans I/O: give it each reading
/// ([`Relay::update`]), drive the heater at the duty it answers.
#[derive(Debug, Clone)]
pub struct Relay {
    target_c: f64,
    max_power: f64,
    heating: bool,
    started: bool,
    peak: Peak,
    peaks: Vec<Peak>,
    min_peaks: usize,
}

impl Relay {
    /// A relay about `target_c` at `max_power`, ending after `min_peaks`
    /// peaks (Klipper: [`MIN_PEAKS`]; at least 5, the first cycle used).
    pub fn new(target_c: f64, max_power: f64, min_peaks: usize) -> Relay {
        Relay {
            target_c,
            max_power,
            heating: false,
            started: false,
            peak: Peak {
                celsius: 0.0,
                time_s: 0.0,
            },
            peaks: Vec::new(),
            min_peaks: min_peaks.max(5),
        }
    }

    /// Takes a reading of `celsius` at `time_s` and answers the duty to
    /// drive.
    pub fn update(&mut self, time_s: f64, celsius: f64) -> f64 {
        // The first peak is the start (Klipper's placeholder, never used
        // in the gains).
        if !self.started {
            self.started = true;
            self.peak = Peak { celsius, time_s };
        }
        let switch_at = if self.heating {
            self.target_c
        } else {
            self.target_c - TUNE_DELTA_C
        };
        if self.heating && celsius >= switch_at {
            self.heating = false;
            self.record();
        } else if !self.heating && celsius <= switch_at {
            self.heating = true;
            self.record();
        }
        let (further, duty) = if self.heating {
            (celsius < self.peak.celsius, self.max_power)
        } else {
            (celsius > self.peak.celsius, 0.0)
        };
        if further {
            self.peak = Peak { celsius, time_s };
        }
        duty
    }

    /// Records the extreme since the last switch and starts looking for
    /// the next one (a low while heating, a high while not).
    fn record(&mut self) {
        self.peaks.push(self.peak);
        let start = if self.heating {
            f64::INFINITY
        } else {
            f64::NEG_INFINITY
        };
        self.peak = Peak {
            celsius: start,
            time_s: 0.0,
        };
    }

    /// Whether the test is done: the heater off, the peaks recorded.
    pub fn done(&self) -> bool {
        !self.heating && self.peaks.len() >= self.min_peaks
    }

    /// The peaks so far.
    pub fn peaks(&self) -> &[Peak] {
        &self.peaks
    }

    /// The gains from the median cycle, once there are five peaks
    /// (Klipper's `calc_final_pid`).
    pub fn result(&self) -> Option<TuneResult> {
        let p = &self.peaks;
        let mut cycles: Vec<(f64, usize)> = (4..p.len())
            .map(|i| (p[i].time_s - p[i - 2].time_s, i))
            .collect();
        if cycles.is_empty() {
            return None;
        }
        cycles.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let (period_s, i) = cycles[cycles.len() / 2];
        let amplitude_c = 0.5 * (p[i].celsius - p[i - 1].celsius).abs();
        Some(TuneResult {
            gains: ziegler_nichols(self.max_power, amplitude_c, period_s),
            amplitude_c,
            period_s,
            peaks: p.clone(),
            target_c: self.target_c,
            max_power: self.max_power,
        })
    }
}

/// What to tune and how long it may take.
#[derive(Debug, Clone, PartialEq)]
pub struct TuneOptions {
    /// The target the relay switches about, °C.
    pub target_c: f64,
    /// Peaks to record ([`MIN_PEAKS`], Klipper's).
    pub min_peaks: usize,
    /// How long the test may take, heat-up included.
    pub timeout: Duration,
}

impl TuneOptions {
    /// Klipper's test about `target_c`, within [`DEFAULT_TIMEOUT`].
    pub fn new(target_c: f64) -> TuneOptions {
        TuneOptions {
            target_c,
            min_peaks: MIN_PEAKS,
            timeout: DEFAULT_TIMEOUT,
        }
    }
}

/// The target `osap heater-tune` takes for a heater without `--target`:
/// 60 °C for `bed`, 210 °C for `hotend` and any other.
pub fn default_target(heater: &str) -> f64 {
    if heater == "bed" {
        60.0
    } else {
        210.0
    }
}

/// Refuses a test the heater cannot run: an unknown heater (naming the
/// known ones) or a target outside what its limits allow.
pub fn check(cfg: &MachineFile, heater: &str, target_c: f64) -> Result<(), TuneError> {
    let Some(h) = cfg.heaters.get(heater) else {
        let known: Vec<&str> = cfg.heaters.keys().map(String::as_str).collect();
        return Err(TuneError::Refused(if known.is_empty() {
            format!("no heater {heater:?}: the machine file has no [heaters]")
        } else {
            format!(
                "no heater {heater:?} in [heaters]; this machine has {}",
                known.join(", ")
            )
        }));
    };
    let low = h.min_temp + TUNE_DELTA_C;
    if !(target_c.is_finite() && target_c > low && target_c < h.max_temp) {
        return Err(TuneError::Refused(format!(
            "heater {heater}: target {target_c} °C must be above {low} °C (its min_temp + {TUNE_DELTA_C}) and below its max_temp {} °C",
            h.max_temp
        )));
    }
    Ok(())
}

/// Runs the relay test on heater `heater` of a started machine and
/// returns the gains (see the module docs). The heater is off when it
/// returns, whatever happened; a caller that drops the future (Ctrl-C)
/// turns it off itself (`set_target(0)`) or stops the machine.
pub async fn tune(
    machine: &Machine,
    heater: &str,
    opts: &TuneOptions,
) -> Result<TuneResult, TuneError> {
    check(machine.config(), heater, opts.target_c)?;
    let h = machine.heater(heater)?;
    let result = run_relay(machine, heater, opts).await;
    let off = h.set_target(0.0).await;
    let r = result?;
    off?;
    Ok(r)
}

async fn run_relay(
    machine: &Machine,
    heater: &str,
    opts: &TuneOptions,
) -> Result<TuneResult, TuneError> {
    let h = machine.heater(heater)?;
    let max_power = machine.config().heaters[heater].max_power;
    let mut relay = Relay::new(opts.target_c, max_power, opts.min_peaks);
    let start = tokio::time::Instant::now();
    let mut tick = tokio::time::interval(POLL);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut last: Option<(u64, f64)> = None;
    loop {
        tick.tick().await;
        // A machine stopped by anything else (a halt, another module's
        // fault) ends the test, also while the relay is off.
        match machine.state() {
            MachineState::Faulted(reason) => return Err(MachineError::Faulted(reason).into()),
            MachineState::Stopped => return Err(MachineError::Stopped.into()),
            _ => {}
        }
        let r = h.read().await?;
        if r.state == HeaterState::Faulted {
            return Err(TuneError::Faulted {
                heater: heater.into(),
                celsius: r.celsius,
            });
        }
        if start.elapsed() > opts.timeout {
            return Err(TuneError::Timeout {
                heater: heater.into(),
                peaks: relay.peaks().len(),
                celsius: r.celsius,
                timeout: opts.timeout,
            });
        }
        // A reading the module has not renewed since the last poll
        // changes nothing.
        if r.time_us == 0 || last.is_some_and(|(t, _)| t == r.time_us) {
            continue;
        }
        let duty = relay.update(r.time_us as f64 * 1e-6, r.celsius);
        if relay.done() {
            return relay
                .result()
                .ok_or_else(|| TuneError::Refused("the test ended without a full cycle".into()));
        }
        if last.is_none_or(|(_, d)| d != duty) {
            h.set_power(duty).await?;
        }
        last = Some((r.time_us, duty));
    }
}

/// The lines to paste under `[heaters.NAME]`.
pub fn gains_lines(g: &Gains) -> [String; 3] {
    [
        format!("kp = {:.3}", g.kp),
        format!("ki = {:.3}", g.ki),
        format!("kd = {:.3}", g.kd),
    ]
}

fn io_err(path: &Path) -> impl Fn(std::io::Error) -> TuneError + '_ {
    |source| TuneError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Sets `kp`, `ki` and `kd` of `[heaters.HEATER]` in the machine file at
/// `path` in place (each line's comment and the rest of the file kept);
/// the file is parsed and validated before it is written.
pub fn write_gains(path: &Path, heater: &str, gains: &Gains) -> Result<(), TuneError> {
    let text = std::fs::read_to_string(path).map_err(io_err(path))?;
    let paste = || gains_lines(gains).join("\n");
    let out = with_gains(&text, heater, gains).ok_or_else(|| {
        TuneError::Refused(format!(
            "{}: no [heaters.{heater}] table with kp, ki and kd lines of its own; put these under it yourself:\n{}",
            path.display(),
            paste()
        ))
    })?;
    let cfg = MachineFile::parse(&out)
        .and_then(|c| c.validate().map(|_| c))
        .map_err(|e| TuneError::Refused(format!("the file with the gains would not load: {e}")))?;
    let landed = cfg.heaters.get(heater).is_some_and(|h| {
        let near = |a: f64, b: f64| (a - b).abs() <= 0.0005 + 1e-9 * b.abs();
        near(h.kp, gains.kp) && near(h.ki, gains.ki) && near(h.kd, gains.kd)
    });
    if !landed {
        return Err(TuneError::Refused(format!(
            "{}: the gains did not land in heater {heater}; put these under [heaters.{heater}] yourself:\n{}",
            path.display(),
            paste()
        )));
    }
    std::fs::write(path, out).map_err(io_err(path))
}

/// `text` with the values of `kp`, `ki` and `kd` in `[heaters.HEATER]`
/// replaced (indentation and trailing comments kept); `None` without the
/// table or one of the three lines in it.
fn with_gains(text: &str, heater: &str, g: &Gains) -> Option<String> {
    let header = format!("[heaters.{heater}]");
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    let h = lines
        .iter()
        .position(|l| l.trim_start().starts_with(&header))?;
    let end = (h + 1..lines.len())
        .find(|&i| lines[i].trim_start().starts_with('['))
        .unwrap_or(lines.len());
    for (key, value) in [("kp", g.kp), ("ki", g.ki), ("kd", g.kd)] {
        let i = (h + 1..end).find(|&i| {
            let t = lines[i].trim_start();
            t.strip_prefix(key)
                .is_some_and(|r| r.trim_start().starts_with('='))
        })?;
        let line = &lines[i];
        let indent = &line[..line.len() - line.trim_start().len()];
        let eq = line.find('=')?;
        let mut new = format!("{indent}{key} = {value:.3}");
        // A trailing comment stays, at its column if the value fits.
        if let Some(c) = line[eq..].find('#').map(|c| eq + c) {
            let pad = c.saturating_sub(new.len()).max(1);
            new.push_str(&" ".repeat(pad));
            new.push_str(&line[c..]);
        }
        lines[i] = new;
    }
    let mut s = lines.join("\n");
    if text.ends_with('\n') {
        s.push('\n');
    }
    Some(s)
}

#[cfg(test)]
mod tests;
