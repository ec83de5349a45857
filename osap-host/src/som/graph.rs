//! A wired dataflow graph as a file: which functions pipe into which, with
//! their argmaps, and every function's input and output modes, keyed by
//! runtime names (never routes), so that `osap graph apply` re-creates it on
//! a fresh network. The format is documented in docs/pipes.md ("Graphs as
//! files") and versioned by [`GRAPH_VERSION`].
//!
//! Functions of the runtime that built the model (index 0, a host) are left
//! out, with every pipe to or from them: they live in that program only.

use std::fmt;

use serde::{Deserialize, Serialize};

use super::manager::{Manager, PipeOptions};
use super::model::{
    Som, SomArg, SomArgPair, SomBlockArgument, SomDelivery, SomInputMode, SomOutputMode,
};
use super::{parse_value, FnRef, SomError};

/// `threshold = 0.5, halt = true`.
fn arguments_text(args: &[SomBlockArgument]) -> String {
    args.iter()
        .map(|a| format!("{} = {}", a.name, a.value))
        .collect::<Vec<_>>()
        .join(", ")
}

/// What a graph file's `format` says.
pub const GRAPH_FORMAT: &str = "osap-graph";
/// The layout version this build writes. It reads this and version 1
/// (before blocks: a version 1 file has none).
pub const GRAPH_VERSION: u32 = 2;

/// A function in a graph: its signature (checked against the network's)
/// and its modes.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct GraphFunction {
    /// The runtime's name.
    pub runtime: String,
    /// The function's name.
    pub function: String,
    /// Its inputs, as its signature has them.
    pub inputs: Vec<SomArg>,
    /// Its outputs.
    pub outputs: Vec<SomArg>,
    /// When it runs on dataflow.
    pub input_mode: SomInputMode,
    /// When it sends its outputs.
    pub output_mode: SomOutputMode,
}

/// One end of a pipe: a function by runtime and name.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
pub struct GraphEnd {
    /// The runtime's name.
    pub runtime: String,
    /// The function's name.
    pub function: String,
}

impl fmt::Display for GraphEnd {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}.{}", self.runtime, self.function)
    }
}

/// A pipe in a graph.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct GraphPipe {
    /// Where it starts.
    pub source: GraphEnd,
    /// The source's slot.
    pub slot: u8,
    /// Where it ends.
    pub destination: GraphEnd,
    /// Which outputs go to which inputs.
    pub argmap: Vec<SomArgPair>,
    /// Time-to-live of each datagram, µs.
    pub ttl_us: u16,
    /// How it delivers.
    pub delivery: SomDelivery,
}

/// A block made at run time, in a graph: re-made when missing.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct GraphBlock {
    /// The runtime's name.
    pub runtime: String,
    /// The block's name (its function's).
    pub name: String,
    /// Its class.
    pub class: String,
    /// The constructor's arguments it is made with, in order.
    pub arguments: Vec<SomBlockArgument>,
}

impl GraphBlock {
    fn end(&self) -> GraphEnd {
        GraphEnd {
            runtime: self.runtime.clone(),
            function: self.name.clone(),
        }
    }
}

/// A graph file.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Graph {
    /// Always [`GRAPH_FORMAT`].
    pub format: String,
    /// [`GRAPH_VERSION`] when written by this build.
    pub version: u32,
    /// Every function with a pipe (either end) or a mode other than the
    /// default, by runtime then name.
    pub functions: Vec<GraphFunction>,
    /// Every pipe between two such functions, by source and slot.
    pub pipes: Vec<GraphPipe>,
    /// Every block made at run time, by runtime then name (version 2).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub blocks: Vec<GraphBlock>,
}

/// One thing `apply` changes (or, dry, would).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum GraphChange {
    /// A block made.
    Block(GraphBlock),
    /// A function's input mode.
    InputMode(GraphEnd, SomInputMode),
    /// A function's output mode.
    OutputMode(GraphEnd, SomOutputMode),
    /// A pipe made.
    Pipe(GraphPipe),
}

impl fmt::Display for GraphChange {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            GraphChange::Block(b) => write!(
                f,
                "{}: make a {}({})",
                b.end(),
                b.class,
                b.arguments
                    .iter()
                    .map(|a| format!("{} = {}", a.name, a.value))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
            GraphChange::InputMode(e, m) => write!(f, "{e}: input mode {m:?}"),
            GraphChange::OutputMode(e, m) => write!(f, "{e}: output mode {m:?}"),
            GraphChange::Pipe(p) => write!(
                f,
                "pipe {} slot {} -> {} ({})",
                p.source,
                p.slot,
                p.destination,
                p.argmap
                    .iter()
                    .map(|a| format!("{}->{}", a.output, a.input))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        }
    }
}

