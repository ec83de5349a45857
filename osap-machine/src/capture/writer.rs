//! Sample files: what a [`Recorder`](super::Recorder) writes, streamed to
//! disk with bounded memory, and read back.
//!
//! One row per sample value, in the "long" layout every data frame library
//! reads directly:
//!
//! | column | type | meaning |
//! |---|---|---|
//! | `time_us` | `u64` | the sample's synchronized time, µs |
//! | `series` | string (dictionary of the series names) | e.g. `z.analog_read.value` |
//! | `value` | `f64` | the value (bools as 0 or 1) |
//!
//! Parquet files are snappy-compressed. Rows are gathered into Arrow
//! batches of [`WriterOptions::batch_rows`] and written into row groups of
//! [`WriterOptions::row_group_rows`], each flushed to disk as it fills, so
//! memory stays bounded however long the capture. Each series' clock
//! ([`Clock`]) goes in the file's key-value metadata (`osap.series`, one
//! `name<TAB>clock` line per series). CSV files have the header
//! `time_us,series,value` and one line per row.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use arrow_array::types::UInt16Type;
use arrow_array::{
    Array, ArrayRef, DictionaryArray, Float64Array, RecordBatch, StringArray, UInt16Array,
    UInt64Array,
};
use arrow_schema::{DataType, Field, Schema, SchemaRef};
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
use parquet::arrow::ArrowWriter;
use parquet::basic::Compression;
use parquet::file::metadata::KeyValue;
use parquet::file::properties::WriterProperties;

use super::CaptureError;

/// The key of the series list in a Parquet file's metadata.
pub const SERIES_KEY: &str = "osap.series";

/// A sample file's format, chosen by its extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// Apache Parquet, snappy-compressed (`.parquet`).
    Parquet,
    /// Comma-separated text (`.csv`).
    Csv,
}

impl Format {
    /// The format `path`'s extension names (`.parquet` or `.csv`, any
    /// case).
    pub fn from_path(path: &Path) -> Result<Format, CaptureError> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        match ext.as_deref() {
            Some("parquet") => Ok(Format::Parquet),
            Some("csv") => Ok(Format::Csv),
            _ => Err(CaptureError::Format {
                path: path.to_path_buf(),
            }),
        }
    }
}

/// Whose clock stamped a series' samples.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Clock {
    /// The source's own synchronized time stamp (its `time` output).
    Source,
    /// The host's synchronized time when the sample arrived: for functions
    /// without a `time` output (step counters, status). Later than the
    /// source's by the link's latency.
    Arrival,
}

impl Clock {
    fn name(self) -> &'static str {
        match self {
            Clock::Source => "source",
            Clock::Arrival => "arrival",
        }
    }

    fn parse(s: &str) -> Option<Clock> {
        match s {
            "source" => Some(Clock::Source),
            "arrival" => Some(Clock::Arrival),
            _ => None,
        }
    }
}

/// A series: one numeric output of one source.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SeriesInfo {
    /// `MODULE.FUNCTION.OUTPUT`, as the file names it.
    pub name: String,
    /// Whose clock stamps it.
    pub clock: Clock,
}

/// One sample value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Row {
    /// Synchronized time, µs.
    pub time_us: u64,
    /// Index of its series in the writer's list.
    pub series: u16,
    /// The value.
    pub value: f64,
}

/// How rows are gathered before they reach the disk.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WriterOptions {
    /// Rows per Parquet row group: each is flushed to disk as it fills.
    pub row_group_rows: usize,
    /// Rows per Arrow batch handed to the Parquet writer.
    pub batch_rows: usize,
}

impl Default for WriterOptions {
    fn default() -> Self {
        WriterOptions {
            row_group_rows: 65_536,
            batch_rows: 8_192,
        }
    }
}

/// Per series: samples written and the span of their times.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct SeriesStats {
    /// Rows written.
    pub rows: u64,
    /// The first time, µs.
    pub first_us: Option<u64>,
    /// The last time, µs.
    pub last_us: Option<u64>,
}

enum Sink {
    Parquet {
        writer: Box<ArrowWriter<BufWriter<File>>>,
        schema: SchemaRef,
        names: ArrayRef,
    },
    Csv(BufWriter<File>),
}

