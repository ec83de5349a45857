//! Resonance measurement: shake one axis with a chirp, record an
//! accelerometer on the synchronized clock, and find the axis's mode and
//! the input shaper for it (`osap resonance`).
//!
//! # The accelerometer
//!
//! `[axes.NAME] accelerometer = { module = "a", channel = 0, range = 200000.0 }`:
//! an analog input of a module, read by the module's own `analog_read`,
//! that measures the toolhead's acceleration along the axis. `range` is the
//! acceleration at full scale in machine units/s²: a reading of 0.5 is at
//! rest, 0 is `−range` and 1 is `+range` (an analog accelerometer biased at
//! mid-supply). On the simulator the module's board carries
//! [`osap_sim::machine::board::accel`]: the module's own carriage drives a
//! mass-spring mode set by `[sim.axes.NAME] resonance_hz` and
//! `damping_ratio` (without them the sensor is mounted stiffly: a 1 kHz
//! mode, damping 0.7, which no chirp here reaches). So in simulation the
//! accelerometer's module must drive a motor that moves the axis (under
//! corexy, either belt motor).
//!
//! # The measurement ([`measure`])
//!
//! 1. The axis stands at the middle of its travel (the caller homes and
//!    moves it there; [`measure`] checks it is homed and goes to the
//!    middle itself).
//! 2. The module's `analog_read` is piped to a host function and run on
//!    the module's timer every [`SAMPLE_PERIOD_US`] (1 kHz); each sample
//!    carries the module's synchronized time.
//! 3. An exponential chirp (maxl's [`Chirp`]: its closed-form phase,
//!    frequency and fade) is added to the planned position at every
//!    control-point stamp ([`crate::Machine::set_excitation`]). Its
//!    amplitude follows the frequency so that it keeps within the axis's
//!    acceleration and velocity limits (and the module's step rate) and
//!    within a tenth of the travel: `A(f) = min(a/(2πf)², v/(2πf), travel/10)`.
//! 4. After the chirp and a ring-down tail, the commanded acceleration is
//!    computed from the control points exactly as the modules evaluate
//!    them (maxl's uniform cubic B-spline), averaged over each sample's
//!    window as the accelerometer averages; [`analysis`] does the rest.
//!
//! # The range
//!
//! From the machine: the chirp ends at the lowest of 200 Hz, a fifth of
//! the sampling rate, 0.4 of the control-point rate, and the frequency at
//! which the acceleration limit leaves an amplitude of [`MIN_STEPS`]
//! microsteps (below that, the steps' quantization swamps the motion). It
//! starts at 5 Hz. A mode outside the range is reported as such.
//!
//! # The shaper key
//!
//! `[axes.NAME] shaper = { kind = "mzv", freq_hz = 45.2, damping = 0.08 }`
//! is validated with the machine file (the kind one of `zv`, `mzv`, `ei`,
//! `2hump_ei`, `zvd`, `3hump_ei`; frequency and damping within maxl's
//! bounds) and written by `osap resonance --write`. The machine's motion
//! source shapes every move with it ([`crate::machine::motion`]); the
//! measurement's own chirp is added after shaping, so it is never shaped.

pub mod analysis;

use std::f64::consts::PI;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use maxl::blocks::chirp::{Chirp, ChirpConfig};
use maxl::blocks::shaper::ShaperConfig;
use osap_host::som::{Disconnect, FnRef, HostFnError, HostFunction, PipeOptions, Value};
use pipes_core::control::{InputMode, OutputMode};
use plotters::prelude::*;

use crate::config::MachineFile;
use crate::machine::drive::MAX_AXES;
use crate::machine::INTERVAL_US;
use crate::network::modfn::{analog_read, same_names, ModuleCall};
use crate::{Machine, MachineError};
use analysis::{Analysis, AnalysisError, Peak};

/// The accelerometer's sampling period, µs (1 kHz, as the modules'
/// position reports).
pub const SAMPLE_PERIOD_US: u32 = 1_000;
/// The smallest chirp amplitude, in the axis's microsteps.
pub const MIN_STEPS: f64 = 1.5;
/// The lowest chirp frequency, Hz.
pub const MIN_FREQ_HZ: f64 = 5.0;
/// The highest chirp frequency, Hz.
pub const MAX_FREQ_HZ: f64 = 200.0;
/// The recording after the sweep, s: a mode at 20 Hz with damping 0.02
/// rings down to 0.05 % of its amplitude.
pub const TAIL_S: f64 = 3.0;
/// The share of the acceleration and velocity limits the chirp uses.
const LIMIT_SHARE: f64 = 0.9;
/// The share of the module's step rate the chirp's velocity keeps under.
const STEP_RATE_SHARE: f64 = 0.5;

