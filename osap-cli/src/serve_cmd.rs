//! `osap serve`: run a simulated machine that other processes connect to
//! over TCP.

use clap::Args;
use osap_host::link::noise::Key;
use osap_host::link::stream::{ListenOptions, Listener, IDLE_TIMEOUT, MAX_CONNECTIONS};
use osap_host::link::tcp;
use osap_host::{Host, HostConfig};
use osap_sim::machine::{Fault, FaultInjector, SimMachine};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;
use tokio::io::{AsyncBufReadExt, BufReader};

/// The arguments of `osap serve`.
#[derive(Args, Clone)]
pub(crate) struct ServeArgs {
    /// The machine: a topology file, or a machine file (its simulated
    /// network is derived from it).
    #[arg(long, value_name = "FILE")]
    pub sim: PathBuf,
    /// Address to listen on for TCP peers.
    #[arg(long, value_name = "ADDR", default_value = "127.0.0.1:7077")]
    pub tcp: SocketAddr,
    /// Allow listening on an address other than loopback (needs --key).
    #[arg(long, requires = "key")]
    pub allow_remote: bool,
    /// Key file that clients must prove they hold (Noise handshake) before
    /// they get a link; make one with `osap keygen FILE`.
    #[arg(long, value_name = "FILE")]
    pub key: Option<PathBuf>,
    /// Clients served at once (1 to 32, the host's link slots; the
    /// machine's own links take some); one more waits up to a second for a
    /// place, then is refused (and logged).
    #[arg(long, value_name = "N", default_value_t = MAX_CONNECTIONS as u16,
          value_parser = clap::value_parser!(u16).range(1..=32))]
    pub max_connections: u16,
    /// Close a client's connection after this many seconds without a frame
    /// from it (0: never).
    #[arg(long, value_name = "SECONDS", default_value_t = IDLE_TIMEOUT.as_secs())]
    pub idle_timeout: u64,
    /// Read fault-injection commands from standard input, one a line:
    /// `cut LINK`, `restore LINK`, `corrupt LINK RATE`, `reset MODULE`,
    /// `freeze MODULE`, `thaw MODULE`, `links`, `stats LINK` (LINK: its
    /// index or its ends, e.g. hub-a), `outputs MODULE` (what its PWM
    /// outputs and digital pins drive now: `ok pwm0=0.050 pwm1=0.000 d0=0
    /// ...`) and `position MODULE` (where its motor's carriage is: units and
    /// steps). Each is answered on standard output with a line starting `ok`
    /// or `error`.
    #[arg(long)]
    pub control: bool,
}

/// Runs `osap serve` until Ctrl-C.
pub(crate) async fn serve(args: ServeArgs) -> Result<ExitCode, String> {
    // A server's log is its connections: who came, who was refused or
    // closed, and why (main logs at info for `serve`).
    let ServeArgs {
        sim: path,
        tcp: addr,
        allow_remote,
        key,
        max_connections,
        idle_timeout,
        control,
    } = args;
    let key = match &key {
        Some(file) => Some(Key::load(file).map_err(|e| e.to_string())?),
        None => None,
    };
    let keyed = key.is_some();
    let options = ListenOptions {
        allow_remote,
        key,
        max_connections: usize::from(max_connections),
        idle_timeout: (idle_timeout > 0).then(|| std::time::Duration::from_secs(idle_timeout)),
        ..ListenOptions::default()
    };
    // The serving host is the clock root of its machine, and trusts no
    // link: a client cannot take the clock or demote it (clients follow
    // it instead, see docs/clock-sync.md "Clock authority").
    let host = Host::start(HostConfig {
        name: "sim-host".into(),
        ..HostConfig::default()
    })
    .map_err(|e| e.to_string())?;
    let topology = crate::load_sim(&path)?;
    let machine = SimMachine::start(&host, &topology)
        .await
        .map_err(|e| format!("cannot start {}: {e}", path.display()))?;
    let listener: Listener = tcp::listen_with(&host, addr, options)
        .await
        .map_err(|e| e.to_string())?;
    println!(
        "serving {} ({} modules) on tcp {}{}; at most {max_connections} clients at once; \
         stop with Ctrl-C",
        topology.name,
        machine.modules().len(),
        listener
            .socket_addr()
            .map_or(addr.to_string(), |a| a.to_string()),
        if keyed { " with a key" } else { "" }
    );
    if control {
        tokio::select! {
            r = tokio::signal::ctrl_c() => r.map_err(|e| format!("cannot wait for Ctrl-C: {e}"))?,
            // Standard input closed: keep serving until Ctrl-C.
            () = control_loop(&machine) => tokio::signal::ctrl_c()
                .await
                .map_err(|e| format!("cannot wait for Ctrl-C: {e}"))?,
        }
    } else {
        tokio::signal::ctrl_c()
            .await
            .map_err(|e| format!("cannot wait for Ctrl-C: {e}"))?;
    }
    drop(listener);
    machine.stop().await.map_err(|e| e.to_string())?;
    Ok(ExitCode::SUCCESS)
}

/// Answers fault-injection commands from standard input until it closes.
async fn control_loop(machine: &SimMachine) {
    let injector = machine.injector();
    let mut lines = BufReader::new(tokio::io::stdin()).lines();
    while let Ok(Some(line)) = lines.next_line().await {
        let line = line.trim();
        if line.is_empty() {
            continue;
        }
        let reply = control_command(machine, &injector, line).await;
        println!("{reply}");
    }
}

/// One control command's answer: a line starting `ok` or `error`.
async fn control_command(machine: &SimMachine, injector: &FaultInjector, line: &str) -> String {
    let words: Vec<&str> = line.split_whitespace().collect();
    match words.as_slice() {
        ["links"] => format!("ok links: {}", injector.links().join(", ")),
        ["outputs", module] => match injector.outputs(module) {
            Ok(outputs) => format!("ok {outputs}"),
            Err(e) => format!("error: {e}"),
        },
        ["position", name] => match machine.module(name).and_then(|m| m.module()) {
            Some(m) => {
                let (at, steps) = m.lock(|mm| {
                    let motor = mm.board().motor();
                    (motor.position(), motor.steps())
                });
                format!("ok position {name}: {at} units, {steps} steps")
            }
            None => format!(
                "error: no module {name:?} with a motor (modules: {})",
                machine
                    .modules()
                    .iter()
                    .filter(|m| m.module().is_some())
                    .map(|m| m.name())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        },
        ["stats", link] => match (injector.corruption(link), injector.link_stats(link)) {
            (Ok(c), Ok([a, b])) => format!(
                "ok stats {link}: corrupted {} rejected {} undetected {}; \
                 frame errors counted {} (side a {}, side b {}); received a {} b {}",
                c.corrupted,
                c.rejected,
                c.undetected,
                a.frame_errors + b.frame_errors,
                a.frame_errors,
                b.frame_errors,
                a.received,
                b.received
            ),
            (Err(e), _) | (_, Err(e)) => format!("error: {e}"),
        },
        _ => match line.parse::<Fault>() {
            Ok(fault) => match injector.inject(&fault).await {
                Ok(()) => {
                    eprintln!("fault injected: {fault}");
                    format!("ok {fault}")
                }
                Err(e) => format!("error: {fault}: {e}"),
            },
            Err(e) => {
                format!("error: {e} (or: links, stats LINK, outputs MODULE, position MODULE)")
            }
        },
    }
}
