//! Run records: what a command that measured or moved a machine did, in
//! one `run.json` beside its data, so that a run can be found, read and
//! re-run later without copying parameters by hand.
//!
//! A record holds the command line, copies of the machine file (and the
//! bed mesh it names) and of the job with their sha256, the host build,
//! every module's firmware (name, version, function-set id), the start
//! and end on the wall clock and on the machine's synchronized clock, the
//! outcome with every fault, the summary as printed, and each data file
//! with its sha256. `osap runs list|show|replay` read them (docs/workflows.md).
//!
//! Folders get names that sort by time ([`folder_name`]):
//! `osap-run-plotter-20261129-143502`.

mod files;
#[cfg(test)]
mod tests;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

pub use files::{find_runs, folder_name, record_path, sha256_hex, FoundRun};

/// A local wall-clock time (folder names).
pub type LocalTime = chrono::DateTime<chrono::Local>;

/// Local time now.
pub fn local_now() -> LocalTime {
    chrono::Local::now()
}

/// The `format` every record carries.
pub const RUN_FORMAT: &str = "osap-run";
/// The layout version this build writes and reads.
pub const RUN_VERSION: u32 = 1;
/// A record's file name inside a run's folder.
pub const RUN_FILE: &str = "run.json";

/// One run of a command on a machine (see the [module docs](self)).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunRecord {
    /// Always [`RUN_FORMAT`].
    pub format: String,
    /// [`RUN_VERSION`] when written by this build.
    pub version: u32,
    /// The command: `run`, `resonance`, `rheo`, `capture`, `level`.
    pub command: String,
    /// The command line as given.
    pub argv: Vec<String>,
    /// The folder it was given in.
    pub cwd: String,
    /// The machine file.
    pub machine: InputFile,
    /// The machine's name (`name =` in its file).
    pub machine_name: String,
    /// Files the machine file names (its bed mesh), by role.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub machine_inputs: BTreeMap<String, InputFile>,
    /// The job, for commands that run one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub job: Option<InputFile>,
    /// Where the machine was: simulated or on links.
    pub target: TargetRecord,
    /// The command's own options (a job's placement, an axis, a rate), as
    /// it needs them to run again.
    #[serde(default)]
    pub options: serde_json::Value,
    /// The record this run replayed (`osap runs replay`), if it did.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub replay_of: Option<String>,
    /// The build of the host program that wrote it.
    pub host: HostBuild,
    /// Every module of the machine, by its key in `[modules]`.
    #[serde(default)]
    pub modules: BTreeMap<String, ModuleFirmware>,
    /// When it started.
    pub started: Stamp,
    /// When it ended (`None` until it has).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ended: Option<Stamp>,
    /// How it ended.
    pub outcome: Outcome,
    /// Every fault heard, as reported.
    #[serde(default)]
    pub faults: Vec<String>,
    /// The summary as printed, line by line.
    #[serde(default)]
    pub summary: Vec<SummaryLine>,
    /// The summary's figures by name (`planned_s`, `executed_s`, ..).
    #[serde(default)]
    pub figures: BTreeMap<String, f64>,
    /// The data files written, with their sha256.
    #[serde(default)]
    pub files: Vec<DataFile>,
}

/// A file a run read, copied whole.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct InputFile {
    /// Its path as given.
    pub path: String,
    /// The sha256 of its bytes, hex.
    pub sha256: String,
    /// Its text.
    pub text: String,
}

impl InputFile {
    /// Reads `path` whole.
    pub fn read(path: &Path) -> std::io::Result<InputFile> {
        let text = std::fs::read_to_string(path)?;
        Ok(InputFile::from_text(path, text))
    }

    /// A file whose text is already read.
    pub fn from_text(path: &Path, text: String) -> InputFile {
        InputFile {
            path: path.display().to_string(),
            sha256: sha256_hex(text.as_bytes()),
            text,
        }
    }