pub use crate::config::{Accelerometer, AxisShaper};

/// Why a measurement failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ResonanceError {
    /// The machine refused or failed.
    #[error(transparent)]
    Machine(#[from] MachineError),
    /// The axis cannot be measured as asked (the message says why and
    /// what to change).
    #[error("{0}")]
    Refused(String),
    /// The recording could not be analysed.
    #[error("analysis: {0}")]
    Analysis(#[from] AnalysisError),
    /// A file could not be written.
    #[error("{}: {source}", .path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
}

/// The chirp chosen for an axis (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    /// The axis.
    pub axis: String,
    /// Its index in the machine's axes.
    pub index: usize,
    /// The middle of its travel: where the chirp is centred.
    pub center: f64,
    /// Start and end frequency, Hz.
    pub f0: f64,
    /// End frequency, Hz.
    pub f1: f64,
    /// The sweep's duration, s.
    pub duration_s: f64,
    /// Fade in and out, s.
    pub fade_s: f64,
    /// Recording after the sweep (ring-down), s.
    pub tail_s: f64,
    /// The acceleration amplitude the chirp keeps within, units/s².
    pub acceleration: f64,
    /// The velocity amplitude it keeps within, units/s.
    pub velocity: f64,
    /// The largest displacement, units.
    pub max_amplitude: f64,
    /// The axis's microstep, units.
    pub step: f64,
    /// The accelerometer.
    pub accelerometer: Accelerometer,
}

impl Plan {
    /// The chirp for `axis` of `cfg`, sweeping for `duration_s` seconds.
    pub fn for_axis(
        cfg: &MachineFile,
        axis: &str,
        duration_s: f64,
    ) -> Result<Plan, ResonanceError> {
        let refused = |m: String| ResonanceError::Refused(m);
        let index = cfg.axes.keys().position(|a| a == axis).ok_or_else(|| {
            refused(format!(
                "no axis {axis:?} in [axes]; measure one of {}",
                cfg.axes.keys().cloned().collect::<Vec<_>>().join(", ")
            ))
        })?;
        let ax = &cfg.axes[axis];
        let accelerometer = ax.accelerometer.clone().ok_or_else(|| {
            refused(format!(
                "axis {axis} has no accelerometer; add [axes.{axis}] accelerometer = {{ module = \"...\", channel = 0, range = 160000.0 }}"
            ))
        })?;
        if !(duration_s.is_finite() && (1.0..=600.0).contains(&duration_s)) {
            return Err(refused(format!(
                "a sweep of {duration_s} s: give 1 to 600 seconds"
            )));
        }
        // The axis's microstep: the coarsest of the motors that may move it.
        let motors: Vec<&crate::config::Motor> = match &ax.motor {
            Some(m) => cfg.motors.get(m).into_iter().collect(),
            None => cfg.motors.values().collect(),
        };
        let step = motors
            .iter()
            .map(|m| 1.0 / (m.full_steps_per_unit * f64::from(m.microsteps)))
            .fold(0.0, f64::max);
        let steps_per_unit = motors
            .iter()
            .map(|m| m.full_steps_per_unit * f64::from(m.microsteps))
            .fold(0.0, f64::max);
        let step_rate = 1e6 / f64::from(osap_module::stepper::STEP_TICK_US);
        let velocity = LIMIT_SHARE
            * ax.velocity
                .min(cfg.limits.velocity)
                .min(STEP_RATE_SHARE * step_rate / steps_per_unit.max(1e-9));
        let acceleration = LIMIT_SHARE * ax.acceleration.min(cfg.limits.acceleration);
        let fs = 1e6 / f64::from(SAMPLE_PERIOD_US);
        let f_steps = (acceleration / (MIN_STEPS * step)).sqrt() / (2.0 * PI);
        let f1 = MAX_FREQ_HZ
            .min(fs / 5.0)
            .min(0.4e6 / f64::from(INTERVAL_US))
            .min(f_steps);
        let f0 = MIN_FREQ_HZ;
        if f1 < 2.0 * f0 {
            return Err(refused(format!(
                "axis {axis} cannot be shaken above {f1:.1} Hz: its acceleration ({acceleration:.0} units/s²) moves it less than {MIN_STEPS} microsteps ({step:.4} units each) there; raise microsteps or the acceleration limit"
            )));
        }
        let center = 0.5 * (ax.min + ax.max);
        Ok(Plan {
            axis: axis.to_string(),
            index,
            center,
            f0,
            f1,
            duration_s,
            fade_s: (0.05 * duration_s).min(0.5),
            tail_s: TAIL_S,
            acceleration,
            velocity,
            max_amplitude: 0.1 * (ax.max - ax.min),
            step,
            accelerometer,
        })
    }

