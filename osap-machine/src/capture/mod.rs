//! Captures: any numeric function output, sampled over pipes beside a job
//! and streamed to a Parquet or CSV file, each sample with its source's
//! synchronized time stamp.
//!
//! ```no_run
//! # async fn f(machine: osap_machine::Machine) -> Result<(), Box<dyn std::error::Error>> {
//! use osap_machine::capture::RecordOptions;
//! let options = RecordOptions::new("run.parquet").period_us(1_000);
//! let recorder = machine.record(&["z.analog_read(0)", "a.get_position"], options).await?;
//! // ... run a job ...
//! let file = recorder.finish().await?;
//! println!("{} rows in {}", file.rows, file.path.display());
//! # Ok(()) }
//! ```
//!
//! A source is `MODULE.FUNCTION[(ARG, ..)][.OUTPUT]`:
//!
//! - `MODULE` is a `[modules]` key of the machine file, or the runtime name
//!   of any module on the network;
//! - `FUNCTION` is one of its PIPES functions; arguments fill its inputs
//!   in order (`analog_read(2)` samples channel 2); inputs not given are 0;
//! - `OUTPUT` picks one output; without it every numeric output but `time`
//!   is recorded. Each becomes a series `MODULE.FUNCTION.OUTPUT` (with the
//!   arguments when there are any: `z.analog_read(2).value`).
//!
//! Numeric means an integer, a float or a bool (0 or 1); strings, arrays
//! and tensors are refused, as are unknown modules, functions and outputs,
//! all before anything is started.
//!
//! **Time stamps.** A function with a `time: u64` output (`get_position`,
//! `analog_read`, `digital_read`, `read_limit`, ..) stamps each sample
//! itself, on the synchronized clock: [`Clock::Source`]. Samples of other
//! functions (`get_steps`, `get_status`) are stamped with the host's
//! synchronized time when they arrive ([`Clock::Arrival`]), later by the
//! link's latency. Per series, samples are kept in time order: one that
//! arrives with a time not after the last kept (a datagram overtaken on a
//! multi-hop link, or an unchanged `read_limit`) is counted as stale and
//! not written.
//!
//! **How.** Each module samples its sources itself: its `sample_block`
//! function (see [`osap_module::sampler`]) runs up to three of them on the
//! module's timer every [`RecordOptions::period_us`], and sends their
//! samples in blocks, one datagram per block (when full, or
//! [`BLOCK_LATENCY_US`] after its first sample), stamped on the
//! synchronized clock and numbered. The recorder's host function for the
//! module decodes each block into rows; samples in a block that never
//! arrived are counted from the numbers, as they happen
//! ([`RecorderStats::lost_at_source`]): loss is never silent. Functions
//! without a `time` output take the module's stamp, so every series of a
//! block is on the source clock.
//!
//! A source `sample_block` cannot take (a module without it, or whose
//! `sample_block` another capture holds; a function whose inputs are not
//! one `u8`; a fourth source on one module) is sampled one datagram a
//! sample: the recorder pipes the source's outputs to a host function (a
//! free pipe slot of the source) and runs the source on its module's timer.
//! Such a source the machine already runs faster (its fault and limit
//! reports) keeps its own period; its timer goes back to what it was when
//! the recorder finishes, and what its pipe could not send is read from the
//! module then.
//!
//! Either way the host function hands each sample to a writer thread
//! through a queue of [`RecordOptions::queue_rows`]; a sample that finds
//! the queue full is dropped and counted, so a slow disk never holds up
//! the host's network runtime. The writer ([`writer::SampleWriter`])
//! flushes a row group as it fills: memory stays bounded.
//!
//! **Closing.** [`Recorder::finish`] unwires the sources and closes the
//! file properly. Dropping a recorder without finishing still closes the
//! file (its pipes stay until the machine stops). A write error (a full
//! disk) stops writing, shows in [`Recorder::check`] at once, and is
//! returned by [`Recorder::finish`].

mod blocks;
mod source;
pub mod writer;

pub use blocks::BLOCK_LATENCY_US;