/// Why a graph was refused or could not be applied.
#[derive(Debug, thiserror::Error)]
pub enum GraphError {
    /// Not a graph this build reads.
    #[error("not an osap graph file: format {format:?}, version {version} (this build reads {GRAPH_FORMAT:?} version {GRAPH_VERSION})")]
    Format {
        /// What it said.
        format: String,
        /// Its version.
        version: u32,
    },
    /// The network does not match the graph; every mismatch is named.
    #[error("the graph does not match the network:\n  {}", .0.join("\n  "))]
    Mismatch(Vec<String>),
    /// A request to the network failed midway.
    #[error(transparent)]
    Network(#[from] SomError),
}

impl Graph {
    /// The graph of the model `som` (see the module docs).
    pub fn from_som(som: &Som) -> Graph {
        let mut functions = Vec::new();
        let mut pipes = Vec::new();
        let default_in = SomInputMode::OnAnyFresh;
        let default_out = SomOutputMode::Always;
        // Which functions a pipe of another runtime ends at.
        let mut targets: Vec<GraphEnd> = Vec::new();
        for rt in som.runtimes.iter().skip(1) {
            for f in &rt.functions {
                for p in &f.pipes {
                    let Some(dest) = &p.destination else { continue };
                    let Some(df) = &dest.function else { continue };
                    if dest.runtime == 0 {
                        continue;
                    }
                    let destination = GraphEnd {
                        runtime: dest.runtime_name.clone(),
                        function: df.clone(),
                    };
                    targets.push(destination.clone());
                    pipes.push(GraphPipe {
                        source: GraphEnd {
                            runtime: rt.record.name.clone(),
                            function: f.name.clone(),
                        },
                        slot: p.slot,
                        destination,
                        argmap: p.argmap.clone(),
                        ttl_us: p.ttl_us,
                        delivery: p.delivery,
                    });
                }
            }
        }
        for rt in som.runtimes.iter().skip(1) {
            for f in &rt.functions {
                let end = GraphEnd {
                    runtime: rt.record.name.clone(),
                    function: f.name.clone(),
                };
                let piped = !f.pipes.is_empty() || targets.contains(&end);
                if piped || f.input_mode != default_in || f.output_mode != default_out {
                    functions.push(GraphFunction {
                        runtime: end.runtime,
                        function: end.function,
                        inputs: f.inputs.clone(),
                        outputs: f.outputs.clone(),
                        input_mode: f.input_mode,
                        output_mode: f.output_mode,
                    });
                }
            }
        }
        functions.sort_by(|a, b| (&a.runtime, &a.function).cmp(&(&b.runtime, &b.function)));
        pipes.sort_by(|a, b| (&a.source, a.slot).cmp(&(&b.source, b.slot)));
        let mut blocks: Vec<GraphBlock> = som
            .runtimes
            .iter()
            .skip(1)
            .flat_map(|rt| {
                rt.blocks.iter().map(|b| GraphBlock {
                    runtime: rt.record.name.clone(),
                    name: b.name.clone(),
                    class: b.class.clone(),
                    arguments: b.arguments.clone(),
                })
            })
            .collect();
        blocks.sort_by(|a, b| (&a.runtime, &a.name).cmp(&(&b.runtime, &b.name)));
        Graph {
            format: GRAPH_FORMAT.into(),
            version: GRAPH_VERSION,
            functions,
            pipes,
            blocks,
        }
    }