/// Writes rows to a sample file as they come (see the module docs).
pub struct SampleWriter {
    path: PathBuf,
    series: Vec<SeriesInfo>,
    sink: Sink,
    options: WriterOptions,
    times: Vec<u64>,
    keys: Vec<u16>,
    values: Vec<f64>,
    stats: Vec<SeriesStats>,
    text: String,
}

impl std::fmt::Debug for SampleWriter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Its parts are tasks, locks and buffers: the name says enough.
        f.debug_struct("SampleWriter").finish_non_exhaustive()
    }
}

fn io_error(path: &Path) -> impl Fn(std::io::Error) -> CaptureError + '_ {
    move |source| CaptureError::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn parquet_error(path: &Path) -> impl Fn(parquet::errors::ParquetError) -> CaptureError + '_ {
    move |e| match e {
        // A full disk or a lost mount, as the system said it.
        parquet::errors::ParquetError::External(inner) => {
            match inner.downcast::<std::io::Error>() {
                Ok(io) => CaptureError::Io {
                    path: path.to_path_buf(),
                    source: *io,
                },
                Err(other) => CaptureError::Parquet {
                    path: path.to_path_buf(),
                    message: other.to_string(),
                },
            }
        }
        other => CaptureError::Parquet {
            path: path.to_path_buf(),
            message: other.to_string(),
        },
    }
}

/// The Arrow schema of a sample file.
pub fn schema() -> SchemaRef {
    Arc::new(Schema::new(vec![
        Field::new("time_us", DataType::UInt64, false),
        Field::new(
            "series",
            DataType::Dictionary(Box::new(DataType::UInt16), Box::new(DataType::Utf8)),
            false,
        ),
        Field::new("value", DataType::Float64, false),
    ]))
}

impl SampleWriter {
    /// Creates (or truncates) `path` in the format its extension names.
    pub fn create(
        path: &Path,
        series: &[SeriesInfo],
        options: WriterOptions,
    ) -> Result<SampleWriter, CaptureError> {
        Self::create_as(path, Format::from_path(path)?, series, options)
    }

