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

mod call_cmd;
mod capture_cmd;
mod flash_cmd;
mod halt_cmd;
mod level_cmd;
mod machine_cmd;
mod resonance_cmd;
mod run_events;
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

#[derive(Args, Clone)]
struct Connect {
    /// Serial port of a module or adapter (repeatable), e.g. /dev/ttyACM0.
    #[arg(long = "port", value_name = "PATH")]
    ports: Vec<String>,
    /// Baud rate for --port (USB CDC modules ignore it).
    #[arg(long, default_value_t = serial::DEFAULT_BAUD)]
    baud: u32,
    /// Connect to an OSAP peer over TCP (repeatable), e.g. 127.0.0.1:7077.
    #[arg(long = "tcp", value_name = "ADDR")]
    tcp: Vec<String>,
    /// Exchange datagrams with an OSAP peer over UDP (repeatable).
    #[arg(long = "udp", value_name = "ADDR")]
    udp: Vec<SocketAddr>,
    /// Connect to an OSAP peer over a Unix socket (repeatable).
    #[arg(long = "unix", value_name = "PATH")]
    unix: Vec<PathBuf>,
    /// Run a simulated machine and use it: a topology file, or a machine
    /// file (its simulated network is derived from it).
    #[arg(long, value_name = "FILE")]
    sim: Option<PathBuf>,
    /// Key file for --tcp peers that require one (`osap keygen FILE`
    /// makes it; docs/security.md).
    #[arg(long, value_name = "FILE")]
    key: Option<PathBuf>,
    /// How long to wait for each reply, ms.
    #[arg(long, default_value_t = 200)]
    timeout_ms: u64,
    /// Whose clock rules: `auto` follows the peer when every link is
    /// --tcp, --udp or --unix (a served machine's host is its root) and is
    /// the root otherwise; `root` is always the root; `follow` follows
    /// every link given.
    #[arg(long, value_enum, default_value_t = ClockRole::Auto)]
    clock: ClockRole,
}

/// Whether this process's host is a clock root or follows its links.
#[derive(clap::ValueEnum, Clone, Copy, PartialEq, Eq)]
enum ClockRole {
    /// Follow a served machine over the network, the root otherwise.
    Auto,
    /// The root: never follows anyone.
    Root,
    /// Follow (trust) every link given.
    Follow,
}

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
        /// Also list every runtime's PIPES functions with their signatures.
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

/// What keeps the host's links alive while a command runs.
struct Connection {
    host: Host,
    _links: Vec<LinkHandle>,
    _sim: Option<SimMachine>,
    timeout: Duration,
}

