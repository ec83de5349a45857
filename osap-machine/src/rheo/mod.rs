//! `osap rheo`: the printer measures its own melt and fits a model of it.
//!
//! The routine ([`measure`]) heats the hotend to each temperature of
//! [`RheoOptions::temps`], tares the load cell at rest, and extrudes into
//! air at rising flows, each held [`RheoOptions::hold_s`], while it reads
//! the load cell and records the extruder's stepped positions on the
//! synchronized clock. Before each flow it predicts the force from the
//! flows already measured at that temperature and skips the rest of them
//! once the prediction, or a force measured, passes
//! [`RheoOptions::force_share`] of the drive's grip (`max_force_n`), so
//! the filament never slips (osap-fit's [`Routine`]).
//!
//! The fit ([`fit`]) reduces each flow to its settled force, fits the melt
//! law (`osap_fit::melt`) by Levenberg–Marquardt with standard errors, and
//! identifies the melt's response time over the whole record: the flow
//! the force says left the nozzle against a first-order lag of the flow
//! the drive pushed (`osap_fit::lag`). It then says, per temperature, the
//! flow at which the force reaches the same share of the grip.

use std::time::Duration;

use osap_fit::experiment::{steady_states, Plan, RanStep, Routine, SteadyState, StepSpec};
use osap_fit::lag::{fit_lag, LagFit};
use osap_fit::{FitError, MeltFit};

use crate::config::MachineFile;
use crate::machine::{Machine, MachineError};

#[cfg(feature = "plot")]
mod plot;
mod write;
#[cfg(feature = "plot")]
pub use plot::plot;
pub use write::{model_lines, write_model};

/// How the melt is measured.
#[derive(Debug, Clone, PartialEq)]
pub struct RheoOptions {
    /// The temperatures, °C, within the filament's range (at least 3).
    pub temps: Vec<f64>,
    /// The flows to step through at each, mm³/s, rising.
    pub flows: Vec<f64>,
    /// How long each flow is held, s.
    pub hold_s: f64,
    /// How long after a flow starts its force counts as settled, s.
    pub settle_s: f64,
    /// The share of the drive's grip the routine stays under, and the
    /// max flow is quoted at (0.8).
    pub force_share: f64,
    /// How long the hotend soaks at each temperature before measuring, s.
    pub soak_s: f64,
    /// Samples the tare averages.
    pub tare_samples: u16,
}

impl Default for RheoOptions {
    /// PLA's range (195, 215, 235 °C), flows from 1 to 25 mm³/s, 2 s each.
    fn default() -> Self {
        RheoOptions {
            temps: vec![195.0, 215.0, 235.0],
            flows: vec![1.0, 2.0, 3.0, 5.0, 7.0, 10.0, 14.0, 19.0, 25.0],
            hold_s: 2.0,
            settle_s: 1.2,
            force_share: crate::config::MODEL_FORCE_SHARE,
            soak_s: 5.0,
            tare_samples: 40,
        }
    }
}

/// Why a measurement or fit could not be made.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RheoError {
    /// The machine failed or faulted.
    #[error(transparent)]
    Machine(#[from] MachineError),
    /// The machine or the options cannot run the routine; the message
    /// says what to change.
    #[error("{0}")]
    Refused(String),
    /// The measurements did not give a model.
    #[error("the fit failed: {0}")]
    Fit(#[from] FitError),
}

/// One load-cell sample of a measurement.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ForceSample {
    /// Seconds since the measurement started (synchronized clock).
    pub t: f64,
    /// The force, N.
    pub force_n: f64,
    /// The hotend's target while it was taken, °C.
    pub temp_c: f64,
}

/// What [`measure`] recorded.
#[derive(Debug, Clone, PartialEq)]
pub struct RheoRecord {
    /// The flows as they ran (condition: °C, setpoint: mm³/s).
    pub steps: Vec<RanStep>,
    /// Every load-cell sample.
    pub force: Vec<ForceSample>,
    /// The flow the drive pushed, from the extruder's planned positions
    /// (which its steps follow within a microstep): `(s, mm³/s)`.
    pub inflow: Vec<(f64, f64)>,
    /// The drive's grip, N.
    pub grip_n: f64,
    /// When the measurement started, synchronized µs.
    pub start_us: u64,
}

