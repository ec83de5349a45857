//! `osap bridge MACHINE.toml …`: the machine served on zenoh until Ctrl-C
//! (`osap_zenoh`), and `osap fleet`: every machine a zenoh session reaches.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use clap::Args;
use osap_zenoh::{zenoh, Bridge, BridgeOptions, ZenohOptions};

use crate::machine_cmd::{Failure, Target, FAULTED};

/// The zenoh options of `osap bridge` and `osap fleet`.
#[derive(Args, Debug, Clone)]
pub(crate) struct ZenohArgs {
    /// A zenoh endpoint to listen on (repeatable), e.g.
    /// tcp/127.0.0.1:7447; off loopback only tls/ with authentication.
    #[arg(long = "zenoh-listen", value_name = "ENDPOINT")]
    pub listen: Vec<String>,
    /// A zenoh endpoint to connect to (repeatable).
    #[arg(long = "zenoh-connect", value_name = "ENDPOINT")]
    pub connect: Vec<String>,
    /// A zenoh config file (JSON5, JSON or YAML): TLS, authentication,
    /// scouting; --zenoh-listen and --zenoh-connect replace its endpoints.
    #[arg(long = "zenoh-config", value_name = "FILE")]
    pub config: Option<PathBuf>,
}

impl ZenohArgs {
    fn options(&self) -> ZenohOptions {
        ZenohOptions {
            listen: self.listen.clone(),
            connect: self.connect.clone(),
            file: self.config.clone(),
        }
    }
}

/// `osap bridge` options.
#[derive(Args, Debug)]
pub(crate) struct BridgeArgs {
    /// Where to find the machine.
    #[command(flatten)]
    pub target: Target,
    /// The machine's name in the keys (osap/NAME/…); default the machine
    /// file's name.
    #[arg(long)]
    pub name: Option<String>,
    #[command(flatten)]
    pub zenoh: ZenohArgs,
    /// How often the state is published, Hz (at least 10).
    #[arg(long, default_value_t = 20.0)]
    pub state_hz: f64,
    /// A source published on osap/NAME/capture/SOURCE (repeatable), as
    /// `osap capture` takes it: MODULE.FUNCTION[(ARGS)][.OUTPUT].
    #[arg(long = "source", value_name = "SOURCE")]
    pub sources: Vec<String>,
    /// Sampling period of every source, µs.
    #[arg(long, default_value_t = 1_000)]
    pub period_us: u32,
}

/// A zenoh session on a multi-thread runtime of its own, in real time,
/// whatever the machine's runtime is (a simulation in virtual time runs on
/// one paused thread). On an error the runtime is let go at once: a
/// runtime may not be dropped inside another's task.
pub(crate) async fn open_zenoh(
    config: zenoh::Config,
) -> Result<(tokio::runtime::Runtime, zenoh::Session), Failure> {
    let failed = |message: String| Failure {
        code: FAULTED,
        message,
    };
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("zenoh")
        .enable_all()
        .build()
        .map_err(|e| failed(format!("cannot start zenoh's runtime: {e}")))?;
    let opened = rt
        .spawn(async move { zenoh::open(config).await.map_err(|e| e.to_string()) })
        .await
        .map_err(|e| e.to_string())
        .and_then(|r| r);
    match opened {
        Ok(session) => Ok((rt, session)),
        Err(e) => {
            rt.shutdown_background();
            Err(failed(format!("zenoh: {e}")))
        }
    }
}

/// Closes the session where it runs, then lets the runtime go.
pub(crate) async fn close(rt: tokio::runtime::Runtime, session: zenoh::Session) {
    let _ = rt.spawn(async move { session.close().await }).await;
    rt.shutdown_background();
}

/// Waits for Ctrl-C or SIGTERM.
async fn interrupted() {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{signal, SignalKind};
        if let Ok(mut term) = signal(SignalKind::terminate()) {
            tokio::select! {
                _ = tokio::signal::ctrl_c() => {}
                _ = term.recv() => {}
            }
            return;
        }
    }
    let _ = tokio::signal::ctrl_c().await;
}

/// Runs `osap bridge`.
pub(crate) async fn bridge(args: BridgeArgs) -> Result<ExitCode, Failure> {
    if !(args.state_hz.is_finite() && (10.0..=1000.0).contains(&args.state_hz)) {
        return Err(Failure::refused(format!(
            "--state-hz {}: give 10 to 1000",
            args.state_hz
        )));
    }
    let cfg = args.target.load()?;
    // Refused before anything starts: an exposed machine never runs.
    let config = args
        .zenoh
        .options()
        .bridge_config()
        .map_err(|e| Failure::refused(e.to_string()))?;
    let listening = config
        .get_json("listen/endpoints")
        .unwrap_or_else(|_| "[]".into());
    // zenoh first: an endpoint already in use fails before the machine
    // is touched.
    let (rt, session) = open_zenoh(config).await?;
    let machine = match args.target.start(&cfg).await {
        Ok(m) => m,
        Err(f) => {
            close(rt, session).await;
            return Err(f);
        }
    };
    let options = BridgeOptions {
        name: args.name.clone(),
        state_period: Duration::from_secs_f64(1.0 / args.state_hz),
        sources: args.sources.clone(),
        period_us: args.period_us,
    };
    let started = Bridge::start(
        session.clone(),
        rt.handle().clone(),
        machine.clone(),
        options,
    )
    .await;
    let bridge = match started {
        Ok(b) => b,
        Err(e) => {
            let _ = machine.stop().await;
            close(rt, session).await;
            return Err(match e {
                osap_zenoh::BridgeError::Source { .. } => Failure::refused(e.to_string()),
                other => Failure {
                    code: FAULTED,
                    message: other.to_string(),
                },
            });
        }
    };
    println!(
        "machine {} bridged on zenoh as osap/{}/… (listening on {listening}); Ctrl-C stops",
        cfg.name,
        bridge.keys().name()
    );
    use std::io::Write;
    let _ = std::io::stdout().flush();
    interrupted().await;
    bridge.close().await;
    let stopped = machine.stop().await;
    close(rt, session).await;
    match stopped {
        Ok(_) => Ok(ExitCode::SUCCESS),
        Err(e) => Err(Failure::from_machine(e)),
    }
}

/// `osap fleet` options.
#[derive(Args, Debug)]
pub(crate) struct FleetArgs {
    #[command(flatten)]
    pub zenoh: ZenohArgs,
    /// How long to wait for replies, ms.
    #[arg(long, default_value_t = 1500)]
    pub timeout_ms: u64,
}

/// Runs `osap fleet`: one line per machine found.
pub(crate) async fn fleet(args: FleetArgs) -> Result<ExitCode, Failure> {
    let config = args
        .zenoh
        .options()
        .client_config()
        .map_err(|e| Failure::refused(e.to_string()))?;
    let (rt, session) = open_zenoh(config).await?;
    let timeout = Duration::from_millis(args.timeout_ms);
    let s = session.clone();
    let found = rt
        .spawn(async move { osap_zenoh::fleet::list(&s, timeout).await })
        .await
        .map_err(|e| e.to_string())
        .and_then(|r| r);
    close(rt, session).await;
    let found = found.map_err(|e| Failure {
        code: FAULTED,
        message: e,
    })?;
    if found.is_empty() {
        println!("no machines found");
    }
    for f in &found {
        println!(
            "{}  {}  {}  modules {}  axes {}",
            f.key_name,
            f.info.kind,
            f.info.state,
            f.info.modules.join(","),
            f.info.axes.join(",")
        );
    }
    Ok(ExitCode::SUCCESS)
}
