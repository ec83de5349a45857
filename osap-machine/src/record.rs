//! What a machine run leaves behind (`osap run --out DIR`): the planned and
//! the executed machine positions over time, as CSV files and SVG plots,
//! with the run's following error and durations.
//!
//! Times are seconds since the run's start on the machine's synchronized
//! clock; positions are machine units (mm, or degrees for rotary axes) in
//! [`Recording::axes`] order.
//!
//! Per-motor readbacks (time, motor position, sampled near 1 kHz and not
//! aligned across motors) go onto a common grid with [`resample_hold`] or
//! [`resample_linear`] before forward kinematics turns them into
//! [`Recording::executed`].
//!
//! Nothing here panics on an empty recording, a single sample, NaN or a
//! sample whose length does not match the axes: writing refuses a
//! mis-shaped sample with an error naming the file, and the analyses and
//! plots skip samples they cannot use.

use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use std::fmt::Write as _;
use std::fs;
use std::io::{self, BufWriter, Write};
use std::ops::Range;
use std::path::{Path, PathBuf};
use thiserror::Error;

/// Most points drawn per series in a plot; longer series are reduced
/// (keeping each bucket's extremes for time series).
pub const PLOT_POINTS: usize = 4000;

/// The shortest window (s) the executed speed is differenced over, so that
/// step quantization does not dominate it.
pub const SPEED_WINDOW_S: f64 = 0.005;

/// The files [`Recording::write_csv`] writes.
pub const PLANNED_CSV: &str = "planned.csv";
/// See [`PLANNED_CSV`].
pub const EXECUTED_CSV: &str = "executed.csv";

/// A machine position at a time: seconds since the run's start (on the
/// machine's synchronized clock), axes in machine units in
/// [`Recording::axes`] order.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Sample {
    /// Seconds since the run's start.
    pub t: f64,
    /// One position per axis, machine units.
    pub pos: Vec<f64>,
}

/// A run: where the machine was asked to be and where it was.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Recording {
    /// The axis names, in the order of every [`Sample::pos`].
    pub axes: Vec<String>,
    /// The planned positions, in time order.
    pub planned: Vec<Sample>,
    /// The executed positions (readbacks through forward kinematics), in
    /// time order.
    pub executed: Vec<Sample>,
}

/// Why a recording could not be written or read; every variant names the
/// file.
#[derive(Debug, Error)]
pub enum RecordError {
    /// Creating, writing or reading a file or directory failed.
    #[error("{}: {source}", .path.display())]
    Io {
        /// The file or directory.
        path: PathBuf,
        /// What the system said.
        #[source]
        source: io::Error,
    },
    /// A sample does not have one position per axis.
    #[error("{}: sample {index} has {len} positions for {axes} axes", .path.display())]
    Shape {
        /// The file it would have gone to.
        path: PathBuf,
        /// The sample's index.
        index: usize,
        /// How many positions it has.
        len: usize,
        /// How many axes the recording has.
        axes: usize,
    },
    /// An axis name would break the CSV header (a comma, quote or line
    /// break).
    #[error("{}: axis name {name:?} cannot go in a CSV header", .path.display())]
    AxisName {
        /// The file.
        path: PathBuf,
        /// The name.
        name: String,
    },
    /// A CSV file is not a recording.
    #[error("{}:{line}: {message}", .path.display())]
    Parse {
        /// The file.
        path: PathBuf,
        /// The 1-based line.
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// Drawing a plot failed.
    #[error("{}: plot: {message}", .path.display())]
    Plot {
        /// The SVG file.
        path: PathBuf,
        /// What plotters said.
        message: String,
    },
}

fn io_err(path: &Path) -> impl Fn(io::Error) -> RecordError + '_ {
    move |source| RecordError::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn plot_err<E: std::fmt::Debug>(path: &Path) -> impl Fn(E) -> RecordError + '_ {
    move |e| RecordError::Plot {
        path: path.to_path_buf(),
        message: format!("{e:?}"),
    }
}

fn create_dir(dir: &Path) -> Result<(), RecordError> {
    fs::create_dir_all(dir).map_err(io_err(dir))
}