/// Checks that the machine can run the routine: an extruder with a
/// filament diameter and a grip, a load cell, a `hotend` heater whose
/// range holds the temperatures, and sane options.
pub fn check(cfg: &MachineFile, opts: &RheoOptions) -> Result<(), RheoError> {
    let refuse = |m: String| Err(RheoError::Refused(m));
    let Some(e) = cfg.extruder() else {
        return refuse("the machine has no extruder ([axes.e] kind = \"extruder\")".into());
    };
    if e.extruder.loadcell.is_none() {
        return refuse(
            "the machine has no load cell: add [axes.e.loadcell] (module, data_pin, clock_pin, newtons_per_count)"
                .into(),
        );
    }
    if e.extruder.max_force_n.is_none() {
        return refuse(
            "give [axes.e] max_force_n: the routine stays under a share of the drive's grip".into(),
        );
    }
    let Some(h) = cfg.heaters.get("hotend") else {
        return refuse("the machine has no [heaters.hotend] to melt the filament".into());
    };
    if opts.temps.len() < 3 {
        return refuse(format!(
            "{} temperature(s): the temperature shift needs at least 3",
            opts.temps.len()
        ));
    }
    if let Some(t) = opts
        .temps
        .iter()
        .find(|t| !(**t >= h.min_temp && **t < h.max_temp))
    {
        return refuse(format!(
            "{t} °C is outside the hotend's min_temp {} to max_temp {} °C",
            h.min_temp, h.max_temp
        ));
    }
    if opts.flows.len() < 2 || opts.flows.iter().any(|q| !(q.is_finite() && *q > 0.0)) {
        return refuse("give at least two positive flows, mm³/s".into());
    }
    if !(opts.hold_s > opts.settle_s && opts.settle_s > 0.0 && opts.hold_s.is_finite()) {
        return refuse(format!(
            "hold {} s must be longer than settle {} s (both positive)",
            opts.hold_s, opts.settle_s
        ));
    }
    if !(opts.force_share > 0.0 && opts.force_share < 1.0) {
        return refuse(format!(
            "force share {} must be within (0, 1)",
            opts.force_share
        ));
    }
    Ok(())
}

/// Runs the routine on `m` (see the module docs). The hotend is left at
/// the last temperature; the caller turns it off.
pub async fn measure(m: &Machine, opts: &RheoOptions) -> Result<RheoRecord, RheoError> {
    let cfg = m.config();
    check(cfg, opts)?;
    let e = cfg.extruder().expect("checked");
    let area = e.extruder.filament_area();
    let grip_n = e.extruder.max_force_n.expect("checked");
    let hotend = m.heater("hotend")?;
    let cell = m.loadcell()?;
    let plan = Plan::grid(&opts.temps, &opts.flows, opts.hold_s);
    let mut routine = Routine::new(plan, opts.force_share * grip_n);

    hotend.set_target(opts.temps[0]).await?;
    hotend.wait_for_target().await?;
    tokio::time::sleep(Duration::from_secs_f64(opts.soak_s)).await;
    cell.tare(opts.tare_samples).await?;
    m.start_recording().await?;
    let start_us = m.now_us().await?;
    let secs = |us: u64| (us as f64 - start_us as f64) * 1e-6;

    let mut steps = Vec::new();
    let mut force = Vec::new();
    let mut last_sample = 0;
    let mut condition = opts.temps[0];
    let mut previous = None;
    while let Some(step) = routine.next_step(previous) {
        if step.condition != condition {
            condition = step.condition;
            hotend.set_target(condition).await?;
            hotend.wait_for_target().await?;
            tokio::time::sleep(Duration::from_secs_f64(opts.soak_s)).await;
        }
        let ran = run_flow(
            m,
            &step,
            area,
            |r: crate::machine::LoadCellReading, temp_c| {
                if r.time_us != last_sample && r.time_us > start_us {
                    force.push(ForceSample {
                        t: secs(r.time_us),
                        force_n: r.force_n,
                        temp_c,
                    });
                    last_sample = r.time_us;
                }
            },
        )
        .await?;
        let ran = RanStep {
            spec: step,
            start_s: secs(ran.0),
            end_s: secs(ran.1),
        };
        let series: Vec<(f64, f64)> = force.iter().map(|f| (f.t, f.force_n)).collect();
        // The decision's window ends before the stop (and the wait for
        // idle) that `end_s` includes.
        let settled = RanStep {
            end_s: ran.end_s - 0.15,
            ..ran
        };
        previous = steady_states(&[settled], &series, opts.settle_s, 10)
            .0
            .first()
            .map(|s| s.mean);
        steps.push(ran);
    }
    let recording = m.take_recording(start_us).await?;
    let e_index = recording.axes.iter().position(|a| a == "e").unwrap_or(0);
    // The flow the drive pushed, from the plan the module follows on the
    // synchronized clock (its steps follow it within a microstep; the
    // stepped positions a module reports are counted as the steps are
    // queued, a few ms ahead of the motor).
    let e: Vec<(f64, f64)> = recording
        .planned
        .iter()
        .map(|p| (p.t, p.pos[e_index]))
        .collect();
    let inflow = rate_on_grid(&e, 0.002)
        .into_iter()
        .map(|(t, v)| (t, v * area))
        .collect();
    Ok(RheoRecord {
        steps,
        force,
        inflow,
        grip_n,
        start_us,
    })
}