    /// Creates (or truncates) `path` in `format`, whatever its name.
    pub fn create_as(
        path: &Path,
        format: Format,
        series: &[SeriesInfo],
        options: WriterOptions,
    ) -> Result<SampleWriter, CaptureError> {
        if series.len() > usize::from(u16::MAX) {
            return Err(CaptureError::BadOptions(format!(
                "{} series: a file holds at most {}",
                series.len(),
                u16::MAX
            )));
        }
        if options.row_group_rows == 0 || options.batch_rows == 0 {
            return Err(CaptureError::BadOptions(
                "row_group_rows and batch_rows must be > 0".into(),
            ));
        }
        for s in series {
            if s.name.contains([',', '"', '\n', '\r', '\t']) {
                return Err(CaptureError::BadSource {
                    source_name: s.name.clone(),
                    reason: "a series name may not hold a comma, quote, tab or line break".into(),
                });
            }
        }
        let file = File::create(path).map_err(io_error(path))?;
        // Large enough that a batch is a few system calls.
        let out = BufWriter::with_capacity(1 << 20, file);
        let sink = match format {
            Format::Parquet => {
                let listing: String = series
                    .iter()
                    .map(|s| format!("{}\t{}\n", s.name, s.clock.name()))
                    .collect();
                let props = WriterProperties::builder()
                    .set_compression(Compression::SNAPPY)
                    .set_max_row_group_row_count(Some(options.row_group_rows))
                    .set_key_value_metadata(Some(vec![KeyValue::new(
                        SERIES_KEY.to_string(),
                        listing,
                    )]))
                    .build();
                let schema = schema();
                let writer = ArrowWriter::try_new(out, schema.clone(), Some(props))
                    .map_err(parquet_error(path))?;
                let names: ArrayRef = Arc::new(StringArray::from_iter_values(
                    series.iter().map(|s| s.name.as_str()),
                ));
                Sink::Parquet {
                    writer: Box::new(writer),
                    schema,
                    names,
                }
            }
            Format::Csv => {
                let mut out = out;
                out.write_all(b"time_us,series,value\n")
                    .map_err(io_error(path))?;
                Sink::Csv(out)
            }
        };
        Ok(SampleWriter {
            path: path.to_path_buf(),
            series: series.to_vec(),
            sink,
            options,
            times: Vec::with_capacity(options.batch_rows),
            keys: Vec::with_capacity(options.batch_rows),
            values: Vec::with_capacity(options.batch_rows),
            stats: vec![SeriesStats::default(); series.len()],
            text: String::new(),
        })
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Adds a row; a full batch goes to the file. A row of a series the
    /// writer does not list is refused.
    pub fn push(&mut self, row: Row) -> Result<(), CaptureError> {
        let Some(stats) = self.stats.get_mut(usize::from(row.series)) else {
            return Err(CaptureError::BadOptions(format!(
                "row of series {} but the file lists {}",
                row.series,
                self.series.len()
            )));
        };
        stats.rows += 1;
        stats.first_us.get_or_insert(row.time_us);
        stats.last_us = Some(row.time_us);
        self.times.push(row.time_us);
        self.keys.push(row.series);
        self.values.push(row.value);
        if self.times.len() >= self.options.batch_rows {
            self.write_batch()?;
        }
        Ok(())
    }

    fn write_batch(&mut self) -> Result<(), CaptureError> {
        if self.times.is_empty() {
            return Ok(());
        }
        let path = self.path.clone();
        match &mut self.sink {
            Sink::Parquet {
                writer,
                schema,
                names,
            } => {
                let keys = UInt16Array::from(std::mem::take(&mut self.keys));
                let series =
                    DictionaryArray::<UInt16Type>::try_new(keys, names.clone()).map_err(|e| {
                        CaptureError::Parquet {
                            path: path.clone(),
                            message: e.to_string(),
                        }
                    })?;
                let batch = RecordBatch::try_new(
                    schema.clone(),
                    vec![
                        Arc::new(UInt64Array::from(std::mem::take(&mut self.times))),
                        Arc::new(series),
                        Arc::new(Float64Array::from(std::mem::take(&mut self.values))),
                    ],
                )
                .map_err(|e| CaptureError::Parquet {
                    path: path.clone(),
                    message: e.to_string(),
                })?;
                writer.write(&batch).map_err(parquet_error(&path))?;
                self.times.reserve(self.options.batch_rows);
                self.keys.reserve(self.options.batch_rows);
                self.values.reserve(self.options.batch_rows);
            }
            Sink::Csv(out) => {
                use std::fmt::Write as _;
                self.text.clear();
                for ((t, k), v) in self.times.iter().zip(&self.keys).zip(&self.values) {
                    let name = &self.series[usize::from(*k)].name;
                    // `{}` prints the shortest text that reads back exactly.
                    let _ = writeln!(self.text, "{t},{name},{v}");
                }
                out.write_all(self.text.as_bytes())
                    .map_err(io_error(&path))?;
                self.times.clear();
                self.keys.clear();
                self.values.clear();
            }
        }
        Ok(())
    }

    /// Writes what is gathered and pushes it to the operating system (a
    /// Parquet row group is closed early).
    pub fn flush(&mut self) -> Result<(), CaptureError> {
        self.write_batch()?;
        let path = self.path.clone();
        match &mut self.sink {
            Sink::Parquet { writer, .. } => writer.flush().map_err(parquet_error(&path)),
            Sink::Csv(out) => out.flush().map_err(io_error(&path)),
        }
    }

    /// Writes the rest and closes the file properly (a Parquet file gets
    /// its footer; without it nothing in it can be read). Returns the
    /// per-series statistics.
    pub fn finish(mut self) -> Result<Vec<SeriesStats>, CaptureError> {
        self.write_batch()?;
        let path = self.path.clone();
        let out = match self.sink {
            Sink::Parquet { writer, .. } => writer.into_inner().map_err(parquet_error(&path))?,
            Sink::Csv(out) => out,
        };
        let file = out
            .into_inner()
            .map_err(|e| io_error(&path)(e.into_error()))?;
        file.sync_all().map_err(io_error(&path))?;
        Ok(self.stats)
    }
}

/// A series read back from a sample file.
#[derive(Debug, Clone, PartialEq)]
pub struct SeriesData {
    /// Its name.
    pub name: String,
    /// Whose clock stamped it (Parquet files say; CSV files do not).
    pub clock: Option<Clock>,
    /// Synchronized times, µs, in file order.
    pub time_us: Vec<u64>,
    /// Values.
    pub value: Vec<f64>,
}

/// A sample file read back: its series, in the order they first appear
/// (Parquet: in the file's list).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Capture {
    /// The series.
    pub series: Vec<SeriesData>,
}