pub use source::SourceSpec;
use source::{resolve, Resolved};

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use osap_host::som::model::SomFunction;
use osap_host::som::{
    parse_value, Disconnect, FnRef, HostFnError, HostFunction, Manager, PipeOptions, SomError,
    Value,
};
use pipes_core::control::InputMode;
use pipes_core::types::{ScalarType, Type};
use thiserror::Error;

use crate::machine::Machine;
pub use writer::{
    Capture, Clock, Format, Row, SampleWriter, SeriesData, SeriesInfo, WriterOptions,
};

/// The shortest sampling period, µs: a module's timers run on its main
/// loop, and a faster source would fill its links with samples.
pub const MIN_PERIOD_US: u32 = 100;

/// Why a capture could not start, run or be read; each names the source,
/// the option or the file, and how to fix it.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum CaptureError {
    /// A source is not of the form `MODULE.FUNCTION[(ARGS)][.OUTPUT]`.
    #[error("source {source_name:?}: {reason}")]
    BadSource {
        /// The source as given.
        source_name: String,
        /// What is wrong.
        reason: String,
    },
    /// No module of that name.
    #[error("source {source_name:?}: no module {module:?} (machine modules: {found}; or give a runtime name)")]
    UnknownModule {
        /// The source as given.
        source_name: String,
        /// The module asked for.
        module: String,
        /// The modules there are.
        found: String,
    },
    /// The module has no such function.
    #[error("source {source_name:?}: module {module:?} has no function {function:?} (functions with numeric outputs: {found})")]
    UnknownFunction {
        /// The source as given.
        source_name: String,
        /// The module.
        module: String,
        /// The function asked for.
        function: String,
        /// Its functions with a numeric output.
        found: String,
    },
    /// The function has no such output.
    #[error("source {source_name:?}: no output {output:?} (outputs: {found})")]
    UnknownOutput {
        /// The source as given.
        source_name: String,
        /// The output asked for.
        output: String,
        /// The function's outputs.
        found: String,
    },
    /// An output that is not a number.
    #[error("source {source_name:?}: output {output:?} is a {type_name}, not a number: only integers, floats and bools are recorded")]
    NotNumeric {
        /// The source as given.
        source_name: String,
        /// The output.
        output: String,
        /// Its type.
        type_name: String,
    },
    /// Every pipe slot of the source is taken.
    #[error("source {source_name:?}: all {slots} pipe slots of the function are in use; record fewer captures of it at once")]
    NoFreeSlot {
        /// The source as given.
        source_name: String,
        /// Its slot count.
        slots: u8,
    },
    /// Options that cannot work.
    #[error("capture options: {0}")]
    BadOptions(String),
    /// The file's extension names no format.
    #[error("{}: unknown format: name the file .parquet or .csv", .path.display())]
    Format {
        /// The file.
        path: PathBuf,
    },
    /// Writing or reading a file failed (a full disk, a missing folder).
    #[error("{}: {source}", .path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// What the system said.
        #[source]
        source: std::io::Error,
    },
    /// The Parquet writer failed.
    #[error("{}: parquet: {message}", .path.display())]
    Parquet {
        /// The file.
        path: PathBuf,
        /// What it said.
        message: String,
    },
    /// A file is not a capture.
    #[error("{}: not a capture: {message}", .path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// The network refused to wire a source.
    #[error(transparent)]
    Network(#[from] SomError),
    /// The writer thread stopped without a result.
    #[error("{}: the writer thread stopped unexpectedly", .path.display())]
    WriterLost {
        /// The file.
        path: PathBuf,
    },
}

/// Options of [`Machine::record`].
#[derive(Debug, Clone, PartialEq)]
pub struct RecordOptions {
    /// The file: `.parquet` or `.csv` (see [`RecordOptions::format`]).
    pub out: PathBuf,
    /// Sampling period of every source, µs (at least [`MIN_PERIOD_US`]).
    pub period_us: u32,
    /// The format; `None`: by the file's extension.
    pub format: Option<Format>,
    /// Rows the queue to the writer thread holds; samples that find it
    /// full are dropped and counted.
    pub queue_rows: usize,
    /// Batching and row groups.
    pub writer: WriterOptions,
}

