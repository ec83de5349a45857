//! `osap`: discover and talk to OSAP networks from the command line.

use clap::{Args, Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use osap_core::bus::BusRole;
use osap_core::route::Route;
use osap_host::link::noise::Key;
use osap_host::link::stream::LinkHandle;
use osap_host::link::{serial, tcp, udp};
use osap_host::map::NetworkMap;
use osap_host::netrunner::{self, Netrunner, ScanOptions, ScanReport};
use osap_host::{Host, HostConfig, HostError};
use osap_sim::machine::{self, SimMachine};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

mod block_cmd;
mod bridge_cmd;
mod call_cmd;
mod capture_cmd;
mod connection;
mod describe_cmd;
mod flash_cmd;
mod graph_cmd;
mod halt_cmd;
mod heater_tune_cmd;
mod level_cmd;
mod machine_cmd;
mod network;
mod resonance_cmd;
mod rheo_cmd;
mod run_events;
mod run_record;
mod runs_cmd;
mod serve_cmd;
mod time_cmd;
mod view;

#[derive(Parser)]
#[command(
    name = "osap",
    version,
    about = "Discover and talk to OSAP networks of modules",
    long_about = "Discover and talk to OSAP networks of modules.\n\nWithout --port, --tcp, --udp, --unix or --sim, every osap-rs USB device plugged in is used."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// More log output (-v info, -vv debug, -vvv trace; RUST_LOG overrides);
    /// with scan, also every link's counters.
    #[arg(short = 'v', long = "verbose", global = true, action = clap::ArgAction::Count)]
    verbose: u8,
}

use connection::*;
use network::*;

