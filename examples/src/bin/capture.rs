//! A machine script: record sensor streams while the plotter draws a job,
//! and plot them against the motion on the machine's synchronized clock.
//!
//! The plotter (simulated by default, in virtual time) homes, then draws
//! `--job` (an SVG) while a capture records both accelerometers
//! (`a.analog_read(0)` sees the carriage along x, `b.analog_read(0)` along
//! y, through `[sim.axes]`'s mass-spring modes) and module a's stepped
//! position. The machine's own recording gives the planned and executed
//! path. The script writes:
//!
//! - `capture.parquet`: every sample with its source's synchronized time;
//! - `timeline.svg`: planned vs executed position and velocity, the
//!   following error, and the accelerometers, on one time axis.
//!
//! and prints, per series, its samples, rate and range, and how long after
//! the plan's first move each accelerometer first saw the carriage move.
//!
//! ```text
//! cargo run -p osap-examples --bin capture -- --out /tmp/plotter-capture
//! ```

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use osap_machine::capture::RecordOptions;
use osap_machine::config::MachineFile;
use osap_machine::sim::SimOptions;
use osap_machine::svg::SvgOptions;
use osap_machine::{job, record, Machine};

#[derive(Parser, Debug)]
#[command(about = "Record sensor streams during a job and plot them against the motion")]
struct Args {
    /// The machine file.
    #[arg(long, default_value = concat!(env!("CARGO_MANIFEST_DIR"), "/machines/plotter.toml"))]
    machine: PathBuf,
    /// The job (SVG).
    #[arg(long, default_value = concat!(env!("CARGO_MANIFEST_DIR"), "/jobs/drawing.svg"))]
    job: PathBuf,
    /// Drawing speed, mm/s.
    #[arg(long, default_value_t = 120.0)]
    feed: f64,
    /// The sources to record (MODULE.FUNCTION[(ARGS)][.OUTPUT]).
    #[arg(
        long = "source",
        default_values_t = ["a.analog_read(0)".to_string(), "b.analog_read(0)".to_string(), "a.get_position".to_string()]
    )]
    sources: Vec<String>,
    /// Sampling period of the captured sources, µs.
    #[arg(long, default_value_t = 2_000)]
    period_us: u32,
    /// Where to write capture.parquet and timeline.svg.
    #[arg(long, default_value = "examples-out/capture")]
    out: PathBuf,
}

/// Accelerometer readings are a fraction of full scale, 0.5 at rest; a
/// change larger than this is motion.
const MOVED: f64 = 0.01;

async fn run(args: Args) -> Result<(), Box<dyn std::error::Error>> {
    let cfg = MachineFile::load(&args.machine)?;
    let text = std::fs::read_to_string(&args.job)
        .map_err(|e| format!("job {}: {e}", args.job.display()))?;
    let drawing = osap_machine::svg::read(&text, &SvgOptions::default())?;
    let program = job::from_svg(&cfg, &drawing, args.feed)?;
    std::fs::create_dir_all(&args.out)
        .map_err(|e| format!("output folder {}: {e}", args.out.display()))?;

    let machine = Machine::simulate_with(&cfg, SimOptions::VIRTUAL).await?;
    machine.home().await?;
    // Homing's last move leaves the carriage ringing for a few time
    // constants of its resonance (45 Hz, damping 0.08: 44 ms); a capture
    // that starts on a still machine sees the job's first move, not that.
    machine.dwell(0.3).await?;

    // The capture first (its sources are checked before anything is
    // wired), then the machine's own recording of planned and executed.
    let sources: Vec<&str> = args.sources.iter().map(String::as_str).collect();
    let parquet = args.out.join("capture.parquet");
    let recorder = machine
        .record(
            &sources,
            RecordOptions::new(&parquet).period_us(args.period_us),
        )
        .await?;
    machine.start_recording().await?;
    let t0 = machine.now_us().await?;
    let ran = machine.run_program(&program, |_| {}).await;
    let recording = machine.take_recording(t0).await;
    // Finish the capture whatever happened to the job: the file is closed
    // and what was recorded stays readable.
    let file = recorder.finish().await;
    machine.stop().await?;
    ran?;
    let (recording, file) = (recording?, file?);

    let capture = file.read()?;
    println!(
        "job: {} moves in {:.2} s; capture: {} rows, {} dropped, {} stale, {} lost at the modules",
        program.moves.len(),
        recording.planned.last().map_or(0.0, |s| s.t),
        file.rows,
        file.stats.dropped,
        file.stats.stale,
        file.stats.lost_at_source,
    );
    let plan_start = recording
        .planned
        .windows(2)
        .find(|w| w[0].pos != w[1].pos)
        .map(|w| w[0].t);
    for s in &capture.series {
        let (lo, hi) = s
            .value
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
                (lo.min(*v), hi.max(*v))
            });
        let span_s = match (s.time_us.first(), s.time_us.last()) {
            (Some(a), Some(b)) if b > a => (b - a) as f64 * 1e-6,
            _ => 0.0,
        };
        let rate = if span_s > 0.0 {
            (s.value.len() - 1) as f64 / span_s
        } else {
            0.0
        };
        println!(
            "series {}: {} samples at {rate:.0} Hz, {lo:.4} .. {hi:.4}",
            s.name,
            s.value.len()
        );
        if s.name.contains("analog_read") {
            let first_motion = s
                .time_us
                .iter()
                .zip(&s.value)
                .find(|(_, v)| (**v - 0.5).abs() > MOVED)
                .map(|(t, _)| (*t as f64 - t0 as f64) * 1e-6);
            if let (Some(seen), Some(planned)) = (first_motion, plan_start) {
                println!(
                    "  first motion seen {:.1} ms after the plan's first move",
                    (seen - planned) * 1e3
                );
            }
        }
    }
    let timeline = args.out.join("timeline.svg");
    record::plot_timeline(&timeline, Some(&recording), &capture.streams(t0))?;
    println!("wrote {}", parquet.display());
    println!("wrote {}", timeline.display());
    Ok(())
}

fn main() -> ExitCode {
    osap_examples::run_virtual(run(Args::parse()))
}