    /// The file's name, without its folders (`plotter.toml`).
    pub fn file_name(&self) -> String {
        Path::new(&self.path)
            .file_name()
            .map_or_else(|| "file".into(), |n| n.to_string_lossy().into_owned())
    }

    /// Whether the file at its path still holds what was recorded:
    /// `None` when it cannot be read.
    pub fn unchanged_on_disk(&self) -> Option<bool> {
        let bytes = std::fs::read(&self.path).ok()?;
        Some(sha256_hex(&bytes) == self.sha256)
    }
}

/// Where the machine was.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct TargetRecord {
    /// On simulated modules.
    pub sim: bool,
    /// In virtual time (with `sim`).
    pub fast: bool,
    /// Serial ports.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub ports: Vec<String>,
    /// TCP addresses.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub tcp: Vec<String>,
}

impl TargetRecord {
    /// `simulated, virtual time`, `simulated`, or the links.
    pub fn describe(&self) -> String {
        match (self.sim, self.fast) {
            (true, true) => "simulated, virtual time".into(),
            (true, false) => "simulated".into(),
            _ => {
                let links: Vec<&str> = self
                    .ports
                    .iter()
                    .chain(&self.tcp)
                    .map(String::as_str)
                    .collect();
                if links.is_empty() {
                    "connected (USB)".into()
                } else {
                    format!("connected ({})", links.join(", "))
                }
            }
        }
    }
}

/// The host program's build.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct HostBuild {
    /// Its name (`osap`).
    pub program: String,
    /// Its version.
    pub version: String,
    /// The source's commit, when it was built from a git checkout.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub commit: Option<String>,
}

/// A module's firmware, as the scan read it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ModuleFirmware {
    /// Its runtime name on the network.
    pub runtime: String,
    /// Its firmware (runtime type).
    pub firmware: String,
    /// The firmware's version.
    pub version: String,
    /// `embedded`, `host` or `simulated`.
    pub build: String,
    /// The function-set id of the functions it was built with, hex.
    pub function_set_id: String,
}

/// A moment on both clocks.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Stamp {
    /// Wall clock, RFC 3339 in UTC.
    pub wall: String,
    /// The machine's synchronized clock, µs (`None` before it runs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sync_us: Option<u64>,
}

impl Stamp {
    /// Now on the wall clock.
    pub fn now() -> Stamp {
        Stamp {
            wall: chrono::Utc::now().to_rfc3339_opts(chrono::SecondsFormat::Millis, true),
            sync_us: None,
        }
    }

    /// Its wall time, if it reads as RFC 3339.
    pub fn wall_time(&self) -> Option<chrono::DateTime<chrono::Utc>> {
        chrono::DateTime::parse_from_rfc3339(&self.wall)
            .ok()
            .map(|t| t.with_timezone(&chrono::Utc))
    }
}

/// How a run ended.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Outcome {
    /// `running`, `ok`, `machine_fault`, `failed` or `refused`.
    pub status: String,
    /// The command's exit code.
    pub exit_code: u8,
    /// Why it did not end well.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
}

/// One line of a printed summary.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct SummaryLine {
    /// The line as printed.
    pub text: String,
    /// Whether it reads the wall clock (start-up and homing times), so
    /// differs between two runs of the same job.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub wall_clock: bool,
}

/// A data file a run wrote.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct DataFile {
    /// Its path, relative to the record when beside it.
    pub path: String,
    /// Its size, bytes.
    pub bytes: u64,
    /// The sha256 of its bytes, hex.
    pub sha256: String,
}

/// Why a record could not be read or written.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RunRecordError {
    /// Reading or writing a file failed.
    #[error("{}: {source}", .path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// What the system said.
        #[source]
        source: std::io::Error,
    },
    /// The file is not a run record this build reads.
    #[error("{}: not an osap run record: {reason}", .path.display())]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> RunRecordError + '_ {
    move |source| RunRecordError::Io {
        path: path.to_path_buf(),
        source,
    }
}