    /// What applying it to the model `som` would change, or every reason
    /// it cannot: a runtime or function missing, a signature that differs,
    /// a slot another pipe holds.
    pub fn changes(&self, som: &Som) -> Result<Vec<GraphChange>, GraphError> {
        if self.format != GRAPH_FORMAT || !(1..=GRAPH_VERSION).contains(&self.version) {
            return Err(GraphError::Format {
                format: self.format.clone(),
                version: self.version,
            });
        }
        let live = Graph::from_som(som);
        let mut mismatches = Vec::new();
        let mut changes = Vec::new();
        // Blocks first: the functions and pipes below may be theirs.
        let mut to_make = Vec::new();
        for b in &self.blocks {
            let Some(rt) = som
                .runtimes
                .iter()
                .skip(1)
                .find(|r| r.record.name == b.runtime)
            else {
                mismatches.push(format!("no runtime {} on the network", b.runtime));
                continue;
            };
            match (
                live.blocks
                    .iter()
                    .find(|l| l.runtime == b.runtime && l.name == b.name),
                rt.functions.iter().any(|f| f.name == b.name),
            ) {
                (Some(l), _) if l.class == b.class && l.arguments == b.arguments => {}
                (Some(l), _) => mismatches.push(format!(
                    "{}: a {} made with ({}) on the network, a {} made with ({}) in the graph",
                    b.end(),
                    l.class,
                    arguments_text(&l.arguments),
                    b.class,
                    arguments_text(&b.arguments)
                )),
                (None, true) => mismatches.push(format!(
                    "{}: a function of that name, not a block, is on the network",
                    b.end()
                )),
                (None, false) => {
                    to_make.push(b.end());
                    changes.push(GraphChange::Block(b.clone()));
                }
            }
        }
        let find = |e: &GraphEnd| {
            som.runtimes
                .iter()
                .skip(1)
                .find(|r| r.record.name == e.runtime)
                .map(|r| r.functions.iter().find(|f| f.name == e.function))
        };
        for g in &self.functions {
            let end = GraphEnd {
                runtime: g.runtime.clone(),
                function: g.function.clone(),
            };
            if to_make.contains(&end) {
                // Made by this apply: its modes are set after it is.
                changes.push(GraphChange::InputMode(end.clone(), g.input_mode));
                changes.push(GraphChange::OutputMode(end, g.output_mode));
                continue;
            }
            match find(&end) {
                None => mismatches.push(format!("no runtime {} on the network", g.runtime)),
                Some(None) => mismatches.push(format!("{end}: no such function on {}", g.runtime)),
                Some(Some(f)) => {
                    if f.inputs != g.inputs || f.outputs != g.outputs {
                        mismatches.push(format!(
                            "{end}: signature ({}) -> ({}) on the network, ({}) -> ({}) in the graph",
                            super::describe(&f.inputs),
                            super::describe(&f.outputs),
                            super::describe(&g.inputs),
                            super::describe(&g.outputs)
                        ));
                        continue;
                    }
                    if f.input_mode != g.input_mode {
                        changes.push(GraphChange::InputMode(end.clone(), g.input_mode));
                    }
                    if f.output_mode != g.output_mode {
                        changes.push(GraphChange::OutputMode(end, g.output_mode));
                    }
                }
            }
        }
        for p in &self.pipes {
            for e in [&p.source, &p.destination] {
                if !self
                    .functions
                    .iter()
                    .any(|f| f.runtime == e.runtime && f.function == e.function)
                {
                    mismatches.push(format!(
                        "pipe {} slot {}: {e} is not among the graph's functions",
                        p.source, p.slot
                    ));
                }
            }
            match live
                .pipes
                .iter()
                .find(|l| l.source == p.source && l.slot == p.slot)
            {
                Some(l) if l == p => {}
                Some(l) => mismatches.push(format!(
                    "{} slot {} holds a pipe to {}, not the graph's to {}",
                    p.source, p.slot, l.destination, p.destination
                )),
                None => changes.push(GraphChange::Pipe(p.clone())),
            }
        }
        if mismatches.is_empty() {
            Ok(changes)
        } else {
            Err(GraphError::Mismatch(mismatches))
        }
    }

    /// Applies it through `manager` (whose model must be fresh): pipes
    /// first, then the modes. Returns what it changed; applying again
    /// changes nothing.
    pub async fn apply(&self, manager: &mut Manager) -> Result<Vec<GraphChange>, GraphError> {
        let changes = self.changes(manager.som())?;
        let fref = |e: &GraphEnd| FnRef::new(e.runtime.as_str(), e.function.as_str());
        for c in &changes {
            if let GraphChange::Block(b) = c {
                let mut values = Vec::new();
                for a in &b.arguments {
                    let bad = |detail: String| {
                        GraphError::Mismatch(vec![format!(
                            "{}: argument {}: {detail}",
                            b.end(),
                            a.name
                        )])
                    };
                    let ty = pipes_core::Type::from_name(&a.type_name)
                        .ok_or_else(|| bad(format!("unknown type {}", a.type_name)))?;
                    values.push(parse_value(&ty, &a.value).map_err(|e| bad(e.to_string()))?);
                }
                manager
                    .new_block(&b.runtime, &b.class, &b.name, &values)
                    .await?;
            }
        }
        for c in &changes {
            if let GraphChange::Pipe(p) = c {
                let outputs: Vec<u8> = p.argmap.iter().map(|a| a.output).collect();
                let inputs: Vec<u8> = p.argmap.iter().map(|a| a.input).collect();
                let options = PipeOptions {
                    ttl_us: p.ttl_us,
                    delivery: p.delivery.into(),
                    slot: Some(p.slot),
                    ..PipeOptions::default()
                };
                manager
                    .connect(
                        &fref(&p.source),
                        &fref(&p.destination),
                        &outputs,
                        &inputs,
                        options,
                    )
                    .await?;
            }
        }
        for c in &changes {
            match c {
                GraphChange::InputMode(e, m) => {
                    manager.set_input_mode(&fref(e), (*m).into()).await?
                }
                GraphChange::OutputMode(e, m) => {
                    manager.set_output_mode(&fref(e), (*m).into()).await?
                }
                GraphChange::Pipe(_) | GraphChange::Block(_) => {}
            }
        }
        Ok(changes)
    }
}