impl RecordOptions {
    /// Into `out`, every 1 ms, format by extension.
    pub fn new(out: impl Into<PathBuf>) -> RecordOptions {
        RecordOptions {
            out: out.into(),
            period_us: 1_000,
            format: None,
            queue_rows: 1 << 17,
            writer: WriterOptions::default(),
        }
    }

    /// The same with sampling period `us`.
    pub fn period_us(mut self, us: u32) -> RecordOptions {
        self.period_us = us;
        self
    }
}

/// Counters shared by the host functions, the writer thread and the
/// recorder.
#[derive(Debug, Default)]
struct Shared {
    received: AtomicU64,
    dropped: AtomicU64,
    stale: AtomicU64,
    lost: AtomicU64,
    taken: AtomicU64,
    stop: AtomicBool,
    error: Mutex<Option<String>>,
}

/// Samples received, dropped and out of order so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RecorderStats {
    /// Sample values handed to the writer.
    pub received: u64,
    /// Sample values dropped on a full queue.
    pub dropped: u64,
    /// Samples not after the series' last (not written).
    pub stale: u64,
    /// Samples taken on the modules that never reached the recorder, or
    /// that a module's source failed to take: for sources sampled in
    /// blocks, counted from the blocks' numbers as they arrive (and, when
    /// the capture finishes, up to the module's last sample); for sources
    /// sampled one datagram at a time, the capture's pipe queue was full
    /// (counted by the modules, read when the capture finishes). Each is
    /// one sample of every series of its source.
    pub lost_at_source: u64,
    /// Samples the modules took of the sources sampled in blocks, each one
    /// sample of one source (so with `stale` and `lost_at_source` it
    /// accounts for every sample: per source, rows of its first series =
    /// taken − lost − stale).
    pub taken_at_source: u64,
}

/// Per series in a finished capture.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SeriesSummary {
    /// Its name and clock.
    pub info: SeriesInfo,
    /// Rows written, and their span.
    pub stats: writer::SeriesStats,
}

/// A finished capture: the file and what went into it.
#[derive(Debug, Clone, PartialEq)]
pub struct CaptureFile {
    /// The file.
    pub path: PathBuf,
    /// Its format.
    pub format: Format,
    /// Rows written.
    pub rows: u64,
    /// Per series.
    pub series: Vec<SeriesSummary>,
    /// Samples received, dropped and stale.
    pub stats: RecorderStats,
}

impl CaptureFile {
    /// Reads the file back.
    pub fn read(&self) -> Result<Capture, CaptureError> {
        Capture::read(&self.path)
    }
}

struct Wired {
    source: FnRef,
    dest: FnRef,
    port: Option<u16>,
    /// The capture's pipe slot on the source, once connected.
    slot: Option<u8>,
    /// A module's `sample_block`: its decoder and inputs.
    group: Option<blocks::GroupWired>,
}

/// A capture running beside whatever the machine does; see the module
/// docs. Made by [`Machine::record`].
pub struct Recorder {
    machine: Machine,
    id: u32,
    path: PathBuf,
    format: Format,
    series: Vec<SeriesInfo>,
    wired: Vec<Wired>,
    shared: Arc<Shared>,
    done: Option<tokio::sync::oneshot::Receiver<Result<Vec<writer::SeriesStats>, CaptureError>>>,
}

impl std::fmt::Debug for Recorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Its parts are tasks, locks and buffers: the name says enough.
        f.debug_struct("Recorder").finish_non_exhaustive()
    }
}

static NEXT_ID: AtomicU32 = AtomicU32::new(1);

