//! `osap run|home|jog|move|halt MACHINE.toml ...`: machine commands.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use osap_host::link::serial;
use osap_machine::config::MachineFile;
use osap_machine::job::{self, HotendTemperature, Program};
use osap_machine::machine::Link;
use osap_machine::runs::{InputFile, RUN_FILE};
use osap_machine::sim::SimOptions;
use osap_machine::svg::SvgOptions;
use osap_machine::{Machine, MachineError, MachineState};
use osap_sim::machine::TimeMode;
use serde::{Deserialize, Serialize};

use crate::run_record::Summary;

/// Exit code of a job or argument refused before any motion.
pub(crate) const REFUSED: u8 = 2;
/// Exit code of a failure during motion that is not the machine's own
/// fault report: the host runtime, a link, or a lost clock.
pub(crate) const FAULTED: u8 = 1;
/// Exit code of a machine fault: a module reported a fault that stops the
/// machine (a refused point, its backstop, late steps, a limit press, a
/// halt) or stopped answering, or a stop did not reach every module; the
/// message names the module and why.
pub(crate) const MACHINE_FAULT: u8 = 3;

/// Where a machine command finds the machine.
#[derive(Args, Clone, Debug)]
pub(crate) struct Target {
    /// The machine file (TOML), e.g. examples/machines/plotter.toml.
    pub machine: PathBuf,
    /// Run on simulated modules derived from the machine file.
    #[arg(long)]
    pub sim: bool,
    /// With --sim: run in virtual time, as fast as the host computes it.
    #[arg(long, requires = "sim")]
    pub fast: bool,
    /// Serial port of a module or adapter (repeatable).
    #[arg(long = "port", value_name = "PATH", conflicts_with = "sim")]
    pub ports: Vec<String>,
    /// Baud rate for --port (USB CDC modules ignore it).
    #[arg(long, default_value_t = serial::DEFAULT_BAUD)]
    pub baud: u32,
    /// Connect over TCP (repeatable), e.g. to `osap serve`.
    #[arg(long = "tcp", value_name = "ADDR", conflicts_with = "sim")]
    pub tcp: Vec<String>,
    /// Key file for --tcp servers that require one (`osap serve --key`;
    /// docs/security.md).
    #[arg(long, value_name = "FILE", requires = "tcp")]
    pub key: Option<PathBuf>,
}

impl Target {
    /// Whether the command must run on a virtual-time runtime.
    pub(crate) fn virtual_time(&self) -> bool {
        self.sim && self.fast
    }

    pub(crate) fn load(&self) -> Result<MachineFile, Failure> {
        MachineFile::load(&self.machine).map_err(|e| Failure::refused(e.to_string()))
    }

    pub(crate) async fn start(&self, cfg: &MachineFile) -> Result<Machine, Failure> {
        let result = if self.sim {
            let time = if self.fast {
                TimeMode::Virtual
            } else {
                TimeMode::RealTime
            };
            Machine::simulate_with(cfg, SimOptions { time }).await
        } else {
            Machine::connect(cfg, &self.links()?).await
        };
        result.map_err(Failure::from_machine)
    }

    /// The links to the machine: --port and --tcp as given, else every
    /// osap-rs USB device plugged in.
    pub(crate) fn links(&self) -> Result<Vec<Link>, Failure> {
        let mut links: Vec<Link> = self
            .ports
            .iter()
            .map(|p| Link::Serial {
                path: p.clone(),
                baud: self.baud,
            })
            .collect();
        let key = match &self.key {
            Some(file) => Some(
                osap_host::link::noise::Key::load(file)
                    .map_err(|e| Failure::refused(e.to_string()))?,
            ),
            None => None,
        };
        links.extend(self.tcp.iter().map(|a| match &key {
            Some(key) => Link::TcpKeyed {
                addr: a.clone(),
                key: key.clone(),
            },
            None => Link::Tcp(a.clone()),
        }));
        if links.is_empty() {
            let found = serial::available_ports().map_err(|e| Failure::refused(e.to_string()))?;
            links.extend(found.into_iter().map(|c| Link::Serial {
                path: c.path,
                baud: self.baud,
            }));
        }
        if links.is_empty() {
            return Err(Failure::refused(
                "no modules found: plug them in over USB, name them with --port PATH or --tcp ADDR, or add --sim to run on simulated modules",
            ));
        }
        Ok(links)
    }
}