async fn connect(args: &Connect) -> Result<Connection, String> {
    let network = !(args.tcp.is_empty() && args.udp.is_empty() && args.unix.is_empty());
    let local = args.sim.is_some() || !args.ports.is_empty() || !network;
    // A served machine's host is its clock root: over the network, follow
    // it (and only it); with modules of our own, be the root.
    let follow = match args.clock {
        ClockRole::Auto => !local,
        ClockRole::Root => false,
        ClockRole::Follow => true,
    };
    let mut config = HostConfig::default();
    config.time.root = !follow;
    let host = Host::start(config).map_err(|e| e.to_string())?;
    let trust = |index: u8| {
        let host = host.clone();
        async move {
            if follow {
                host.trust_time_link(index)
                    .await
                    .map_err(|e| e.to_string())?;
            }
            Ok::<(), String>(())
        }
    };
    let timeout = Duration::from_millis(args.timeout_ms.max(1));
    let mut links = Vec::new();
    let mut sim_machine = None;
    if let Some(path) = &args.sim {
        let topology = load_sim(path)?;
        sim_machine = Some(
            SimMachine::start(&host, &topology)
                .await
                .map_err(|e| format!("cannot start {}: {e}", path.display()))?,
        );
    }
    let key = match &args.key {
        Some(path) => Some(Key::load(path).map_err(|e| e.to_string())?),
        None => None,
    };
    for addr in &args.tcp {
        let link = match &key {
            Some(key) => tcp::connect_with_key(&host, addr, key).await,
            None => tcp::connect(&host, addr).await,
        }
        .map_err(|e| e.to_string())?;
        trust(link.index()).await?;
        links.push(link);
    }
    for peer in &args.udp {
        let local = SocketAddr::new(peer.ip(), 0);
        let remote = !peer.ip().is_loopback();
        let link = udp::bind(&host, local, Some(*peer), remote)
            .await
            .map_err(|e| e.to_string())?;
        trust(link.index()).await?;
        links.push(link);
    }
    #[cfg(unix)]
    for path in &args.unix {
        let link = osap_host::link::unix::connect(&host, path)
            .await
            .map_err(|e| e.to_string())?;
        trust(link.index()).await?;
        links.push(link);
    }
    let mut paths = args.ports.clone();
    let nothing_given = paths.is_empty()
        && args.tcp.is_empty()
        && args.udp.is_empty()
        && args.unix.is_empty()
        && args.sim.is_none();
    if nothing_given {
        let found = serial::available_ports().map_err(|e| e.to_string())?;
        if found.is_empty() {
            return Err("no osap-rs devices found: plug a module in over USB, \
                 or name one with --port PATH, --tcp ADDR or --sim FILE \
                 (try the shipped osap-sim/topologies/small-machine.toml)"
                .into());
        }
        paths = found.into_iter().map(|c| c.path).collect();
    }
    for path in &paths {
        let link = serial::spawn_serial(&host, path, args.baud)
            .await
            .map_err(|e| e.to_string())?;
        // An open port is not yet an OSAP device: ask it.
        link.probe(&host, timeout.max(Duration::from_millis(500)))
            .await
            .map_err(|e| format!("{path}: {e}"))?;
        trust(link.index()).await?;
        links.push(link);
    }
    Ok(Connection {
        host,
        _links: links,
        _sim: sim_machine,
        timeout,
    })
}

