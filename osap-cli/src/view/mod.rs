//! `osap view`: the live machine in a browser. A small HTTP server (axum)
//! on loopback serves one page (embedded, no network needed) and pushes
//! the network's state over a websocket a few times a second: the graph
//! of runtimes, links and pipes, each link's load against what it
//! carries, every runtime's clock, the axes, and fault events. The page
//! can call any function with typed inputs, and plot captures.
//!
//! Two kinds of source:
//! - a machine file (`osap view MACHINE.toml [--sim | --port |
//!   --tcp]`): the machine is started as `osap run` starts it, and
//!   `--job FILE` runs a job on it while the page watches;
//! - a plain network (`osap view --sim TOPOLOGY | --port | --tcp`), with
//!   no machine: the graph, links, clocks, functions and faults.

mod fleet;
mod http;
mod info;
mod poll;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Duration;

use clap::Args;
use osap_host::som::Manager;
use osap_host::Host;
use osap_machine::Machine;
use tokio::sync::Mutex;

use crate::machine_cmd::{Failure, Target};

/// `osap view` options.
#[derive(Args, Debug)]
pub(crate) struct ViewArgs {
    /// The machine file (TOML). Without it, give --sim TOPOLOGY, --port or
    /// --tcp to view a plain network.
    pub machine: Option<PathBuf>,
    /// Run on simulated modules: those of the machine file, or of this
    /// topology or machine file.
    #[arg(long, value_name = "FILE")]
    #[allow(clippy::option_option)] // absent, --sim, or --sim FILE
    pub sim: Option<Option<PathBuf>>,
    /// Serial port of a module or adapter (repeatable).
    #[arg(long = "port", value_name = "PATH")]
    pub ports: Vec<String>,
    /// Baud rate for --port.
    #[arg(long, default_value_t = osap_host::link::serial::DEFAULT_BAUD)]
    pub baud: u32,
    /// Connect over TCP (repeatable), e.g. to `osap serve`.
    #[arg(long = "tcp", value_name = "ADDR")]
    pub tcp: Vec<String>,
    /// Key file for --tcp servers that require one.
    #[arg(long, value_name = "FILE")]
    pub key: Option<PathBuf>,
    /// Where the page is served. Loopback unless told otherwise; an
    /// address other machines can reach needs --token. Port 0: any free.
    #[arg(long, value_name = "ADDR", default_value = "127.0.0.1:7078")]
    pub http: SocketAddr,
    /// A token the page and every request must carry (`?token=`); required
    /// when --http is not a loopback address.
    #[arg(long, value_name = "TOKEN")]
    pub token: Option<String>,
    /// With a machine file: home, then run this job (G-code or SVG) while
    /// the page watches.
    #[arg(long, value_name = "FILE")]
    pub job: Option<PathBuf>,
    /// A folder of captures (.parquet, .csv) the page can plot.
    #[arg(long, value_name = "DIR")]
    pub captures: Option<PathBuf>,
    /// How often the page is updated, ms (at least 100: 10 Hz).
    #[arg(long, default_value_t = 200)]
    pub interval_ms: u64,
    /// Instead of one machine: every machine bridged on zenoh (`osap
    /// bridge`) reachable through this endpoint (repeatable), a card each.
    #[arg(long = "zenoh", value_name = "ENDPOINT")]
    pub zenoh: Vec<String>,
    /// A zenoh config file for --zenoh (TLS, authentication).
    #[arg(long = "zenoh-config", value_name = "FILE")]
    pub zenoh_config: Option<PathBuf>,
}

/// What the server watches: the host, its model of the network, and the
/// machine when there is one.
pub(crate) struct Source {
    pub host: Host,
    /// A plain network's model (a machine keeps its own).
    network: Option<Mutex<Manager>>,
    pub machine: Option<Machine>,
    pub title: String,
    /// Keeps a plain network's links and simulation alive.
    _connection: Option<crate::Connection>,
}

impl Source {
    /// The model of the network: the machine's, or the plain network's.
    pub(crate) fn manager(&self) -> Option<&Mutex<Manager>> {
        match &self.machine {
            Some(m) => Some(m.manager()),
            None => self.network.as_ref(),
        }
    }
}

impl ViewArgs {
    fn check(&self) -> Result<(), Failure> {
        if self.interval_ms < 100 {
            return Err(Failure::refused(format!(
                "--interval-ms {}: at least 100 (10 updates a second)",
                self.interval_ms
            )));
        }
        if !self.http.ip().is_loopback() && self.token.is_none() {
            return Err(Failure::refused(format!(
                "--http {}: not a loopback address, so anyone who can reach it could drive the machine; give --token TOKEN (docs/view.md)",
                self.http
            )));
        }
        if let Some(t) = &self.token {
            if t.len() < 16
                || !t
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
            {
                return Err(Failure::refused(
                    "--token: at least 16 characters of A-Z, a-z, 0-9, - and _ (e.g. from `openssl rand -hex 16`)",
                ));
            }
        }
        let fleet = !self.zenoh.is_empty() || self.zenoh_config.is_some();
        let local = self.machine.is_some()
            || self.sim.is_some()
            || !self.ports.is_empty()
            || !self.tcp.is_empty()
            || self.job.is_some()
            || self.captures.is_some();
        if fleet && local {
            return Err(Failure::refused(
                "--zenoh views the machines bridged on zenoh: give it without a machine file, --sim, --port, --tcp, --job or --captures",
            ));
        }
        if self.job.is_some() && self.machine_file().is_none() {
            return Err(Failure::refused(
                "--job needs a machine file: osap view MACHINE.toml --job FILE",
            ));
        }
        Ok(())
    }

