//! Where records live: folder names, hashes and finding runs on disk.

use std::path::{Path, PathBuf};

use sha2::{Digest, Sha256};

use super::{RunRecord, RunRecordError, RUN_FILE};

/// The sha256 of `bytes`, lowercase hex.
pub fn sha256_hex(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// A new output folder's name in `parent`:
/// `osap-KIND-NAME[-DETAIL]-YYYYMMDD-HHMMSS` at `now` (local time), the
/// machine's name made safe for a path; `-2`, `-3`, .. after it when a
/// folder of that name exists already (two runs in one second).
pub fn folder_name(
    parent: &Path,
    kind: &str,
    machine: &str,
    detail: Option<&str>,
    now: super::LocalTime,
) -> PathBuf {
    let safe: String = machine
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect();
    let detail = detail.map(|d| format!("-{d}")).unwrap_or_default();
    let base = format!("osap-{kind}-{safe}{detail}-{}", now.format("%Y%m%d-%H%M%S"));
    let mut name = parent.join(&base);
    let mut n = 2;
    while name.exists() {
        name = parent.join(format!("{base}-{n}"));
        n += 1;
    }
    name
}

/// The record of `path`: `path/run.json` for a folder, else `path`
/// itself, or `path.run.json` when `path` is a data file with a record
/// beside it.
pub fn record_path(path: &Path) -> PathBuf {
    if path.is_dir() {
        return path.join(RUN_FILE);
    }
    let name = path.to_string_lossy();
    if name.ends_with(".json") {
        return path.to_path_buf();
    }
    PathBuf::from(format!("{name}.run.json"))
}

/// A run found on disk.
#[derive(Debug)]
pub struct FoundRun {
    /// Its record file.
    pub path: PathBuf,
    /// The record, or why it could not be read.
    pub record: Result<RunRecord, RunRecordError>,
}

/// Every run in `dir`: its folders holding a `run.json` and its
/// `*.run.json` files (and `dir` itself when it is a run), oldest first.
pub fn find_runs(dir: &Path) -> Result<Vec<FoundRun>, RunRecordError> {
    let io = |source| RunRecordError::Io {
        path: dir.to_path_buf(),
        source,
    };
    let mut paths = Vec::new();
    if dir.join(RUN_FILE).is_file() {
        paths.push(dir.join(RUN_FILE));
    }
    for entry in std::fs::read_dir(dir).map_err(io)? {
        let entry = entry.map_err(io)?;
        let p = entry.path();
        if p.is_dir() && p.join(RUN_FILE).is_file() {
            paths.push(p.join(RUN_FILE));
        } else if p.is_file() && p.to_string_lossy().ends_with(".run.json") {
            paths.push(p);
        }
    }
    let mut runs: Vec<FoundRun> = paths
        .into_iter()
        .map(|path| FoundRun {
            record: RunRecord::read(&path),
            path,
        })
        .collect();
    runs.sort_by(|a, b| {
        let key = |r: &FoundRun| {
            r.record
                .as_ref()
                .ok()
                .map(|r| r.started.wall.clone())
                .unwrap_or_default()
        };
        key(a).cmp(&key(b)).then_with(|| a.path.cmp(&b.path))
    });
    Ok(runs)
}