/// Why a command failed, and its exit code.
pub(crate) struct Failure {
    /// The exit code.
    pub code: u8,
    /// The message.
    pub message: String,
}

impl Failure {
    pub(crate) fn refused(message: impl Into<String>) -> Failure {
        Failure {
            code: REFUSED,
            message: message.into(),
        }
    }

    pub(crate) fn from_machine(e: MachineError) -> Failure {
        let code = match e {
            MachineError::Faulted(_) | MachineError::StopIncomplete(_) => MACHINE_FAULT,
            MachineError::Homing { .. } | MachineError::Probe { .. } | MachineError::Stopped => {
                FAULTED
            }
            MachineError::Host(_)
            | MachineError::Network(_)
            | MachineError::NotSynchronised { .. } => FAULTED,
            _ => REFUSED,
        };
        Failure {
            code,
            message: e.to_string(),
        }
    }
}

/// `osap run` options.
#[derive(Args, Clone, Debug)]
pub(crate) struct RunArgs {
    #[command(flatten)]
    pub target: Target,
    /// The job: G-code (.gcode, .nc, .ngc, .g) or a drawing (.svg).
    pub job: PathBuf,
    /// Where to write planned.csv, executed.csv and the plots (default: a
    /// new folder osap-run-NAME-TIME in the current directory).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Drawing speed for SVG jobs, units/s (default: half the machine's
    /// velocity limit).
    #[arg(long)]
    pub feed: Option<f64>,
    /// SVG: scale the drawing about its bottom-left corner.
    #[arg(long, default_value_t = 1.0)]
    pub scale: f64,
    /// SVG: where the drawing's bottom-left corner goes, "X,Y".
    #[arg(long, value_parser = parse_pair, value_name = "X,Y")]
    pub offset: Option<[f64; 2]>,
    /// G-code: the work zero, "X,Y,Z" in machine coordinates (mm), that
    /// G54 selects (instead of the machine file's [work_offsets] G54, or
    /// the machine's zero).
    #[arg(long, value_parser = parse_triple, value_name = "X,Y,Z")]
    pub origin: Option<[f64; 3]>,
    /// Do not home first: the machine is taken to be at its start position
    /// (0 on each axis, or its min).
    #[arg(long)]
    pub no_home: bool,
    /// G-code: the hotend's temperature, replacing the job's M104/M109
    /// targets: N °C, or `auto`, the lowest in the melt model's range
    /// ([axes.e.model], from `osap rheo --write`) at which the job's peak
    /// flow stays under the model's limit.
    #[arg(long, value_parser = parse_temperature, value_name = "auto|C")]
    pub temperature: Option<HotendTemperature>,
}

/// `auto` or a temperature, °C.
fn parse_temperature(s: &str) -> Result<HotendTemperature, String> {
    if s.eq_ignore_ascii_case("auto") {
        return Ok(HotendTemperature::Auto);
    }
    s.trim()
        .parse::<f64>()
        .ok()
        .filter(|c| c.is_finite() && *c > 0.0)
        .map(HotendTemperature::Celsius)
        .ok_or_else(|| format!("{s:?}: give auto or a temperature in °C, e.g. 215"))
}

/// `N` finite numbers separated by commas (`X,Y` or `X,Y,Z`).
fn parse_numbers<const N: usize>(s: &str, what: &str) -> Result<[f64; N], String> {
    let parts: Vec<&str> = s.split(',').collect();
    if parts.len() != N {
        return Err(format!("{s:?}: give {what}"));
    }
    let mut out = [0.0; N];
    for (o, v) in out.iter_mut().zip(parts) {
        *o = v
            .trim()
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| format!("{v:?} is not a number"))?;
    }
    Ok(out)
}

fn parse_pair(s: &str) -> Result<[f64; 2], String> {
    parse_numbers(s, "X,Y")
}

fn parse_triple(s: &str) -> Result<[f64; 3], String> {
    parse_numbers(s, "X,Y,Z")
}

/// How a job is placed: an SVG drawing's scale, offset and feed, a G-code
/// job's origin.
pub(crate) struct JobPlacement {
    pub scale: f64,
    pub offset: Option<[f64; 2]>,
    pub feed: Option<f64>,
    pub origin: Option<[f64; 3]>,
    pub temperature: Option<HotendTemperature>,
}

impl Default for JobPlacement {
    fn default() -> Self {
        JobPlacement {
            scale: 1.0,
            offset: None,
            feed: None,
            origin: None,
            temperature: None,
        }
    }
}

