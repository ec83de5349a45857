//! `osap rheo MACHINE.toml`: the printer measures its own melt with the
//! load cell on its filament and fits a model of it
//! ([`osap_machine::rheo`]); `--write` puts the model into the file.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::Args;
use osap_machine::rheo::{self, RheoError, RheoFit, RheoOptions, RheoRecord};

use osap_machine::runs::RUN_FILE;

use crate::machine_cmd::{check_out, default_folder, Failure, Target, FAULTED, MACHINE_FAULT};
use crate::run_record::{self, Summary};

/// `osap rheo` options.
#[derive(Args, Debug)]
pub(crate) struct RheoArgs {
    /// Where to find the machine.
    #[command(flatten)]
    pub target: Target,
    /// The temperatures to measure at, °C, within the filament's range (at
    /// least three; default PLA's 195,215,235).
    #[arg(long, value_delimiter = ',', value_name = "C,C,C")]
    pub temps: Vec<f64>,
    /// Where to write force.csv, inflow.csv and steady.csv (default: a new
    /// folder osap-rheo-NAME-TIME).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Put the model into `[axes.e.model]` of the machine file (in place,
    /// comments kept).
    #[arg(long)]
    pub write: bool,
}

fn failure(e: RheoError) -> Failure {
    match e {
        RheoError::Machine(e) => Failure::from_machine(e),
        RheoError::Refused(m) => Failure::refused(m),
        e => Failure {
            code: FAULTED,
            message: e.to_string(),
        },
    }
}

fn io_failure(path: &Path) -> impl Fn(std::io::Error) -> Failure + '_ {
    move |e| Failure {
        code: FAULTED,
        message: format!("{}: {e}", path.display()),
    }
}

/// Runs `osap rheo`, recorded in `run.json` in its folder.
pub(crate) async fn rheo(args: RheoArgs) -> Result<ExitCode, Failure> {
    let cfg = args.target.load()?;
    let mut opts = RheoOptions::default();
    if !args.temps.is_empty() {
        opts.temps = args.temps.clone();
    }
    rheo::check(&cfg, &opts).map_err(failure)?;
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| default_folder("rheo", &cfg, None));
    check_out(&out)?;
    let mut record = run_record::begin("rheo", &args.target, &cfg)?;
    record.options = serde_json::json!({ "temps": opts.temps, "write": args.write });
    let record_file = out.join(RUN_FILE);
    let mut end_sync = None;
    let result = measure(
        &args,
        &cfg,
        &opts,
        &out,
        &record_file,
        &mut record,
        &mut end_sync,
    )
    .await;
    run_record::finish(record, &record_file, end_sync, result).map(ExitCode::from)
}

async fn measure(
    args: &RheoArgs,
    cfg: &osap_machine::config::MachineFile,
    opts: &RheoOptions,
    out: &Path,
    record_file: &Path,
    run: &mut osap_machine::runs::RunRecord,
    end_sync: &mut Option<u64>,
) -> Result<u8, Failure> {
    let (out, opts) = (out.to_path_buf(), opts.clone());
    let machine = args.target.start(cfg).await?;
    run_record::machine_started(run, &machine).await;
    println!(
        "measuring the melt at {:?} °C, flows up to {} mm³/s under {:.0} % of the drive's grip (Ctrl-C stops; the hotend is turned off)",
        opts.temps,
        opts.flows.last().copied().unwrap_or(0.0),
        opts.force_share * 100.0
    );
    let result = tokio::select! {
        r = rheo::measure(&machine, &opts) => Some(r),
        _ = tokio::signal::ctrl_c() => None,
    };
    if let Ok(h) = machine.heater("hotend") {
        let _ = h.set_target(0.0).await;
    }
    *end_sync = machine.now_us().await.ok();
    let _ = machine.stop().await;
    let Some(record) = result else {
        return Err(Failure {
            code: FAULTED,
            message: "interrupted: the hotend is off, no model".into(),
        });
    };
    let record = record.map_err(|e| match e {
        RheoError::Machine(e) => {
            let mut f = Failure::from_machine(e);
            f.code = MACHINE_FAULT;
            f
        }
        e => failure(e),
    })?;
    std::fs::create_dir_all(&out).map_err(io_failure(&out))?;
    let mut files = write_record(&out, &record)?;
    let fit = rheo::fit(&record, &opts).map_err(failure)?;
    files.push(write_steady(&out, &fit)?);
    files.extend(rheo::plot(&record, &fit, &out).map_err(|e| Failure {
        code: FAULTED,
        message: e.to_string(),
    })?);
    let mut sum = Summary {
        record: run,
        print: true,
    };
    print_fit(&mut sum, &fit);
    sum.record.add_files(&out, &files).map_err(|e| Failure {
        code: FAULTED,
        message: e.to_string(),
    })?;
    let run = record_file.display().to_string();
    if args.write {
        let notes = rheo::write_model(&args.target.machine, &fit, Some(&run)).map_err(failure)?;
        println!(
            "wrote [axes.e.model] into {}",
            args.target.machine.display()
        );
        for n in notes {
            println!("note: {n}");
        }
    } else {
        println!("put this into the machine file (or run with --write):");
        for l in rheo::model_lines(&fit, Some(&run)) {
            println!("{l}");
        }
    }
    println!("data in {}", out.display());
    Ok(0)
}

