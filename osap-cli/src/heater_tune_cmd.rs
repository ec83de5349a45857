//! `osap heater-tune MACHINE.toml --heater NAME`: a relay test about the
//! target and the PID gains from it, Klipper's `PID_CALIBRATE`
//! ([`osap_machine::heater_tune`]); `--write` puts them into the file.

use std::process::ExitCode;
use std::time::Duration;

use clap::Args;
use osap_machine::heater_tune::{self, TuneError, TuneOptions, TUNE_DELTA_C};

use crate::machine_cmd::{Failure, Target, FAULTED, MACHINE_FAULT};

/// `osap heater-tune` options.
#[derive(Args, Debug)]
pub(crate) struct HeaterTuneArgs {
    /// Where to find the machine.
    #[command(flatten)]
    pub target: Target,
    /// The heater to tune (a `[heaters.NAME]` of the machine file).
    #[arg(long)]
    pub heater: String,
    /// The temperature to tune about, °C (default: 60 for `bed`, 210 for
    /// any other heater). Tune at the temperature you print at.
    #[arg(long = "target", value_name = "CELSIUS")]
    pub celsius: Option<f64>,
    /// How long the test may take, heat-up included, s.
    #[arg(long, default_value_t = heater_tune::DEFAULT_TIMEOUT.as_secs_f64())]
    pub timeout: f64,
    /// Put kp, ki and kd into `[heaters.NAME]` of the machine file (in
    /// place, comments kept).
    #[arg(long)]
    pub write: bool,
}

fn failure(e: TuneError) -> Failure {
    match e {
        TuneError::Machine(e) => Failure::from_machine(e),
        TuneError::Refused(m) => Failure::refused(m),
        e @ TuneError::Faulted { .. } => Failure {
            code: MACHINE_FAULT,
            message: e.to_string(),
        },
        e => Failure {
            code: FAULTED,
            message: e.to_string(),
        },
    }
}

/// Runs `osap heater-tune`.
pub(crate) async fn heater_tune(args: HeaterTuneArgs) -> Result<ExitCode, Failure> {
    let cfg = args.target.load()?;
    let celsius = args
        .celsius
        .unwrap_or_else(|| heater_tune::default_target(&args.heater));
    // Refuse an unknown heater or a bad target before anything starts.
    heater_tune::check(&cfg, &args.heater, celsius).map_err(failure)?;
    if !(args.timeout.is_finite() && args.timeout > 0.0) {
        return Err(Failure::refused(format!(
            "--timeout {} must be a positive number of seconds",
            args.timeout
        )));
    }
    let mut opts = TuneOptions::new(celsius);
    opts.timeout = Duration::from_secs_f64(args.timeout);
    let machine = args.target.start(&cfg).await?;
    println!(
        "tuning heater {}: full power below {celsius:.1} °C, off until {:.1} °C, for {} peaks (Ctrl-C stops; the heater is turned off)",
        args.heater,
        celsius - TUNE_DELTA_C,
        opts.min_peaks
    );
    let result = tokio::select! {
        r = heater_tune::tune(&machine, &args.heater, &opts) => Some(r),
        _ = tokio::signal::ctrl_c() => None,
    };
    // The test turns the heater off itself; an interrupted one (or one
    // whose last call failed) is turned off here, and the stop turns every
    // heater off on its module.
    if let Ok(h) = machine.heater(&args.heater) {
        let _ = h.set_target(0.0).await;
    }
    let _ = machine.stop().await;
    let Some(result) = result else {
        return Err(Failure {
            code: FAULTED,
            message: format!("interrupted: heater {} is off, no gains", args.heater),
        });
    };
    let r = result.map_err(failure)?;
    println!(
        "oscillation: {:.2} °C amplitude, {:.1} s period ({} peaks)",
        r.amplitude_c,
        r.period_s,
        r.peaks.len()
    );
    let lines = heater_tune::gains_lines(&r.gains);
    if args.write {
        heater_tune::write_gains(&args.target.machine, &args.heater, &r.gains).map_err(failure)?;
        println!(
            "wrote {} into [heaters.{}] of {}",
            lines.join(", "),
            args.heater,
            args.target.machine.display()
        );
    } else {
        println!(
            "put these under [heaters.{}] (or run with --write):",
            args.heater
        );
        for l in &lines {
            println!("{l}");
        }
    }
    Ok(ExitCode::SUCCESS)
}