/// Reads the job into a program checked against the machine's travel.
fn read_job(cfg: &MachineFile, args: &RunArgs) -> Result<Program, Failure> {
    let placement = JobPlacement {
        scale: args.scale,
        offset: args.offset,
        feed: args.feed,
        origin: args.origin,
        temperature: args.temperature,
    };
    read_job_file(cfg, &args.job, &placement)
}

/// Reads the job `path` (G-code or SVG) into a program checked against the
/// machine's travel.
pub(crate) fn read_job_file(
    cfg: &MachineFile,
    path: &std::path::Path,
    placement: &JobPlacement,
) -> Result<Program, Failure> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| Failure::refused(format!("job {}: {e}", path.display())))?;
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    let start = osap_machine::machine::drive::start_position(cfg);
    let name = path.display();
    match ext.as_str() {
        "svg" => {
            if placement.origin.is_some() {
                return Err(Failure::refused(format!(
                    "{name}: --origin X,Y,Z places G-code jobs; place a drawing with --offset X,Y"
                )));
            }
            if placement.temperature.is_some() {
                return Err(Failure::refused(format!(
                    "{name}: --temperature sets a printer's hotend for a G-code job; a drawing heats nothing"
                )));
            }
            let options = SvgOptions {
                scale: placement.scale,
                offset: placement.offset.unwrap_or([0.0, 0.0]),
                ..SvgOptions::default()
            };
            let drawing = osap_machine::svg::read(&text, &options)
                .map_err(|e| Failure::refused(format!("{name}: {e}")))?;
            let feed = placement.feed.unwrap_or(cfg.limits.velocity / 2.0);
            job::from_svg(cfg, &drawing, feed).map_err(|e| Failure::refused(format!("{name}: {e}; nothing moved")))
        }
        "gcode" | "nc" | "ngc" | "g" | "gc" | "tap" => {
            if placement.offset.is_some() {
                return Err(Failure::refused(format!(
                    "{name}: --offset X,Y places drawings; place G-code with --origin X,Y,Z (the work zero G54 selects)"
                )));
            }
            let options = job::gcode_options(cfg, placement.origin);
            let program = osap_machine::gcode::read_with(&text, &options)
                .map_err(|e| Failure::refused(format!("{name}: {e}")))?;
            let hotend = placement.temperature.unwrap_or_default();
            job::from_gcode_with(cfg, &program, &start, hotend)
                .map_err(|e| Failure::refused(format!("{name}: {e}; nothing moved")))
        }
        other => Err(Failure::refused(format!(
            "{name}: unknown job type {other:?}: give a .svg drawing or G-code (.gcode, .nc, .ngc, .g)"
        ))),
    }
}

/// A new output folder in the current directory:
/// `osap-KIND-NAME[-DETAIL]-YYYYMMDD-HHMMSS` (local time), the machine's
/// name made safe for a path ([`osap_machine::runs::folder_name`]).
pub(crate) fn default_folder(kind: &str, cfg: &MachineFile, detail: Option<&str>) -> PathBuf {
    osap_machine::runs::folder_name(
        Path::new(""),
        kind,
        &cfg.name,
        detail,
        osap_machine::runs::local_now(),
    )
}

/// Refuses an output folder inside a repository's `docs` (runs are not
/// documentation).
pub(crate) fn check_out(dir: &Path) -> Result<(), Failure> {
    let abs = std::path::absolute(dir).unwrap_or_else(|_| dir.to_path_buf());
    let mut p = abs.as_path();
    while let Some(parent) = p.parent() {
        if p.file_name().is_some_and(|n| n == "docs") && parent.join(".git").exists() {
            return Err(Failure::refused(format!(
                "--out {}: not inside a repository's docs; pick another folder",
                dir.display()
            )));
        }
        p = parent;
    }
    Ok(())
}

/// What `osap run` records of a job's placement (`run.json`'s
/// `options`), to run it again the same way.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub(crate) struct RunOptions {
    /// `--feed`.
    #[serde(default)]
    pub feed: Option<f64>,
    /// `--scale`.
    #[serde(default = "one")]
    pub scale: f64,
    /// `--offset`.
    #[serde(default)]
    pub offset: Option<[f64; 2]>,
    /// `--origin`.
    #[serde(default)]
    pub origin: Option<[f64; 3]>,
    /// `--no-home`.
    #[serde(default)]
    pub no_home: bool,
    /// `--temperature`: `auto` or °C.
    #[serde(default)]
    pub temperature: Option<String>,
}

