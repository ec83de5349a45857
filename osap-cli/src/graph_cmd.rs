//! `osap graph save FILE.json` and `osap graph apply FILE.json
//! [--dry-run]`: a network's wired dataflow graph as a file
//! (`osap_host::som::graph`), re-created on a fresh network.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Subcommand;
use osap_host::som::graph::Graph;
use osap_host::som::Manager;

use crate::Connect;

/// `osap graph` subcommands.
#[derive(Subcommand)]
pub(crate) enum GraphCommand {
    /// Write the live graph (pipes, argmaps, input and output modes, by
    /// runtime name) to FILE.json.
    Save {
        /// The file to write.
        file: PathBuf,
        #[command(flatten)]
        connect: Connect,
    },
    /// Re-create the graph of FILE.json on the network; applying twice
    /// changes nothing the second time.
    Apply {
        /// The graph file (`osap graph save`).
        file: PathBuf,
        /// Print what would change, and change nothing.
        #[arg(long)]
        dry_run: bool,
        #[command(flatten)]
        connect: Connect,
    },
}

async fn manager(connect_args: &Connect) -> Result<(crate::Connection, Manager), String> {
    crate::connection::connect_scanned(connect_args).await
}

/// Runs `osap graph …`.
pub(crate) async fn graph(command: GraphCommand) -> Result<ExitCode, String> {
    match command {
        GraphCommand::Save { file, connect } => {
            let (_c, m) = manager(&connect).await?;
            let graph = Graph::from_som(m.som());
            let text = serde_json::to_string_pretty(&graph).map_err(|e| e.to_string())?;
            std::fs::write(&file, text + "\n").map_err(|e| format!("{}: {e}", file.display()))?;
            println!(
                "graph: {} functions, {} pipes written to {}",
                graph.functions.len(),
                graph.pipes.len(),
                file.display()
            );
            Ok(ExitCode::SUCCESS)
        }
        GraphCommand::Apply {
            file,
            dry_run,
            connect,
        } => {
            let text =
                std::fs::read_to_string(&file).map_err(|e| format!("{}: {e}", file.display()))?;
            let graph: Graph = serde_json::from_str(&text)
                .map_err(|e| format!("{}: not a graph file: {e}", file.display()))?;
            let (_c, mut m) = manager(&connect).await?;
            let changes = if dry_run {
                graph.changes(m.som())
            } else {
                graph.apply(&mut m).await
            }
            .map_err(|e| e.to_string())?;
            let verb = if dry_run { "would change" } else { "changed" };
            if changes.is_empty() {
                println!("graph: nothing to change");
            } else {
                println!("graph: {verb} {}:", changes.len());
                for c in &changes {
                    println!("  {c}");
                }
            }
            Ok(ExitCode::SUCCESS)
        }
    }
}