/// The writer thread: rows from the queue to the file, until told to stop
/// or every sender is gone; then the file is closed.
fn write_loop(
    mut w: SampleWriter,
    rx: Receiver<Row>,
    shared: Arc<Shared>,
) -> Result<Vec<writer::SeriesStats>, CaptureError> {
    let mut failed: Option<CaptureError> = None;
    let take = |row: Row, w: &mut SampleWriter, failed: &mut Option<CaptureError>| {
        if failed.is_none() {
            if let Err(e) = w.push(row) {
                *shared.error.lock().unwrap_or_else(|p| p.into_inner()) = Some(e.to_string());
                *failed = Some(e);
            }
        }
    };
    loop {
        match rx.recv_timeout(Duration::from_millis(50)) {
            Ok(row) => take(row, &mut w, &mut failed),
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => break,
        }
        if shared.stop.load(Ordering::Acquire) {
            while let Ok(row) = rx.try_recv() {
                take(row, &mut w, &mut failed);
            }
            break;
        }
    }
    match failed {
        Some(e) => Err(e),
        None => w.finish(),
    }
}

impl Machine {
    /// Starts recording `sources` (see [`crate::capture`]) into
    /// `options.out`. Every source is checked, and the file created, before
    /// anything is wired.
    pub async fn record(
        &self,
        sources: &[&str],
        options: RecordOptions,
    ) -> Result<Recorder, CaptureError> {
        if options.period_us < MIN_PERIOD_US {
            return Err(CaptureError::BadOptions(format!(
                "period_us = {}: at least {MIN_PERIOD_US} µs",
                options.period_us
            )));
        }
        if options.queue_rows == 0 {
            return Err(CaptureError::BadOptions("queue_rows must be > 0".into()));
        }
        let format = match options.format {
            Some(f) => f,
            None => Format::from_path(&options.out)?,
        };
        let (resolved, plan, series) = self.prepare(sources).await?;
        let w = SampleWriter::create_as(&options.out, format, &series, options.writer)?;

        let id = NEXT_ID.fetch_add(1, Ordering::Relaxed);
        let shared = Arc::new(Shared::default());
        let (tx, rx) = std::sync::mpsc::sync_channel::<Row>(options.queue_rows);
        let (done_tx, done_rx) = tokio::sync::oneshot::channel();
        {
            let shared = shared.clone();
            std::thread::Builder::new()
                .name(format!("capture-{id}"))
                .spawn(move || {
                    let _ = done_tx.send(write_loop(w, rx, shared));
                })
                .map_err(|e| CaptureError::Io {
                    path: options.out.clone(),
                    source: e,
                })?;
        }
        // Arrival stamps: the host's local clock, moved onto the
        // synchronized one through the host runtime's time map.
        let host = self.host().clone();
        let map = host
            .with_runtime(|rt, _| rt.time_map())
            .await
            .map_err(SomError::from)?;
        let mut recorder = Recorder {
            machine: self.clone(),
            id,
            path: options.out.clone(),
            format,
            series,
            wired: Vec::new(),
            shared: shared.clone(),
            done: Some(done_rx),
        };
        recorder
            .wire_all(&resolved, &plan, tx, map, options.period_us)
            .await?;
        Ok(recorder)
    }

    /// Streams `sources` (see [`crate::capture`]) instead of writing them:
    /// every sample arrives on the returned channel as a [`Row`] (its
    /// `series` indexes [`Stream::series`]). The channel holds
    /// `queue_rows`; samples that find it full are dropped and counted in
    /// [`Stream::stats`].
    pub async fn stream(
        &self,
        sources: &[&str],
        period_us: u32,
        queue_rows: usize,
    ) -> Result<(Stream, Receiver<Row>), CaptureError> {
        if period_us < MIN_PERIOD_US {
            return Err(CaptureError::BadOptions(format!(
                "period_us = {period_us}: at least {MIN_PERIOD_US} µs"
            )));
        }
        if queue_rows == 0 {
            return Err(CaptureError::BadOptions("queue_rows must be > 0".into()));
        }
        let (resolved, plan, series) = self.prepare(sources).await?;
        let (tx, rx) = std::sync::mpsc::sync_channel::<Row>(queue_rows);
        let map = self
            .host()
            .with_runtime(|rt, _| rt.time_map())
            .await
            .map_err(SomError::from)?;
        let mut recorder = Recorder {
            machine: self.clone(),
            id: NEXT_ID.fetch_add(1, Ordering::Relaxed),
            path: PathBuf::new(),
            format: Format::Csv,
            series,
            wired: Vec::new(),
            shared: Arc::new(Shared::default()),
            done: None,
        };
        recorder
            .wire_all(&resolved, &plan, tx, map, period_us)
            .await?;
        Ok((Stream { recorder }, rx))
    }