fn one() -> f64 {
    1.0
}

impl RunOptions {
    /// The options `args` gives.
    pub(crate) fn of(args: &RunArgs) -> RunOptions {
        RunOptions {
            feed: args.feed,
            scale: args.scale,
            offset: args.offset,
            origin: args.origin,
            no_home: args.no_home,
            temperature: args.temperature.and_then(|t| match t {
                HotendTemperature::AsJob => None,
                HotendTemperature::Auto => Some("auto".to_string()),
                HotendTemperature::Celsius(c) => Some(c.to_string()),
            }),
        }
    }

    /// `osap run` arguments for `job` on `target` with these options.
    pub(crate) fn args(
        &self,
        target: Target,
        job: PathBuf,
        out: PathBuf,
    ) -> Result<RunArgs, Failure> {
        let temperature = self
            .temperature
            .as_deref()
            .map(parse_temperature)
            .transpose()
            .map_err(Failure::refused)?;
        Ok(RunArgs {
            target,
            job,
            out: Some(out),
            feed: self.feed,
            scale: self.scale,
            offset: self.offset,
            origin: self.origin,
            no_home: self.no_home,
            temperature,
        })
    }
}

/// `osap run`.
pub(crate) async fn run(args: RunArgs, started: Instant) -> Result<ExitCode, Failure> {
    let job = args.job.display().to_string();
    run_recorded(&args, started, &job, true, None)
        .await
        .map(|(code, _)| ExitCode::from(code))
}

/// `osap run`, recorded in `run.json` in its folder however it ends: the
/// exit code and the folder. `job_name` is the job as the summary names
/// it; `print` says whether the summary is printed (replay prints it side
/// by side instead); `replay_of` names the record it replays.
pub(crate) async fn run_recorded(
    args: &RunArgs,
    started: Instant,
    job_name: &str,
    print: bool,
    replay_of: Option<String>,
) -> Result<(u8, PathBuf), Failure> {
    let cfg = args.target.load()?;
    let program = read_job(&cfg, args)?;
    for w in &program.warnings {
        eprintln!("warning: {w}");
    }
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| default_folder("run", &cfg, None));
    check_out(&out)?;
    let mut record = crate::run_record::begin("run", &args.target, &cfg)?;
    record.job = Some(
        InputFile::read(&args.job)
            .map_err(|e| Failure::refused(format!("job {}: {e}", args.job.display())))?,
    );
    record.options = serde_json::to_value(RunOptions::of(args)).unwrap_or_default();
    record.replay_of = replay_of;
    let mut end_sync = None;
    let result = run_job(
        args,
        &cfg,
        &program,
        &out,
        started,
        job_name,
        Summary {
            record: &mut record,
            print,
        },
        &mut end_sync,
    )
    .await;
    let code = crate::run_record::finish(record, &out.join(RUN_FILE), end_sync, result)?;
    Ok((code, out))
}

