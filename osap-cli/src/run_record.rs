//! The run record each measuring or moving command leaves beside what it
//! wrote (`run.json`, `FILE.run.json`; [`osap_machine::runs`]): begun
//! before the machine starts, filled as the command goes, and written
//! however it ends.

use std::path::{Path, PathBuf};

use osap_machine::config::MachineFile;
use osap_machine::runs::{HostBuild, RunRecord, TargetRecord};

use crate::machine_cmd::{Failure, Target, FAULTED, MACHINE_FAULT, REFUSED};

/// This program's build.
pub(crate) fn host_build() -> HostBuild {
    let commit = env!("OSAP_COMMIT");
    HostBuild {
        program: "osap".into(),
        version: env!("CARGO_PKG_VERSION").into(),
        commit: (!commit.is_empty()).then(|| commit.to_string()),
    }
}

/// A record of `command` on the machine `target` names (loaded as `cfg`).
pub(crate) fn begin(
    command: &str,
    target: &Target,
    cfg: &MachineFile,
) -> Result<RunRecord, Failure> {
    let mut record = RunRecord::start(command, &target.machine, cfg, host_build())
        .map_err(|e| Failure::refused(e.to_string()))?;
    record.target = TargetRecord {
        sim: target.sim,
        fast: target.fast,
        ports: target.ports.clone(),
        tcp: target.tcp.clone(),
    };
    Ok(record)
}

/// Notes the machine's modules and the synchronized time now on `record`.
pub(crate) async fn machine_started(record: &mut RunRecord, machine: &osap_machine::Machine) {
    let now = machine.now_us().await.ok();
    record.machine_started(machine, now).await;
}

/// A summary that is printed and recorded, line by line.
pub(crate) struct Summary<'a> {
    /// The record the lines go into.
    pub record: &'a mut RunRecord,
    /// Whether the lines are printed too (`osap runs replay` prints them
    /// side by side instead).
    pub print: bool,
}

impl Summary<'_> {
    /// A line of the summary (stdout).
    pub(crate) fn line(&mut self, text: impl Into<String>) {
        let text = text.into();
        if self.print {
            println!("{text}");
        }
        self.record.line(text);
    }

    /// A line that reads the wall clock (stderr: start-up, homing).
    pub(crate) fn wall(&mut self, text: impl Into<String>) {
        let text = text.into();
        if self.print {
            eprintln!("{text}");
        }
        self.record.wall_line(text);
    }

    /// A line that reports a fault: recorded among the faults as well.
    pub(crate) fn fault(&mut self, text: impl Into<String>) {
        let text = text.into();
        self.record.faults.push(text.clone());
        self.line(text);
    }
}

/// The outcome's status for an exit code.
fn status_of(code: u8) -> &'static str {
    match code {
        0 => "ok",
        MACHINE_FAULT => "machine_fault",
        REFUSED => "refused",
        // FAULTED, and any other code.
        _ => "failed",
    }
}

/// Ends `record` with `result` (the command's exit code, or why it
/// failed), at synchronized time `sync_us`, and writes it to `path`. A
/// record that cannot be written is a failure of the command: a run with
/// no record is the loss the record exists to prevent.
pub(crate) fn finish(
    mut record: RunRecord,
    path: &Path,
    sync_us: Option<u64>,
    result: Result<u8, Failure>,
) -> Result<u8, Failure> {
    let (code, reason) = match &result {
        Ok(code) => (*code, record.faults.first().cloned().filter(|_| *code != 0)),
        Err(f) => (f.code, Some(f.message.clone())),
    };
    if let Err(f) = &result {
        record.faults.push(f.message.clone());
    }
    record.finish(sync_us, code, status_of(code), reason);
    if let Err(e) = record.write(path) {
        let message = format!("the run record was not written: {e}");
        return Err(match result {
            Err(f) => Failure {
                code: f.code,
                message: format!("{}; {message}", f.message),
            },
            Ok(_) => Failure {
                code: FAULTED,
                message,
            },
        });
    }
    result
}

/// The record beside a data file: `FILE.run.json`.
pub(crate) fn beside(file: &Path) -> PathBuf {
    PathBuf::from(format!("{}.run.json", file.display()))
}