fn print_fit(sum: &mut Summary<'_>, fit: &RheoFit) {
    let m = &fit.melt.model;
    let e = &fit.melt.fit.std_errors;
    sum.line(format!(
        "melt law: F = {:.3} ± {:.3} · Q^({:.4} ± {:.4}) · exp(−({:.5} ± {:.5}) · (T − {:.1})) N",
        m.flow_k, e[0], m.flow_n, e[1], m.temp_coeff, e[2], m.t_ref
    ));
    sum.line(format!(
        "fit: {} settled flows, residual {:.3} N rms",
        fit.melt.fit.points, fit.melt.fit.rms_residual
    ));
    sum.line(format!(
        "response time: {:.1} ± {:.1} ms (pressure advance {:.3} s)",
        fit.lag.tau_s * 1000.0,
        fit.lag.std_error * 1000.0,
        fit.lag.tau_s
    ));
    for &(t, q, err) in &fit.max_flows {
        sum.line(format!(
            "max flow at {t:.0} °C: {q:.1} mm³/s (± {err:.2}; the force reaches {:.1} N)",
            fit.force_limit_n
        ));
    }
    for (name, v) in [
        ("flow_k", m.flow_k),
        ("flow_n", m.flow_n),
        ("temp_coeff", m.temp_coeff),
        ("response_time_s", fit.lag.tau_s),
        ("rms_residual_n", fit.melt.fit.rms_residual),
    ] {
        sum.record.figure(name, v);
    }
}

fn write_record(out: &Path, record: &RheoRecord) -> Result<Vec<PathBuf>, Failure> {
    let path = out.join("force.csv");
    let mut f = std::io::BufWriter::new(std::fs::File::create(&path).map_err(io_failure(&path))?);
    let w = |f: &mut std::io::BufWriter<std::fs::File>, s: String| {
        f.write_all(s.as_bytes()).map_err(io_failure(&path))
    };
    w(&mut f, "t,force_n,temp_c\n".into())?;
    for s in &record.force {
        w(
            &mut f,
            format!("{:.6},{:.4},{:.2}\n", s.t, s.force_n, s.temp_c),
        )?;
    }
    f.flush().map_err(io_failure(&path))?;
    let force = path;
    let path = out.join("inflow.csv");
    let mut text = String::from("t,flow_mm3_s\n");
    for (t, q) in &record.inflow {
        text.push_str(&format!("{t:.6},{q:.4}\n"));
    }
    std::fs::write(&path, text).map_err(io_failure(&path))?;
    Ok(vec![force, path])
}

fn write_steady(out: &Path, fit: &RheoFit) -> Result<PathBuf, Failure> {
    let path = out.join("steady.csv");
    let mut text = String::from("temp_c,flow_mm3_s,force_n,std_dev_n,samples\n");
    for s in &fit.steady {
        text.push_str(&format!(
            "{:.1},{:.3},{:.4},{:.4},{}\n",
            s.spec.condition, s.spec.setpoint, s.mean, s.std_dev, s.samples
        ));
    }
    std::fs::write(&path, text).map_err(io_failure(&path))?;
    Ok(path)
}