impl Capture {
    /// Reads a sample file (format by extension).
    pub fn read(path: &Path) -> Result<Capture, CaptureError> {
        match Format::from_path(path)? {
            Format::Parquet => read_parquet(path),
            Format::Csv => read_csv(path),
        }
    }

    /// The series named `name`.
    pub fn get(&self, name: &str) -> Option<&SeriesData> {
        self.series.iter().find(|s| s.name == name)
    }

    /// Every series as a [`Stream`](crate::record::Stream) for
    /// [`plot_timeline`](crate::record::plot_timeline): times in seconds
    /// since synchronized time `origin_us` (the `from_us` of the machine's
    /// own recording, to align with it).
    pub fn streams(&self, origin_us: u64) -> Vec<crate::record::Stream> {
        self.series
            .iter()
            .map(|s| crate::record::Stream {
                name: s.name.clone(),
                points: s
                    .time_us
                    .iter()
                    .zip(&s.value)
                    .map(|(t, v)| ((*t as f64 - origin_us as f64) * 1e-6, *v))
                    .collect(),
            })
            .collect()
    }

    /// Rows in all series.
    pub fn rows(&self) -> usize {
        self.series.iter().map(|s| s.time_us.len()).sum()
    }

    fn series_mut(&mut self, name: &str) -> &mut SeriesData {
        let i = match self.series.iter().position(|s| s.name == name) {
            Some(i) => i,
            None => {
                self.series.push(SeriesData {
                    name: name.to_string(),
                    clock: None,
                    time_us: Vec::new(),
                    value: Vec::new(),
                });
                self.series.len() - 1
            }
        };
        &mut self.series[i]
    }
}

