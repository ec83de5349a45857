//! `osap level MACHINE.toml [--sim]`: home, probe the bed on the grid the
//! machine file's `[probe]` gives, fit a mesh, save it to the file the
//! machine file names (`bed_mesh`, or `--mesh FILE`), and plot it.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Args;
use osap_machine::level;

use crate::machine_cmd::{Failure, Target, FAULTED};

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
    // Probe on a flat machine: the mesh file may not exist yet, or be the
    // stale one this run replaces.
    cfg.bed_mesh = None;
    let machine = args.target.start(&cfg).await?;
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
    let machine_s = machine
        .now_us()
        .await
        .map_or(f64::NAN, |t| t.saturating_sub(t0) as f64 / 1e6);
    level::save(&levelled, &mesh_path).map_err(|e| Failure {
        code: FAULTED,
        message: e.to_string(),
    })?;
    level::plot(&levelled, &plot_path).map_err(|e| Failure {
        code: FAULTED,
        message: e.to_string(),
    })?;
    let s = &levelled.stats;
    let plane = &levelled.plane;
    println!(
        "bed: mean z {:.4}; heights {:+.4} to {:+.4} (rms {:.4}); tilt {:+.5} along x, {:+.5} along y; a plane leaves up to {:.4} (the warp)",
        levelled.reference, s.min, s.max, s.rms, plane.plane.a, plane.plane.b, plane.max_residual
    );
    println!(
        "probed {} points in {machine_s:.1} s of machine time ({:.1} s here); mesh written to {}, plot to {}",
        levelled.points.len(),
        took.as_secs_f64(),
        mesh_path.display(),
        plot_path.display()
    );
    println!(
        "jobs now follow the bed: z = {:.4} + h is h above it (name this mesh in bed_mesh to use it)",
        levelled.reference
    );
    machine.stop().await.map_err(Failure::from_machine)?;
    Ok(ExitCode::SUCCESS)
}
