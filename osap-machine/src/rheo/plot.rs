//! `osap rheo`'s plots (feature `plot`): the settled force against flow at
//! each temperature with the fitted law through it, and the step
//! responses, the flow the drive pushed against the flow the load cell
//! saw and the fitted lag's.

use std::path::{Path, PathBuf};

use osap_fit::lag::lagged;
use plotters::prelude::*;

use super::{RheoFit, RheoRecord};
use crate::record::plot::{draw_line, legend, pad, plot_err, range};
use crate::record::RecordError;

/// Series colours, one per temperature.
const COLOURS: [RGBColor; 6] = [BLUE, RED, GREEN, MAGENTA, CYAN, BLACK];

/// Writes `force_flow.svg` and `step_response.svg` into `dir` and returns
/// their paths.
pub fn plot(record: &RheoRecord, fit: &RheoFit, dir: &Path) -> Result<Vec<PathBuf>, RecordError> {
    let files = [dir.join("force_flow.svg"), dir.join("step_response.svg")];
    plot_force_flow(&files[0], fit)?;
    plot_steps(&files[1], record, fit)?;
    Ok(files.to_vec())
}

/// The temperatures the steps held, each once, rising.
fn temperatures(fit: &RheoFit) -> Vec<f64> {
    let mut temps: Vec<f64> = fit.steady.iter().map(|s| s.spec.condition).collect();
    temps.sort_by(f64::total_cmp);
    temps.dedup();
    temps
}

fn plot_force_flow(path: &Path, fit: &RheoFit) -> Result<(), RecordError> {
    let err = plot_err(path);
    let area = SVGBackend::new(path, (900, 600)).into_drawing_area();
    area.fill(&WHITE).map_err(&err)?;
    let temps = temperatures(fit);
    let q_max = fit
        .points
        .iter()
        .map(|p| p.0)
        .chain(fit.max_flows.iter().map(|m| m.1))
        .fold(1.0, f64::max)
        * 1.1;
    let f_max = fit
        .points
        .iter()
        .map(|p| p.2)
        .fold(fit.force_limit_n, f64::max)
        * 1.1;
    let mut chart = ChartBuilder::on(&area)
        .caption(
            "settled force against flow, and the fitted melt law",
            ("sans-serif", 20),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..q_max, 0.0..f_max)
        .map_err(&err)?;
    chart
        .configure_mesh()
        .x_desc("flow (mm³/s)")
        .y_desc("force on the filament (N)")
        .draw()
        .map_err(&err)?;
    let model = fit.melt.model;
    for (i, &t) in temps.iter().enumerate() {
        let colour = COLOURS[i % COLOURS.len()];
        let curve = (1..=200)
            .map(|k| {
                let q = q_max * k as f64 / 200.0;
                (q, model.force(q, t))
            })
            .filter(|p| p.1 <= f_max)
            .collect();
        draw_line(
            &mut chart,
            curve,
            colour.to_rgba(),
            &format!("{t} °C, fitted"),
            &err,
        )?;
        let measured = fit
            .points
            .iter()
            .filter(|p| nearest(&temps, p.1) == Some(t))
            .map(|p| Circle::new((p.0, p.2), 4, colour.filled()));
        chart.draw_series(measured).map_err(&err)?;
    }
    draw_line(
        &mut chart,
        vec![(0.0, fit.force_limit_n), (q_max, fit.force_limit_n)],
        BLACK.mix(0.5),
        "flow limit's force (share of the grip)",
        &err,
    )?;
    legend(&mut chart, &err)?;
    area.present().map_err(&err)
}

fn nearest(temps: &[f64], t: f64) -> Option<f64> {
    temps
        .iter()
        .copied()
        .min_by(|a, b| (a - t).abs().total_cmp(&(b - t).abs()))
}

/// The first temperature's steps: the flow pushed, the flow the load cell
/// saw (its force through the law) and the fitted lag of the push.
fn plot_steps(path: &Path, record: &RheoRecord, fit: &RheoFit) -> Result<(), RecordError> {
    let err = plot_err(path);
    let area = SVGBackend::new(path, (1200, 500)).into_drawing_area();
    area.fill(&WHITE).map_err(&err)?;
    let Some(first) = record.steps.first() else {
        return area.present().map_err(&err);
    };
    let t = first.spec.condition;
    let same: Vec<_> = record
        .steps
        .iter()
        .filter(|s| s.spec.condition == t)
        .collect();
    let from = first.start_s - 0.5;
    let to = same.last().map_or(first.end_s, |s| s.end_s) + 1.0;
    let inside = |x: f64| x >= from && x <= to;
    let pushed: Vec<(f64, f64)> = record
        .inflow
        .iter()
        .copied()
        .filter(|p| inside(p.0))
        .collect();
    let seen: Vec<(f64, f64)> = record
        .force
        .iter()
        .filter(|f| inside(f.t))
        .map(|f| (f.t, fit.melt.model.flow_at(f.force_n.max(0.0), f.temp_c)))
        .collect();
    let at: Vec<f64> = seen.iter().map(|p| p.0).collect();
    let model: Vec<(f64, f64)> = at
        .iter()
        .copied()
        .zip(lagged(&record.inflow, fit.lag.tau_s, &at))
        .collect();
    let yr = pad(range(pushed.iter().chain(&seen).map(|p| p.1)));
    let mut chart = ChartBuilder::on(&area)
        .caption(
            format!(
                "step responses at {t} °C: response time {:.1} ms",
                fit.lag.tau_s * 1000.0
            ),
            ("sans-serif", 20),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(from..to, yr)
        .map_err(&err)?;
    chart
        .configure_mesh()
        .x_desc("time (s)")
        .y_desc("flow (mm³/s)")
        .draw()
        .map_err(&err)?;
    draw_line(
        &mut chart,
        pushed,
        BLUE.to_rgba(),
        "pushed (planned extruder)",
        &err,
    )?;
    draw_line(
        &mut chart,
        seen,
        RED.mix(0.6),
        "out of the nozzle (load cell, through the law)",
        &err,
    )?;
    draw_line(
        &mut chart,
        model,
        BLACK.to_rgba(),
        "fitted lag of the push",
        &err,
    )?;
    legend(&mut chart, &err)?;
    area.present().map_err(&err)
}
