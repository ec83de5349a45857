//! `osap resonance MACHINE.toml --axis X`: home, shake the axis with a
//! chirp about the middle of its travel, record its accelerometer on the
//! synchronized clock, and report the frequency response, its peak and
//! the input shaper for it ([`osap_machine::resonance`]).

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Args;
use osap_machine::resonance::{self, ResonanceError};

use osap_machine::runs::RUN_FILE;

use crate::machine_cmd::{check_out, default_folder, Failure, Target, FAULTED};
use crate::run_record::{self, Summary};

/// `osap resonance` options.
#[derive(Args, Debug)]
pub(crate) struct ResonanceArgs {
    /// Where to find the machine.
    #[command(flatten)]
    pub target: Target,
    /// The axis to measure; it needs `accelerometer = { .. }` in the
    /// machine file.
    #[arg(long)]
    pub axis: String,
    /// How long the sweep lasts, s (3 s of ring-down follow).
    #[arg(long, default_value_t = 8.0)]
    pub seconds: f64,
    /// Where to write response.csv, samples.csv and bode.svg (default: a
    /// new folder osap-resonance-NAME-AXIS-TIME).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Put the recommended shaper into the machine file (`[axes.AXIS]
    /// shaper = { .. }`).
    #[arg(long)]
    pub write: bool,
    /// Do not home first (the axis must already be homed, e.g. on a
    /// served machine).
    #[arg(long)]
    pub no_home: bool,
}

fn failure(e: ResonanceError) -> Failure {
    match e {
        ResonanceError::Machine(e) => Failure::from_machine(e),
        ResonanceError::Refused(m) => Failure::refused(m),
        e => Failure {
            code: FAULTED,
            message: e.to_string(),
        },
    }
}

/// Runs `osap resonance`, recorded in `run.json` in its folder.
pub(crate) async fn resonance(args: ResonanceArgs) -> Result<ExitCode, Failure> {
    let cfg = args.target.load()?;
    // Refuse a bad axis or a missing accelerometer before anything starts.
    let plan = resonance::Plan::for_axis(&cfg, &args.axis, args.seconds).map_err(failure)?;
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| default_folder("resonance", &cfg, Some(&plan.axis)));
    check_out(&out)?;
    let mut record = run_record::begin("resonance", &args.target, &cfg)?;
    record.options = serde_json::json!({
        "axis": args.axis,
        "seconds": args.seconds,
        "no_home": args.no_home,
        "write": args.write,
    });
    let record_file = out.join(RUN_FILE);
    let mut end_sync = None;
    let result = measure(
        &args,
        &cfg,
        &plan,
        &out,
        &record_file,
        &mut record,
        &mut end_sync,
    )
    .await;
    run_record::finish(record, &record_file, end_sync, result).map(ExitCode::from)
}

async fn measure(
    args: &ResonanceArgs,
    cfg: &osap_machine::config::MachineFile,
    plan: &resonance::Plan,
    out: &std::path::Path,
    record_file: &std::path::Path,
    record: &mut osap_machine::runs::RunRecord,
    end_sync: &mut Option<u64>,
) -> Result<u8, Failure> {
    let machine = args.target.start(cfg).await?;
    run_record::machine_started(record, &machine).await;
    if !args.no_home {
        machine.home().await.map_err(Failure::from_machine)?;
    }
    println!(
        "shaking {} from {:.1} to {:.1} Hz for {:.1} s",
        plan.axis, plan.f0, plan.f1, plan.duration_s
    );
    let result = resonance::measure(&machine, &args.axis, args.seconds).await;
    *end_sync = machine.now_us().await.ok();
    let _ = machine.stop().await;
    let m = result.map_err(failure)?;
    let mut sum = Summary {
        record,
        print: true,
    };
    for line in resonance::summary(&m) {
        sum.line(line);
    }
    if let Some(s) = &m.analysis.recommended {
        sum.record.figure("shaper_freq_hz", s.freq_hz());
        sum.record.figure("shaper_damping", s.damping());
    }
    let files = resonance::write(&m, out).map_err(failure)?;
    for f in &files {
        println!("wrote {}", f.display());
    }
    sum.record.add_files(out, &files).map_err(|e| Failure {
        code: FAULTED,
        message: e.to_string(),
    })?;
    if args.write {
        match m.analysis.recommended {
            Some(s) => {
                let from = record_file.display().to_string();
                resonance::write_shaper(&args.target.machine, &args.axis, &s, Some(&from))
                    .map_err(failure)?;
                println!(
                    "wrote shaper = {} at {:.2} Hz into {} (validated; every move the machine makes is shaped with it)",
                    s.kind().name(),
                    s.freq_hz(),
                    args.target.machine.display()
                );
            }
            None => return Err(Failure::refused(
                "--write: no shaper to write, as no mode was measured within the range (see above)",
            )),
        }
    }
    Ok(0)
}