    /// The frequencies swept at full amplitude (between the fades), Hz:
    /// the range the response is analysed over. At the fades the
    /// commanded motion is small and its spectrum near the ends carries
    /// more quantization noise than motion.
    pub fn range(&self) -> (f64, f64) {
        let t = self.duration_s;
        let k = self.f1 / self.f0;
        let at = |tau: f64| self.f0 * k.powf(tau / t);
        (at(self.fade_s), at(t - self.fade_s))
    }

    /// The displacement amplitude at `f` Hz.
    pub fn amplitude(&self, f: f64) -> f64 {
        let w = 2.0 * PI * f.max(1e-3);
        (self.acceleration / (w * w))
            .min(self.velocity / w)
            .min(self.max_amplitude)
    }

    /// maxl's chirp with this plan's sweep, unit amplitude, centred on 0.
    pub fn chirp(&self) -> Result<Chirp, ResonanceError> {
        Chirp::new(ChirpConfig {
            f0: self.f0,
            f1: self.f1,
            duration_s: self.duration_s,
            amplitude: 1.0,
            center: 0.0,
            exponential: true,
            fade_s: self.fade_s,
        })
        .map_err(|e| ResonanceError::Refused(e.to_string()))
    }

    /// The displacement `t` µs after a start at `start` µs.
    pub fn offset(&self, chirp: &Chirp, start: u64, t: u64) -> f64 {
        if t < start {
            return 0.0;
        }
        let tau = (t - start) as f64 * 1e-6;
        if tau >= self.duration_s {
            return 0.0;
        }
        self.amplitude(chirp.frequency(tau)) * chirp.position_from(start, t)
    }
}

/// A measurement: the plan, the samples and what they say.
#[derive(Debug, Clone)]
pub struct Measurement {
    /// The chirp.
    pub plan: Plan,
    /// Per accelerometer sample: synchronized time (s since the chirp
    /// started), measured and commanded mean acceleration over the
    /// sample's window (units/s²).
    pub samples: Vec<(f64, f64, f64)>,
    /// The analysis.
    pub analysis: Analysis,
}

static NEXT: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);

