//! `osap runs list|show|replay`: the run records (`run.json`) commands
//! leave beside their data, listed, shown, and re-run.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use clap::{Args, Subcommand};
use osap_machine::runs::{find_runs, RunRecord, RUN_FILE};

use crate::machine_cmd::{check_out, Failure, RunOptions, Target};

/// `osap runs` subcommands.
#[derive(Subcommand, Debug)]
pub(crate) enum RunsCommand {
    /// List the runs in a folder (default: the current one): date,
    /// machine, command and job, outcome, duration.
    List {
        /// The folder to look in.
        dir: Option<PathBuf>,
    },
    /// Print one run's record: inputs, firmware, outcome, summary, files.
    Show {
        /// The run: its folder, its run.json, or a data file with a
        /// FILE.run.json beside it.
        run: PathBuf,
    },
    /// Run a recorded job again, from the record's own copies of the
    /// machine file and the job, and print both summaries side by side.
    Replay(ReplayArgs),
}

/// `osap runs replay` options.
#[derive(Args, Debug)]
pub(crate) struct ReplayArgs {
    /// The run: its folder or its run.json.
    pub run: PathBuf,
    /// On simulated modules (default: where the run was; give --sim, --port
    /// or --tcp to run elsewhere).
    #[arg(long)]
    pub sim: bool,
    /// With --sim: in virtual time.
    #[arg(long, requires = "sim")]
    pub fast: bool,
    /// Serial port of a module or adapter (repeatable).
    #[arg(long = "port", value_name = "PATH", conflicts_with = "sim")]
    pub ports: Vec<String>,
    /// Connect over TCP (repeatable).
    #[arg(long = "tcp", value_name = "ADDR", conflicts_with = "sim")]
    pub tcp: Vec<String>,
    /// Where the replay writes its run (default: a new folder
    /// osap-run-NAME-TIME in the current directory).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
}

impl ReplayArgs {
    /// Whether the replay runs in virtual time: `--fast`, or a run
    /// recorded in virtual time replayed without a target of its own.
    pub(crate) fn virtual_time(&self) -> bool {
        if self.sim || !self.ports.is_empty() || !self.tcp.is_empty() {
            return self.fast;
        }
        RunRecord::read(&self.run).is_ok_and(|r| r.target.sim && r.target.fast)
    }
}

fn refused(e: impl std::fmt::Display) -> Failure {
    Failure::refused(e.to_string())
}

/// Runs `osap runs ...`.
pub(crate) async fn runs(command: RunsCommand, started: Instant) -> Result<ExitCode, Failure> {
    match command {
        RunsCommand::List { dir } => list(dir.as_deref().unwrap_or(Path::new("."))),
        RunsCommand::Show { run } => show(&run),
        RunsCommand::Replay(args) => replay(args, started).await,
    }
}

/// Local `YYYY-MM-DD HH:MM:SS` of a record's RFC 3339 stamp.
fn local_time(wall: &str) -> String {
    chrono::DateTime::parse_from_rfc3339(wall).map_or_else(
        |_| wall.to_string(),
        |t| {
            t.with_timezone(&chrono::Local)
                .format("%Y-%m-%d %H:%M:%S")
                .to_string()
        },
    )
}

fn duration(r: &RunRecord) -> String {
    r.duration_s()
        .map_or_else(|| "-".into(), |s| format!("{s:.1} s"))
}

fn what(r: &RunRecord) -> String {
    match &r.job {
        Some(job) => format!("{} {}", r.command, job.file_name()),
        None => r.command.clone(),
    }
}

fn list(dir: &Path) -> Result<ExitCode, Failure> {
    let runs = find_runs(dir).map_err(refused)?;
    if runs.is_empty() {
        println!(
            "no runs in {} (folders with a {RUN_FILE}, or FILE.run.json)",
            dir.display()
        );
        return Ok(ExitCode::SUCCESS);
    }
    println!(
        "{:<19}  {:<14}  {:<28}  {:<13}  {:>9}  run",
        "date", "machine", "command and job", "outcome", "duration"
    );
    for found in &runs {
        let shown = found
            .path
            .strip_prefix(dir)
            .unwrap_or(&found.path)
            .display()
            .to_string();
        let shown = shown
            .strip_suffix(&format!("/{RUN_FILE}"))
            .unwrap_or(&shown)
            .to_string();
        match &found.record {
            Ok(r) => println!(
                "{:<19}  {:<14}  {:<28}  {:<13}  {:>9}  {shown}",
                local_time(&r.started.wall),
                r.machine_name,
                what(r),
                r.outcome.status,
                duration(r)
            ),
            Err(e) => println!("{:<19}  unreadable: {e}", "-"),
        }
    }
    Ok(ExitCode::SUCCESS)
}

