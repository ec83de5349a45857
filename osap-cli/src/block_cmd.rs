//! `osap block types|new|delete`: blocks made on a runtime while it runs
//! (`pipes_core::manager`): a comparator, a filter, a trigger, each a
//! function of its own once made.

use std::process::ExitCode;

use clap::Subcommand;
use osap_host::som::{describe, Manager};

use crate::call_cmd::parse_inputs;
use crate::Connect;

/// `osap block` subcommands.
#[derive(Subcommand)]
pub(crate) enum BlockCommand {
    /// List the block classes RUNTIME can make: their constructor
    /// arguments, what each block takes and gives, and how many it holds.
    Types {
        /// The runtime's name (`osap scan` lists them).
        runtime: String,
        #[command(flatten)]
        connect: Connect,
    },
    /// Make a block of CLASS named NAME on RUNTIME from its constructor's
    /// arguments, e.g. `osap block new z comparator probe 0.5 0.1 true`.
    New {
        /// The runtime's name.
        runtime: String,
        /// The class (`osap block types RUNTIME` lists them).
        class: String,
        /// The new block's name: 1 to 24 letters, digits or `_`.
        name: String,
        /// One value per constructor argument, in order.
        #[arg(allow_negative_numbers = true, value_name = "ARG")]
        args: Vec<String>,
        #[command(flatten)]
        connect: Connect,
    },
    /// Delete the block NAME on RUNTIME, first removing every pipe into it.
    Delete {
        /// The runtime's name.
        runtime: String,
        /// The block's name.
        name: String,
        #[command(flatten)]
        connect: Connect,
    },
}

async fn manager(connect_args: &Connect) -> Result<(crate::Connection, Manager), String> {
    crate::connection::connect_scanned(connect_args).await
}

/// Runs `osap block …`.
pub(crate) async fn block(command: BlockCommand) -> Result<ExitCode, String> {
    match command {
        BlockCommand::Types { runtime, connect } => {
            let (_c, m) = manager(&connect).await?;
            let classes = m.block_classes(&runtime).await.map_err(|e| e.to_string())?;
            for c in classes {
                let outputs = if c.outputs.is_empty() {
                    String::new()
                } else {
                    format!(" -> ({})", describe(&c.outputs))
                };
                println!(
                    "{}({}): block ({}){outputs}, {} of {} in use",
                    c.name,
                    describe(&c.arguments),
                    describe(&c.inputs),
                    c.used,
                    c.capacity
                );
            }
            Ok(ExitCode::SUCCESS)
        }
        BlockCommand::New {
            runtime,
            class,
            name,
            args,
            connect,
        } => {
            let (_c, mut m) = manager(&connect).await?;
            let classes = m.block_classes(&runtime).await.map_err(|e| e.to_string())?;
            let info = classes.iter().find(|c| c.name == class).ok_or_else(|| {
                format!(
                    "{runtime} has no block class {class:?} (it has {}: `osap block types {runtime}`)",
                    classes
                        .iter()
                        .map(|c| c.name.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                )
            })?;
            let values = parse_inputs(&format!("{class} on {runtime}"), &info.arguments, &args)?;
            let b = m
                .new_block(&runtime, &class, &name, &values)
                .await
                .map_err(|e| e.to_string())?;
            println!(
                "{runtime}.{} made: a {} in slot {} at port {}",
                b.name, b.class, b.slot, b.port
            );
            Ok(ExitCode::SUCCESS)
        }
        BlockCommand::Delete {
            runtime,
            name,
            connect,
        } => {
            let (_c, mut m) = manager(&connect).await?;
            let b = m
                .delete_block(&runtime, &name)
                .await
                .map_err(|e| e.to_string())?;
            println!("{runtime}.{} deleted (slot {} is free)", b.name, b.slot);
            Ok(ExitCode::SUCCESS)
        }
    }
}