#[derive(Subcommand)]
enum Command {
    /// Scan the network and print it as a tree.
    Scan {
        #[command(flatten)]
        connect: Connect,
        /// Write the network map as JSON to this file.
        #[arg(short = 'o', long, value_name = "FILE")]
        output: Option<PathBuf>,
        /// Also read every PIPES function, class and pipe, and write the
        /// system object model (the input of `proxygen`) as JSON to this file.
        #[arg(long, value_name = "FILE")]
        som: Option<PathBuf>,
        /// Also list every runtime's PIPES functions with their signatures
        /// and, after `  # `, their summary lines (`osap describe` prints
        /// a function's whole documentation).
        #[arg(short = 'f', long)]
        functions: bool,
        /// Retries for a request that got no reply.
        #[arg(long, default_value_t = 2)]
        retries: u8,
    },
    /// Rename a runtime, given its current name or its route (e.g. 0,2).
    Rename {
        #[command(flatten)]
        connect: Connect,
        /// Current name, or route as link indices from the host.
        target: String,
        /// New name (at most 31 bytes).
        name: String,
    },
    /// Set a module's bus role on one of its links (its UART, link 1, by
    /// default): off (point to point), head:N (the bus head, polling drops
    /// 1..=N) or drop:D. The module keeps the role in flash. Set roles over
    /// another link (USB) before wiring the bus: a role changed over the
    /// link itself cuts it until the other end matches.
    Bus {
        #[command(flatten)]
        connect: Connect,
        /// The runtime: its name, or its route as link indices (e.g. 0,2).
        target: String,
        /// off, head:N or drop:D (N and D from 1 to 254).
        #[arg(value_parser = parse_bus_role)]
        role: BusRole,
        /// The link to set (a module's UART is link 1).
        #[arg(long, default_value_t = 1)]
        link: u8,
    },
    /// Call a runtime's PIPES function once: its outputs print one a
    /// line, a refusal by name (exit code 3).
    Call(call_cmd::CallArgs),
    /// Print what a runtime's PIPES function says of itself: its
    /// signature, its documentation, and its refusal codes with their
    /// fixes.
    Describe(describe_cmd::DescribeArgs),
    /// Save a network's wired dataflow graph to a file, or apply one.
    #[command(subcommand)]
    Graph(graph_cmd::GraphCommand),
    /// Make and delete blocks (comparators, filters, triggers) on a
    /// runtime while it runs.
    #[command(subcommand)]
    Block(block_cmd::BlockCommand),
    /// The run records (`run.json`) that run, resonance, rheo, capture and
    /// level leave: list them, show one, replay a job.
    #[command(subcommand)]
    Runs(runs_cmd::RunsCommand),
    /// Update a module's firmware over the network: reboot it into its
    /// UF2 bootloader, copy FIRMWARE (a .uf2, or an ELF with its .uf2)
    /// onto the drive, check it came back, and optionally rename it.
    Flash(flash_cmd::FlashArgs),
    /// Measure round-trip times to a runtime.
    Ping {
        #[command(flatten)]
        connect: Connect,
        /// Name, or route as link indices from the host.
        target: String,
        /// How many round trips.
        #[arg(short = 'n', long, default_value_t = 100)]
        count: usize,
    },
    /// Show the clock-sync status of every runtime (settled or not),
    /// once or with --watch, as a table or --json.
    Time(time_cmd::TimeArgs),
    /// Run a job (G-code or SVG) on a machine: home, run, summarize, and
    /// write planned.csv, executed.csv and plots.
    Run(machine_cmd::RunArgs),
    /// Record function outputs (sensors, positions) on the synchronized
    /// clock into a Parquet or CSV file, for --seconds or until Ctrl-C.
    Capture(capture_cmd::CaptureArgs),
    /// Level the bed: home, probe the grid of the machine file's [probe],
    /// fit a mesh, save it (bed_mesh or --mesh) and plot it.
    Level(level_cmd::LevelArgs),
    /// Measure an axis's resonance: shake it with a chirp, record its
    /// accelerometer, write the response (CSV, Bode SVG), and print the
    /// peak and the recommended input shaper (--write: into the file).
    Resonance(resonance_cmd::ResonanceArgs),
    /// Tune a heater's PID gains: drive it as a relay about the target
    /// (Klipper's PID_CALIBRATE), print kp, ki, kd (--write: into the file).
    HeaterTune(heater_tune_cmd::HeaterTuneArgs),
    /// Measure the melt with the load cell on the filament: heat through
    /// temperatures, extrude at stepped flows, fit the melt law and its
    /// response time, print the max flow per temperature (--write: the
    /// model into the file).
    Rheo(rheo_cmd::RheoArgs),
    /// Home a machine (every axis, or the ones named).
    Home {
        #[command(flatten)]
        target: machine_cmd::Target,
        /// Axes to home (default: all, in the file's order).
        #[arg(long = "axis", value_name = "AXIS")]
        axes: Vec<String>,
    },
    /// Move one axis by a distance (relative; within travel once homed).
    Jog {
        #[command(flatten)]
        target: machine_cmd::Target,
        /// The axis, e.g. x.
        #[arg(long)]
        axis: String,
        /// How far, in the axis's units (negative: toward min).
        #[arg(long, allow_negative_numbers = true)]
        distance: f64,
        /// Speed, units/s (default: a quarter of the axis's limit).
        #[arg(long)]
        rate: Option<f64>,
    },
    /// Home, then move to a position given as AXIS=VALUE (axes not named
    /// stay).
    Move {
        #[command(flatten)]
        target: machine_cmd::Target,
        /// Coordinates, e.g. x=10 y=20.
        #[arg(
            long = "to",
            value_name = "AXIS=VALUE",
            required = true,
            allow_hyphen_values = true
        )]
        coords: Vec<String>,
        /// Speed, units/s (default: half the machine's velocity limit).
        #[arg(long)]
        rate: Option<f64>,
    },
    /// Halt every module of a machine at once and switch every tool off,
    /// from the network alone: nothing is set up and no clock waited for,
    /// so it stops a machine another process is running. Exit code 0 when
    /// every module confirmed, 1 when one could not be reached.
    Halt {
        #[command(flatten)]
        target: machine_cmd::Target,
    },
    /// Run a simulated machine that other processes can connect to.
    Serve(serve_cmd::ServeArgs),
    /// Serve a machine on zenoh (osap/NAME/info, state, events, call,
    /// home, halt, job) until Ctrl-C; docs/fleet.md.
    Bridge(bridge_cmd::BridgeArgs),
    /// List every machine bridged on zenoh that this computer reaches.
    Fleet(bridge_cmd::FleetArgs),
    /// The live machine in a browser: the graph of runtimes, links and
    /// pipes, link load, clocks, axes and faults; call functions, plot
    /// captures (docs/view.md).
    View(view::ViewArgs),
    /// Make a key file for keyed TCP links (`--key FILE` on both ends),
    /// readable by its owner only.
    Keygen {
        /// Where to write it (an existing file is not overwritten).
        file: PathBuf,
    },
}