/// Extrudes `step.setpoint` mm³/s for `step.hold_s`, reading the load cell
/// into `sample` meanwhile and for 0.3 s after (the force's decay, for
/// the response time); returns when the move was queued and when it
/// ended, synchronized µs.
async fn run_flow(
    m: &Machine,
    step: &StepSpec,
    area: f64,
    mut sample: impl FnMut(crate::machine::LoadCellReading, f64),
) -> Result<(u64, u64), RheoError> {
    let cell = m.loadcell()?;
    let hotend = m.heater("hotend")?;
    // The hotend's reading, every 20 load-cell reads (about 10 a second).
    let mut temp_c = hotend.read().await?.celsius;
    let mut reads = 0u32;
    let mut read = async || -> Result<(crate::machine::LoadCellReading, f64), RheoError> {
        reads += 1;
        if reads.is_multiple_of(20) {
            temp_c = hotend.read().await?.celsius;
        }
        Ok((cell.read().await?, temp_c))
    };
    let v = step.setpoint / area;
    let e = m
        .axes()
        .iter()
        .position(|a| a == "e")
        .ok_or_else(|| RheoError::Refused("the machine has no axis e".into()))?;
    let mut to = m.position();
    to[e] += v * step.hold_s;
    m.line(&to, v).await?;
    let start = m.now_us().await?;
    let until = start + ((step.hold_s + 0.5) * 1e6) as u64;
    loop {
        let (r, t) = read().await?;
        sample(r, t);
        let now = m.now_us().await?;
        if now > until || (m.queued_moves() == 0 && now > start + (step.hold_s * 1e6) as u64) {
            break;
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    m.idle().await?;
    let end = m.now_us().await?;
    // The force's decay after the stop, for the response time.
    while m.now_us().await? < end + 300_000 {
        let (r, t) = read().await?;
        sample(r, t);
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    Ok((start, end))
}

/// The rate of change of `samples` (`(s, value)`, time-ordered), on a
/// grid of `step` s: the difference of the values interpolated at each
/// grid point's ends (irregular or repeated sample times give no spikes).
fn rate_on_grid(samples: &[(f64, f64)], step: f64) -> Vec<(f64, f64)> {
    let (Some(first), Some(last)) = (samples.first(), samples.last()) else {
        return Vec::new();
    };
    let mut k = 0;
    let mut at = |t: f64| {
        while k + 1 < samples.len() && samples[k + 1].0 <= t {
            k += 1;
        }
        match samples.get(k + 1) {
            Some(&(t1, v1)) if t1 > samples[k].0 => {
                let (t0, v0) = samples[k];
                v0 + (v1 - v0) * (t - t0) / (t1 - t0)
            }
            _ => samples[k].1,
        }
    };
    let n = ((last.0 - first.0) / step).floor() as usize;
    let mut out = Vec::with_capacity(n);
    let mut before = at(first.0);
    for i in 1..=n {
        let t = first.0 + step * i as f64;
        let now = at(t);
        out.push((t - 0.5 * step, (now - before) / step));
        before = now;
    }
    out
}

/// When the drive's flow reached its plateau within `ran`, and when it
/// left it: the flow smoothed over 20 ms, its plateau the 90th percentile
/// within the step, and the first and last times within 3 % of it.
fn plateau(inflow: &[(f64, f64)], ran: &RanStep) -> Option<(f64, f64)> {
    let within: Vec<(f64, f64)> = inflow
        .iter()
        .filter(|p| p.0 >= ran.start_s && p.0 < ran.end_s)
        .copied()
        .collect();
    const SPAN: usize = 10;
    if within.len() < 4 * SPAN {
        return None;
    }
    let smooth: Vec<(f64, f64)> = within
        .windows(SPAN)
        .map(|w| {
            (
                w[SPAN / 2].0,
                w.iter().map(|p| p.1).sum::<f64>() / SPAN as f64,
            )
        })
        .collect();
    let mut levels: Vec<f64> = smooth.iter().map(|p| p.1).collect();
    levels.sort_by(f64::total_cmp);
    let top = levels[levels.len() * 9 / 10];
    if top <= 0.0 {
        return None;
    }
    let on = |p: &&(f64, f64)| p.1 >= 0.97 * top;
    let rise = smooth.iter().find(on)?.0;
    let fall = smooth.iter().rev().find(on)?.0;
    (fall > rise).then_some((rise, fall))
}

/// A fitted melt.
#[derive(Debug, Clone, PartialEq)]
pub struct RheoFit {
    /// The melt law with its uncertainty.
    pub melt: MeltFit,
    /// The melt's response time.
    pub lag: LagFit,
    /// Each flow's settled force.
    pub steady: Vec<SteadyState>,
    /// The settled points the law was fitted to: (mm³/s, °C, N), flow
    /// and temperature as measured.
    pub points: Vec<(f64, f64, f64)>,
    /// Per temperature: (°C, max flow mm³/s, its standard error).
    pub max_flows: Vec<(f64, f64, f64)>,
    /// The share of the grip the max flows are quoted at, and the grip, N.
    pub force_limit_n: f64,
    /// The temperatures measured, lowest and highest, °C.
    pub temp_range: [f64; 2],
}

/// Fits the melt law and the response time to a measurement.
pub fn fit(record: &RheoRecord, opts: &RheoOptions) -> Result<RheoFit, RheoError> {
    let series: Vec<(f64, f64)> = record.force.iter().map(|f| (f.t, f.force_n)).collect();
    let mean = |v: &mut dyn Iterator<Item = f64>| {
        let (sum, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x, n + 1));
        (n > 0).then(|| sum / n as f64)
    };
    // Each flow's settled force, at the flow the drive really pushed and
    // the temperature the hotend really read over the same window (a
    // machine cap such as max_volumetric_speed, or a heater a degree off
    // its target, is then measured, not assumed).
    let mut steady = Vec::new();
    let mut points = Vec::new();
    for ran in &record.steps {
        // The flow's plateau, from the drive's own flow: settled from
        // `settle_s` after it reached it until it left it.
        let Some((rise, fall)) = plateau(&record.inflow, ran) else {
            continue;
        };
        let window_step = RanStep {
            start_s: rise,
            end_s: fall,
            ..*ran
        };
        let Some(s) = steady_states(&[window_step], &series, opts.settle_s, 10)
            .0
            .pop()
        else {
            continue;
        };
        let window = |t: f64| t >= rise + opts.settle_s && t < fall;
        let q = mean(&mut record.inflow.iter().filter(|p| window(p.0)).map(|p| p.1));
        let t = mean(
            &mut record
                .force
                .iter()
                .filter(|f| window(f.t))
                .map(|f| f.temp_c),
        );
        // Forces too small to tell from the cell's noise say nothing of
        // the law.
        if let (Some(q), Some(t)) = (q, t) {
            if s.mean > 0.5 && q > 0.0 {
                points.push((q, t, s.mean));
            }
        }
        steady.push(s);
    }
    let temps: Vec<f64> = opts.temps.clone();
    let t_ref = temps.iter().sum::<f64>() / temps.len() as f64;
    let melt = MeltFit::fit(&points, t_ref)?;
    // The flow that left the nozzle, from the force through the law, while
    // the extruder ran and just after.
    let in_steps = |t: f64| {
        record
            .steps
            .iter()
            .any(|s| t >= s.start_s - 0.1 && t < s.end_s + 0.3)
    };
    let measured: Vec<(f64, f64)> = record
        .force
        .iter()
        .filter(|f| in_steps(f.t))
        .map(|f| (f.t, melt.model.flow_at(f.force_n.max(0.0), f.temp_c)))
        .collect();
    let lag = fit_lag(&record.inflow, &measured, (0.002, 2.0)).ok_or_else(|| {
        RheoError::Refused(
            "too few load-cell samples while extruding to fit the response time".into(),
        )
    })?;
    let force_limit_n = opts.force_share * record.grip_n;
    let max_flows = temps
        .iter()
        .map(|&t| {
            let (q, err) = melt.max_flow(t, force_limit_n);
            (t, q, err)
        })
        .collect();
    let lo = temps.iter().cloned().fold(f64::INFINITY, f64::min);
    let hi = temps.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    Ok(RheoFit {
        melt,
        lag,
        steady,
        points,
        max_flows,
        force_limit_n,
        temp_range: [lo, hi],
    })
}
