//! `osap serve`: run a simulated machine that other processes connect to
//! over TCP.

use clap::Args;
use osap_host::link::stream::Listener;
use osap_host::link::tcp;
use osap_host::{Host, HostConfig};
use osap_sim::machine::SimMachine;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;

/// The arguments of `osap serve`.
#[derive(Args, Clone)]
pub struct ServeArgs {
    /// The machine: a topology file, or a machine file (its simulated
    /// network is derived from it).
    #[arg(long, value_name = "FILE")]
    pub sim: PathBuf,
    /// Address to listen on for TCP peers.
    #[arg(long, value_name = "ADDR", default_value = "127.0.0.1:7077")]
    pub tcp: SocketAddr,
    /// Allow listening on an address other than loopback.
    #[arg(long)]
    pub allow_remote: bool,
}

/// Runs `osap serve` until Ctrl-C.
pub async fn serve(args: ServeArgs) -> Result<ExitCode, String> {
    let ServeArgs {
        sim: path,
        tcp: addr,
        allow_remote,
    } = args;
    // The serving host relays for the machine; the client's host
    // is the clock root.
    let host = Host::start(HostConfig {
        name: "sim-host".into(),
        time: osap_core::clock::TimeConfig::default(),
        ..HostConfig::default()
    })
    .map_err(|e| e.to_string())?;
    let topology = crate::load_sim(&path)?;
    let machine = SimMachine::start(&host, &topology)
        .await
        .map_err(|e| format!("cannot start {}: {e}", path.display()))?;
    let listener: Listener = tcp::listen(&host, addr, allow_remote)
        .await
        .map_err(|e| e.to_string())?;
    println!(
        "serving {} ({} modules) on tcp {}; stop with Ctrl-C",
        topology.name,
        machine.modules().len(),
        listener
            .socket_addr()
            .map_or(addr.to_string(), |a| a.to_string())
    );
    // Control commands for the served machine (fault injection) go here,
    // beside the wait for Ctrl-C.
    tokio::signal::ctrl_c()
        .await
        .map_err(|e| format!("cannot wait for Ctrl-C: {e}"))?;
    drop(listener);
    machine.stop().await.map_err(|e| e.to_string())?;
    Ok(ExitCode::SUCCESS)
}