/// Runs the job: the machine from start to stop, the summary and the
/// data files (listed in the record). The exit code, or why it failed.
#[allow(clippy::too_many_arguments)] // one call site; the parts are distinct
async fn run_job(
    args: &RunArgs,
    cfg: &MachineFile,
    program: &Program,
    out: &Path,
    started: Instant,
    job_name: &str,
    mut sum: Summary<'_>,
    end_sync: &mut Option<u64>,
) -> Result<u8, Failure> {
    let print = sum.print;
    let start = osap_machine::machine::drive::start_position(cfg);

    let machine = args.target.start(cfg).await?;
    crate::run_record::machine_started(sum.record, &machine).await;
    // Every event, taken as it comes: a long job must not outrun the
    // stream.
    let (events_done, done) = tokio::sync::oneshot::channel();
    let judge = machine.clone();
    let heard = tokio::spawn(crate::run_events::collect(
        machine.events(),
        Box::new(move |module, kind, detail| judge.fault_stops(module, kind, detail)),
        done,
    ));
    sum.wall(format!(
        "machine {} ready ({} modules, {}) after {:.2} s",
        cfg.name,
        machine.modules().len(),
        if args.target.sim {
            if args.target.fast {
                "simulated, virtual time"
            } else {
                "simulated"
            }
        } else {
            "connected"
        },
        started.elapsed().as_secs_f64()
    ));
    if args.no_home {
        machine
            .set_position(&start)
            .map_err(Failure::from_machine)?;
    } else {
        machine.home().await.map_err(Failure::from_machine)?;
        sum.wall(format!(
            "homed after {:.2} s",
            started.elapsed().as_secs_f64()
        ));
    }

    let planned_s = program
        .planned_seconds(cfg, &machine.position())
        .map_err(Failure::from_machine)?;
    // What the flow limit cost, planned: the same job at the feeds it asked.
    let unlimited_s = if program.slowed.is_empty() {
        planned_s
    } else {
        program
            .without_flow_limit()
            .planned_seconds(cfg, &machine.position())
            .map_err(Failure::from_machine)?
    };
    let bar = ProgressBar::new(program.moves.len() as u64);
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} moves  {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    machine
        .start_recording()
        .await
        .map_err(Failure::from_machine)?;
    let t0 = machine.now_us().await.map_err(Failure::from_machine)?;
    // Every heater at 10 Hz on the synchronized clock, for heaters.csv.
    let heater_log = (!cfg.heaters.is_empty())
        .then(|| machine.log_heaters(std::time::Duration::from_millis(100)));
    let mut first = None;
    // Machine time (tokio's clock: virtual with --fast).
    let began = tokio::time::Instant::now();
    let result = machine
        .run_program(program, |p| {
            if first.is_none() {
                let line = format!(
                    "first job move queued {:.2} s after start",
                    started.elapsed().as_secs_f64()
                );
                if print {
                    eprintln!("{line}");
                }
                first = Some(line);
            }
            bar.set_position(p.done as u64);
            let left = (planned_s - began.elapsed().as_secs_f64()).max(0.0);
            bar.set_message(format!("about {left:.0} s left (line/path {})", p.line));
        })
        .await;
    bar.finish_and_clear();
    if let Some(line) = first {
        sum.record.wall_line(line);
    }
    if result.is_err() && heater_log.is_some() {
        // The fault's stop turns every heater off on its module: let it
        // finish, so the log's last row shows them off.
        let _ = machine.halt().await;
    }
    let heater_rows = match heater_log {
        Some(log) => {
            let names = log.names().to_vec();
            Some((names, log.finish().await))
        }
        None => None,
    };
    let t1 = machine.now_us().await.map_err(Failure::from_machine)?;
    *end_sync = Some(t1);
    let mut recording = machine
        .take_recording(t0)
        .await
        .map_err(Failure::from_machine)?;
    if args.target.sim {
        recording.vibration = osap_machine::sim::vibration(cfg, &recording);
        // Each stall on the recording's clock: the host's clock now and
        // the synchronized time now pair the two.
        let spans = machine.sim_stall_spans();
        if !spans.is_empty() {
            let now = osap_host::clock::now();
            let sync_now = machine.now_us().await.map_err(Failure::from_machine)?;
            let at = |t: f64| -> std::time::Instant {
                let sync = t0 as f64 + t * 1e6;
                let back =
                    std::time::Duration::from_secs_f64(((sync_now as f64 - sync) * 1e-6).max(0.0));
                now.checked_sub(back).unwrap_or(now)
            };
            recording.stalled = spans
                .into_iter()
                .map(|(motor, spans)| {
                    let flags = recording
                        .executed
                        .iter()
                        .map(|e| {
                            let i = at(e.t);
                            let stalled = spans
                                .iter()
                                .any(|(a, b)| *a <= i && b.is_none_or(|b| i < b));
                            f64::from(u8::from(stalled))
                        })
                        .collect();
                    (motor, flags)
                })
                .collect();
        }
    }

    // What the simulated melt and motors did, read before the machine stops.
    let melt = machine.sim_melt();
    let stalls = machine.sim_stalls();
    // Whether a fault stopped the machine: its first fault is the reason.
    let faulted = match machine.state() {
        MachineState::Faulted(reason) => Some(reason),
        _ => None,
    };
    // The machine's stop at the end, heard with the rest.
    let stopped = machine.clone().stop().await;
    let _ = events_done.send(());
    let heard = heard.await.map_err(|e| Failure {
        code: FAULTED,
        message: format!("collecting the machine's events: {e}"),
    })?;
    let stopped_by = faulted.or_else(|| heard.stopping.first().cloned());

    sum.line(format!("job {job_name}: {} moves", program.moves.len()));
    if let Some(dialect) = program.dialect {
        sum.line(format!(
            "G-code dialect     {dialect} ({})",
            if cfg.gcode.dialect.is_some() {
                "[gcode] dialect".to_string()
            } else {
                format!("the default for kind = \"{}\"", cfg.kind)
            }
        ));
    }
    sum.line(format!("planned duration   {:>9.3} s", planned_s));
    sum.record.figure("planned_s", planned_s);
    print_flow(&mut sum, cfg, program, planned_s - unlimited_s);
    let executed_s = recording.executed_duration();
    let with_waits_s = (t1.saturating_sub(t0)) as f64 * 1e-6;
    sum.line(format!(
        "executed duration  {:>9.3} s (motion; {:.3} s with tool waits)",
        executed_s, with_waits_s
    ));
    sum.record.figure("executed_s", executed_s);
    sum.record.figure("executed_with_waits_s", with_waits_s);
    for (axis, err) in recording.following_error() {
        sum.line(format!("largest following error {axis}: {:.4} mm", err));
        sum.record
            .figure(&format!("following_error_{axis}_mm"), err);
    }
    for (axis, v) in recording.largest_vibration() {
        sum.line(format!("largest vibration {axis}: {v:.4} mm"));
        sum.record.figure(&format!("vibration_{axis}_mm"), v);
    }
    // A stall is a fault the open-loop machine cannot hear: the job is
    // spoilt all the same.
    let stalled: usize = stalls.iter().map(|s| s.stalls).sum();
    if !stalls.is_empty() {
        sum.line(format!("stalls: {stalled}"));
        sum.record.figure("stalls", stalled as f64);
        for s in stalls.iter().filter(|s| s.stalls > 0) {
            sum.fault(format!(
                "error: motor {} stalled {} times and lost {:.0} full steps: its carriage is not where the machine thinks",
                s.motor, s.stalls, s.lost_full_steps
            ));
        }
    }
    if let Some(k) = recording.axes.iter().position(|a| a == "e") {
        let e_at = |s: Option<&osap_machine::record::Sample>| s.map_or(0.0, |s| s.pos[k]);
        let executed = e_at(recording.executed.last()) - e_at(recording.executed.first());
        sum.line(format!(
            "filament used      {:>9.2} mm of e executed ({:.2} mm in the job)",
            executed,
            program.extruded_mm()
        ));
        sum.record.figure("filament_mm", executed);
    }
    if let Some((spec, stats)) = &melt {
        sum.line(format!(
            "nozzle force peak  {:>9.2} N (simulated melt; grip {} N)",
            stats.peak_force_n, spec.grip_n
        ));
        sum.line(format!(
            "filament slips     {:>9} ({:.2} mm of filament stepped while slipping)",
            stats.slips, stats.slipped_mm
        ));
        sum.record.figure("nozzle_force_peak_n", stats.peak_force_n);
        sum.record.figure("filament_slips", stats.slips as f64);
    }
    if let Ok(stats) = &result {
        if !cfg.heaters.is_empty() {
            sum.line(format!("waited on heaters  {:>9.3} s", stats.heater_wait_s));
            sum.record.figure("heater_wait_s", stats.heater_wait_s);
        }
    }
    for (module, (count, reason)) in &heard.refusals {
        sum.fault(format!(
            "module {module} refused {count} points (the latest: {reason})"
        ));
    }
    for f in &heard.passed {
        sum.line(format!(
            "note: {f} (within this machine file's bounds: not a stop)"
        ));
    }
    if heard.missed > 0 {
        sum.fault(format!(
            "error: {} machine events were missed (the event stream lagged): the faults below may be incomplete",
            heard.missed
        ));
    }
    if !heard.stopped() && stopped_by.is_none() && heard.missed == 0 && stalled == 0 {
        sum.line("faults: none");
    }
    for f in &heard.stopping {
        sum.fault(format!("error: fault: {f}"));
    }
    for s in heard.stops.iter().filter(|s| !s.is_complete()) {
        sum.fault(format!("error: {s}"));
    }
    let mut files = recording
        .write_csv(out)
        .and_then(|mut f| {
            f.extend(recording.plot(out)?);
            Ok(f)
        })
        .map_err(|e| Failure {
            code: FAULTED,
            message: e.to_string(),
        })?;
    if !program.slowed.is_empty() {
        let path = out.join("slowed.csv");
        program.write_slowed_csv(&path).map_err(|e| Failure {
            code: FAULTED,
            message: format!("{}: {e}", path.display()),
        })?;
        files.push(path);
    }
    if let Some((names, rows)) = &heater_rows {
        let path = out.join("heaters.csv");
        osap_machine::machine::heaters::write_heaters_csv(&path, names, rows, t0).map_err(|e| {
            Failure {
                code: FAULTED,
                message: format!("{}: {e}", path.display()),
            }
        })?;
        files.push(path);
    }
    sum.record.add_files(out, &files).map_err(|e| Failure {
        code: FAULTED,
        message: e.to_string(),
    })?;
    if print {
        println!(
            "wrote {} files to {}: {}",
            files.len(),
            out.display(),
            files
                .iter()
                .filter_map(|f| f.file_name().map(|n| n.to_string_lossy().into_owned()))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    result.map_err(Failure::from_machine)?;
    stopped.map_err(Failure::from_machine)?;
    let verdict = if let Some(reason) = stopped_by {
        Some((MACHINE_FAULT, format!("error: machine fault: {reason}")))
    } else if heard.stopped() {
        Some((
            MACHINE_FAULT,
            "error: machine fault: a stop did not reach every module".to_string(),
        ))
    } else if stalled > 0 {
        Some((MACHINE_FAULT, format!("error: machine fault: a simulated motor stalled ({stalled} stalls): the carriages are not where the job put them")))
    } else if heard.missed > 0 {
        Some((
            FAULTED,
            format!(
                "error: {} machine events were missed: whether the job ran clean is unknown",
                heard.missed
            ),
        ))
    } else {
        None
    };
    match verdict {
        Some((code, line)) => {
            if print {
                eprintln!("{line}");
            }
            sum.record.faults.insert(0, line);
            Ok(code)
        }
        None => Ok(0),
    }
}

/// The run summary's hotend and flow-limit lines: the temperature
/// `--temperature` set, and which moves the flow limit slowed and what it
/// cost (`added_s`, planned).
fn print_flow(sum: &mut Summary<'_>, cfg: &MachineFile, program: &Program, added_s: f64) {
    if let Some(h) = &program.hotend {
        let limit = h
            .limit
            .map_or(String::new(), |l| format!(", limit there {l:.2} mm³/s"));
        sum.line(format!(
            "hotend             {:>9.0} °C (--temperature {}: the job's peak flow {:.2} mm³/s{limit})",
            h.celsius,
            if h.auto { "auto".to_string() } else { format!("{}", h.celsius) },
            h.peak_flow,
        ));
    }
    let Some(e) = cfg.extruder().map(|a| &a.extruder) else {
        return;
    };
    let source = match (&e.model, e.max_volumetric_speed) {
        (Some(_), Some(_)) => "[axes.e.model] and max_volumetric_speed",
        (Some(_), None) => "[axes.e.model]",
        (None, Some(_)) => "max_volumetric_speed",
        (None, None) => return,
    };
    if program.slowed.is_empty() {
        sum.line(format!("flow limit         no move slowed ({source})"));
        return;
    }
    let mut lines: Vec<String> = program
        .slowed
        .iter()
        .take(6)
        .map(|s| s.line.to_string())
        .collect();
    if program.slowed.len() > lines.len() {
        lines.push("…".into());
    }
    let worst = program
        .slowed
        .iter()
        .map(|s| s.flow / s.limit)
        .fold(0.0, f64::max);
    sum.line(format!(
        "flow limit         {:>9} moves held to it ({source}): {added_s:+.3} s as planned (at most {:+.3} s at cruise); lines {} (slowed.csv); the most asked {:.0} % of its limit",
        program.slowed.len(),
        program.flow_limit_added_s(),
        lines.join(", "),
        worst * 100.0
    ));
}

/// `osap home MACHINE [AXIS ..]`.
pub(crate) async fn home(target: Target, axes: Vec<String>) -> Result<ExitCode, Failure> {
    let cfg = target.load()?;
    let machine = target.start(&cfg).await?;
    let names: Vec<&str> = axes.iter().map(String::as_str).collect();
    let r = if names.is_empty() {
        machine.home().await
    } else {
        machine.home_axes(&names).await
    };
    r.map_err(Failure::from_machine)?;
    println!("homed; position {}", show(&machine));
    machine.stop().await.map_err(Failure::from_machine)?;
    Ok(ExitCode::SUCCESS)
}

fn show(machine: &Machine) -> String {
    machine
        .axes()
        .iter()
        .zip(machine.position())
        .map(|(a, v)| format!("{a}={v:.3}"))
        .collect::<Vec<_>>()
        .join(" ")
}

/// `osap jog MACHINE AXIS DISTANCE`.
pub(crate) async fn jog(
    target: Target,
    axis: String,
    distance: f64,
    rate: Option<f64>,
) -> Result<ExitCode, Failure> {
    let cfg = target.load()?;
    if !cfg.axes.contains_key(&axis) {
        return Err(Failure::refused(format!(
            "no axis {axis:?} in {}; it has {}",
            target.machine.display(),
            cfg.axis_names().join(", ")
        )));
    }
    let rate = rate.unwrap_or(cfg.axes[&axis].velocity / 4.0);
    let machine = target.start(&cfg).await?;
    machine
        .jog(&axis, distance, rate)
        .await
        .map_err(Failure::from_machine)?;
    println!("jogged {axis} by {distance}; position {}", show(&machine));
    machine.stop().await.map_err(Failure::from_machine)?;
    Ok(ExitCode::SUCCESS)
}

/// `osap move MACHINE AXIS=VALUE ..`: homes, then moves there.
pub(crate) async fn move_to(
    target: Target,
    coords: Vec<String>,
    rate: Option<f64>,
) -> Result<ExitCode, Failure> {
    let cfg = target.load()?;
    let axes: Vec<String> = cfg.axis_names().iter().map(|s| s.to_string()).collect();
    let mut to: Vec<Option<f64>> = vec![None; axes.len()];
    for c in &coords {
        let (a, v) = c
            .split_once('=')
            .ok_or_else(|| Failure::refused(format!("{c:?}: give AXIS=VALUE, e.g. x=10")))?;
        let k = axes.iter().position(|n| n == a).ok_or_else(|| {
            Failure::refused(format!(
                "no axis {a:?}; the machine has {}",
                axes.join(", ")
            ))
        })?;
        let v: f64 = v
            .parse()
            .ok()
            .filter(|x: &f64| x.is_finite())
            .ok_or_else(|| Failure::refused(format!("{c:?}: {v:?} is not a number")))?;
        to[k] = Some(v);
    }
    let rate = rate.unwrap_or(cfg.limits.velocity / 2.0);
    let machine = target.start(&cfg).await?;
    machine.home().await.map_err(Failure::from_machine)?;
    let here = machine.position();
    let target_pos: Vec<f64> = to.iter().zip(&here).map(|(t, h)| t.unwrap_or(*h)).collect();
    machine
        .goto_now(&target_pos, rate)
        .await
        .map_err(Failure::from_machine)?;
    println!("moved; position {}", show(&machine));
    machine.stop().await.map_err(Failure::from_machine)?;
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_machine_fault_exits_with_its_own_code_and_names_the_module() {
        let f = Failure::from_machine(MachineError::Faulted(
            "module y refused a point: point not after the newest queued one (arrived late)".into(),
        ));
        assert_eq!(f.code, MACHINE_FAULT);
        assert!(
            f.message.contains("module y refused a point"),
            "{}",
            f.message
        );
        assert_eq!(Failure::from_machine(MachineError::Stopped).code, FAULTED);
        assert_eq!(
            Failure::from_machine(MachineError::BadRate(-1.0)).code,
            REFUSED
        );
        assert!(![0, FAULTED, REFUSED].contains(&MACHINE_FAULT));
    }

    #[test]
    fn default_folders_name_the_command_the_machine_and_the_detail() {
        let cfg = MachineFile::load(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../examples/machines/plotter.toml"
        ))
        .unwrap();
        let name = |p: PathBuf| p.to_string_lossy().into_owned();
        let mut odd = cfg.clone();
        odd.name = "my printer/2".into();
        let odd = name(default_folder("rheo", &odd, None));
        assert!(odd.starts_with("osap-rheo-my_printer_2-"), "{odd}");
        let safe = "plotter";
        let run = name(default_folder("run", &cfg, None));
        assert!(run.starts_with(&format!("osap-run-{safe}-")), "{run}");
        let res = name(default_folder("resonance", &cfg, Some("y")));
        assert!(
            res.starts_with(&format!("osap-resonance-{safe}-y-")),
            "{res}"
        );
        // …-YYYYMMDD-HHMMSS.
        let mut tail = res.rsplit('-');
        let (time, date) = (tail.next().unwrap(), tail.next().unwrap());
        assert_eq!((date.len(), time.len()), (8, 6), "{res}");
        assert!(
            date.parse::<u32>().is_ok() && time.parse::<u32>().is_ok(),
            "{res}"
        );
    }
}