async fn scan(c: &Connection, retries: u8) -> Result<ScanReport, String> {
    let options = ScanOptions {
        timeout: c.timeout,
        retries,
        ..ScanOptions::default()
    };
    let bar = ProgressBar::new_spinner();
    bar.set_style(
        ProgressStyle::with_template("{spinner} scanning: {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_spinner()),
    );
    bar.enable_steady_tick(Duration::from_millis(100));
    let report = netrunner::scan_with_progress(&c.host, &options, |found, queued| {
        bar.set_message(format!("{found} runtimes found, {queued} to visit"));
    })
    .await
    .map_err(|e| e.to_string());
    bar.finish_and_clear();
    report
}

/// A route given as link indices ("0,2" or "0 2"), if `target` is one.
fn parse_route(target: &str) -> Option<Result<Route, String>> {
    let parts: Vec<&str> = target
        .split(|c: char| c == ',' || c.is_whitespace())
        .filter(|p| !p.is_empty())
        .collect();
    if parts.is_empty() || !parts.iter().all(|p| p.chars().all(|c| c.is_ascii_digit())) {
        return None;
    }
    let links: Result<Vec<u8>, _> = parts.iter().map(|p| p.parse::<u8>()).collect();
    Some(match links {
        Ok(l) => Route::through_links(&l).map_err(|e| format!("bad route {target}: {e}")),
        Err(_) => Err(format!("bad route {target}: link indices are 0..=63")),
    })
}

/// The route to `target`: parsed, or found by name in a scan.
/// `off`, `head:N` or `drop:D`, as `osap bus` takes it.
fn parse_bus_role(text: &str) -> Result<BusRole, String> {
    let address = |n: &str, what: &str| {
        n.parse::<u8>()
            .ok()
            .filter(|d| (1..=254).contains(d))
            .ok_or_else(|| format!("{what} {n:?} must be a number from 1 to 254"))
    };
    match text.split_once(':') {
        None if text == "off" => Ok(BusRole::Off),
        Some(("head", n)) => Ok(BusRole::Head {
            max_drop: address(n, "the highest drop")?,
        }),
        Some(("drop", n)) => Ok(BusRole::Drop(address(n, "the drop address")?)),
        _ => Err(format!(
            "{text:?} is not a bus role: use off, head:N (polls drops 1..=N) or drop:D"
        )),
    }
}

/// A role as `osap bus` names it.
fn bus_role_text(role: BusRole) -> String {
    match role {
        BusRole::Off => "off (point to point)".into(),
        BusRole::Head { max_drop } => format!("the bus head, polling drops 1 to {max_drop}"),
        BusRole::Drop(d) => format!("drop {d} on its bus"),
    }
}

/// What `osap bus` says when the runtime does not take the role.
fn bus_error(e: HostError, route: &Route, link: u8) -> String {
    use osap_core::netresponder::Status;
    match e {
        HostError::Remote {
            status: Status::Refused,
            ..
        } => format!(
            "the runtime at {route} cannot give link {link} a bus role: only a module \
             firmware's UART can take one (USB links and simulated links cannot)"
        ),
        HostError::Remote {
            status: Status::NoSuchIndex,
            ..
        } => format!("the runtime at {route} has no link {link}"),
        HostError::Remote {
            status: Status::UnknownKey,
            ..
        } => format!(
            "the runtime at {route} does not know bus roles: update its firmware (osap flash)"
        ),
        e => e.to_string(),
    }
}

async fn resolve(c: &Connection, target: &str) -> Result<Route, String> {
    if let Some(route) = parse_route(target) {
        return route;
    }
    let map = scan(c, 2).await?.map;
    lookup(&map, target)
}

fn lookup(map: &NetworkMap, name: &str) -> Result<Route, String> {
    if map.duplicate_names().contains(&name) {
        return Err(format!(
            "more than one runtime is named {name}: rename them apart by route first"
        ));
    }
    map.find(name).map(|r| r.route()).ok_or_else(|| {
        let names: Vec<&str> = map.runtimes.iter().map(|r| r.name.as_str()).collect();
        format!("no runtime named {name} (found: {})", names.join(", "))
    })
}

fn percentile(sorted: &[Duration], p: f64) -> Duration {
    let i = ((sorted.len() as f64 - 1.0) * p).round() as usize;
    sorted[i.min(sorted.len() - 1)]
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
        Command::Capture(args) => machine_result(capture_cmd::capture(args).await),
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
        Command::Capture(a) => a.target.virtual_time(),
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

/// The simulated machine of `path`: a topology file, or a machine file
/// (with `[motors]` or `[axes]`), whose simulated network is derived from it.
fn load_sim(path: &std::path::Path) -> Result<machine::Topology, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let is_machine_file = text.lines().any(|l| {
        let l = l.trim_start();
        l.starts_with("[motors") || l.starts_with("[axes")
    });
    if is_machine_file {
        let cfg = osap_machine::config::MachineFile::load(path).map_err(|e| e.to_string())?;
        cfg.validate().map_err(|e| e.to_string())?;
        osap_machine::sim::topology(&cfg).map_err(|e| e.to_string())
    } else {
        machine::load(path).map_err(|e| e.to_string())
    }
}

/// Scans, prints the tree (and `listing` after it), writes the map to
/// `output` if given; exit code 2 when the map is partial. An open link
/// where nothing was heard and nothing answered (an unwired UART) has no
/// neighbour: the tree marks it, and it leaves the map whole.
async fn scan_and_print(
    c: &Connection,
    retries: u8,
    output: Option<PathBuf>,
    listing: &str,
    verbose: bool,
) -> Result<ExitCode, String> {
    let report = scan(c, retries).await?;
    print!("{}", report.map.tree());
    if verbose {
        print!("{}", link_counter_listing(c, &report.map).await?);
    }
    let lone = report
        .map
        .runtimes
        .iter()
        .flat_map(|r| &r.links)
        .filter(|l| l.no_neighbour())
        .count();
    let lone = match lone {
        0 => String::new(),
        1 => " (1 open link with no neighbour)".to_string(),
        n => format!(" ({n} open links with no neighbour)"),
    };
    println!(
        "{} runtimes, {} links{lone}, scanned in {:.1} ms",
        report.map.runtimes.len(),
        report.map.links.len(),
        report.elapsed.as_secs_f64() * 1e3
    );
    print!("{listing}");
    if let Some(path) = output {
        std::fs::write(&path, report.map.to_json())
            .map_err(|e| format!("cannot write {}: {e}", path.display()))?;
        println!("map written to {}", path.display());
    }
    if report.failures.is_empty() {
        Ok(ExitCode::SUCCESS)
    } else {
        eprintln!("unreachable:");
        for f in &report.failures {
            eprintln!("  {}: {}", describe_route(&report.map, &f.route), f.error);
        }
        eprintln!(
            "the map is partial: {} request(s) failed (exit code 2); check the cables \
             and power of what is listed, or raise --timeout-ms and --retries for slow links",
            report.failures.len()
        );
        Ok(ExitCode::from(2))
    }
}

/// Where a route leads, in the map's terms: `the runtime behind hub's
/// link 2 (route 0,0,2)`, or the runtime's name if it is on the map.
fn describe_route(map: &NetworkMap, route: &[u8]) -> String {
    let hops = route
        .iter()
        .map(u8::to_string)
        .collect::<Vec<_>>()
        .join(",");
    if let Some(r) = map.runtimes.iter().find(|r| r.route == route) {
        return format!("{} (route {hops})", r.name);
    }
    match route.split_last() {
        Some((link, parent)) => match map.runtimes.iter().find(|r| r.route == parent) {
            Some(p) => format!("the runtime behind {}'s link {link} (route {hops})", p.name),
            None => format!("route {hops}"),
        },
        None => "this host".to_string(),
    }
}

/// Every link's counters, one link a line:
/// `x link 0 (uart): in 1203 (0 dropped), out 1180 (0 expired, 0 closed,
/// 0 failed); wire: 1203 frames, 0 bad, 0 dropped in, 0 dropped out,
/// 0 disconnects`.
async fn link_counter_listing(c: &Connection, map: &NetworkMap) -> Result<String, String> {
    let runner = Netrunner::new(&c.host).await.map_err(|e| e.to_string())?;
    let mut out = String::from("link counters:\n");
    for r in &map.runtimes {
        for l in &r.links {
            let line = match runner.link_counters(&r.route(), l.index).await {
                Ok(k) => {
                    let wire = match k.gateway {
                        Some(g) => format!(
                            "wire: {} frames, {} bad, {} dropped in, {} dropped out, {} disconnects",
                            g.frames, g.frame_errors, g.rx_dropped, g.tx_dropped, g.disconnects
                        ),
                        None => "wire: not counted by this link".into(),
                    };
                    format!(
                        "in {} ({} dropped), out {} ({} expired, {} closed, {} failed); {wire}",
                        k.received, k.rx_dropped, k.sent, k.expired, k.closed, k.send_errors
                    )
                }
                Err(e) => format!("counters unavailable: {e}"),
            };
            out.push_str(&format!(
                "  {} link {} ({}): {line}\n",
                r.name, l.index, l.type_name
            ));
        }
    }
    Ok(out)
}

/// Every runtime's functions, one signature a line:
/// `x: add_point(time: u64, position: f32)`,
/// `x: get_position() -> (time: u64, position: f32)`.
fn function_listing(som: &osap_host::som::Som) -> String {
    let args = |a: &[osap_host::som::model::SomArg]| {
        a.iter()
            .map(|a| format!("{}: {}", a.name, a.type_name))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let mut out = String::new();
    for rt in &som.runtimes {
        for f in &rt.functions {
            out.push_str(&format!(
                "{}: {}({})",
                rt.record.name,
                f.name,
                args(&f.inputs)
            ));
            if !f.outputs.is_empty() {
                out.push_str(&format!(" -> ({})", args(&f.outputs)));
            }
            out.push('\n');
        }
    }
    out
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
