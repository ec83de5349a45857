//! A machine script: measure the plotter's y resonance and pick its input
//! shaper (what `osap resonance` does, through the `Machine` API).
//!
//! On the simulator (the default, in virtual time) the accelerometer of
//! `[axes.y] accelerometer` is an analog input of module b that sees b's
//! carriage through `[sim.axes.y]`'s mass-spring mode (38 Hz, damping 0.1);
//! the script prints the peak, the fitted mode, every shaper's residual
//! vibration and the recommended shaper, and writes the response (CSV and a
//! Bode plot) to `--out`.
//!
//! ```text
//! cargo run -p osap-examples --bin resonance -- --out /tmp/plotter-y
//! ```

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use osap_machine::config::MachineFile;
use osap_machine::sim::SimOptions;
use osap_machine::{resonance, Machine};

#[derive(Parser, Debug)]
#[command(about = "Measure an axis's resonance on a simulated machine and pick its shaper")]
struct Args {
    /// The machine file.
    #[arg(long, default_value = concat!(env!("CARGO_MANIFEST_DIR"), "/machines/plotter.toml"))]
    machine: PathBuf,
    /// The axis.
    #[arg(long, default_value = "y")]
    axis: String,
    /// The sweep's length, s.
    #[arg(long, default_value_t = 4.0)]
    seconds: f64,
    /// Where to write response.csv, samples.csv and bode.svg.
    #[arg(long, default_value = "examples-out/resonance")]
    out: PathBuf,
}

async fn run(args: Args) -> Result<(), Box<dyn std::error::Error>> {
    let cfg = MachineFile::load(&args.machine)?;
    let machine = Machine::simulate_with(&cfg, SimOptions::VIRTUAL).await?;
    machine.home().await?;
    let m = resonance::measure(&machine, &args.axis, args.seconds).await;
    machine.stop().await?;
    let m = m?;
    for line in resonance::summary(&m) {
        println!("{line}");
    }
    for f in resonance::write(&m, &args.out)? {
        println!("wrote {}", f.display());
    }
    Ok(())
}

fn main() -> ExitCode {
    osap_examples::run_virtual(run(Args::parse()))
}
