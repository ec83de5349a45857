//! `osap capture MACHINE.toml [--sim] --source MODULE.FUNCTION ... --seconds
//! S --out FILE.parquet`: records function outputs on the synchronized
//! clock into a Parquet or CSV file (`osap_machine::capture`), until the
//! time is up or Ctrl-C; the file is closed properly either way.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use clap::Args;
use osap_machine::capture::{Capture, CaptureError, Clock, RecordOptions, MIN_PERIOD_US};

use crate::machine_cmd::{Failure, Target, FAULTED};
use crate::run_record::{self, Summary};

/// `osap capture` options.
#[derive(Args, Debug)]
pub(crate) struct CaptureArgs {
    /// Where to find the machine.
    #[command(flatten)]
    pub target: Target,
    /// A source, MODULE.FUNCTION[(ARGS)][.OUTPUT] (repeatable), e.g.
    /// z.analog_read(0) or a.get_position; MODULE is a [modules] key or a
    /// runtime name.
    #[arg(long = "source", value_name = "SOURCE", required = true)]
    pub sources: Vec<String>,
    /// How long to record, seconds (Ctrl-C stops early).
    #[arg(long)]
    pub seconds: f64,
    /// The file: .parquet or .csv.
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
    /// Sampling period of every source, µs.
    #[arg(long, default_value_t = 1_000)]
    pub period_us: u32,
    /// Also plot every series against time (SVG), aligned on the
    /// synchronized clock.
    #[arg(long, value_name = "FILE.svg")]
    pub plot: Option<PathBuf>,
}

fn refused(e: CaptureError) -> Failure {
    Failure::refused(e.to_string())
}

/// Runs `osap capture`.
pub(crate) async fn capture(args: CaptureArgs) -> Result<ExitCode, Failure> {
    if !(args.seconds.is_finite() && args.seconds > 0.0 && args.seconds <= 1e6) {
        return Err(Failure::refused(format!(
            "--seconds {}: give a duration above 0 (at most 1e6 s)",
            args.seconds
        )));
    }
    if args.period_us < MIN_PERIOD_US {
        return Err(Failure::refused(format!(
            "--period-us {}: at least {MIN_PERIOD_US}",
            args.period_us
        )));
    }
    // Checked before the machine starts: a typo costs nothing.
    osap_machine::capture::Format::from_path(&args.out).map_err(refused)?;
    for s in &args.sources {
        osap_machine::capture::SourceSpec::parse(s).map_err(refused)?;
    }
    if let Some(dir) = args.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .map_err(|e| Failure::refused(format!("{}: {e}", dir.display())))?;
    }
    let cfg = args.target.load()?;
    let mut record = run_record::begin("capture", &args.target, &cfg)?;
    record.options = serde_json::json!({
        "sources": args.sources,
        "seconds": args.seconds,
        "period_us": args.period_us,
        "out": args.out.display().to_string(),
        "plot": args.plot.as_ref().map(|p| p.display().to_string()),
    });
    let record_file = run_record::beside(&args.out);
    let mut end_sync = None;
    let result = record_sources(&args, &cfg, &mut record, &mut end_sync).await;
    run_record::finish(record, &record_file, end_sync, result).map(ExitCode::from)
}

/// Records the sources into the file (and plots them).
async fn record_sources(
    args: &CaptureArgs,
    cfg: &osap_machine::config::MachineFile,
    record: &mut osap_machine::runs::RunRecord,
    end_sync: &mut Option<u64>,
) -> Result<u8, Failure> {
    let machine = args.target.start(cfg).await?;
    run_record::machine_started(record, &machine).await;
    let sources: Vec<&str> = args.sources.iter().map(String::as_str).collect();
    let options = RecordOptions::new(&args.out).period_us(args.period_us);
    let recorder = machine.record(&sources, options).await.map_err(refused)?;
    let t0 = machine.now_us().await.map_err(Failure::from_machine)?;
    println!(
        "recording {} series into {} for {} s (Ctrl-C stops)",
        recorder.series().len(),
        args.out.display(),
        args.seconds
    );
    let deadline = tokio::time::Instant::now() + Duration::from_secs_f64(args.seconds);
    let mut write_error = None;
    let mut interrupted = false;
    let ctrl_c = tokio::signal::ctrl_c();
    tokio::pin!(ctrl_c);
    loop {
        let tick = tokio::time::sleep_until(
            deadline.min(tokio::time::Instant::now() + Duration::from_millis(100)),
        );
        tokio::select! {
            _ = &mut ctrl_c => {
                interrupted = true;
                break;
            }
            _ = tick => {}
        }
        if let Err(e) = recorder.check() {
            write_error = Some(e);
            break;
        }
        if tokio::time::Instant::now() >= deadline {
            break;
        }
    }
    let result = recorder.finish().await;
    *end_sync = machine.now_us().await.ok();
    let _ = machine.stop().await;
    let file = match (result, write_error) {
        (Ok(file), None) => file,
        (Err(e), _) | (Ok(_), Some(e)) => {
            return Err(Failure {
                code: FAULTED,
                message: format!("{e} (free space or write elsewhere)"),
            })
        }
    };
    let mut sum = Summary {
        record,
        print: true,
    };
    if interrupted {
        sum.line("interrupted: the file is closed and holds what came so far");
    }
    sum.line(format!("{} rows in {}", file.rows, file.path.display()));
    sum.record.figure("rows", file.rows as f64);
    for s in &file.series {
        let span = match (s.stats.first_us, s.stats.last_us) {
            (Some(a), Some(b)) => format!("{:.3} s", (b - a) as f64 * 1e-6),
            _ => "no samples".into(),
        };
        let clock = match s.info.clock {
            Clock::Source => "",
            Clock::Arrival => "  (stamped on arrival at the host)",
        };
        sum.line(format!(
            "  {:<32} {:>9} rows over {span}{clock}",
            s.info.name, s.stats.rows
        ));
    }
    sum.record.figure("dropped", file.stats.dropped as f64);
    sum.record.figure("stale", file.stats.stale as f64);
    sum.record
        .figure("lost_at_source", file.stats.lost_at_source as f64);
    if file.stats.dropped > 0 || file.stats.stale > 0 {
        sum.line(format!(
            "  {} samples dropped on a full queue, {} out of order (not written)",
            file.stats.dropped, file.stats.stale
        ));
    }
    if file.stats.lost_at_source > 0 {
        sum.line(format!(
            "  {} samples lost at the modules (blocks that never arrived, a full pipe queue or a failed read: sample less often with --period-us, or record fewer sources per module)",
            file.stats.lost_at_source
        ));
    }
    let mut files = vec![file.path.clone()];
    if let Some(plot) = &args.plot {
        let capture = Capture::read(&file.path).map_err(refused)?;
        osap_machine::record::plot_timeline(plot, None, &capture.streams(t0))
            .map_err(|e| Failure::refused(e.to_string()))?;
        println!("plot: {}", plot.display());
        files.push(plot.clone());
    }
    let beside = args.out.parent().unwrap_or(std::path::Path::new(""));
    sum.record.add_files(beside, &files).map_err(|e| Failure {
        code: FAULTED,
        message: e.to_string(),
    })?;
    Ok(0)
}
