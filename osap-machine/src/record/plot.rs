//! The SVG plots of a run (feature `plot`): path, speed and following
//! error, and a timeline of any streams beside the motion.

use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use std::io;
use std::ops::Range;
use std::path::{Path, PathBuf};

use super::{create_dir, RecordError, Recording, Sample, Stream, PLOT_POINTS, SPEED_WINDOW_S};

impl Recording {
    /// Writes `path.svg` (planned and executed path on the first two axes,
    /// or position against time for a one-axis machine), `speed.svg`
    /// (speed along the path against time, planned and executed; the
    /// executed speed is differenced over at least [`SPEED_WINDOW_S`]) and
    /// `error.svg` (each axis's executed − planned position against time)
    /// into `dir` (created if missing), and returns their paths. Each
    /// series is reduced to at most [`PLOT_POINTS`] points.
    pub fn plot(&self, dir: &Path) -> Result<Vec<PathBuf>, RecordError> {
        create_dir(dir)?;
        let planned = self.usable(&self.planned);
        let executed = self.usable(&self.executed);
        let files = [
            dir.join("path.svg"),
            dir.join("speed.svg"),
            dir.join("error.svg"),
        ];
        self.plot_path(&files[0], &planned, &executed)?;
        plot_speed(&files[1], &planned, &executed)?;
        self.plot_error(&files[2])?;
        Ok(files.to_vec())
    }