fn show(run: &Path) -> Result<ExitCode, Failure> {
    let r = RunRecord::read(run).map_err(refused)?;
    println!("run        {}", run.display());
    println!("command    {}", r.argv.join(" "));
    println!("in         {}", r.cwd);
    if let Some(of) = &r.replay_of {
        println!("replay of  {of}");
    }
    let changed = |unchanged: Option<bool>| match unchanged {
        Some(true) => "",
        Some(false) => "  (changed on disk since)",
        None => "  (no longer on disk)",
    };
    println!(
        "machine    {} ({}, sha256 {}){}",
        r.machine.path,
        r.machine_name,
        &r.machine.sha256[..12],
        changed(r.machine.unchanged_on_disk())
    );
    for (role, f) in &r.machine_inputs {
        println!("  {role:<8} {} (sha256 {})", f.path, &f.sha256[..12]);
    }
    if let Some(job) = &r.job {
        println!(
            "job        {} (sha256 {}){}",
            job.path,
            &job.sha256[..12],
            changed(job.unchanged_on_disk())
        );
    }
    println!("target     {}", r.target.describe());
    println!(
        "host       {} {}{}",
        r.host.program,
        r.host.version,
        r.host
            .commit
            .as_ref()
            .map_or(String::new(), |c| format!(" (commit {c})"))
    );
    for (key, m) in &r.modules {
        println!(
            "module     {key}: {} ({} {} {}, function set {})",
            m.runtime, m.firmware, m.version, m.build, m.function_set_id
        );
    }
    println!("started    {}", local_time(&r.started.wall));
    if let Some(end) = &r.ended {
        println!(
            "ended      {} ({}{})",
            local_time(&end.wall),
            duration(&r),
            r.sync_duration_s().map_or(String::new(), |s| format!(
                "; {s:.3} s on the machine's clock"
            ))
        );
    }
    println!(
        "outcome    {} (exit code {}){}",
        r.outcome.status,
        r.outcome.exit_code,
        r.outcome
            .reason
            .as_ref()
            .map_or(String::new(), |s| format!(": {s}"))
    );
    for f in &r.faults {
        println!("fault      {f}");
    }
    if !r.summary.is_empty() {
        println!("summary");
        for l in &r.summary {
            println!("  {}", l.text);
        }
    }
    for f in &r.files {
        println!(
            "file       {} ({} bytes, sha256 {})",
            f.path,
            f.bytes,
            &f.sha256[..12]
        );
    }
    Ok(ExitCode::SUCCESS)
}

async fn replay(args: ReplayArgs, started: Instant) -> Result<ExitCode, Failure> {
    let record_file = osap_machine::runs::record_path(&args.run);
    let old = RunRecord::read(&args.run).map_err(refused)?;
    if old.command != "run" {
        return Err(Failure::refused(format!(
            "{}: a record of `osap {}`; replay re-runs jobs (`osap run` records); run `osap {}` again to measure again",
            record_file.display(),
            old.command,
            old.command
        )));
    }
    let job = old.job.as_ref().ok_or_else(|| {
        Failure::refused(format!(
            "{}: the record holds no job",
            record_file.display()
        ))
    })?;
    let options: RunOptions = serde_json::from_value(old.options.clone()).map_err(|e| {
        Failure::refused(format!(
            "{}: the job's options do not read: {e}",
            record_file.display()
        ))
    })?;
    let elsewhere = args.sim || !args.ports.is_empty() || !args.tcp.is_empty();
    let (sim, fast, ports, tcp) = if elsewhere {
        (args.sim, args.fast, args.ports.clone(), args.tcp.clone())
    } else {
        (
            old.target.sim,
            old.target.fast,
            old.target.ports.clone(),
            old.target.tcp.clone(),
        )
    };
    let out = args.out.clone().unwrap_or_else(|| {
        osap_machine::runs::folder_name(
            Path::new(""),
            "run",
            &old.machine_name,
            None,
            osap_machine::runs::local_now(),
        )
    });
    check_out(&out)?;
    // The record's own copies: the files on disk may have changed since.
    let (machine, job_copy) = old.restore_inputs(&out.join("inputs")).map_err(refused)?;
    let job_copy = job_copy.ok_or_else(|| Failure::refused("the record holds no job"))?;
    let target = Target {
        machine,
        sim,
        fast,
        ports,
        baud: osap_host::link::serial::DEFAULT_BAUD,
        tcp,
        key: None,
    };
    let run_args = options.args(target, job_copy, out.clone())?;
    println!(
        "replaying {} (osap run {}, {}) on {}",
        record_file.display(),
        job.path,
        local_time(&old.started.wall),
        if sim && fast {
            "simulated modules in virtual time"
        } else if sim {
            "simulated modules"
        } else {
            "the connected machine"
        }
    );
    let (code, out) = crate::machine_cmd::run_recorded(
        &run_args,
        started,
        &job.path,
        false,
        Some(record_file.display().to_string()),
    )
    .await?;
    let new = RunRecord::read(&out).map_err(refused)?;
    let differ = side_by_side(&old, &new);
    println!(
        "recorded: {} (exit {})   replayed: {} (exit {}), in {}",
        old.outcome.status,
        old.outcome.exit_code,
        new.outcome.status,
        new.outcome.exit_code,
        out.display()
    );
    if differ == 0 {
        println!("the summaries agree (wall-clock lines aside)");
    } else {
        println!("{differ} summary lines differ (marked |), wall-clock lines aside");
    }
    Ok(ExitCode::from(code))
}

/// Prints the two summaries side by side, `=` between lines that agree,
/// `|` between lines that differ and `~` between wall-clock lines; the
/// count of lines that differ (wall-clock lines aside).
fn side_by_side(old: &RunRecord, new: &RunRecord) -> usize {
    const WIDTH: usize = 64;
    let cut = |s: &str| -> String {
        let mut t: String = s.chars().take(WIDTH).collect();
        if s.chars().count() > WIDTH {
            t.pop();
            t.push('…');
        }
        format!("{t:<WIDTH$}")
    };
    println!("{}   replayed", cut("recorded"));
    let rows = old.summary.len().max(new.summary.len());
    let mut differ = 0;
    for i in 0..rows {
        let a = old.summary.get(i);
        let b = new.summary.get(i);
        let wall = a.is_some_and(|l| l.wall_clock) && b.is_some_and(|l| l.wall_clock);
        let same = matches!((a, b), (Some(a), Some(b)) if a.text == b.text);
        let mark = if wall {
            '~'
        } else if same {
            '='
        } else {
            differ += 1;
            '|'
        };
        println!(
            "{} {mark} {}",
            cut(a.map_or("", |l| l.text.as_str())),
            b.map_or("", |l| l.text.as_str())
        );
    }
    differ
}