impl Recording {
    /// Writes `planned.csv` and `executed.csv` into `dir` (created if
    /// missing) and returns their paths. Each has the header
    /// `t,<axis names>` and one line per sample: time in seconds, then
    /// positions in machine units, each printed so that it reads back to
    /// the same `f64` (NaN as `NaN`, infinities as `inf`/`-inf`).
    ///
    /// A sample whose length does not match the axes, or an axis name with
    /// a comma, quote or line break, is refused before anything is written.
    pub fn write_csv(&self, dir: &Path) -> Result<Vec<PathBuf>, RecordError> {
        let files = [
            (dir.join(PLANNED_CSV), &self.planned),
            (dir.join(EXECUTED_CSV), &self.executed),
        ];
        for (path, samples) in &files {
            if let Some(name) = self
                .axes
                .iter()
                .find(|n| n.contains([',', '"', '\n', '\r']))
            {
                return Err(RecordError::AxisName {
                    path: path.clone(),
                    name: name.clone(),
                });
            }
            if let Some((index, s)) = samples
                .iter()
                .enumerate()
                .find(|(_, s)| s.pos.len() != self.axes.len())
            {
                return Err(RecordError::Shape {
                    path: path.clone(),
                    index,
                    len: s.pos.len(),
                    axes: self.axes.len(),
                });
            }
        }
        create_dir(dir)?;
        let mut written = Vec::with_capacity(files.len());
        for (path, samples) in files {
            write_samples(&path, &self.axes, samples).map_err(io_err(&path))?;
            written.push(path);
        }
        Ok(written)
    }

    /// Reads back what [`Recording::write_csv`] wrote in `dir`. Both files
    /// must name the same axes.
    pub fn read_csv(dir: &Path) -> Result<Recording, RecordError> {
        let (axes, planned) = read_samples(&dir.join(PLANNED_CSV))?;
        let path = dir.join(EXECUTED_CSV);
        let (executed_axes, executed) = read_samples(&path)?;
        if executed_axes != axes {
            return Err(RecordError::Parse {
                path,
                line: 1,
                message: format!("axes {executed_axes:?} differ from {PLANNED_CSV}'s {axes:?}"),
            });
        }
        Ok(Recording {
            axes,
            planned,
            executed,
        })
    }

    /// The largest |executed − planned| of each axis, with the planned
    /// position interpolated linearly at each executed sample's time.
    /// Only executed samples inside the planned samples' time span count;
    /// samples of the wrong length and non-finite values are skipped, and
    /// an axis with nothing to compare is left out (so an empty recording
    /// gives an empty list).
    pub fn following_error(&self) -> Vec<(String, f64)> {
        let mut worst: Vec<Option<f64>> = vec![None; self.axes.len()];
        for (_, err) in self.errors() {
            for (w, e) in worst.iter_mut().zip(err) {
                if e.is_finite() {
                    let e = e.abs();
                    *w = Some(w.map_or(e, |w| w.max(e)));
                }
            }
        }
        self.axes
            .iter()
            .zip(worst)
            .filter_map(|(name, w)| w.map(|w| (name.clone(), w)))
            .collect()
    }

    /// How long the planned motion lasts, seconds: from the last sample
    /// before the position first changes to the sample where it last
    /// changes (any axis). 0 when nothing moves (no samples, one sample,
    /// all equal); samples of the wrong length or with non-finite values
    /// are skipped.
    pub fn planned_duration(&self) -> f64 {
        motion_span(&self.usable(&self.planned))
    }

    /// How long the executed motion lasts, seconds, measured as
    /// [`Recording::planned_duration`] measures the planned motion.
    pub fn executed_duration(&self) -> f64 {
        motion_span(&self.usable(&self.executed))
    }

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

