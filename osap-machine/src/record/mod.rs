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

use std::fmt::Write as _;
use std::fs;
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use thiserror::Error;

#[cfg(feature = "plot")]
pub(crate) mod plot;
#[cfg(feature = "plot")]
pub use plot::plot_timeline;

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
    /// The planned positions, in time order: what the motors were sent,
    /// after input shaping.
    pub planned: Vec<Sample>,
    /// The executed positions (readbacks through forward kinematics), in
    /// time order.
    pub executed: Vec<Sample>,
    /// The planner's positions before input shaping, at the times of
    /// [`Recording::planned`] (the same positions without a shaper; empty
    /// when not known, as for a recording read back from CSV).
    pub unshaped: Vec<Sample>,
    /// A simulated run's vibration of each axis with a simulated
    /// resonance: (axis name, one value per [`Recording::executed`]
    /// sample, machine units). Written as `vibration_AXIS` columns of
    /// `executed.csv`.
    pub vibration: Vec<(String, Vec<f64>)>,
    /// A simulated run's stalled motors: (motor key, 1 at every
    /// [`Recording::executed`] sample while the motor was stalled, else
    /// 0). Written as `stalled_MOTOR` columns of `executed.csv`.
    pub stalled: Vec<(String, Vec<f64>)>,
    /// The output each streamed tool's module drove: (tool key, one PWM
    /// duty per [`Recording::executed`] sample, interpolated between the
    /// module's readbacks). Written as `tool_TOOL` columns of
    /// `executed.csv`.
    pub tools: Vec<(String, Vec<f64>)>,
    /// The module's readbacks behind [`Recording::tools`]: (tool key, (s
    /// since the start, duty) as `level_read` reported them). Not written.
    pub tool_readbacks: Vec<(String, Vec<(f64, f64)>)>,
}

/// The prefix of a vibration column's name in `executed.csv`.
pub const VIBRATION_PREFIX: &str = "vibration_";
/// The prefix of a stalled motor's column in `executed.csv`.
pub const STALLED_PREFIX: &str = "stalled_";
/// The prefix of a streamed tool's applied duty column in `executed.csv`.
pub const TOOL_PREFIX: &str = "tool_";

