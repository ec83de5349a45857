//! Reaching a network: the link options every command shares (`--port`,
//! `--tcp`, `--udp`, `--unix`, `--sim`), the host they start, and naming a
//! runtime by name or route.

use crate::*;

#[derive(Args, Clone)]
pub(crate) struct Connect {
    /// Serial port of a module or adapter (repeatable), e.g. /dev/ttyACM0.
    #[arg(long = "port", value_name = "PATH")]
    pub(crate) ports: Vec<String>,
    /// Baud rate for --port (USB CDC modules ignore it).
    #[arg(long, default_value_t = serial::DEFAULT_BAUD)]
    pub(crate) baud: u32,
    /// Connect to an OSAP peer over TCP (repeatable), e.g. 127.0.0.1:7077.
    #[arg(long = "tcp", value_name = "ADDR")]
    pub(crate) tcp: Vec<String>,
    /// Exchange datagrams with an OSAP peer over UDP (repeatable).
    #[arg(long = "udp", value_name = "ADDR")]
    pub(crate) udp: Vec<SocketAddr>,
    /// Connect to an OSAP peer over a Unix socket (repeatable).
    #[arg(long = "unix", value_name = "PATH")]
    pub(crate) unix: Vec<PathBuf>,
    /// Run a simulated machine and use it: a topology file, or a machine
    /// file (its simulated network is derived from it).
    #[arg(long, value_name = "FILE")]
    pub(crate) sim: Option<PathBuf>,
    /// Key file for --tcp peers that require one (`osap keygen FILE`
    /// makes it; docs/security.md).
    #[arg(long, value_name = "FILE")]
    pub(crate) key: Option<PathBuf>,
    /// How long to wait for each reply, ms.
    #[arg(long, default_value_t = 200)]
    pub(crate) timeout_ms: u64,
    /// Whose clock rules: `auto` follows the peer when every link is
    /// --tcp, --udp or --unix (a served machine's host is its root) and is
    /// the root otherwise; `root` is always the root; `follow` follows
    /// every link given.
    #[arg(long, value_enum, default_value_t = ClockRole::Auto)]
    pub(crate) clock: ClockRole,
}

/// Whether this process's host is a clock root or follows its links.
#[derive(clap::ValueEnum, Clone, Copy, PartialEq, Eq)]
pub(crate) enum ClockRole {
    /// Follow a served machine over the network, the root otherwise.
    Auto,
    /// The root: never follows anyone.
    Root,
    /// Follow (trust) every link given.
    Follow,
}

/// What keeps the host's links alive while a command runs.
pub(crate) struct Connection {
    pub(crate) host: Host,
    pub(crate) _links: Vec<LinkHandle>,
    pub(crate) _sim: Option<SimMachine>,
    pub(crate) timeout: Duration,
}

/// Connects as `args` say and reads the network into a fresh
/// [`Manager`](osap_host::som::Manager), warning of what did not answer:
/// what `osap call`, `describe`, `block` and `graph` start from.
pub(crate) async fn connect_scanned(
    args: &Connect,
) -> Result<(Connection, osap_host::som::Manager), String> {
    let c = connect(args).await?;
    let mut manager = osap_host::som::Manager::new(&c.host)
        .await
        .map_err(|e| e.to_string())?;
    let report = manager.refresh().await.map_err(|e| e.to_string())?;
    for f in &report.function_failures {
        eprintln!("warning: {f}");
    }
    Ok((c, manager))
}

pub(crate) async fn connect(args: &Connect) -> Result<Connection, String> {
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

pub(crate) async fn resolve(c: &Connection, target: &str) -> Result<Route, String> {
    if let Some(route) = parse_route(target) {
        return route;
    }
    let map = scan(c, 2).await?.map;
    lookup(&map, target)
}

pub(crate) fn lookup(map: &NetworkMap, name: &str) -> Result<Route, String> {
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

/// The simulated machine of `path`: a topology file, or a machine file
/// (with `[motors]` or `[axes]`), whose simulated network is derived from it.
pub(crate) fn load_sim(path: &std::path::Path) -> Result<osap_sim::SimSpec, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let is_machine_file = text.lines().any(|l| {
        let l = l.trim_start();
        l.starts_with("[motors") || l.starts_with("[axes")
    });
    if is_machine_file {
        let cfg = osap_machine::config::MachineFile::load(path).map_err(|e| e.to_string())?;
        cfg.validate().map_err(|e| e.to_string())?;
        osap_machine::sim::spec(&cfg).map_err(|e| e.to_string())
    } else {
        osap_sim::SimSpec::load(path).map_err(|e| e.to_string())
    }
}