    fn plot_path(
        &self,
        path: &Path,
        planned: &[&Sample],
        executed: &[&Sample],
    ) -> Result<(), RecordError> {
        let err = plot_err(path);
        let area = SVGBackend::new(path, (900, 900)).into_drawing_area();
        area.fill(&WHITE).map_err(&err)?;
        let series = |s: &[&Sample]| -> Vec<(f64, f64)> {
            match self.axes.len() {
                0 => Vec::new(),
                1 => reduce_minmax(&s.iter().map(|s| (s.t, s.pos[0])).collect::<Vec<_>>()),
                _ => reduce_stride(&s.iter().map(|s| (s.pos[0], s.pos[1])).collect::<Vec<_>>()),
            }
        };
        let (p, e) = (series(planned), series(executed));
        let all = || p.iter().chain(&e).copied();
        let (x_desc, y_desc, xr, yr) = if self.axes.len() >= 2 {
            let (xr, yr) = square(range(all().map(|q| q.0)), range(all().map(|q| q.1)));
            (self.axes[0].clone(), self.axes[1].clone(), xr, yr)
        } else {
            let y = self.axes.first().cloned().unwrap_or_default();
            let yr = pad(range(all().map(|q| q.1)));
            ("time (s)".to_string(), y, range(all().map(|q| q.0)), yr)
        };
        let mut chart = ChartBuilder::on(&area)
            .caption("planned and executed path", ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(xr, yr)
            .map_err(&err)?;
        chart
            .configure_mesh()
            .x_desc(x_desc)
            .y_desc(y_desc)
            .draw()
            .map_err(&err)?;
        // The executed path under the planned one: where they differ, the
        // executed one shows.
        draw_line(&mut chart, e, RED.to_rgba(), "executed", &err)?;
        draw_line(&mut chart, p, BLUE.to_rgba(), "planned", &err)?;
        legend(&mut chart, &err)?;
        area.present().map_err(&err)
    }

    fn plot_error(&self, path: &Path) -> Result<(), RecordError> {
        let err = plot_err(path);
        let errors = self.errors();
        let per_axis: Vec<Vec<(f64, f64)>> = (0..self.axes.len())
            .map(|i| {
                let v: Vec<(f64, f64)> = errors
                    .iter()
                    .map(|(t, e)| (*t, e[i]))
                    .filter(|(_, e)| e.is_finite())
                    .collect();
                reduce_minmax(&v)
            })
            .collect();
        let all = || per_axis.iter().flatten().copied();
        let xr = range(all().map(|q| q.0));
        let yr = pad(range(all().map(|q| q.1)));
        let area = SVGBackend::new(path, (1100, 600)).into_drawing_area();
        area.fill(&WHITE).map_err(&err)?;
        let mut chart = ChartBuilder::on(&area)
            .caption("following error (executed − planned)", ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(70)
            .build_cartesian_2d(xr, yr)
            .map_err(&err)?;
        chart
            .configure_mesh()
            .x_desc("time (s)")
            .y_desc("error (machine units)")
            .draw()
            .map_err(&err)?;
        for (i, (name, points)) in self.axes.iter().zip(per_axis).enumerate() {
            let color = Palette99::pick(i).to_rgba();
            draw_line(&mut chart, points, color, name, &err)?;
        }
        legend(&mut chart, &err)?;
        area.present().map_err(&err)
    }
}

/// Speed along the path (Euclidean over all axes) from differences over
/// windows of at least `window` seconds (at least one sample apart), at
/// each window's middle.
pub(super) fn speeds(samples: &[&Sample], window: f64) -> Vec<(f64, f64)> {
    let mut out = Vec::with_capacity(samples.len());
    let mut j = 0;
    for (i, a) in samples.iter().enumerate() {
        j = j.max(i + 1);
        while j < samples.len() && !(samples[j].t - a.t >= window && samples[j].t > a.t) {
            j += 1;
        }
        let Some(b) = samples.get(j) else {
            break;
        };
        let d = a
            .pos
            .iter()
            .zip(&b.pos)
            .map(|(p, q)| (q - p) * (q - p))
            .sum::<f64>()
            .sqrt();
        out.push(((a.t + b.t) / 2.0, d / (b.t - a.t)));
    }
    out
}

pub(super) fn plot_speed(
    path: &Path,
    planned: &[&Sample],
    executed: &[&Sample],
) -> Result<(), RecordError> {
    let err = plot_err(path);
    let p = reduce_minmax(&speeds(planned, 0.0));
    let e = reduce_minmax(&speeds(executed, SPEED_WINDOW_S));
    let all = || p.iter().chain(&e).copied();
    let xr = range(all().map(|q| q.0));
    let top = all().map(|q| q.1).fold(0.0, f64::max);
    // Headroom above the fastest speed for the legend.
    let yr = 0.0..if top > 0.0 { top * 1.2 } else { 1.0 };
    let area = SVGBackend::new(path, (1100, 600)).into_drawing_area();
    area.fill(&WHITE).map_err(&err)?;
    let mut chart = ChartBuilder::on(&area)
        .caption("speed along the path", ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(xr, yr)
        .map_err(&err)?;
    chart
        .configure_mesh()
        .x_desc("time (s)")
        .y_desc("speed (machine units/s)")
        .draw()
        .map_err(&err)?;
    let label = format!("executed ({:.0} ms windows)", SPEED_WINDOW_S * 1e3);
    draw_line(&mut chart, e, RED.to_rgba(), &label, &err)?;
    draw_line(&mut chart, p, BLUE.to_rgba(), "planned", &err)?;
    legend(&mut chart, &err)?;
    area.present().map_err(&err)
}

pub(crate) type Chart<'a, 'b> =
    ChartContext<'a, SVGBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

pub(crate) fn draw_line<F: Fn(DrawingAreaErrorKind<io::Error>) -> RecordError>(
    chart: &mut Chart<'_, '_>,
    points: Vec<(f64, f64)>,
    color: RGBAColor,
    label: &str,
    err: F,
) -> Result<(), RecordError> {
    if points.is_empty() {
        return Ok(());
    }
    chart
        .draw_series(LineSeries::new(points, color.stroke_width(1)))
        .map_err(err)?
        .label(label)
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], color));
    Ok(())
}

pub(crate) fn legend<'a, 'b: 'a, F: Fn(DrawingAreaErrorKind<io::Error>) -> RecordError>(
    chart: &mut Chart<'a, 'b>,
    err: F,
) -> Result<(), RecordError> {
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(err)
}

/// The range of finite values, widened when empty or a single value.
pub(crate) fn range(values: impl Iterator<Item = f64>) -> Range<f64> {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    if lo > hi {
        0.0..1.0
    } else if hi - lo <= f64::EPSILON * lo.abs().max(1.0) {
        let w = 0.5 * lo.abs().max(1e-3);
        lo - w..hi + w
    } else {
        lo..hi
    }
}