async fn run(cli: Cli, started: std::time::Instant) -> Result<ExitCode, String> {
    let machine_result = |r: Result<ExitCode, machine_cmd::Failure>| match r {
        Ok(code) => Ok(code),
        Err(f) => {
            eprintln!("error: {}", f.message);
            Ok(ExitCode::from(f.code))
        }
    };
    match cli.command {
        Command::Run(args) => machine_result(machine_cmd::run(args, started).await),
        Command::Level(args) => machine_result(level_cmd::level(args).await),
        Command::Resonance(args) => machine_result(resonance_cmd::resonance(args).await),
        Command::HeaterTune(args) => machine_result(heater_tune_cmd::heater_tune(args).await),
        Command::Rheo(args) => machine_result(rheo_cmd::rheo(args).await),
        Command::Capture(args) => machine_result(capture_cmd::capture(args).await),
        Command::Bridge(args) => machine_result(bridge_cmd::bridge(args).await),
        Command::Fleet(args) => machine_result(bridge_cmd::fleet(args).await),
        Command::View(args) => machine_result(view::view(args).await),
        Command::Home { target, axes } => machine_result(machine_cmd::home(target, axes).await),
        Command::Jog {
            target,
            axis,
            distance,
            rate,
        } => machine_result(machine_cmd::jog(target, axis, distance, rate).await),
        Command::Move {
            target,
            coords,
            rate,
        } => machine_result(machine_cmd::move_to(target, coords, rate).await),
        Command::Halt { target } => machine_result(halt_cmd::halt(target, started).await),
        Command::Scan {
            connect: args,
            output,
            som,
            functions,
            retries,
        } => {
            let verbose = cli.verbose > 0;
            let c = connect(&args).await?;
            let mut listing = String::new();
            if som.is_some() || functions {
                let mut manager = osap_host::som::Manager::new(&c.host)
                    .await
                    .map_err(|e| e.to_string())?;
                let refresh = manager.refresh().await.map_err(|e| e.to_string())?;
                for f in &refresh.function_failures {
                    eprintln!("warning: {f}");
                }
                if functions {
                    listing = function_listing(manager.som());
                }
                let Some(path) = &som else {
                    return scan_and_print(&c, retries, output, &listing, verbose).await;
                };
                std::fs::write(path, manager.som().to_json())
                    .map_err(|e| format!("cannot write {}: {e}", path.display()))?;
                println!(
                    "system object model written to {} ({} functions)",
                    path.display(),
                    manager
                        .som()
                        .runtimes
                        .iter()
                        .map(|r| r.functions.len())
                        .sum::<usize>()
                );
            }
            scan_and_print(&c, retries, output, &listing, verbose).await
        }
        Command::Rename {
            connect: args,
            target,
            name,
        } => {
            let c = connect(&args).await?;
            let route = resolve(&c, &target).await?;
            let stored = netrunner::rename(&c.host, &route, &name)
                .await
                .map_err(|e| e.to_string())?;
            println!("renamed the runtime at {route} to {stored}");
            Ok(ExitCode::SUCCESS)
        }
        Command::Bus {
            connect: args,
            target,
            role,
            link,
        } => {
            let c = connect(&args).await?;
            let route = resolve(&c, &target).await?;
            let runner = Netrunner::new(&c.host).await.map_err(|e| e.to_string())?;
            let set = runner
                .set_bus(&route, link, role)
                .await
                .map_err(|e| bus_error(e, &route, link))?;
            println!(
                "link {link} of the runtime at {route} is now {}",
                bus_role_text(set)
            );
            Ok(ExitCode::SUCCESS)
        }
        Command::Ping {
            connect: args,
            target,
            count,
        } => {
            let c = connect(&args).await?;
            let route = resolve(&c, &target).await?;
            let mut runner = Netrunner::new(&c.host).await.map_err(|e| e.to_string())?;
            runner.timeout = c.timeout;
            let mut times = runner
                .ping(&route, count.max(1))
                .await
                .map_err(|e| e.to_string())?;
            times.sort();
            let mean = times.iter().sum::<Duration>() / times.len() as u32;
            println!(
                "{} round trips to {route}: min {:?}  p50 {:?}  p99 {:?}  max {:?}  mean {:?}",
                times.len(),
                times[0],
                percentile(&times, 0.5),
                percentile(&times, 0.99),
                times[times.len() - 1],
                mean
            );
            Ok(ExitCode::SUCCESS)
        }
        Command::Time(args) => time_cmd::time(args).await,
        Command::Flash(args) => flash_cmd::flash(args).await,
        Command::Call(args) => call_cmd::call(args).await,
        Command::Describe(args) => describe_cmd::describe(args).await,
        Command::Graph(command) => graph_cmd::graph(command).await,
        Command::Block(command) => block_cmd::block(command).await,
        Command::Runs(command) => machine_result(runs_cmd::runs(command, started).await),
        Command::Serve(args) => serve_cmd::serve(args).await,
        Command::Keygen { file } => {
            Key::write_new(&file).map_err(|e| e.to_string())?;
            println!(
                "key written to {} (mode 600); copy it to each client over a safe channel \
                 and pass --key {} on both ends",
                file.display(),
                file.display()
            );
            Ok(ExitCode::SUCCESS)
        }
    }
}

