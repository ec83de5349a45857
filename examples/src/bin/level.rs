//! A machine script: level the mill's bed, then run a job that follows it.
//!
//! The mill (simulated by default, in virtual time) has a tilted, warped
//! bed (`[sim.bed]` in mill.toml) and a probe switch on module z's limit
//! input (`[probe]`). The script homes, probes the `[probe]` grid (what
//! `osap level` does), saves the mesh and its heat map to `--out`, and then
//! runs a zigzag across the bed at `--height` above it with the mesh in
//! force. On the simulator it also reads where the tool tip really is (from
//! the motors' steps) and prints how high above the simulated bed it
//! stayed, against the target.
//!
//! ```text
//! cargo run -p osap-examples --bin level -- --out /tmp/mill-level
//! ```

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use clap::Parser;
use osap_machine::config::MachineFile;
use osap_machine::level;
use osap_machine::sim::SimOptions;
use osap_machine::Machine;

#[derive(Parser, Debug)]
#[command(about = "Level a simulated mill's bed and run a job that follows it")]
struct Args {
    /// The machine file (with [probe] and, for simulation, [sim.bed]).
    #[arg(long, default_value = concat!(env!("CARGO_MANIFEST_DIR"), "/machines/mill.toml"))]
    machine: PathBuf,
    /// The tool's height above the bed during the job, mm.
    #[arg(long, default_value_t = 0.5)]
    height: f64,
    /// Where to write mesh.toml and mesh.svg.
    #[arg(long, default_value = "examples-out/level")]
    out: PathBuf,
}

/// The job: a zigzag over the probed area, as (x, y) in mm.
const ZIGZAG: [[f64; 2]; 9] = [
    [270.0, 30.0],
    [270.0, 70.0],
    [30.0, 70.0],
    [30.0, 110.0],
    [270.0, 110.0],
    [270.0, 150.0],
    [30.0, 150.0],
    [150.0, 100.0],
    [270.0, 170.0],
];

async fn run(args: Args) -> Result<(), Box<dyn std::error::Error>> {
    let mut cfg = MachineFile::load(&args.machine)?;
    // Start flat: the mesh this script makes replaces any the file names.
    cfg.bed_mesh = None;
    let machine = Machine::simulate_with(&cfg, SimOptions::VIRTUAL).await?;
    let result = level_and_run(&machine, &cfg, &args).await;
    machine.stop().await?;
    result
}

async fn level_and_run(
    machine: &Machine,
    cfg: &MachineFile,
    args: &Args,
) -> Result<(), Box<dyn std::error::Error>> {
    // On the simulator: the bed the probe touches.
    let surface = cfg.sim.as_ref().and_then(|s| s.bed);
    machine.home().await?;
    let levelled = level::level(machine, |p, total| {
        println!(
            "probed ({}, {}) of {total}: x {:.2} y {:.2} z {:.4}",
            p.ix, p.iy, p.x, p.y, p.z
        );
    })
    .await?;
    println!(
        "bed: mean height {:.4} mm, tilt {:.5} along x and {:.5} along y, unflatness (rms) {:.4} mm",
        levelled.reference,
        levelled.plane.plane.a,
        levelled.plane.plane.b,
        levelled.stats.rms
    );
    if let Some(surface) = &surface {
        let worst = levelled
            .points
            .iter()
            .map(|p| (p.z - surface.height(p.x, p.y)).abs())
            .fold(0.0, f64::max);
        println!("probe error against the simulated bed: worst {worst:.4} mm");
    }
    std::fs::create_dir_all(&args.out)
        .map_err(|e| format!("output folder {}: {e}", args.out.display()))?;
    let mesh = args.out.join("mesh.toml");
    let plot = args.out.join("mesh.svg");
    level::save(&levelled, &mesh, None)?;
    level::plot(&levelled, &plot)?;
    println!("wrote {}", mesh.display());
    println!("wrote {}", plot.display());

    // The job, with the mesh in force: z is the height above the bed.
    let z = levelled.reference + args.height;
    machine.goto_now([30.0, 30.0, z], 20.0).await?;
    for [x, y] in ZIGZAG {
        machine.goto_via_queue([x, y, z], 40.0).await?;
    }
    // On the simulator: where the tip really is, every millisecond of
    // machine time, against the simulated bed under it.
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    let idle = machine.idle();
    tokio::pin!(idle);
    loop {
        if let Some(surface) = &surface {
            let tip = ["x", "y", "z"].map(|a| machine.sim_axis_position(a));
            if let [Some(x), Some(y), Some(z)] = tip {
                let above = z - surface.height(x, y);
                lo = lo.min(above);
                hi = hi.max(above);
            }
        }
        tokio::select! {
            r = &mut idle => { r?; break; }
            _ = tokio::time::sleep(Duration::from_millis(1)) => {}
        }
    }
    println!("job done: {} moves at z {z:.4} mm (levelled)", ZIGZAG.len());
    if lo.is_finite() {
        println!(
            "tool height above the simulated bed: {lo:.4} .. {hi:.4} mm (target {})",
            args.height
        );
    }
    Ok(())
}

fn main() -> ExitCode {
    osap_examples::run_virtual(run(Args::parse()))
}
