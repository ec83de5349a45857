//! `proxygen`: typed Rust proxies from a system object model.
//!
//! ```text
//! proxygen --som som.json -o src/proxies          # from a saved scan
//! proxygen --sim machine.toml -o src/proxies      # scan a simulated machine (feature `sim`)
//! proxygen --som som.json --starter my-script     # a starter binary crate
//! ```

use clap::Parser;
use osap_host::som::Som;
use osap_sim::topology::SimSpec;
use proxygen::{Options, StarterOptions};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "proxygen",
    about = "Generate typed Rust proxies (one struct per runtime type) from a system object model"
)]
struct Args {
    /// The system object model, as JSON (e.g. from `osap scan --som -o som.json`).
    #[arg(long, conflicts_with = "sim")]
    som: Option<PathBuf>,
    /// Scan a simulated machine (a topology file) instead (needs the
    /// `sim` feature, on by default).
    #[arg(long)]
    sim: Option<PathBuf>,
    /// Where to write the proxies (`mod.rs` and one file per runtime type).
    #[arg(short, long)]
    out: Option<PathBuf>,
    /// Write a starter script (a binary crate) into this directory. Files
    /// already there are not overwritten unless --force is given.
    #[arg(long)]
    starter: Option<PathBuf>,
    /// With --starter: overwrite files that already exist (your edits to
    /// src/main.rs and Cargo.toml are lost).
    #[arg(long, requires = "starter")]
    force: bool,
    /// The `osap-host` crate's path for the starter's Cargo.toml.
    #[arg(long, default_value = concat!(env!("CARGO_MANIFEST_DIR"), "/../osap-host"))]
    osap_host: String,
    /// The `osap-sim` crate's path for the starter's Cargo.toml.
    #[arg(long, default_value = concat!(env!("CARGO_MANIFEST_DIR"), "/../osap-sim"))]
    osap_sim: String,
    /// Also save the model as JSON (useful with --sim).
    #[arg(long)]
    save_som: Option<PathBuf>,
    /// Also generate a proxy for the scanning host (runtime 0).
    #[arg(long)]
    include_host: bool,
}

#[cfg(feature = "sim")]
async fn live_som(path: &Path) -> Result<Som, String> {
    use osap_host::som::Manager;
    use osap_host::{Host, HostConfig};
    use osap_sim::machine::SimMachine;
    let host = Host::start(HostConfig::default()).map_err(|e| e.to_string())?;
    let topology = SimSpec::load(path).map_err(|e| e.to_string())?;
    let _machine = SimMachine::start(&host, &topology)
        .await
        .map_err(|e| format!("cannot start {}: {e}", path.display()))?;
    let mut manager = Manager::new(&host).await.map_err(|e| e.to_string())?;
    manager.refresh().await.map_err(|e| e.to_string())?;
    Ok(manager.som().clone())
}

#[cfg(not(feature = "sim"))]
async fn live_som(path: &Path) -> Result<Som, String> {
    Err(format!(
        "cannot scan {}: this proxygen was built without the `sim` feature; rebuild it \
         with `--features sim`, or give --som FILE (a model saved by `osap scan --som`)",
        path.display()
    ))
}

async fn run(args: Args) -> Result<(), String> {
    let som = match (&args.som, &args.sim) {
        (Some(path), _) => {
            let text = std::fs::read_to_string(path)
                .map_err(|e| format!("cannot read {}: {e}", path.display()))?;
            Som::from_json(&text).map_err(|e| format!("{}: {e}", path.display()))?
        }
        (None, Some(path)) => live_som(path).await?,
        (None, None) => return Err("give --som FILE or --sim FILE".into()),
    };
    if let Some(path) = &args.save_som {
        std::fs::write(path, som.to_json() + "\n")
            .map_err(|e| format!("{}: {e}", path.display()))?;
    }
    if args.out.is_none() && args.starter.is_none() && args.save_som.is_none() {
        return Err("give -o DIR, --starter DIR or --save-som FILE".into());
    }
    let options = Options {
        include_host: args.include_host,
    };
    if let Some(out) = &args.out {
        let files = proxygen::generate(&som, &options).map_err(|e| e.to_string())?;
        proxygen::write(out, &files).map_err(|e| format!("{}: {e}", out.display()))?;
        println!("{} files written to {}", files.len(), out.display());
    }
    if let Some(dir) = &args.starter {
        let name = dir
            .file_name()
            .map(|n| proxygen::names::snake(&n.to_string_lossy()).replace('_', "-"))
            .unwrap_or_else(|| "starter".into());
        let files = proxygen::starter(
            &som,
            &StarterOptions {
                name,
                osap_host: args.osap_host.clone(),
                osap_sim: args.osap_sim.clone(),
                proxies: options,
            },
        )
        .map_err(|e| e.to_string())?;
        if !args.force {
            refuse_overwrite(dir, &files)?;
        }
        proxygen::write(dir, &files).map_err(|e| format!("{}: {e}", dir.display()))?;
        println!(
            "starter written to {} (cargo run -- --sim FILE | --port PATH | --tcp ADDR)",
            dir.display()
        );
    }
    Ok(())
}

/// Refuses to write a starter over files that exist: the user may have
/// edited them.
fn refuse_overwrite(dir: &Path, files: &[proxygen::GeneratedFile]) -> Result<(), String> {
    let existing: Vec<String> = files
        .iter()
        .filter(|f| dir.join(&f.path).exists())
        .map(|f| f.path.display().to_string())
        .collect();
    if existing.is_empty() {
        return Ok(());
    }
    let shown = existing
        .iter()
        .take(4)
        .cloned()
        .collect::<Vec<_>>()
        .join(", ");
    let more = existing
        .len()
        .checked_sub(4)
        .filter(|n| *n > 0)
        .map_or(String::new(), |n| format!(" and {n} more"));
    Err(format!(
        "{} already holds {shown}{more}: nothing written. Give --force to overwrite them (edits are lost), \
         or refresh only the proxies with -o {}",
        dir.display(),
        dir.join("src/proxies").display()
    ))
}

#[tokio::main]
async fn main() -> ExitCode {
    // RUST_LOG (e.g. RUST_LOG=osap_host=debug) shows what the scan does.
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn"));
    let _ = tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_env_filter(filter)
        .try_init();
    match run(Args::parse()).await {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("proxygen: {e}");
            ExitCode::FAILURE
        }
    }
}