fn main() -> ExitCode {
    let started = std::time::Instant::now();
    let cli = Cli::parse();
    init_logging(cli.verbose, matches!(cli.command, Command::Serve(_)));
    // A simulated machine in virtual time runs on one paused
    // current-thread runtime; everything else on tokio's default.
    let virtual_time = match &cli.command {
        Command::Run(a) => a.target.virtual_time(),
        Command::Level(a) => a.target.virtual_time(),
        Command::Resonance(a) => a.target.virtual_time(),
        Command::HeaterTune(a) => a.target.virtual_time(),
        Command::Rheo(a) => a.target.virtual_time(),
        Command::Capture(a) => a.target.virtual_time(),
        Command::Bridge(a) => a.target.virtual_time(),
        Command::Runs(runs_cmd::RunsCommand::Replay(a)) => a.virtual_time(),
        Command::Home { target, .. }
        | Command::Jog { target, .. }
        | Command::Move { target, .. }
        | Command::Halt { target } => target.virtual_time(),
        _ => false,
    };
    let runtime = if virtual_time {
        machine::virtual_runtime()
    } else {
        tokio::runtime::Builder::new_multi_thread()
            .enable_all()
            .build()
    };
    let runtime = match runtime {
        Ok(r) => r,
        Err(e) => {
            eprintln!("error: cannot start the async runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    match runtime.block_on(run(cli, started)) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

/// Logs to stderr through tracing: RUST_LOG when set (e.g.
/// `RUST_LOG=osap_host=debug`), else warnings and errors, raised by each
/// -v; a server logs its connections (info) by default.
fn init_logging(verbose: u8, serving: bool) {
    use tracing_subscriber::EnvFilter;
    let level = match (verbose, serving) {
        (0, false) => "warn",
        (0, true) | (1, _) => "info",
        (2, _) => "debug",
        _ => "trace",
    };
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new(level));
    let _ = tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_env_filter(filter)
        .with_target(verbose > 1)
        .try_init();
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn routes_parse_from_link_lists() {
        assert_eq!(
            parse_route("0,2").unwrap().unwrap(),
            Route::through_links(&[0, 2]).unwrap()
        );
        assert_eq!(
            parse_route("1 3").unwrap().unwrap(),
            Route::through_links(&[1, 3]).unwrap()
        );
        assert!(parse_route("x-axis").is_none());
        assert!(parse_route("0,300").unwrap().is_err());
        assert!(parse_route("64").unwrap().is_err());
    }

    #[test]
    fn cli_definition_is_consistent() {
        use clap::CommandFactory;
        Cli::command().debug_assert();
    }
}
