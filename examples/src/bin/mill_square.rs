//! A machine script: mill a square pocket outline on the 3-axis mill of
//! `examples/machines/mill.toml`.
//!
//! The script is about the machine, not the network: home, spin the
//! spindle up, plunge, cut the square with queued (lookahead) moves,
//! retract, spin down. The same script runs on simulated modules (the
//! default, real time; `--fast` for virtual time, for CI) and on hardware
//! (`--port` or `--tcp`).
//!
//! ```text
//! cargo run -p osap-examples --bin mill_square -- --fast
//! cargo run -p osap-examples --bin mill_square -- --port /dev/ttyACM0
//! ```

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use osap_machine::config::MachineFile;
use osap_machine::machine::Link;
use osap_machine::sim::SimOptions;
use osap_machine::Machine;
use osap_sim::machine::virtual_runtime;

#[derive(Parser, Debug)]
#[command(about = "Mill a square on the mill of a machine file (simulated, or on hardware)")]
struct Args {
    /// The machine file.
    #[arg(long, default_value = concat!(env!("CARGO_MANIFEST_DIR"), "/machines/mill.toml"))]
    machine: PathBuf,
    /// Simulate in virtual time (as fast as the host computes).
    #[arg(long, conflicts_with_all = ["port", "tcp"])]
    fast: bool,
    /// Drive hardware over this serial port instead of simulating.
    #[arg(long)]
    port: Option<String>,
    /// The serial port's baud rate (USB CDC ignores it).
    #[arg(long, default_value_t = 115_200)]
    baud: u32,
    /// Drive hardware over a TCP link (e.g. `osap serve`) instead of
    /// simulating.
    #[arg(long)]
    tcp: Option<String>,
    /// Side of the square, mm.
    #[arg(long, default_value_t = 30.0)]
    side: f64,
    /// Where the stock's top is, machine z (mm).
    #[arg(long, default_value_t = -20.0, allow_hyphen_values = true)]
    stock_top: f64,
    /// Depth of cut below the stock's top, mm.
    #[arg(long, default_value_t = 1.0)]
    depth: f64,
    /// Cutting feed, mm/s.
    #[arg(long, default_value_t = 20.0)]
    feed: f64,
    /// Print every machine event (limit edges, state changes).
    #[arg(long)]
    verbose: bool,
    /// Spindle speed, rpm.
    #[arg(long, default_value_t = 12_000.0)]
    rpm: f64,
}

/// Clearance above the stock for travel, mm.
const CLEARANCE: f64 = 5.0;
/// Plunge feed, mm/s.
const PLUNGE: f64 = 2.0;
/// Travel feed, mm/s.
const RAPID: f64 = 50.0;

/// The part of the script about the machine.
async fn mill_square(m: &Machine, args: &Args) -> Result<(), Box<dyn std::error::Error>> {
    m.home().await?;
    println!("homed at {}", fmt(&m.position()));

    let spindle = m.tool("spindle")?;
    spindle.set_rpm(args.rpm).await?;
    spindle.await_ready().await?;
    println!("spindle at {} rpm", args.rpm);

    // The square is centred in the travel.
    let cfg = m.config();
    let cx = (cfg.axes["x"].min + cfg.axes["x"].max) / 2.0;
    let cy = (cfg.axes["y"].min + cfg.axes["y"].max) / 2.0;
    let h = args.side / 2.0;
    let (x0, y0, x1, y1) = (cx - h, cy - h, cx + h, cy + h);
    let safe = args.stock_top + CLEARANCE;
    let cut = args.stock_top - args.depth;

    m.goto_now([x0, y0, safe], RAPID).await?;
    m.goto_via_queue([x0, y0, cut], PLUNGE).await?;
    for (x, y) in [(x1, y0), (x1, y1), (x0, y1), (x0, y0)] {
        m.goto_via_queue([x, y, cut], args.feed).await?;
    }
    m.goto_via_queue([x0, y0, safe], PLUNGE * 5.0).await?;
    m.idle().await?;
    println!(
        "milled a {} mm square, {} mm deep, at {} mm/s",
        args.side, args.depth, args.feed
    );

    spindle.off().await?;
    spindle.await_ready().await?;
    println!("spindle off");
    Ok(())
}

async fn run(args: Args) -> Result<(), Box<dyn std::error::Error>> {
    let cfg = MachineFile::load(&args.machine)?;
    let links: Vec<Link> = args
        .port
        .iter()
        .map(|p| Link::Serial {
            path: p.clone(),
            baud: args.baud,
        })
        .chain(args.tcp.iter().map(|a| Link::Tcp(a.clone())))
        .collect();
    let m = if !links.is_empty() {
        Machine::connect(&cfg, &links).await?
    } else if args.fast {
        Machine::simulate_with(&cfg, SimOptions::VIRTUAL).await?
    } else {
        Machine::simulate(&cfg).await?
    };
    println!("machine {} up: axes {}", cfg.name, m.axes().join(", "));
    let mut events = m.events();
    let verbose = args.verbose;
    tokio::spawn(async move {
        use osap_machine::MachineEvent as E;
        while let Ok(e) = events.recv().await {
            match e {
                E::Homed { .. } if !verbose => {}
                E::Limit { expected: true, .. } | E::Limit { pressed: false, .. } | E::State(_)
                    if !verbose => {}
                // A stop every module confirmed (the script's own at the
                // end; a fault's cause is an event of its own).
                E::Stop(r) if !verbose && r.is_complete() => {}
                e => println!("event: {e:?}"),
            }
        }
    });

    let wall = std::time::Instant::now();
    let clock = tokio::time::Instant::now();
    let result = mill_square(&m, &args).await;
    let position = m.position();
    let (machine_s, wall_s) = (clock.elapsed().as_secs_f64(), wall.elapsed().as_secs_f64());
    m.stop().await?;
    result?;
    println!("position {}", fmt(&position));
    println!("took {machine_s:.2} s machine time ({wall_s:.2} s wall)");
    Ok(())
}

fn fmt(p: &[f64]) -> String {
    let v: Vec<String> = p.iter().map(|v| format!("{v:.3}")).collect();
    format!("[{}]", v.join(", "))
}

fn main() -> ExitCode {
    osap_examples::init_logging();
    let args = Args::parse();
    let runtime = if args.fast {
        virtual_runtime()
    } else {
        tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
    };
    let result = match runtime {
        Ok(rt) => rt.block_on(run(args)),
        Err(e) => Err(e.into()),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("mill_square: {e}");
            ExitCode::FAILURE
        }
    }
}