/// `r` with a 5 % margin on each side.
pub(crate) fn pad(r: Range<f64>) -> Range<f64> {
    let m = (r.end - r.start) * 0.05;
    r.start - m..r.end + m
}

/// Two ranges padded and widened to one span, so a square chart draws the
/// path at equal scales.
pub(super) fn square(x: Range<f64>, y: Range<f64>) -> (Range<f64>, Range<f64>) {
    let (x, y) = (pad(x), pad(y));
    let half = (x.end - x.start).max(y.end - y.start) / 2.0;
    let (cx, cy) = ((x.start + x.end) / 2.0, (y.start + y.end) / 2.0);
    (cx - half..cx + half, cy - half..cy + half)
}

/// At most [`PLOT_POINTS`] points, every k-th and the last (for paths).
pub(super) fn reduce_stride(points: &[(f64, f64)]) -> Vec<(f64, f64)> {
    if points.len() <= PLOT_POINTS {
        return points.to_vec();
    }
    let per = points.len().div_ceil(PLOT_POINTS - 1);
    let mut out: Vec<(f64, f64)> = points.iter().copied().step_by(per).collect();
    if let Some(&last) = points.last() {
        if out.last() != Some(&last) {
            out.push(last);
        }
    }
    out
}

/// At most [`PLOT_POINTS`] points, keeping each bucket's smallest and
/// largest value in time order (for time series: spikes survive).
pub(super) fn reduce_minmax(points: &[(f64, f64)]) -> Vec<(f64, f64)> {
    if points.len() <= PLOT_POINTS {
        return points.to_vec();
    }
    let per = points.len().div_ceil(PLOT_POINTS / 2);
    let mut out = Vec::with_capacity(PLOT_POINTS);
    for bucket in points.chunks(per) {
        let lo = (0..bucket.len())
            .min_by(|&a, &b| bucket[a].1.total_cmp(&bucket[b].1))
            .unwrap_or(0);
        let hi = (0..bucket.len())
            .max_by(|&a, &b| bucket[a].1.total_cmp(&bucket[b].1))
            .unwrap_or(0);
        let (a, b) = (lo.min(hi), lo.max(hi));
        out.push(bucket[a]);
        if b != a {
            out.push(bucket[b]);
        }
    }
    out
}

/// Velocity of axis `axis` from differences over windows of at least
/// `window` seconds, at each window's middle.
pub(super) fn axis_velocity(samples: &[&Sample], axis: usize, window: f64) -> Vec<(f64, f64)> {
    let mut out = Vec::with_capacity(samples.len());
    let mut j = 0;
    for (i, a) in samples.iter().enumerate() {
        j = j.max(i + 1);
        while j < samples.len() && !(samples[j].t - a.t >= window && samples[j].t > a.t) {
            j += 1;
        }
        let Some(b) = samples.get(j) else {
            break;
        };
        out.push(((a.t + b.t) / 2.0, (b.pos[axis] - a.pos[axis]) / (b.t - a.t)));
    }
    out
}

/// Height of one panel of [`plot_timeline`], pixels.
const PANEL_PX: u32 = 260;

