//! my-machine: connects to the machine, binds every device the scan found
//! to its proxy and prints what it found. Start here.
//!
//! ```text
//! cargo run -- --sim topology.toml      # a simulated machine
//! cargo run -- --port /dev/ttyACM0      # a module or hub over USB
//! cargo run -- --tcp 127.0.0.1:7077     # a machine served by `osap serve`
//! ```

mod proxies;

use clap::Parser;
use osap_host::link::stream::LinkHandle;
use osap_host::link::{serial, tcp, udp};
use osap_host::som::Manager;
use osap_host::{Host, HostConfig};
use osap_sim::machine::SimMachine;
use osap_sim::topology::SimSpec;
use std::error::Error;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;

/// Where the machine is: the same link options as `osap`.
#[derive(Parser)]
struct Args {
    /// Serial port of a module or hub (repeatable), e.g. /dev/ttyACM0.
    #[arg(long = "port", value_name = "PATH")]
    ports: Vec<String>,
    /// Baud rate for --port (USB modules ignore it).
    #[arg(long, default_value_t = serial::DEFAULT_BAUD)]
    baud: u32,
    /// A peer over TCP (repeatable), e.g. `osap serve`'s address.
    #[arg(long = "tcp", value_name = "ADDR")]
    tcp: Vec<String>,
    /// A peer over UDP (repeatable).
    #[arg(long = "udp", value_name = "ADDR")]
    udp: Vec<SocketAddr>,
    /// A peer over a Unix socket (repeatable).
    #[arg(long = "unix", value_name = "PATH")]
    unix: Vec<PathBuf>,
    /// Run a simulated machine (a topology file) and use it.
    #[arg(long, value_name = "FILE")]
    sim: Option<PathBuf>,
    /// Log more (repeatable: -v info, -vv debug, -vvv trace). RUST_LOG,
    /// when set, decides instead (e.g. RUST_LOG=osap_host=debug).
    #[arg(short, long, action = clap::ArgAction::Count)]
    verbose: u8,
}

/// Logs to stderr: RUST_LOG when set, else warnings raised by each -v.
fn init_logging(verbose: u8) {
    use tracing_subscriber::EnvFilter;
    let level = ["warn", "info", "debug", "trace"][usize::from(verbose.min(3))];
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new(level));
    let _ = tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_env_filter(filter)
        .try_init();
}

#[tokio::main]
async fn main() -> ExitCode {
    let args = Args::parse();
    init_logging(args.verbose);
    match run(args).await {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // Display, not Debug: errors name the function, a refusal its
            // code by name, and the fix.
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

async fn run(args: Args) -> Result<(), Box<dyn Error>> {
    let network = !(args.tcp.is_empty() && args.udp.is_empty() && args.unix.is_empty());
    if !network && args.ports.is_empty() && args.sim.is_none() {
        return Err("give --sim FILE, --port PATH, --tcp ADDR, --udp ADDR or --unix PATH".into());
    }
    // A served machine's host keeps its clock: over the network only,
    // follow it; with modules of our own, be the clock root.
    let follow = network && args.ports.is_empty() && args.sim.is_none();
    let mut config = HostConfig::default();
    config.time.root = !follow;
    let host = Host::start(config)?;
    // Keep the simulated machine and the links alive while the script runs.
    let mut _sim: Option<SimMachine> = None;
    let mut links: Vec<LinkHandle> = Vec::new();
    if let Some(file) = &args.sim {
        _sim = Some(SimMachine::start(&host, &SimSpec::load(file)?).await?);
    }
    for path in &args.ports {
        links.push(serial::spawn_serial(&host, path, args.baud).await?);
    }
    for addr in &args.tcp {
        links.push(tcp::connect(&host, addr).await?);
    }
    for peer in &args.udp {
        let local = SocketAddr::new(peer.ip(), 0);
        links.push(udp::bind(&host, local, Some(*peer), !peer.ip().is_loopback()).await?);
    }
    #[cfg(unix)]
    for path in &args.unix {
        links.push(osap_host::link::unix::connect(&host, path).await?);
    }
    if follow {
        for link in &links {
            host.trust_time_link(link.index()).await?;
        }
    }
    let mut manager = Manager::new(&host).await?;
    manager.refresh().await?;
    println!("{} runtimes found", manager.som().runtimes.len());

    let x = proxies::Stepper::bind(&manager, "x")?;
    println!("{:?}: {} {}", x.runtime(), proxies::Stepper::TYPE_NAME, proxies::Stepper::FIRMWARE_VERSION);
    let y = proxies::Stepper::bind(&manager, "y")?;
    println!("{:?}: {} {}", y.runtime(), proxies::Stepper::TYPE_NAME, proxies::Stepper::FIRMWARE_VERSION);
    let z = proxies::Stepper::bind(&manager, "z")?;
    println!("{:?}: {} {}", z.runtime(), proxies::Stepper::TYPE_NAME, proxies::Stepper::FIRMWARE_VERSION);
    let tool = proxies::Stepper::bind(&manager, "tool")?;
    println!("{:?}: {} {}", tool.runtime(), proxies::Stepper::TYPE_NAME, proxies::Stepper::FIRMWARE_VERSION);

    // Your script goes here, e.g. (on a stepper named x):
    //   let (t, p) = { let o = x.get_position().await?; (o.time, o.position) };
    Ok(())
}