/// Why a recording could not be written or read; every variant names the
/// file.
#[derive(Debug, Error)]
#[non_exhaustive]
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
    /// An extra column does not have one value per sample.
    #[error("{}: column {name} has {len} values for {samples} samples", .path.display())]
    Column {
        /// The file it would have gone to.
        path: PathBuf,
        /// The column.
        name: String,
        /// How many values it has.
        len: usize,
        /// How many samples the file has.
        samples: usize,
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

pub(crate) fn create_dir(dir: &Path) -> Result<(), RecordError> {
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
        let executed_extra: Vec<(String, &[f64])> = self
            .vibration
            .iter()
            .map(|(a, v)| (format!("{VIBRATION_PREFIX}{a}"), &v[..]))
            .chain(
                self.stalled
                    .iter()
                    .map(|(m, v)| (format!("{STALLED_PREFIX}{m}"), &v[..])),
            )
            .chain(
                self.tools
                    .iter()
                    .map(|(t, v)| (format!("{TOOL_PREFIX}{t}"), &v[..])),
            )
            .collect();
        let files = [
            (dir.join(PLANNED_CSV), &self.planned, &[][..]),
            (dir.join(EXECUTED_CSV), &self.executed, &executed_extra[..]),
        ];
        for (path, samples, extra) in &files {
            if let Some((name, values)) = extra.iter().find(|(_, v)| v.len() != samples.len()) {
                return Err(RecordError::Column {
                    path: path.clone(),
                    name: name.clone(),
                    len: values.len(),
                    samples: samples.len(),
                });
            }
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
        for (path, samples, extra) in files {
            write_samples(&path, &self.axes, samples, extra).map_err(io_err(&path))?;
            written.push(path);
        }
        Ok(written)
    }

    /// Reads back what [`Recording::write_csv`] wrote in `dir`. Both files
    /// must name the same axes.
    pub fn read_csv(dir: &Path) -> Result<Recording, RecordError> {
        let (axes, planned, _) = read_samples(&dir.join(PLANNED_CSV))?;
        let path = dir.join(EXECUTED_CSV);
        let (executed_axes, executed, extra) = read_samples(&path)?;
        let pick = |prefix: &str| -> Vec<(String, Vec<f64>)> {
            extra
                .iter()
                .filter_map(|(n, v)| Some((n.strip_prefix(prefix)?.to_string(), v.clone())))
                .collect()
        };
        let (vibration, stalled) = (pick(VIBRATION_PREFIX), pick(STALLED_PREFIX));
        let tools = pick(TOOL_PREFIX);
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
            unshaped: Vec::new(),
            vibration,
            stalled,
            tools,
            tool_readbacks: Vec::new(),
        })
    }

    /// The largest vibration of each axis that has a vibration column
    /// (non-finite values skipped).
    pub fn largest_vibration(&self) -> Vec<(String, f64)> {
        self.vibration
            .iter()
            .map(|(axis, v)| {
                let worst = v
                    .iter()
                    .filter(|x| x.is_finite())
                    .fold(0.0f64, |a, b| a.max(b.abs()));
                (axis.clone(), worst)
            })
            .collect()
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

/// Writes `t,<axes>,<extra columns>`: each extra column (its full name)
/// has one value per sample (checked by the caller).
fn write_samples(
    path: &Path,
    axes: &[String],
    samples: &[Sample],
    extra: &[(String, &[f64])],
) -> io::Result<()> {
    let mut w = BufWriter::new(fs::File::create(path)?);
    let mut line = String::from("t");
    for a in axes {
        line.push(',');
        line.push_str(a);
    }
    for (name, _) in extra {
        line.push(',');
        line.push_str(name);
    }
    writeln!(w, "{line}")?;
    for (i, s) in samples.iter().enumerate() {
        line.clear();
        // Display prints the shortest text that reads back to the same f64.
        let _ = write!(line, "{}", s.t);
        for p in &s.pos {
            let _ = write!(line, ",{p}");
        }
        for (_, v) in extra {
            let _ = write!(line, ",{}", v[i]);
        }
        writeln!(w, "{line}")?;
    }
    w.flush()
}

/// The axes, the samples and any further columns (full names) of a
/// recording's CSV.
type ReadSamples = (Vec<String>, Vec<Sample>, Vec<(String, Vec<f64>)>);

fn read_samples(path: &Path) -> Result<ReadSamples, RecordError> {
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
    let names: Vec<String> = cols.map(str::to_string).collect();
    // Vibration, stall and tool columns come after the axes.
    let split = names
        .iter()
        .position(|n| {
            [VIBRATION_PREFIX, STALLED_PREFIX, TOOL_PREFIX]
                .iter()
                .any(|p| n.starts_with(p))
        })
        .unwrap_or(names.len());
    let axes = names[..split].to_vec();
    let mut vibration: Vec<(String, Vec<f64>)> = names[split..]
        .iter()
        .map(|n| (n.clone(), Vec::new()))
        .collect();
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
        if values.len() != names.len() + 1 {
            return Err(parse(
                i + 1,
                format!("{} values for t and {} columns", values.len(), names.len()),
            ));
        }
        samples.push(Sample {
            t: values[0],
            pos: values[1..=split].to_vec(),
        });
        for (col, v) in vibration.iter_mut().zip(&values[split + 1..]) {
            col.1.push(*v);
        }
    }
    Ok((axes, samples, vibration))
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

/// A named time series (for `plot_timeline`): seconds since the run's
/// start on the synchronized clock, and values.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Stream {
    /// Its name, as the legend shows it.
    pub name: String,
    /// (seconds, value), in time order.
    pub points: Vec<(f64, f64)>,
}

#[cfg(all(test, feature = "plot"))]
mod tests;