    /// The machine file, given as the argument or as --sim's file.
    fn machine_file(&self) -> Option<PathBuf> {
        if let Some(m) = &self.machine {
            return Some(m.clone());
        }
        let sim = self.sim.as_ref()?.as_ref()?;
        let text = std::fs::read_to_string(sim).ok()?;
        let is_machine = text.lines().any(|l| {
            let l = l.trim_start();
            l.starts_with("[motors") || l.starts_with("[axes")
        });
        is_machine.then(|| sim.clone())
    }

    async fn source(&self) -> Result<Source, Failure> {
        if let Some(file) = self.machine_file() {
            let target = Target {
                machine: file,
                sim: self.sim.is_some(),
                fast: false,
                ports: self.ports.clone(),
                baud: self.baud,
                tcp: self.tcp.clone(),
                key: self.key.clone(),
            };
            let cfg = target.load()?;
            let machine = target.start(&cfg).await?;
            return Ok(Source {
                host: machine.host().clone(),
                network: None,
                title: cfg.name.clone(),
                machine: Some(machine),
                _connection: None,
            });
        }
        let connect = crate::Connect {
            ports: self.ports.clone(),
            baud: self.baud,
            tcp: self.tcp.clone(),
            udp: Vec::new(),
            unix: Vec::new(),
            sim: self.sim.clone().flatten(),
            key: self.key.clone(),
            timeout_ms: 200,
            clock: crate::ClockRole::Auto,
        };
        if self.sim.is_some() && connect.sim.is_none() {
            return Err(Failure::refused(
                "--sim without a file needs a machine file: osap view MACHINE.toml --sim, or --sim TOPOLOGY",
            ));
        }
        let c = crate::connect(&connect).await.map_err(Failure::refused)?;
        // A simulated network's clocks settle before the first scan.
        let mut manager = Manager::new(&c.host)
            .await
            .map_err(|e| Failure::refused(e.to_string()))?;
        let report = manager
            .refresh()
            .await
            .map_err(|e| Failure::refused(e.to_string()))?;
        for f in &report.function_failures {
            eprintln!("warning: {f}");
        }
        Ok(Source {
            host: c.host.clone(),
            network: Some(Mutex::new(manager)),
            machine: None,
            title: "network".into(),
            _connection: Some(c),
        })
    }
}

/// Runs `osap view`.
pub(crate) async fn view(args: ViewArgs) -> Result<ExitCode, Failure> {
    args.check()?;
    if !args.zenoh.is_empty() || args.zenoh_config.is_some() {
        return fleet::view_fleet(args).await;
    }
    let source = Arc::new(args.source().await?);
    let info = info::build(&source).await;
    let (state_tx, _) = tokio::sync::broadcast::channel::<String>(32);
    let poller = poll::Poller::new(&source, &info)
        .await
        .map_err(|e| Failure::refused(format!("cannot read the network: {e}")))?;
    let interval = Duration::from_millis(args.interval_ms);
    let latest = Arc::new(std::sync::Mutex::new(String::from("null")));
    let poll_task = tokio::spawn(poller.run(interval, state_tx.clone(), latest.clone()));

    let listener = tokio::net::TcpListener::bind(args.http).await.map_err(|e| {
        Failure::refused(format!(
            "--http {}: {e} (another osap view? choose another port, or 127.0.0.1:0 for any free one)",
            args.http
        ))
    })?;
    let addr = listener
        .local_addr()
        .map_err(|e| Failure::refused(e.to_string()))?;
    let app = http::App {
        source: source.clone(),
        info: Arc::new(info),
        states: state_tx,
        latest,
        token: args.token.clone(),
        captures: args.captures.clone(),
        listen: addr,
    };
    let url = match &args.token {
        Some(t) => format!("http://{addr}/?token={t}"),
        None => format!("http://{addr}/"),
    };
    println!("osap view: {url}");
    println!("({} runtimes; Ctrl-C stops)", app.info.runtimes_len());
    let server = tokio::spawn(http::serve(listener, app));

    let job = match (&args.job, &source.machine) {
        (Some(file), Some(machine)) => Some(run_job(machine, file).await),
        _ => None,
    };
    if let Some(Err(f)) = job {
        // On stdout with the job's other lines; the page stays up to show
        // what happened.
        println!("job: failed: {}", f.message);
    }
    let _ = tokio::signal::ctrl_c().await;
    server.abort();
    poll_task.abort();
    if let Ok(source) = Arc::try_unwrap(source) {
        if let Some(m) = source.machine {
            let _ = m.stop().await;
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// Homes and runs `file` on the machine, printing when it starts and ends.
async fn run_job(machine: &Machine, file: &std::path::Path) -> Result<(), Failure> {
    let placement = crate::machine_cmd::JobPlacement::default();
    let program = crate::machine_cmd::read_job_file(machine.config(), file, &placement)?;
    machine.home().await.map_err(Failure::from_machine)?;
    println!("job: {} moves from {}", program.moves.len(), file.display());
    machine
        .run_program(&program, |_| {})
        .await
        .map_err(Failure::from_machine)?;
    println!("job: done");
    Ok(())
}