/// One SVG of panels stacked on one time axis (seconds since the run's
/// start, on the synchronized clock): with a recording, each axis's
/// planned and executed position, its planned and executed velocity (the
/// executed one differenced over at least [`SPEED_WINDOW_S`]) and its
/// following error; then one panel per stream (sensor readings, captured
/// positions). Streams and recording must share their origin: a capture's
/// times minus the `from_us` given to [`crate::Machine::take_recording`]
/// (a capture's `streams`). Each series is reduced to at
/// most [`PLOT_POINTS`] points.
pub fn plot_timeline(
    path: &Path,
    recording: Option<&Recording>,
    streams: &[Stream],
) -> Result<(), RecordError> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        create_dir(dir)?;
    }
    let err = plot_err(path);
    // Panels: (title, y label, series (label, colour, points)).
    type Series = (String, RGBAColor, Vec<(f64, f64)>);
    let mut panels: Vec<(String, String, Vec<Series>)> = Vec::new();
    if let Some(rec) = recording {
        let planned = rec.usable(&rec.planned);
        let executed = rec.usable(&rec.executed);
        let n = rec.axes.len();
        let track = |s: &[&Sample], i: usize| -> Vec<(f64, f64)> {
            reduce_minmax(&s.iter().map(|s| (s.t, s.pos[i])).collect::<Vec<_>>())
        };
        let mut pos = Vec::new();
        let mut vel = Vec::new();
        for (i, axis) in rec.axes.iter().enumerate() {
            let c = Palette99::pick(i);
            pos.push((format!("{axis} planned"), c.mix(0.5), track(&planned, i)));
            pos.push((format!("{axis} executed"), c.to_rgba(), track(&executed, i)));
            vel.push((
                format!("{axis} planned"),
                c.mix(0.5),
                reduce_minmax(&axis_velocity(&planned, i, 0.0)),
            ));
            vel.push((
                format!("{axis} executed"),
                c.to_rgba(),
                reduce_minmax(&axis_velocity(&executed, i, SPEED_WINDOW_S)),
            ));
        }
        let errors = rec.errors();
        let err_series = (0..n)
            .map(|i| {
                let v: Vec<(f64, f64)> = errors
                    .iter()
                    .map(|(t, e)| (*t, e[i]))
                    .filter(|(_, e)| e.is_finite())
                    .collect();
                (
                    rec.axes[i].clone(),
                    Palette99::pick(i).to_rgba(),
                    reduce_minmax(&v),
                )
            })
            .collect();
        panels.push((
            "position: planned and executed".into(),
            "machine units".into(),
            pos,
        ));
        panels.push((
            "velocity: planned and executed".into(),
            "units/s".into(),
            vel,
        ));
        panels.push((
            "following error (executed − planned)".into(),
            "machine units".into(),
            err_series,
        ));
    }
    for (k, s) in streams.iter().enumerate() {
        let points: Vec<(f64, f64)> = s
            .points
            .iter()
            .copied()
            .filter(|(t, v)| t.is_finite() && v.is_finite())
            .collect();
        let c = Palette99::pick(k + 3).to_rgba();
        panels.push((
            s.name.clone(),
            "value".into(),
            vec![(s.name.clone(), c, reduce_minmax(&points))],
        ));
    }
    if panels.is_empty() {
        return Err(RecordError::Plot {
            path: path.to_path_buf(),
            message: "nothing to plot: no recording and no stream".into(),
        });
    }
    let xr = range(
        panels
            .iter()
            .flat_map(|p| p.2.iter())
            .flat_map(|s| s.2.iter().map(|q| q.0)),
    );
    let height = PANEL_PX.saturating_mul(panels.len() as u32);
    let area = SVGBackend::new(path, (1100, height)).into_drawing_area();
    area.fill(&WHITE).map_err(&err)?;
    let parts = area.split_evenly((panels.len(), 1));
    for (part, (title, y_desc, series)) in parts.iter().zip(panels) {
        let yr = pad(range(series.iter().flat_map(|s| s.2.iter().map(|q| q.1))));
        let mut chart = ChartBuilder::on(part)
            .caption(title, ("sans-serif", 16))
            .margin(8)
            .x_label_area_size(30)
            .y_label_area_size(70)
            .build_cartesian_2d(xr.clone(), yr)
            .map_err(&err)?;
        chart
            .configure_mesh()
            .x_desc("time (s, synchronized clock)")
            .y_desc(y_desc)
            .draw()
            .map_err(&err)?;
        for (label, color, points) in series {
            draw_line(&mut chart, points, color, &label, &err)?;
        }
        legend(&mut chart, &err)?;
    }
    area.present().map_err(&err)
}

pub(crate) fn plot_err<E: std::fmt::Debug>(path: &Path) -> impl Fn(E) -> RecordError + '_ {
    move |e| RecordError::Plot {
        path: path.to_path_buf(),
        message: format!("{e:?}"),
    }
}