    /// Every source parsed, resolved on the network and checked, and the
    /// series they give, in order.
    async fn prepare(
        &self,
        sources: &[&str],
    ) -> Result<(Vec<Resolved>, blocks::Plan, Vec<SeriesInfo>), CaptureError> {
        if sources.is_empty() {
            return Err(CaptureError::BadOptions(
                "no source given: name one as MODULE.FUNCTION, e.g. x.get_position".into(),
            ));
        }
        let specs: Vec<SourceSpec> = sources
            .iter()
            .map(|s| SourceSpec::parse(s))
            .collect::<Result<_, _>>()?;
        let keys: BTreeMap<String, String> = self
            .modules()
            .iter()
            .map(|(k, m)| (k.clone(), m.runtime.clone()))
            .collect();
        let (resolved, plan) = {
            let manager = self.manager().lock().await;
            let resolved: Vec<Resolved> = specs
                .iter()
                .map(|s| resolve(s, &keys, &manager))
                .collect::<Result<_, _>>()?;
            let plan = blocks::plan(&resolved, &manager);
            (resolved, plan)
        };
        for (i, r) in resolved.iter().enumerate() {
            if resolved[..i].iter().any(|o| o.function == r.function) {
                return Err(CaptureError::BadSource {
                    source_name: r.spec.text.clone(),
                    reason: format!(
                        "{} is sampled by another source too: a function has one set of inputs and one timer; name it once (without .OUTPUT it records every numeric output)",
                        r.function
                    ),
                });
            }
        }
        let mut series = Vec::new();
        for (i, r) in resolved.iter().enumerate() {
            // A block's records carry the module's stamp of each sample.
            let source_clock = r.stamped || plan.in_blocks(i);
            for name in &r.series {
                if series.iter().any(|s: &SeriesInfo| &s.name == name) {
                    return Err(CaptureError::BadSource {
                        source_name: r.spec.text.clone(),
                        reason: format!("series {name} is recorded twice"),
                    });
                }
                series.push(SeriesInfo {
                    name: name.clone(),
                    clock: if source_clock {
                        Clock::Source
                    } else {
                        Clock::Arrival
                    },
                });
            }
        }
        Ok((resolved, plan, series))
    }
}

/// A stream of samples (see [`Machine::stream`]), until [`Stream::stop`].
#[derive(Debug)]
pub struct Stream {
    recorder: Recorder,
}

impl Stream {
    /// The series, in the order rows index them.
    pub fn series(&self) -> &[SeriesInfo] {
        self.recorder.series()
    }

    /// Samples received, dropped and stale so far.
    pub fn stats(&self) -> RecorderStats {
        self.recorder.stats()
    }

    /// Stops sampling and unwires the sources.
    pub async fn stop(mut self) {
        self.recorder.unwire().await;
    }
}

/// Defines the host function `function`, named `name`, that a capture's
/// pipe feeds: its reference and its port on the host runtime, with the
/// manager still locked for the wiring that follows.
async fn define_sink<'m>(
    machine: &'m Machine,
    name: &str,
    function: HostFunction,
) -> Result<(tokio::sync::MutexGuard<'m, Manager>, FnRef, Option<u16>), CaptureError> {
    let mut manager = machine.manager().lock().await;
    let dest = manager.define(function).await?;
    let port = manager
        .som()
        .runtimes
        .first()
        .and_then(|h| h.functions.iter().find(|f| f.name == name))
        .map(|f| f.port);
    Ok((manager, dest, port))
}