    /// The samples of the right length with finite values, in time order.
    fn usable<'a>(&self, samples: &'a [Sample]) -> Vec<&'a Sample> {
        let mut v: Vec<&Sample> = samples
            .iter()
            .filter(|s| {
                s.pos.len() == self.axes.len()
                    && s.t.is_finite()
                    && s.pos.iter().all(|p| p.is_finite())
            })
            .collect();
        if !v.is_sorted_by(|a, b| a.t <= b.t) {
            v.sort_by(|a, b| a.t.total_cmp(&b.t));
        }
        v
    }

    /// (time, executed − planned per axis) at each executed sample of the
    /// right length inside the planned span. Values may be NaN where a
    /// position is.
    fn errors(&self) -> Vec<(f64, Vec<f64>)> {
        let n = self.axes.len();
        let mut planned: Vec<&Sample> = self
            .planned
            .iter()
            .filter(|s| s.pos.len() == n && s.t.is_finite())
            .collect();
        if !planned.is_sorted_by(|a, b| a.t <= b.t) {
            planned.sort_by(|a, b| a.t.total_cmp(&b.t));
        }
        let (Some(first), Some(last)) = (planned.first(), planned.last()) else {
            return Vec::new();
        };
        let span = first.t..=last.t;
        self.executed
            .iter()
            .filter(|e| e.pos.len() == n && span.contains(&e.t))
            .map(|e| {
                let k = planned.partition_point(|s| s.t < e.t);
                let err = match (planned.get(k), k.checked_sub(1).map(|j| planned[j])) {
                    (Some(b), _) if b.t == e.t => sub(&e.pos, &b.pos, |b, _| b),
                    (Some(b), Some(a)) => {
                        let f = (e.t - a.t) / (b.t - a.t);
                        sub(&e.pos, &a.pos, |a, i| a + (b.pos[i] - a) * f)
                    }
                    _ => vec![f64::NAN; n],
                };
                (e.t, err)
            })
            .collect()
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

/// The span of motion in time-ordered samples, seconds: from the last
/// sample before the position first changes to the sample where it last
/// changes; 0 when nothing moves (no samples, one sample, or all equal).
fn motion_span(samples: &[&Sample]) -> f64 {
    let mut start = None;
    let mut end = None;
    for w in samples.windows(2) {
        if w[0].pos != w[1].pos {
            start.get_or_insert(w[0].t);
            end = Some(w[1].t);
        }
    }
    match (start, end) {
        (Some(s), Some(e)) => (e - s).max(0.0),
        _ => 0.0,
    }
}

/// `a[i] - f(b[i], i)` for each axis.
fn sub(a: &[f64], b: &[f64], f: impl Fn(f64, usize) -> f64) -> Vec<f64> {
    a.iter()
        .zip(b)
        .enumerate()
        .map(|(i, (a, b))| a - f(*b, i))
        .collect()
}

fn write_samples(path: &Path, axes: &[String], samples: &[Sample]) -> io::Result<()> {
    let mut w = BufWriter::new(fs::File::create(path)?);
    let mut line = String::from("t");
    for a in axes {
        line.push(',');
        line.push_str(a);
    }
    writeln!(w, "{line}")?;
    for s in samples {
        line.clear();
        // Display prints the shortest text that reads back to the same f64.
        let _ = write!(line, "{}", s.t);
        for p in &s.pos {
            let _ = write!(line, ",{p}");
        }
        writeln!(w, "{line}")?;
    }
    w.flush()
}

fn read_samples(path: &Path) -> Result<(Vec<String>, Vec<Sample>), RecordError> {
    let text = fs::read_to_string(path).map_err(io_err(path))?;
    let parse = |line: usize, message: String| RecordError::Parse {
        path: path.to_path_buf(),
        line,
        message,
    };
    let mut lines = text.lines().enumerate();
    let header = lines.next().map(|(_, l)| l).unwrap_or("");
    let mut cols = header.split(',');
    if cols.next() != Some("t") {
        return Err(parse(
            1,
            format!("header {header:?} does not start with `t`"),
        ));
    }
    let axes: Vec<String> = cols.map(str::to_string).collect();
    let mut samples = Vec::new();
    for (i, l) in lines {
        if l.trim().is_empty() {
            continue;
        }
        let values = l
            .split(',')
            .map(|v| v.trim().parse::<f64>())
            .collect::<Result<Vec<f64>, _>>()
            .map_err(|e| parse(i + 1, format!("{l:?}: {e}")))?;
        if values.len() != axes.len() + 1 {
            return Err(parse(
                i + 1,
                format!("{} values for t and {} axes", values.len(), axes.len()),
            ));
        }
        samples.push(Sample {
            t: values[0],
            pos: values[1..].to_vec(),
        });
    }
    Ok((axes, samples))
}

/// Resamples `(time, value)` samples onto the grid `t0 + k·dt`,
/// `k = 0..n`, holding: each grid time gets the value of the last sample
/// at or before it (the later one of samples with equal times), and a grid
/// time before the first sample gets the first value.
///
/// Samples need not be in time order; samples with a non-finite time or
/// value are skipped. With no usable sample, or at a non-finite grid
/// time, the value is NaN.
pub fn resample_hold(samples: &[(f64, f64)], t0: f64, dt: f64, n: usize) -> Vec<f64> {
    let s = clean(samples);
    grid(t0, dt, n)
        .map(|t| {
            if s.is_empty() || !t.is_finite() {
                return f64::NAN;
            }
            let k = s.partition_point(|q| q.0 <= t);
            s[k.saturating_sub(1)].1
        })
        .collect()
}

/// As [`resample_hold`], interpolating linearly between the samples around
/// each grid time; before the first sample the first value, after the last
/// the last value.
pub fn resample_linear(samples: &[(f64, f64)], t0: f64, dt: f64, n: usize) -> Vec<f64> {
    let s = clean(samples);
    grid(t0, dt, n)
        .map(|t| {
            if s.is_empty() || !t.is_finite() {
                return f64::NAN;
            }
            let k = s.partition_point(|q| q.0 <= t);
            match (k.checked_sub(1).map(|j| s[j]), s.get(k)) {
                (Some(a), Some(b)) => a.1 + (b.1 - a.1) * ((t - a.0) / (b.0 - a.0)),
                (Some(a), None) => a.1,
                (None, Some(b)) => b.1,
                (None, None) => f64::NAN,
            }
        })
        .collect()
}

/// The grid times `t0 + k·dt` (multiplied, not accumulated).
fn grid(t0: f64, dt: f64, n: usize) -> impl Iterator<Item = f64> {
    (0..n).map(move |k| t0 + k as f64 * dt)
}

/// The finite samples, stably sorted by time.
fn clean(samples: &[(f64, f64)]) -> Vec<(f64, f64)> {
    let mut s: Vec<(f64, f64)> = samples
        .iter()
        .copied()
        .filter(|(t, v)| t.is_finite() && v.is_finite())
        .collect();
    if !s.is_sorted_by(|a, b| a.0 <= b.0) {
        s.sort_by(|a, b| a.0.total_cmp(&b.0));
    }
    s
}

/// Speed along the path (Euclidean over all axes) from differences over
/// windows of at least `window` seconds (at least one sample apart), at
/// each window's middle.
fn speeds(samples: &[&Sample], window: f64) -> Vec<(f64, f64)> {
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

fn plot_speed(path: &Path, planned: &[&Sample], executed: &[&Sample]) -> Result<(), RecordError> {
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

type Chart<'a, 'b> = ChartContext<'a, SVGBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

fn draw_line<F: Fn(DrawingAreaErrorKind<io::Error>) -> RecordError>(
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

fn legend<'a, 'b: 'a, F: Fn(DrawingAreaErrorKind<io::Error>) -> RecordError>(
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
fn range(values: impl Iterator<Item = f64>) -> Range<f64> {
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
fn pad(r: Range<f64>) -> Range<f64> {
    let m = (r.end - r.start) * 0.05;
    r.start - m..r.end + m
}

/// Two ranges padded and widened to one span, so a square chart draws the
/// path at equal scales.
fn square(x: Range<f64>, y: Range<f64>) -> (Range<f64>, Range<f64>) {
    let (x, y) = (pad(x), pad(y));
    let half = (x.end - x.start).max(y.end - y.start) / 2.0;
    let (cx, cy) = ((x.start + x.end) / 2.0, (y.start + y.end) / 2.0);
    (cx - half..cx + half, cy - half..cy + half)
}

/// At most [`PLOT_POINTS`] points, every k-th and the last (for paths).
fn reduce_stride(points: &[(f64, f64)]) -> Vec<(f64, f64)> {
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
fn reduce_minmax(points: &[(f64, f64)]) -> Vec<(f64, f64)> {
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

/// A named time series for [`plot_timeline`]: seconds since the run's
/// start on the synchronized clock, and values.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Stream {
    /// Its name, as the legend shows it.
    pub name: String,
    /// (seconds, value), in time order.
    pub points: Vec<(f64, f64)>,
}

/// Velocity of axis `axis` from differences over windows of at least
/// `window` seconds, at each window's middle.
fn axis_velocity(samples: &[&Sample], axis: usize, window: f64) -> Vec<(f64, f64)> {
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
/// ([`crate::capture::Capture::streams`]). Each series is reduced to at
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A fresh directory under the system's temporary directory.
    fn tmp(name: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("osap-machine-record-{name}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        dir
    }

    fn s(t: f64, pos: &[f64]) -> Sample {
        Sample {
            t,
            pos: pos.to_vec(),
        }
    }

    fn axes(names: &[&str]) -> Vec<String> {
        names.iter().map(|n| n.to_string()).collect()
    }

    /// A run at `v` units/s along x and y from 0.1 s to 0.6 s, still before
    /// and after, sampled every `dt` from `t_from`.
    fn ramp(v: f64, dt: f64, t_from: f64, n: usize, delay: f64, offset: [f64; 2]) -> Vec<Sample> {
        (0..n)
            .map(|k| {
                let t = t_from + k as f64 * dt;
                let x = v * ((t - delay).clamp(0.1, 0.6) - 0.1);
                s(t, &[x + offset[0], x + offset[1]])
            })
            .collect()
    }

    #[test]
    fn csv_round_trip() {
        let rec = Recording {
            axes: axes(&["x", "y"]),
            planned: vec![
                s(0.0, &[0.0, 0.0]),
                s(0.001, &[0.1, 1.0 / 3.0]),
                s(0.002, &[-2.5e-7, 1e6]),
            ],
            executed: vec![s(0.0005, &[0.05, f64::NAN])],
        };
        let dir = tmp("csv");
        let files = rec.write_csv(&dir.join("out")).unwrap();
        assert_eq!(
            files,
            vec![dir.join("out/planned.csv"), dir.join("out/executed.csv")]
        );

        // By hand: the header, then t and the positions.
        let text = fs::read_to_string(&files[0]).unwrap();
        let mut lines = text.lines();
        assert_eq!(lines.next(), Some("t,x,y"));
        let rows: Vec<Vec<f64>> = lines
            .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
            .collect();
        assert_eq!(rows.len(), 3);
        assert_eq!(rows[1], vec![0.001, 0.1, 1.0 / 3.0]);
        assert_eq!(rows[2], vec![0.002, -2.5e-7, 1e6]);
        let text = fs::read_to_string(&files[1]).unwrap();
        assert_eq!(text, "t,x,y\n0.0005,0.05,NaN\n");

        // Through the reader (NaN != NaN, so compare the rest).
        let back = Recording::read_csv(&dir.join("out")).unwrap();
        assert_eq!(back.axes, rec.axes);
        assert_eq!(back.planned, rec.planned);
        assert_eq!(back.executed[0].t, 0.0005);
        assert_eq!(back.executed[0].pos[0], 0.05);
        assert!(back.executed[0].pos[1].is_nan());
        let _ = fs::remove_dir_all(&dir);
    }

    #[test]
    fn csv_refuses_mismatched_samples_and_bad_names() {
        let dir = tmp("csv-bad");
        let mut rec = Recording {
            axes: axes(&["x", "y"]),
            planned: vec![s(0.0, &[0.0, 0.0])],
            executed: vec![s(0.0, &[0.0, 0.0]), s(0.001, &[1.0])],
        };
        let e = rec.write_csv(&dir).unwrap_err();
        assert!(
            matches!(
                e,
                RecordError::Shape {
                    index: 1,
                    len: 1,
                    axes: 2,
                    ..
                }
            ),
            "{e:?}"
        );
        assert!(e.to_string().contains("executed.csv"), "{e}");
        assert!(!dir.join(PLANNED_CSV).exists(), "nothing written on error");

        rec.executed.pop();
        rec.axes[1] = "y,z".into();
        let e = rec.write_csv(&dir).unwrap_err();
        assert!(matches!(e, RecordError::AxisName { .. }), "{e:?}");
        assert!(e.to_string().contains("planned.csv"), "{e}");

        // A reader error names the file and line.
        fs::create_dir_all(&dir).unwrap();
        fs::write(dir.join(PLANNED_CSV), "t,x\n0,1\n0.1,oops\n").unwrap();
        let e = Recording::read_csv(&dir).unwrap_err();
        assert!(e.to_string().contains("planned.csv:3"), "{e}");
        fs::write(dir.join(PLANNED_CSV), "").unwrap();
        assert!(Recording::read_csv(&dir).is_err());
        let _ = fs::remove_dir_all(&dir);
    }

    #[test]
    fn following_error_of_offset_and_delay() {
        // Planned every 1 ms; executed every 1 ms but 0.4 ms later, x off by
        // 0.05 and y 10 ms late at 20 units/s: 0.2 behind while moving.
        let planned = ramp(20.0, 0.001, 0.0, 801, 0.0, [0.0, 0.0]);
        let mut executed = ramp(20.0, 0.001, 0.0004, 900, 0.0, [0.05, 0.0]);
        let late = ramp(20.0, 0.001, 0.0004, 900, 0.010, [0.0, 0.0]);
        for (e, l) in executed.iter_mut().zip(&late) {
            e.pos[1] = l.pos[1];
        }
        let rec = Recording {
            axes: axes(&["x", "y"]),
            planned,
            executed,
        };
        let fe = rec.following_error();
        assert_eq!(fe.len(), 2);
        assert_eq!(fe[0].0, "x");
        assert!((fe[0].1 - 0.05).abs() < 1e-9, "{fe:?}");
        assert_eq!(fe[1].0, "y");
        assert!((fe[1].1 - 0.2).abs() < 1e-9, "{fe:?}");

        assert!((rec.planned_duration() - 0.5).abs() < 1e-9);
        // Executed x moves after 0.0994 (its last still sample), y stops at 0.6104.
        assert!(
            (rec.executed_duration() - 0.511).abs() < 1e-9,
            "{}",
            rec.executed_duration()
        );
    }

    #[test]
    fn following_error_skips_what_it_cannot_use() {
        let rec = Recording {
            axes: axes(&["x", "y"]),
            planned: vec![
                s(0.0, &[0.0, 0.0]),
                s(1.0, &[1.0, f64::NAN]),
                s(f64::NAN, &[0.0, 0.0]),
            ],
            executed: vec![
                s(0.5, &[0.75, 0.0]),
                s(0.5, &[9.0]),
                s(2.0, &[9.0, 9.0]),
                s(f64::NAN, &[9.0, 9.0]),
            ],
        };
        // x: 0.75 - 0.5; y: NaN planned, so nothing to compare.
        assert_eq!(rec.following_error(), vec![("x".to_string(), 0.25)]);

        // Planned out of order is sorted first.
        let mut r2 = rec.clone();
        r2.planned.reverse();
        assert_eq!(r2.following_error(), vec![("x".to_string(), 0.25)]);

        // One planned sample: only an executed sample at its time counts.
        let one = Recording {
            axes: axes(&["x"]),
            planned: vec![s(1.0, &[2.0])],
            executed: vec![s(1.0, &[2.5]), s(1.5, &[7.0])],
        };
        assert_eq!(one.following_error(), vec![("x".to_string(), 0.5)]);
        assert_eq!(one.planned_duration(), 0.0);
        assert_eq!(one.executed_duration(), 0.5);
    }

    #[test]
    fn resampling() {
        // Out of order, with a NaN to skip.
        let s = [
            (0.003, 30.0),
            (0.001, 10.0),
            (0.002, f64::NAN),
            (0.005, 50.0),
        ];
        let hold = resample_hold(&s, 0.0, 0.001, 7);
        assert_eq!(hold, vec![10.0, 10.0, 10.0, 30.0, 30.0, 50.0, 50.0]);
        let lin = resample_linear(&s, 0.0, 0.001, 7);
        let want = [10.0, 10.0, 20.0, 30.0, 40.0, 50.0, 50.0];
        for (a, b) in lin.iter().zip(want) {
            assert!((a - b).abs() < 1e-9, "{lin:?}");
        }
        // Between grid points of a finer grid, and equal times.
        let lin = resample_linear(&[(0.0, 0.0), (1.0, 1.0)], 0.25, 0.5, 2);
        assert_eq!(lin, vec![0.25, 0.75]);
        let dup = [(0.0, 1.0), (1.0, 2.0), (1.0, 3.0), (2.0, 3.0)];
        assert_eq!(resample_hold(&dup, 1.0, 1.0, 1), vec![3.0]);
        assert_eq!(resample_linear(&dup, 1.0, 1.0, 1), vec![3.0]);
        assert_eq!(resample_linear(&dup, 0.5, 1.0, 1), vec![1.5]);

        // Nothing usable, or no grid, or a non-finite grid.
        assert!(resample_hold(&[], 0.0, 0.001, 3).iter().all(|v| v.is_nan()));
        assert!(resample_linear(&[(f64::NAN, 1.0)], 0.0, 0.001, 3)
            .iter()
            .all(|v| v.is_nan()));
        assert!(resample_hold(&s, 0.0, 0.001, 0).is_empty());
        assert!(resample_linear(&s, f64::NAN, 0.001, 2)
            .iter()
            .all(|v| v.is_nan()));
        assert_eq!(resample_hold(&[(5.0, 2.0)], 0.0, 1.0, 3), vec![2.0; 3]);

        // Motors read at ~1 kHz, not aligned, onto a common 1 kHz grid.
        let motor: Vec<(f64, f64)> = (0..1000)
            .map(|k| {
                let t = 0.00037 + k as f64 * 0.00097;
                (t, 3.0 * t)
            })
            .collect();
        let on_grid = resample_linear(&motor, 0.001, 0.001, 900);
        for (k, v) in on_grid.iter().enumerate() {
            let t = 0.001 + k as f64 * 0.001;
            assert!((v - 3.0 * t).abs() < 1e-9);
        }
    }

    fn assert_svgs(files: &[PathBuf], names: &[&str]) {
        assert_eq!(files.len(), names.len());
        for (f, n) in files.iter().zip(names) {
            assert!(f.ends_with(n), "{f:?}");
            let text = fs::read_to_string(f).unwrap();
            assert!(text.starts_with("<svg"), "{f:?}");
            assert!(text.trim_end().ends_with("</svg>"), "{f:?}");
        }
    }

    #[test]
    fn plots_written_and_small() {
        // A 20 s run at 1 kHz: 20 000 samples per series, a circle.
        let n = 20_000;
        let circle = |delay: f64, q: f64| -> Vec<Sample> {
            (0..n)
                .map(|k| {
                    let t = k as f64 * 0.001;
                    let a = 0.5 * (t - delay).max(0.0);
                    let x = ((30.0 * a.cos()) / q).round() * q;
                    let y = ((30.0 * a.sin()) / q).round() * q;
                    s(t, &[x, y])
                })
                .collect()
        };
        let rec = Recording {
            axes: axes(&["x", "y"]),
            planned: circle(0.0, 1e-12),
            executed: circle(0.002, 0.0125),
        };
        let dir = tmp("plot");
        let files = rec.plot(&dir).unwrap();
        assert_svgs(&files, &["path.svg", "speed.svg", "error.svg"]);
        for f in &files {
            let len = fs::metadata(f).unwrap().len();
            assert!(len > 1000 && len < 400_000, "{f:?}: {len} bytes");
        }
        // The executed speed, from 5 ms windows over 12.5 µm steps, stays
        // within √2 · 12.5 µm / 5 ms = 3.54 units/s of 15 (30 · 0.5), and
        // averages to it.
        let usable = rec.usable(&rec.executed);
        let v = speeds(&usable, SPEED_WINDOW_S);
        assert!(v[100..].iter().all(|(_, v)| (v - 15.0).abs() < 3.6));
        let mean = v[100..].iter().map(|(_, v)| v).sum::<f64>() / (v.len() - 100) as f64;
        assert!((mean - 15.0).abs() < 0.05, "{mean}");
        assert!(v.windows(2).all(|w| w[1].0 - w[0].0 > 0.0));

        // One axis: position against time.
        let one = Recording {
            axes: axes(&["z"]),
            planned: ramp(20.0, 0.001, 0.0, 700, 0.0, [0.0, 0.0])
                .into_iter()
                .map(|s| Sample {
                    t: s.t,
                    pos: vec![s.pos[0]],
                })
                .collect(),
            executed: vec![s(0.2, &[2.0])],
        };
        assert_svgs(
            &one.plot(&dir.join("one")).unwrap(),
            &["path.svg", "speed.svg", "error.svg"],
        );
        let _ = fs::remove_dir_all(&dir);
    }

    #[test]
    fn empty_and_degenerate_recordings() {
        let dir = tmp("empty");
        let empty = Recording::default();
        assert_eq!(empty.following_error(), vec![]);
        assert_eq!(empty.planned_duration(), 0.0);
        assert_eq!(empty.executed_duration(), 0.0);
        let files = empty.write_csv(&dir).unwrap();
        assert_eq!(fs::read_to_string(&files[0]).unwrap(), "t\n");
        assert_eq!(Recording::read_csv(&dir).unwrap(), empty);
        assert_svgs(
            &empty.plot(&dir).unwrap(),
            &["path.svg", "speed.svg", "error.svg"],
        );

        // Axes but no samples, single samples, NaN and mismatched lengths.
        let odd = [
            Recording {
                axes: axes(&["x", "y"]),
                ..Recording::default()
            },
            Recording {
                axes: axes(&["x", "y"]),
                planned: vec![s(0.0, &[1.0, 2.0])],
                executed: vec![s(0.0, &[1.0, 2.0])],
            },
            Recording {
                axes: axes(&["x", "y", "z"]),
                planned: vec![
                    s(0.0, &[f64::NAN; 3]),
                    s(f64::NAN, &[1.0; 3]),
                    s(1.0, &[1.0]),
                ],
                executed: vec![s(0.5, &[]), s(0.5, &[f64::INFINITY, 0.0, f64::NAN])],
            },
        ];
        for (i, rec) in odd.iter().enumerate() {
            let sub = dir.join(format!("odd{i}"));
            assert_svgs(
                &rec.plot(&sub).unwrap(),
                &["path.svg", "speed.svg", "error.svg"],
            );
            let _ = rec.following_error();
            assert_eq!(rec.planned_duration(), 0.0);
            assert_eq!(rec.executed_duration(), 0.0);
        }
        assert!(odd[2].write_csv(&dir.join("odd2")).is_err());
        assert_eq!(odd[1].following_error().len(), 2);
        let _ = fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_timeline_stacks_motion_and_streams() {
        let dir = std::env::temp_dir().join(format!("osap-timeline-{}", std::process::id()));
        let rec = Recording {
            axes: vec!["x".into()],
            planned: (0..100)
                .map(|i| Sample {
                    t: i as f64 * 0.01,
                    pos: vec![i as f64],
                })
                .collect(),
            executed: (0..100)
                .map(|i| Sample {
                    t: i as f64 * 0.01,
                    pos: vec![i as f64 - 0.1],
                })
                .collect(),
        };
        let stream = Stream {
            name: "z.analog_read(0).value".into(),
            points: (0..500)
                .map(|i| (i as f64 * 0.002, (i as f64).sin()))
                .collect(),
        };
        let path = dir.join("timeline.svg");
        plot_timeline(&path, Some(&rec), std::slice::from_ref(&stream)).unwrap();
        let svg = std::fs::read_to_string(&path).unwrap();
        assert!(svg.contains("following error") && svg.contains("z.analog_read(0).value"));
        plot_timeline(&path, None, &[stream]).unwrap();
        assert!(plot_timeline(&path, None, &[]).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