impl RunRecord {
    /// A record of `command` starting now, on the machine file at
    /// `machine_path` (copied, with the bed mesh it names).
    pub fn start(
        command: &str,
        machine_path: &Path,
        cfg: &crate::config::MachineFile,
        host: HostBuild,
    ) -> Result<RunRecord, RunRecordError> {
        let machine = InputFile::read(machine_path).map_err(io_err(machine_path))?;
        let mut machine_inputs = BTreeMap::new();
        if let (Some(path), Some(given)) = (cfg.bed_mesh_path(), &cfg.bed_mesh) {
            let mut mesh = InputFile::read(&path).map_err(io_err(&path))?;
            // As the machine file names it, so a copy of both resolves.
            mesh.path = given.display().to_string();
            machine_inputs.insert("bed_mesh".into(), mesh);
        }
        Ok(RunRecord {
            format: RUN_FORMAT.into(),
            version: RUN_VERSION,
            command: command.into(),
            argv: std::env::args().collect(),
            cwd: std::env::current_dir()
                .map(|d| d.display().to_string())
                .unwrap_or_default(),
            machine,
            machine_name: cfg.name.clone(),
            machine_inputs,
            job: None,
            target: TargetRecord::default(),
            options: serde_json::Value::Null,
            replay_of: None,
            host,
            modules: BTreeMap::new(),
            started: Stamp::now(),
            ended: None,
            outcome: Outcome {
                status: "running".into(),
                exit_code: 0,
                reason: None,
            },
            faults: Vec::new(),
            summary: Vec::new(),
            figures: BTreeMap::new(),
            files: Vec::new(),
        })
    }

    /// Records the modules of `machine`, as its scan read them, and the
    /// synchronized time the run started at.
    pub async fn machine_started(&mut self, machine: &crate::Machine, sync_us: Option<u64>) {
        let manager = machine.manager().lock().await;
        let som = manager.som();
        self.modules = machine
            .modules()
            .iter()
            .filter_map(|(key, m)| {
                let rt = som.runtimes.iter().find(|r| r.record.name == m.runtime)?;
                let build = match rt.record.build {
                    1 => "embedded".to_string(),
                    2 => "host".to_string(),
                    3 => "simulated".to_string(),
                    b => format!("build {b}"),
                };
                let id = crate::network::function_set_id_of(rt)
                    .map_or_else(|| "unknown".into(), |id| format!("{id:#010x}"));
                Some((
                    key.clone(),
                    ModuleFirmware {
                        runtime: m.runtime.clone(),
                        firmware: rt.record.type_name.clone(),
                        version: rt.record.version.clone(),
                        build,
                        function_set_id: id,
                    },
                ))
            })
            .collect();
        self.started.sync_us = sync_us;
    }

    /// Records a summary line as printed.
    pub fn line(&mut self, text: impl Into<String>) {
        self.summary.push(SummaryLine {
            text: text.into(),
            wall_clock: false,
        });
    }

    /// Records a summary line that reads the wall clock.
    pub fn wall_line(&mut self, text: impl Into<String>) {
        self.summary.push(SummaryLine {
            text: text.into(),
            wall_clock: true,
        });
    }

    /// Records a figure of the summary.
    pub fn figure(&mut self, name: &str, value: f64) {
        self.figures.insert(name.into(), value);
    }

    /// Records the end: now, at synchronized time `sync_us`, with the
    /// command's exit code and why it failed.
    pub fn finish(
        &mut self,
        sync_us: Option<u64>,
        exit_code: u8,
        status: &str,
        reason: Option<String>,
    ) {
        let mut end = Stamp::now();
        end.sync_us = sync_us;
        self.ended = Some(end);
        self.outcome = Outcome {
            status: status.into(),
            exit_code,
            reason,
        };
    }

    /// Wall-clock seconds from start to end, when both read.
    pub fn duration_s(&self) -> Option<f64> {
        let a = self.started.wall_time()?;
        let b = self.ended.as_ref()?.wall_time()?;
        Some((b - a).num_milliseconds() as f64 * 1e-3)
    }