impl Recorder {
    /// Wires every source, their series numbered in order: a module's
    /// group through its `sample_block`, the others one datagram a sample.
    /// On an error what was wired is unwired again.
    async fn wire_all(
        &mut self,
        resolved: &[Resolved],
        plan: &blocks::Plan,
        tx: SyncSender<Row>,
        map: osap_core::clock::TimeMap,
        period_us: u32,
    ) -> Result<(), CaptureError> {
        let mut first_series = Vec::with_capacity(resolved.len());
        let mut next = 0u16;
        for r in resolved {
            first_series.push(next);
            next += r.series.len() as u16;
        }
        for g in &plan.groups {
            let result = self
                .wire_group(g, resolved, &first_series, tx.clone(), period_us)
                .await;
            if let Err(e) = result {
                self.unwire().await;
                return Err(e);
            }
        }
        for &i in &plan.singles {
            let result = self
                .wire(&resolved[i], first_series[i], tx.clone(), map, period_us)
                .await;
            if let Err(e) = result {
                self.unwire().await;
                return Err(e);
            }
        }
        Ok(())
    }

    async fn wire(
        &mut self,
        r: &Resolved,
        first_series: u16,
        tx: SyncSender<Row>,
        map: osap_core::clock::TimeMap,
        period_us: u32,
    ) -> Result<(), CaptureError> {
        let name = format!("capture{}.{}.{}", self.id, r.spec.module, r.spec.function);
        let inputs: Vec<(&str, Type)> = r.types.iter().map(|(n, t)| (n.as_str(), *t)).collect();
        let stamped = r.stamped;
        let count = r.series.len();
        let shared = self.shared.clone();
        let clock = self.machine.host().clock();
        let mut last: Option<u64> = None;
        let body = move |ins: &[Value<'static>]| {
            let (time, values) = if stamped {
                let Some(Value::U64(t)) = ins.first() else {
                    return Err(HostFnError::bad_input());
                };
                (*t, &ins[1..])
            } else {
                let t = i128::from(map.system_time(clock.now()).as_micros());
                (u64::try_from(t.max(0)).unwrap_or(u64::MAX), ins)
            };
            if last.is_some_and(|l| time <= l) {
                shared.stale.fetch_add(1, Ordering::Relaxed);
                return Ok(Vec::new());
            }
            last = Some(time);
            for (k, v) in values.iter().take(count).enumerate() {
                let value = v.as_f64().or_else(|| lossy_f64(v)).unwrap_or(f64::NAN);
                let row = Row {
                    time_us: time,
                    series: first_series + k as u16,
                    value,
                };
                match tx.try_send(row) {
                    Ok(()) => shared.received.fetch_add(1, Ordering::Relaxed),
                    Err(TrySendError::Full(_)) => shared.dropped.fetch_add(1, Ordering::Relaxed),
                    // The writer is gone (finished or dropped).
                    Err(TrySendError::Disconnected(_)) => return Ok(Vec::new()),
                };
            }
            Ok(Vec::new())
        };
        let function = HostFunction::new(&name, &inputs, &[], body)?;
        let (mut manager, dest, port) = define_sink(&self.machine, &name, function).await?;
        self.wired.push(Wired {
            source: r.function.clone(),
            dest: dest.clone(),
            port,
            slot: None,
            group: None,
        });
        let map: Vec<u8> = (0..r.outputs.len() as u8).collect();
        let pipe = manager
            .connect(&r.function, &dest, &r.outputs, &map, PipeOptions::default())
            .await?;
        if let Some(w) = self.wired.last_mut() {
            w.slot = Some(pipe.slot);
        }
        if !r.args.is_empty() {
            // Stored in its inputs: its timer runs it with them.
            manager.function(&r.function)?.push(&r.args).await?;
        }
        let current = manager
            .som()
            .runtime_index(&r.function.runtime)
            .ok()
            .and_then(|ri| manager.som().function(ri, &r.function.function))
            .map(|f| InputMode::from(f.input_mode))
            .unwrap_or_default();
        let mode = self
            .machine
            .capture_holds()
            .acquire(&r.function, self.id, period_us, current);
        manager.set_input_mode(&r.function, mode).await?;
        Ok(())
    }

