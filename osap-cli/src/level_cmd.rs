//! `osap level MACHINE.toml [--sim]`: home, probe the bed on the grid the
//! machine file's `[probe]` gives, fit a mesh, save it to the file the
//! machine file names (`bed_mesh`, or `--mesh FILE`), and plot it.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::Args;
use osap_machine::level;

use crate::machine_cmd::{Failure, Target, FAULTED};
use crate::run_record::{self, Summary};

/// `osap level` options.
#[derive(Args, Debug)]
pub(crate) struct LevelArgs {
    /// Where to find the machine.
    #[command(flatten)]
    pub target: Target,
    /// Where to write the mesh (default: the machine file's `bed_mesh`).
    #[arg(long, value_name = "FILE")]
    pub mesh: Option<PathBuf>,
    /// Where to write the mesh's plot, an SVG heat map (default: the mesh
    /// file with the extension .svg).
    #[arg(long, value_name = "FILE")]
    pub plot: Option<PathBuf>,
}

/// Runs `osap level`.
pub(crate) async fn level(args: LevelArgs) -> Result<ExitCode, Failure> {
    let mut cfg = args.target.load()?;
    if cfg.probe.is_none() {
        return Err(Failure::refused(format!(
            "{}: no [probe] section; describe the probe (module, grid, start_z, search_depth, search_speed, travel_speed) as in examples/machines/mill.toml",
            args.target.machine.display()
        )));
    }
    let mesh_path = args.mesh.clone().or_else(|| cfg.bed_mesh_path()).ok_or_else(|| {
        Failure::refused(format!(
            "{}: names no bed_mesh file to write; add bed_mesh = \"{}-mesh.toml\" or give --mesh FILE",
            args.target.machine.display(),
            cfg.name
        ))
    })?;
    let plot_path = args
        .plot
        .clone()
        .unwrap_or_else(|| mesh_path.with_extension("svg"));
    // The record copies the machine file as it is (its old mesh too).
    let mut record = run_record::begin("level", &args.target, &cfg)?;
    record.options = serde_json::json!({
        "mesh": mesh_path.display().to_string(),
        "plot": plot_path.display().to_string(),
    });
    // Probe on a flat machine: the mesh file may not exist yet, or be the
    // stale one this run replaces.
    cfg.bed_mesh = None;
    let record_file = run_record::beside(&mesh_path);
    let mut end_sync = None;
    let result = probe(
        &args,
        &cfg,
        (&mesh_path, &plot_path, &record_file),
        &mut record,
        &mut end_sync,
    )
    .await;
    run_record::finish(record, &record_file, end_sync, result).map(ExitCode::from)
}

/// Probes the bed and writes the mesh and its plot.
async fn probe(
    args: &LevelArgs,
    cfg: &osap_machine::config::MachineFile,
    (mesh_path, plot_path, record_file): (&Path, &Path, &Path),
    record: &mut osap_machine::runs::RunRecord,
    end_sync: &mut Option<u64>,
) -> Result<u8, Failure> {
    let machine = args.target.start(cfg).await?;
    run_record::machine_started(record, &machine).await;
    machine.home().await.map_err(Failure::from_machine)?;
    let started = std::time::Instant::now();
    let t0 = machine.now_us().await.map_err(Failure::from_machine)?;
    let mut done = 0;
    let levelled = level::level(&machine, |p, total| {
        done += 1;
        println!(
            "point {done:>2}/{total} ({}, {}): x {:8.3}  y {:8.3}  z {:9.4}",
            p.ix, p.iy, p.x, p.y, p.z
        );
    })
    .await
    .map_err(Failure::from_machine)?;
    let took = started.elapsed();
    let now = machine.now_us().await.ok();
    *end_sync = now;
    let machine_s = now.map_or(f64::NAN, |t| t.saturating_sub(t0) as f64 / 1e6);
    let from = record_file.display().to_string();
    level::save(&levelled, mesh_path, Some(&from)).map_err(|e| Failure {
        code: FAULTED,
        message: e.to_string(),
    })?;
    level::plot(&levelled, plot_path).map_err(|e| Failure {
        code: FAULTED,
        message: e.to_string(),
    })?;
    let files = [mesh_path.to_path_buf(), plot_path.to_path_buf()];
    let s = &levelled.stats;
    let plane = &levelled.plane;
    let mut sum = Summary {
        record,
        print: true,
    };
    sum.line(format!(
        "bed: mean z {:.4}; heights {:+.4} to {:+.4} (rms {:.4}); tilt {:+.5} along x, {:+.5} along y; a plane leaves up to {:.4} (the warp)",
        levelled.reference, s.min, s.max, s.rms, plane.plane.a, plane.plane.b, plane.max_residual
    ));
    // Reads the wall clock too ("s here").
    let probed = format!(
        "probed {} points in {machine_s:.1} s of machine time ({:.1} s here); mesh written to {}, plot to {}",
        levelled.points.len(),
        took.as_secs_f64(),
        mesh_path.display(),
        plot_path.display()
    );
    println!("{probed}");
    sum.record.wall_line(probed);
    sum.line(format!(
        "jobs now follow the bed: z = {:.4} + h is h above it (name this mesh in bed_mesh to use it)",
        levelled.reference
    ));
    for (name, v) in [
        ("mean_z", levelled.reference),
        ("rms", s.rms),
        ("min", s.min),
        ("max", s.max),
        ("warp", plane.max_residual),
    ] {
        sum.record.figure(name, v);
    }
    let beside = mesh_path.parent().unwrap_or(Path::new(""));
    sum.record.add_files(beside, &files).map_err(|e| Failure {
        code: FAULTED,
        message: e.to_string(),
    })?;
    machine.stop().await.map_err(Failure::from_machine)?;
    Ok(0)
}