/// Measures `axis` (see the module docs). The machine must be homed on
/// that axis and at rest; it moves the axis to the middle of its travel,
/// shakes it, and leaves it there.
pub async fn measure(
    machine: &Machine,
    axis: &str,
    duration_s: f64,
) -> Result<Measurement, ResonanceError> {
    let plan = Plan::for_axis(machine.config(), axis, duration_s)?;
    if !machine.homed().get(plan.index).copied().unwrap_or(false) {
        return Err(MachineError::NotHomed(axis.to_string()).into());
    }
    let mut target = machine.position();
    target[plan.index] = plan.center;
    let rate = 0.5 * machine.config().axes[axis].velocity;
    machine.goto_now(&target, rate).await?;

    // The accelerometer's samples, pushed by the module.
    let acc = &plan.accelerometer;
    let runtime = machine
        .modules()
        .get(&acc.module)
        .map(|m| m.runtime.clone())
        .ok_or_else(|| {
            ResonanceError::Refused(format!(
                "the accelerometer's module {} is not one of the machine's modules",
                acc.module
            ))
        })?;
    let samples: Arc<Mutex<Vec<(u64, f32)>>> = Arc::default();
    let sink = samples.clone();
    let id = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    // Its inputs are `analog_read`'s outputs, piped in by name.
    let f = HostFunction::typed(
        &format!("resonance.accel{id}"),
        move |r: analog_read::Outputs| {
            sink.lock()
                .unwrap_or_else(|e| e.into_inner())
                .push((r.time, r.value));
            Ok::<(), HostFnError>(())
        },
    )
    .map_err(MachineError::from)?;
    let from = analog_read::on(&runtime);
    let to = {
        let mut m = machine.manager().lock().await;
        let to = m.define(f).await.map_err(MachineError::from)?;
        let pairs = same_names::<analog_read::Outputs>();
        m.connect_named(&from, &to, &pairs, PipeOptions::default())
            .await
            .map_err(MachineError::from)?;
        m.set_output_mode(&from, OutputMode::Always)
            .await
            .map_err(MachineError::from)?;
        // Stored in its inputs: its timer samples the channel.
        let channel = analog_read::Inputs {
            channel: acc.channel,
        };
        let stored: Vec<(u8, Value<'static>)> = (0u8..).zip(channel.values()).collect();
        m.function(&from)
            .map_err(MachineError::from)?
            .push(&stored)
            .await
            .map_err(|e| {
                ResonanceError::Refused(format!(
                    "module {} refused analog input {}: {e}",
                    acc.module, acc.channel
                ))
            })?;
        m.set_input_mode(&from, InputMode::OnTimer(SAMPLE_PERIOD_US))
            .await
            .map_err(MachineError::from)?;
        to
    };

    // The chirp, from a stamp far enough ahead that its first point is
    // not yet sent.
    let interval = u64::from(INTERVAL_US);
    let now = match machine.now_us().await {
        Ok(t) => t,
        Err(e) => {
            stop_sampling(machine, &from, to).await;
            return Err(e.into());
        }
    };
    let start = (now + 4 * u64::from(crate::machine::LEAD_US)).div_ceil(interval) * interval;
    let sent: Arc<Mutex<Vec<(u64, f64)>>> = Arc::default();
    let record = sent.clone();
    let chirp = plan.chirp()?;
    let (p, index) = (plan.clone(), plan.index);
    machine.set_excitation(Some(Box::new(move |stamp| {
        let d = p.offset(&chirp, start, stamp);
        record
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push((stamp, d));
        let mut out = [0.0; MAX_AXES];
        out[index] = d;
        out
    })));
    let end = start + ((plan.duration_s + plan.tail_s) * 1e6) as u64;
    let result = wait_until(machine, end).await;
    machine.set_excitation(None);
    stop_sampling(machine, &from, to).await;
    result?;

    let samples = std::mem::take(&mut *samples.lock().unwrap_or_else(|e| e.into_inner()));
    let sent = std::mem::take(&mut *sent.lock().unwrap_or_else(|e| e.into_inner()));
    let rows = pair_samples(&plan, &samples, &sent, start, end)?;
    let n = rows.len();
    let dt = if n > 1 {
        (rows[n - 1].0 - rows[0].0) / (n - 1) as f64
    } else {
        SAMPLE_PERIOD_US as f64 * 1e-6
    };
    let measured: Vec<f64> = rows.iter().map(|r| r.1).collect();
    let commanded: Vec<f64> = rows.iter().map(|r| r.2).collect();
    let analysis = analysis::analyze(dt, &measured, &commanded, plan.range())?;
    Ok(Measurement {
        plan,
        samples: rows,
        analysis,
    })
}

/// Stops the accelerometer's timer and removes its pipe (best effort: a
/// module that no longer answers keeps neither once it reboots).
async fn stop_sampling(machine: &Machine, from: &FnRef, to: FnRef) {
    let mut m = machine.manager().lock().await;
    let _ = m.set_input_mode(from, InputMode::OnAnyFresh).await;
    let _ = m.disconnect(from, Disconnect::To(to)).await;
}

/// Waits until the machine's synchronized clock passes `end` µs, failing
/// if the machine faults meanwhile.
async fn wait_until(machine: &Machine, end: u64) -> Result<(), ResonanceError> {
    loop {
        if let crate::MachineState::Faulted(reason) = machine.state() {
            return Err(MachineError::Faulted(reason).into());
        }
        let now = machine.now_us().await?;
        if now >= end {
            return Ok(());
        }
        // A wait for the chirp to play out, in at most 0.5 s steps so a
        // fault is seen soon.
        let left = (end - now).min(500_000);
        tokio::time::sleep(std::time::Duration::from_micros(left)).await;
    }
}

/// The control points' B-spline velocity at `t` µs (maxl's uniform cubic
/// B-spline, as the modules evaluate it), units/s; `None` outside them.
fn spline_velocity(sent: &[(u64, f64)], t: u64) -> Option<f64> {
    let (t0, iv) = (sent.first()?.0, u64::from(INTERVAL_US));
    let i = usize::try_from(t.checked_sub(t0)? / iv).ok()?;
    let p = |k: usize| sent.get(k).map(|s| s.1);
    let (p0, p1, p2, p3) = (p(i.checked_sub(1)?)?, p(i)?, p(i + 1)?, p(i + 2)?);
    let u = (t - sent[i].0) as f64 / iv as f64;
    let c1 = 3.0 * (p2 - p0);
    let c2 = 3.0 * (p0 - 2.0 * p1 + p2);
    let c3 = -p0 + 3.0 * p1 - 3.0 * p2 + p3;
    Some((c1 + u * (2.0 * c2 + u * 3.0 * c3)) / 6.0 * 1e6 / iv as f64)
}

/// Pairs each accelerometer sample in `[start − 0.2 s, end]` with the
/// commanded mean acceleration over its window: `(s since start,
/// measured, commanded)`.
fn pair_samples(
    plan: &Plan,
    samples: &[(u64, f32)],
    sent: &[(u64, f64)],
    start: u64,
    end: u64,
) -> Result<Vec<(f64, f64, f64)>, ResonanceError> {
    // The stamps must be consecutive for the spline.
    let iv = u64::from(INTERVAL_US);
    if sent.windows(2).any(|w| w[1].0 != w[0].0 + iv) {
        return Err(ResonanceError::Refused(
            "the control points sent during the chirp are not consecutive (the motion source skipped stamps); measure again on a less loaded host".into(),
        ));
    }
    let from = start.saturating_sub(200_000);
    let range = plan.accelerometer.range;
    let mut rows = Vec::new();
    for w in samples.windows(2) {
        let ((ta, _), (tb, v)) = (w[0], w[1]);
        if tb < from || tb > end || tb <= ta {
            continue;
        }
        let (Some(va), Some(vb)) = (spline_velocity(sent, ta), spline_velocity(sent, tb)) else {
            continue;
        };
        let secs = (tb - ta) as f64 * 1e-6;
        let measured = (f64::from(v) - 0.5) * 2.0 * range;
        rows.push((
            (tb as f64 - start as f64) * 1e-6,
            measured,
            (vb - va) / secs,
        ));
    }
    let want = ((end - from) / u64::from(SAMPLE_PERIOD_US)) as usize;
    if rows.len() < want * 9 / 10 {
        return Err(ResonanceError::Refused(format!(
            "only {} of {want} accelerometer samples arrived: the link dropped them; measure again",
            rows.len()
        )));
    }
    let clipped = samples.iter().filter(|s| s.1 <= 0.0 || s.1 >= 1.0).count();
    if clipped > 0 {
        return Err(ResonanceError::Refused(format!(
            "{clipped} accelerometer samples were at full scale (±{range} units/s²): the reading clipped; raise accelerometer.range or lower the axis's acceleration"
        )));
    }
    Ok(rows)
}

/// One line per fact: the range, the peak, the mode and the shaper.
pub fn summary(m: &Measurement) -> Vec<String> {
    let a = &m.analysis;
    let mut out = vec![format!(
        "axis {}: chirp {:.1} to {:.1} Hz over {:.1} s about {:.3}, at most {:.0} units/s²; analysed {:.1} to {:.1} Hz",
        m.plan.axis,
        m.plan.f0,
        m.plan.f1,
        m.plan.duration_s,
        m.plan.center,
        m.plan.acceleration,
        a.range.0,
        a.range.1
    )];
    match a.peak {
        Peak::Found { freq_hz, magnitude } => {
            out.push(format!("peak: {freq_hz:.2} Hz (|H| = {magnitude:.2})"))
        }
        Peak::BelowRange { f0 } => out.push(format!(
            "peak: none within the range; the response is largest at its low end, so the mode is at or below {f0:.1} Hz (not measured)"
        )),
        Peak::AboveRange { f1 } => out.push(format!(
            "peak: none within the range; the response is largest at its high end, so the mode is at or above {f1:.1} Hz (not measured)"
        )),
    }
    match a.mode {
        Some(mode) => out.push(format!(
            "mode: natural frequency {:.2} Hz, damping ratio {:.3} (fitted; gain {:.2})",
            mode.freq_hz, mode.damping, mode.gain
        )),
        None if matches!(a.peak, Peak::Found { .. }) => out.push(
            "mode: the response around the peak is not a damped mode; no shaper recommended".into(),
        ),
        None => {}
    }
    for s in &a.shapers {
        out.push(format!(
            "  {:<8} residual {:5.1} % at the mode, {:5.1} % worst within ±15 %, {:5.1} ms",
            s.shaper.kind().name(),
            100.0 * s.residual,
            100.0 * s.worst,
            1e3 * s.duration_s
        ));
    }
    if let Some(s) = a.recommended {
        out.push(format!(
            "recommended shaper: {} at {:.2} Hz, damping {:.3}",
            s.kind().name(),
            s.freq_hz(),
            s.damping()
        ));
    }
    out
}

fn io_err(path: &Path) -> impl Fn(std::io::Error) -> ResonanceError + '_ {
    move |source| ResonanceError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Writes `response.csv` (frequency, |H|, dB, phase), `samples.csv` (time,
/// measured and commanded acceleration) and `bode.svg` into `dir`.
pub fn write(m: &Measurement, dir: &Path) -> Result<Vec<PathBuf>, ResonanceError> {
    std::fs::create_dir_all(dir).map_err(io_err(dir))?;
    let response = dir.join("response.csv");
    {
        let e = io_err(&response);
        let mut w = std::io::BufWriter::new(std::fs::File::create(&response).map_err(&e)?);
        writeln!(w, "freq_hz,magnitude,magnitude_db,phase_deg").map_err(&e)?;
        for p in &m.analysis.response {
            writeln!(
                w,
                "{:.4},{:.6},{:.3},{:.2}",
                p.freq_hz,
                p.magnitude(),
                p.magnitude_db(),
                p.phase_deg()
            )
            .map_err(&e)?;
        }
        w.flush().map_err(&e)?;
    }
    let samples = dir.join("samples.csv");
    {
        let e = io_err(&samples);
        let mut w = std::io::BufWriter::new(std::fs::File::create(&samples).map_err(&e)?);
        writeln!(w, "t,measured,commanded").map_err(&e)?;
        for (t, a, c) in &m.samples {
            writeln!(w, "{t:.6},{a:.3},{c:.3}").map_err(&e)?;
        }
        w.flush().map_err(&e)?;
    }
    let bode = dir.join("bode.svg");
    plot_bode(m, &bode)?;
    Ok(vec![response, samples, bode])
}

fn plot_bode(m: &Measurement, path: &Path) -> Result<(), ResonanceError> {
    let err = |e: DrawingAreaErrorKind<std::io::Error>| ResonanceError::Io {
        path: path.to_path_buf(),
        source: std::io::Error::other(e.to_string()),
    };
    let r = &m.analysis.response;
    // At most ~2000 points per curve.
    let every = (r.len() / 2000).max(1);
    let pts: Vec<_> = r.iter().step_by(every).collect();
    let (f0, f1) = m.analysis.range;
    let db: Vec<(f64, f64)> = pts.iter().map(|p| (p.freq_hz, p.magnitude_db())).collect();
    let ph: Vec<(f64, f64)> = pts.iter().map(|p| (p.freq_hz, p.phase_deg())).collect();
    let lo = db.iter().map(|p| p.1).fold(f64::INFINITY, f64::min);
    let hi = db.iter().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max);
    let (lo, hi) = if lo < hi {
        (lo - 3.0, hi + 3.0)
    } else {
        (-20.0, 20.0)
    };
    let area = SVGBackend::new(path, (1000, 700)).into_drawing_area();
    area.fill(&WHITE).map_err(err)?;
    let (top, bottom) = area.split_vertically(420);
    let title = match m.analysis.peak {
        Peak::Found { freq_hz, .. } => format!("axis {}: peak {freq_hz:.2} Hz", m.plan.axis),
        _ => format!("axis {}: no peak within {f0:.0}-{f1:.0} Hz", m.plan.axis),
    };
    let mut c = ChartBuilder::on(&top)
        .caption(title, ("sans-serif", 20))
        .margin(10)
        .x_label_area_size(30)
        .y_label_area_size(60)
        .build_cartesian_2d((f0..f1).log_scale(), lo..hi)
        .map_err(err)?;
    c.configure_mesh()
        .y_desc("|accel / commanded| (dB)")
        .draw()
        .map_err(err)?;
    c.draw_series(LineSeries::new(db, BLUE.stroke_width(1)))
        .map_err(err)?;
    if let Peak::Found { freq_hz, .. } = m.analysis.peak {
        c.draw_series(LineSeries::new(
            [(freq_hz, lo), (freq_hz, hi)],
            RED.stroke_width(1),
        ))
        .map_err(err)?;
    }
    let mut c = ChartBuilder::on(&bottom)
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d((f0..f1).log_scale(), -180.0..180.0)
        .map_err(err)?;
    c.configure_mesh()
        .x_desc("frequency (Hz)")
        .y_desc("phase (°)")
        .draw()
        .map_err(err)?;
    c.draw_series(LineSeries::new(ph, BLUE.stroke_width(1)))
        .map_err(err)?;
    area.present().map_err(err)
}

/// Puts `shaper = { .. }` into `[axes.AXIS]` of the machine file at
/// `path`, replacing one already there, with `fitted_from` naming the
/// run record of the measurement; the file is parsed and validated
/// before it is written, and the rest of it (comments too) is kept.
pub fn write_shaper(
    path: &Path,
    axis: &str,
    shaper: &ShaperConfig,
    fitted_from: Option<&str>,
) -> Result<(), ResonanceError> {
    let text = std::fs::read_to_string(path).map_err(io_err(path))?;
    let from = fitted_from
        .map(|run| format!(", fitted_from = {run:?}"))
        .unwrap_or_default();
    let line = format!(
        "shaper = {{ kind = \"{}\", freq_hz = {:.2}, damping = {:.3}{from} }}   # osap resonance",
        shaper.kind().name(),
        shaper.freq_hz(),
        shaper.damping()
    );
    let out = with_shaper_line(&text, axis, &line).ok_or_else(|| {
        ResonanceError::Refused(format!(
            "{}: no [axes.{axis}] table to put the shaper in; add the line `{line}` under the axis yourself",
            path.display()
        ))
    })?;
    let cfg = MachineFile::parse(&out)
        .and_then(|c| c.validate().map(|_| c))
        .map_err(|e| {
            ResonanceError::Refused(format!("the file with the shaper would not load: {e}"))
        })?;
    if cfg.axes.get(axis).and_then(|a| a.shaper.as_ref()).is_none() {
        return Err(ResonanceError::Refused(format!(
            "{}: the shaper line did not land in axis {axis}; add `{line}` under [axes.{axis}] yourself",
            path.display()
        )));
    }
    std::fs::write(path, out).map_err(io_err(path))
}

/// `text` with `line` as the `shaper` key of `[axes.AXIS]` (replacing the
/// table's own `shaper =` line, else right under its header); `None`
/// without such a table.
fn with_shaper_line(text: &str, axis: &str, line: &str) -> Option<String> {
    let header = format!("[axes.{axis}]");
    let lines: Vec<&str> = text.lines().collect();
    let h = lines
        .iter()
        .position(|l| l.trim_start().starts_with(&header))?;
    let end = (h + 1..lines.len())
        .find(|&i| lines[i].trim_start().starts_with('['))
        .unwrap_or(lines.len());
    let existing = (h + 1..end).find(|&i| {
        let t = lines[i].trim_start();
        t.strip_prefix("shaper")
            .is_some_and(|r| r.trim_start().starts_with('='))
    });
    let mut out: Vec<String> = lines.iter().map(|l| l.to_string()).collect();
    match existing {
        Some(i) => out[i] = line.to_string(),
        None => out.insert(h + 1, line.to_string()),
    }
    let mut s = out.join("\n");
    if text.ends_with('\n') {
        s.push('\n');
    }
    Some(s)
}

#[cfg(all(test, feature = "sim"))]
mod tests;