    /// Undoes the wiring: the sources' timers back, the pipes gone, the
    /// host functions detached. Best effort: a module that stopped
    /// answering keeps its pipe until it reboots.
    async fn unwire(&mut self) {
        let holds = self.machine.capture_holds();
        let mut manager = self.machine.manager().lock().await;
        let wired: Vec<Wired> = self.wired.drain(..).collect();
        for w in wired {
            if let Some(g) = &w.group {
                self.unwire_group(&mut manager, &w, g).await;
            } else if let Some(mode) = holds.release(&w.source, self.id) {
                if let Err(e) = manager.set_input_mode(&w.source, mode).await {
                    tracing::warn!("capture: {}: timer not restored: {e}", w.source);
                }
            }
            // What the module could not send: its pipe's queue was full
            // (the function's port busy with its other pipes' datagrams).
            if let Some(slot) = w.slot.filter(|_| w.group.is_none()) {
                match manager.pipe_stats(&w.source, slot).await {
                    Ok(st) => {
                        let lost = u64::from(st.overflows)
                            + u64::from(st.send_errors)
                            + u64::from(st.failures);
                        self.shared.lost.fetch_add(lost, Ordering::Relaxed);
                    }
                    Err(e) => tracing::warn!("capture: {}: pipe counters not read: {e}", w.source),
                }
            }
            if let Err(e) = manager
                .disconnect(&w.source, Disconnect::To(w.dest.clone()))
                .await
            {
                tracing::warn!("capture: {}: pipe not removed: {e}", w.source);
            }
            if let Some(port) = w.port {
                let _ = self.machine.host().detach_port(port).await;
            }
        }
    }

    /// The file being written.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The series, in file order.
    pub fn series(&self) -> &[SeriesInfo] {
        &self.series
    }

    /// Samples received, dropped and stale so far.
    pub fn stats(&self) -> RecorderStats {
        RecorderStats {
            received: self.shared.received.load(Ordering::Relaxed),
            dropped: self.shared.dropped.load(Ordering::Relaxed),
            stale: self.shared.stale.load(Ordering::Relaxed),
            lost_at_source: self.shared.lost.load(Ordering::Relaxed),
            taken_at_source: self.shared.taken.load(Ordering::Relaxed),
        }
    }

    /// Whether writing still works: a full disk shows here at once (the
    /// recorder then writes nothing more).
    pub fn check(&self) -> Result<(), CaptureError> {
        match &*self.shared.error.lock().unwrap_or_else(|p| p.into_inner()) {
            Some(message) => Err(CaptureError::Parquet {
                path: self.path.clone(),
                message: format!("writing stopped: {message}"),
            }),
            None => Ok(()),
        }
    }

    /// Stops sampling, unwires the sources and closes the file properly.
    pub async fn finish(mut self) -> Result<CaptureFile, CaptureError> {
        self.unwire().await;
        self.shared.stop.store(true, Ordering::Release);
        let done = self.done.take();
        let stats = match done {
            Some(rx) => rx.await.map_err(|_| CaptureError::WriterLost {
                path: self.path.clone(),
            })??,
            None => {
                return Err(CaptureError::WriterLost {
                    path: self.path.clone(),
                })
            }
        };
        let series: Vec<SeriesSummary> = self
            .series
            .iter()
            .cloned()
            .zip(stats)
            .map(|(info, stats)| SeriesSummary { info, stats })
            .collect();
        Ok(CaptureFile {
            path: self.path.clone(),
            format: self.format,
            rows: series.iter().map(|s| s.stats.rows).sum(),
            series,
            stats: self.stats(),
        })
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        // Closes the file even when finish was not called (a script that
        // returned early with an error).
        self.shared.stop.store(true, Ordering::Release);
    }
}

/// Integers an f64 cannot hold exactly, rounded; f16 widened.
fn lossy_f64(v: &Value<'static>) -> Option<f64> {
    Some(match v {
        Value::U64(x) => *x as f64,
        Value::I64(x) => *x as f64,
        Value::U128(x) => *x as f64,
        Value::I128(x) => *x as f64,
        Value::F16(bits) => pipes_core::f16::f16_to_f64(*bits),
        _ => return None,
    })
}

#[cfg(test)]
mod tests;