fn read_error(path: &Path, message: impl Into<String>) -> CaptureError {
    CaptureError::Read {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

fn read_parquet(path: &Path) -> Result<Capture, CaptureError> {
    let file = File::open(path).map_err(io_error(path))?;
    let builder = ParquetRecordBatchReaderBuilder::try_new(file)
        .map_err(|e| read_error(path, e.to_string()))?;
    let mut capture = Capture::default();
    if let Some(kv) = builder.metadata().file_metadata().key_value_metadata() {
        let listing = kv
            .iter()
            .find(|k| k.key == SERIES_KEY)
            .and_then(|k| k.value.as_deref())
            .unwrap_or("");
        for line in listing.lines().filter(|l| !l.is_empty()) {
            let (name, clock) = line.split_once('\t').unwrap_or((line, ""));
            capture.series_mut(name).clock = Clock::parse(clock);
        }
    }
    let reader = builder
        .with_batch_size(65_536)
        .build()
        .map_err(|e| read_error(path, e.to_string()))?;
    let bad_column = |c: &str| read_error(path, format!("column {c} missing or of the wrong type"));
    for batch in reader {
        let batch = batch.map_err(|e| read_error(path, e.to_string()))?;
        let times = batch
            .column_by_name("time_us")
            .and_then(|c| c.as_any().downcast_ref::<UInt64Array>())
            .ok_or_else(|| bad_column("time_us"))?;
        let values = batch
            .column_by_name("value")
            .and_then(|c| c.as_any().downcast_ref::<Float64Array>())
            .ok_or_else(|| bad_column("value"))?;
        let series = batch
            .column_by_name("series")
            .ok_or_else(|| bad_column("series"))?;
        let names: Vec<String> = if let Some(d) = series
            .as_any()
            .downcast_ref::<DictionaryArray<UInt16Type>>()
        {
            let dict = d
                .values()
                .as_any()
                .downcast_ref::<StringArray>()
                .ok_or_else(|| bad_column("series"))?;
            d.keys()
                .iter()
                .map(|k| {
                    k.and_then(|k| {
                        let k = usize::from(k);
                        (k < dict.len()).then(|| dict.value(k).to_string())
                    })
                    .ok_or_else(|| bad_column("series"))
                })
                .collect::<Result<_, _>>()?
        } else if let Some(s) = series.as_any().downcast_ref::<StringArray>() {
            s.iter()
                .map(|v| v.map(str::to_string).ok_or_else(|| bad_column("series")))
                .collect::<Result<_, _>>()?
        } else {
            return Err(bad_column("series"));
        };
        for (i, name) in names.iter().enumerate() {
            let s = capture.series_mut(name);
            s.time_us.push(times.value(i));
            s.value.push(values.value(i));
        }
    }
    Ok(capture)
}

fn read_csv(path: &Path) -> Result<Capture, CaptureError> {
    let text = std::fs::read_to_string(path).map_err(io_error(path))?;
    let mut lines = text.lines().enumerate();
    match lines.next() {
        Some((_, "time_us,series,value")) => {}
        _ => {
            return Err(read_error(
                path,
                "line 1: expected the header time_us,series,value",
            ))
        }
    }
    let mut capture = Capture::default();
    for (i, line) in lines {
        if line.is_empty() {
            continue;
        }
        let bad = || {
            read_error(
                path,
                format!("line {}: expected TIME_US,SERIES,VALUE", i + 1),
            )
        };
        let mut parts = line.splitn(3, ',');
        let (Some(t), Some(name), Some(v)) = (parts.next(), parts.next(), parts.next()) else {
            return Err(bad());
        };
        let t: u64 = t.parse().map_err(|_| bad())?;
        let v: f64 = v.parse().map_err(|_| bad())?;
        let s = capture.series_mut(name);
        s.time_us.push(t);
        s.value.push(v);
    }
    Ok(capture)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn series() -> Vec<SeriesInfo> {
        vec![
            SeriesInfo {
                name: "z.analog_read.value".into(),
                clock: Clock::Source,
            },
            SeriesInfo {
                name: "a.get_steps.steps".into(),
                clock: Clock::Arrival,
            },
        ]
    }

    fn rows(n: u64) -> impl Iterator<Item = Row> {
        (0..n).map(|i| Row {
            time_us: 1_000_000 + i * 500,
            series: (i % 2) as u16,
            value: i as f64 * 0.25 - 3.0,
        })
    }

    fn round_trip(ext: &str) {
        let dir = std::env::temp_dir().join(format!("osap-capture-writer-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(format!("t.{ext}"));
        let options = WriterOptions {
            row_group_rows: 1000,
            batch_rows: 300,
        };
        let mut w = SampleWriter::create(&path, &series(), options).unwrap();
        for r in rows(5001) {
            w.push(r).unwrap();
        }
        let stats = w.finish().unwrap();
        assert_eq!(stats[0].rows, 2501);
        assert_eq!(stats[1].rows, 2500);
        let c = Capture::read(&path).unwrap();
        assert_eq!(c.rows(), 5001);
        let a = c.get("z.analog_read.value").unwrap();
        assert_eq!(a.time_us[1], 1_001_000);
        assert_eq!(a.value[1], 2.0 * 0.25 - 3.0);
        if ext == "parquet" {
            assert_eq!(a.clock, Some(Clock::Source));
            assert_eq!(
                c.get("a.get_steps.steps").unwrap().clock,
                Some(Clock::Arrival)
            );
        }
        std::fs::remove_file(&path).unwrap();
    }

    #[test]
    fn parquet_round_trips_across_row_groups() {
        round_trip("parquet");
    }

    #[test]
    fn csv_round_trips() {
        round_trip("csv");
    }

    #[test]
    fn an_unknown_extension_is_refused_naming_the_formats() {
        let e = SampleWriter::create(Path::new("x.txt"), &series(), WriterOptions::default())
            .err()
            .unwrap();
        assert!(e.to_string().contains(".parquet or .csv"), "{e}");
    }

    #[test]
    fn a_full_disk_is_an_error_not_a_panic() {
        let full = Path::new("/dev/full");
        if !full.exists() {
            return;
        }
        for format in [Format::Parquet, Format::Csv] {
            let mut w =
                SampleWriter::create_as(full, format, &series(), WriterOptions::default()).unwrap();
            let mut failed = None;
            for r in rows(200_000) {
                if let Err(e) = w.push(r) {
                    failed = Some(e);
                    break;
                }
            }
            let e = match failed {
                Some(e) => e,
                None => w.finish().expect_err("writing to /dev/full fails"),
            };
            assert!(e.to_string().contains("No space left"), "{format:?}: {e}");
        }
    }
}