    /// Synchronized seconds from start to end, when both were read.
    pub fn sync_duration_s(&self) -> Option<f64> {
        let a = self.started.sync_us?;
        let b = self.ended.as_ref()?.sync_us?;
        Some(b.saturating_sub(a) as f64 * 1e-6)
    }

    /// Adds the data files `paths`, hashed, by their paths relative to
    /// `base` (the record's folder) where they lie within it.
    pub fn add_files(&mut self, base: &Path, paths: &[PathBuf]) -> Result<(), RunRecordError> {
        for p in paths {
            let bytes = std::fs::read(p).map_err(io_err(p))?;
            let shown = p.strip_prefix(base).unwrap_or(p);
            self.files.push(DataFile {
                path: shown.display().to_string(),
                bytes: bytes.len() as u64,
                sha256: sha256_hex(&bytes),
            });
        }
        Ok(())
    }

    /// Writes the record to `path` (`DIR/run.json`, or `FILE.run.json`).
    pub fn write(&self, path: &Path) -> Result<(), RunRecordError> {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(io_err(dir))?;
        }
        let text = serde_json::to_string_pretty(self).map_err(|e| RunRecordError::Invalid {
            path: path.to_path_buf(),
            reason: e.to_string(),
        })?;
        // Whole or not at all: a reader never sees half a record.
        let tmp = path.with_extension("json.partial");
        std::fs::write(&tmp, text + "\n").map_err(io_err(&tmp))?;
        std::fs::rename(&tmp, path).map_err(io_err(path))
    }

    /// Reads a record: a run's folder (its `run.json`) or a record file.
    pub fn read(path: &Path) -> Result<RunRecord, RunRecordError> {
        let file = record_path(path);
        let text = std::fs::read_to_string(&file).map_err(io_err(&file))?;
        let record: RunRecord =
            serde_json::from_str(&text).map_err(|e| RunRecordError::Invalid {
                path: file.clone(),
                reason: e.to_string(),
            })?;
        if record.format != RUN_FORMAT || !(1..=RUN_VERSION).contains(&record.version) {
            return Err(RunRecordError::Invalid {
                path: file,
                reason: format!(
                    "format {:?} version {} (this build reads {RUN_FORMAT:?} version {RUN_VERSION})",
                    record.format, record.version
                ),
            });
        }
        Ok(record)
    }

    /// The summary lines that do not read the wall clock.
    pub fn steady_summary(&self) -> impl Iterator<Item = &str> {
        self.summary
            .iter()
            .filter(|l| !l.wall_clock)
            .map(|l| l.text.as_str())
    }

    /// Writes the machine file, its bed mesh and the job into `dir` as
    /// they were recorded, and gives the machine file's and the job's
    /// paths there. The mesh lands where the machine file names it, when
    /// that is a plain relative path.
    pub fn restore_inputs(&self, dir: &Path) -> Result<(PathBuf, Option<PathBuf>), RunRecordError> {
        std::fs::create_dir_all(dir).map_err(io_err(dir))?;
        let machine = dir.join(self.machine.file_name());
        std::fs::write(&machine, &self.machine.text).map_err(io_err(&machine))?;
        for input in self.machine_inputs.values() {
            let given = Path::new(&input.path);
            let plain = given.is_relative()
                && given
                    .components()
                    .all(|c| matches!(c, std::path::Component::Normal(_)));
            if !plain {
                return Err(RunRecordError::Invalid {
                    path: machine,
                    reason: format!(
                        "the machine file names {:?}, outside its folder: replay cannot put the recorded copy there",
                        input.path
                    ),
                });
            }
            let at = dir.join(given);
            if let Some(parent) = at.parent() {
                std::fs::create_dir_all(parent).map_err(io_err(parent))?;
            }
            std::fs::write(&at, &input.text).map_err(io_err(&at))?;
        }
        let job = match &self.job {
            Some(job) => {
                let at = dir.join(job.file_name());
                std::fs::write(&at, &job.text).map_err(io_err(&at))?;
                Some(at)
            }
            None => None,
        };
        Ok((machine, job))
    }
}
