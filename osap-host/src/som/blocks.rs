//! Blocks made and deleted on devices at run time, from the host: the
//! client of a runtime's block manager (`pipes_core::manager`,
//! `docs/pipes.md` §7), keeping the model in step.

use super::handle::Target;
use super::manager::host_route;
use super::model::{Som, SomArg, SomBlock, SomBlockArgument};
use super::value::value_text;
use super::{FnRef, Manager, SomError, Value};
use crate::HOST_MTU;
use osap_core::codec::Writer;
use pipes_core::control::{ControlKey, Request};
use pipes_core::function::PIPE_PORT_TYPE;
use pipes_core::manager::{
    parse_reply, ClassPart, ManagerError, ManagerReply, ManagerRequest, BLOCK_PORT_TYPE, END,
    FREE_PORT_TYPE,
};
use pipes_core::signature::SignatureView;
use pipes_core::{Args, ArgsWriter};

/// A class of blocks a runtime can make.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BlockClassInfo {
    /// Its index on the runtime.
    pub index: u8,
    /// Its name.
    pub name: String,
    /// How many blocks of it the runtime can hold.
    pub capacity: u8,
    /// How many it holds.
    pub used: u8,
    /// The arguments a block is made with.
    pub arguments: Vec<SomArg>,
    /// Each block's inputs.
    pub inputs: Vec<SomArg>,
    /// Each block's outputs.
    pub outputs: Vec<SomArg>,
}

fn args_of(list: pipes_core::signature::ArgList<'_>) -> Vec<SomArg> {
    list.iter()
        .map(|a| SomArg {
            name: a.name.to_string(),
            type_name: a.ty.name().to_string(),
        })
        .collect()
}

/// Where runtime `ri`'s block manager is in `som`.
fn manager_target(som: &Som, ri: usize) -> Result<Target, SomError> {
    let rt = &som.runtimes[ri];
    let port = rt
        .block_manager_port()
        .ok_or_else(|| SomError::NoBlockManager(rt.record.name.clone()))?;
    Ok(Target {
        function: FnRef::new(rt.record.name.clone(), "block manager"),
        route: host_route(som, ri),
        port,
    })
}

impl Manager {
    /// Where `runtime`'s block manager is.
    fn block_manager(&self, runtime: &str) -> Result<(usize, Target), SomError> {
        let ri = self.runtime_index(runtime)?;
        Ok((ri, manager_target(self.som(), ri)?))
    }

    /// The blocks runtime `ri` of `som` holds, by slot, with their
    /// classes' names (what a refresh adds to the model).
    pub(super) async fn read_blocks(
        &self,
        som: &Som,
        ri: usize,
    ) -> Result<Vec<SomBlock>, SomError> {
        let at = manager_target(som, ri)?;
        let classes = self.list_classes(&at).await?;
        let mut blocks = Vec::new();
        let mut from = 0;
        while from != END {
            let bytes = self
                .ask_manager(
                    &at,
                    "list blocks",
                    &ManagerRequest::ListBlocks { from },
                    true,
                )
                .await?;
            let ManagerReply::Blocks(page) = Self::manager_reply(&at, "list blocks", &bytes)?
            else {
                return Err(malformed(&at, "list blocks"));
            };
            for b in page.blocks() {
                let class = classes
                    .iter()
                    .find(|c| c.index == b.class)
                    .map_or_else(|| format!("class {}", b.class), |c| c.name.clone());
                blocks.push(SomBlock {
                    name: b.name.to_string(),
                    class,
                    slot: b.slot,
                    port: at.port + b.offset,
                    arguments: Vec::new(),
                });
            }
            if page.next != END && page.next <= from {
                return Err(malformed(&at, "list blocks"));
            }
            from = page.next;
        }
        // What each was made with, named by its class's constructor.
        let mut constructors: Vec<(u8, Vec<SomArg>)> = Vec::new();
        for b in &mut blocks {
            let request = ManagerRequest::GetBlock { slot: b.slot };
            let bytes = self.ask_manager(&at, "get block", &request, true).await?;
            let ManagerReply::Block {
                block: Some((entry, args)),
                ..
            } = Self::manager_reply(&at, "get block", &bytes)?
            else {
                return Err(malformed(&at, "get block"));
            };
            let names = match constructors.iter().find(|(c, _)| *c == entry.class) {
                Some((_, names)) => names.clone(),
                None => {
                    let names = self.block_constructor(&at, entry.class).await?;
                    constructors.push((entry.class, names.clone()));
                    names
                }
            };
            b.arguments = args
                .iter()
                .map(|(i, v)| {
                    let arg = names.get(usize::from(i));
                    SomBlockArgument {
                        name: arg.map_or_else(|| format!("argument {i}"), |a| a.name.clone()),
                        type_name: v.ty().name().to_string(),
                        value: value_text(&v),
                    }
                })
                .collect();
        }
        Ok(blocks)
    }

    /// The constructor arguments of class `class` at the manager `at`.
    async fn block_constructor(&self, at: &Target, class: u8) -> Result<Vec<SomArg>, SomError> {
        let request = ManagerRequest::GetClass {
            class,
            part: ClassPart::Constructor,
        };
        let bytes = self
            .ask_manager(at, "get block class", &request, true)
            .await?;
        match Self::manager_reply(at, "get block class", &bytes)? {
            ManagerReply::Class { signature, .. } => Ok(args_of(signature.inputs())),
            _ => Err(malformed(at, "get block class")),
        }
    }

    /// Sends `request` to the manager at `at` and returns its reply bytes
    /// (`[key][status][body]`), checked to answer that key.
    async fn ask_manager(
        &self,
        at: &Target,
        what: &'static str,
        request: &ManagerRequest<'_>,
        idempotent: bool,
    ) -> Result<Vec<u8>, SomError> {
        let mut buf = vec![0u8; HOST_MTU];
        let mut w = Writer::new(&mut buf);
        request.encode(&mut w).map_err(|e| SomError::BadArguments {
            function: at.function.clone(),
            detail: format!("{what}: the request does not fit one packet: {e}"),
        })?;
        let n = w.len();
        buf.truncate(n);
        let reply = self.control().ask_raw(at, what, &buf, idempotent).await?;
        Ok(reply.into_bytes())
    }

    /// Parses a reply to `what`, turning a refusal into [`SomError::Block`].
    fn manager_reply<'r>(
        at: &Target,
        what: &'static str,
        bytes: &'r [u8],
    ) -> Result<ManagerReply<'r>, SomError> {
        let (_, result) = parse_reply(bytes).map_err(|e| SomError::Malformed {
            function: at.function.clone(),
            request: what,
            detail: e.to_string(),
        })?;
        result.map_err(|error| SomError::Block {
            runtime: at.function.runtime.clone(),
            request: what,
            error,
        })
    }

    /// The block classes `runtime` can make, with their signatures.
    pub async fn block_classes(&self, runtime: &str) -> Result<Vec<BlockClassInfo>, SomError> {
        let (_, at) = self.block_manager(runtime)?;
        let mut classes = self.list_classes(&at).await?;
        for c in &mut classes {
            for part in [ClassPart::Constructor, ClassPart::Block] {
                let request = ManagerRequest::GetClass {
                    class: c.index,
                    part,
                };
                let bytes = self
                    .ask_manager(&at, "get block class", &request, true)
                    .await?;
                let ManagerReply::Class { signature, .. } =
                    Self::manager_reply(&at, "get block class", &bytes)?
                else {
                    return Err(malformed(&at, "get block class"));
                };
                let s: SignatureView<'_> = signature;
                match part {
                    ClassPart::Constructor => c.arguments = args_of(s.inputs()),
                    ClassPart::Block => {
                        c.inputs = args_of(s.inputs());
                        c.outputs = args_of(s.outputs());
                    }
                }
            }
        }
        Ok(classes)
    }

    /// The classes of the manager at `at`, without their signatures.
    async fn list_classes(&self, at: &Target) -> Result<Vec<BlockClassInfo>, SomError> {
        let mut classes = Vec::new();
        let mut from = 0;
        while from != END {
            let bytes = self
                .ask_manager(
                    at,
                    "list block classes",
                    &ManagerRequest::ListClasses { from },
                    true,
                )
                .await?;
            let ManagerReply::Classes(page) =
                Self::manager_reply(at, "list block classes", &bytes)?
            else {
                return Err(malformed(at, "list block classes"));
            };
            for c in page.classes() {
                classes.push(BlockClassInfo {
                    index: c.class,
                    name: c.name.to_string(),
                    capacity: c.capacity,
                    used: c.used,
                    arguments: Vec::new(),
                    inputs: Vec::new(),
                    outputs: Vec::new(),
                });
            }
            // A page that makes no progress would ask forever.
            if page.next != END && page.next <= from {
                return Err(malformed(at, "list block classes"));
            }
            from = page.next;
        }
        Ok(classes)
    }

    /// Makes a block of class `class` named `name` on `runtime` from the
    /// constructor's `arguments` (one per argument, in order, converted
    /// like a call's), and adds it to the model as a function. Refuses a
    /// name another function of the runtime has.
    pub async fn new_block(
        &mut self,
        runtime: &str,
        class: &str,
        name: &str,
        arguments: &[Value<'static>],
    ) -> Result<SomBlock, SomError> {
        let (ri, at) = self.block_manager(runtime)?;
        if self.som().function(ri, name).is_some() {
            return Err(SomError::Block {
                runtime: runtime.to_string(),
                request: "new block",
                error: ManagerError::NameTaken,
            });
        }
        let classes = self.block_classes(runtime).await?;
        let info =
            classes
                .iter()
                .find(|c| c.name == class)
                .ok_or_else(|| SomError::BadArguments {
                    function: FnRef::new(runtime, name),
                    detail: format!(
                        "{runtime} has no block class {class:?}; it has {}",
                        classes
                            .iter()
                            .map(|c| c.name.as_str())
                            .collect::<Vec<_>>()
                            .join(", ")
                    ),
                })?;
        let mut buf = vec![0u8; HOST_MTU];
        let mut w = Writer::new(&mut buf);
        let bad = |detail: String| SomError::BadArguments {
            function: FnRef::new(runtime, name),
            detail,
        };
        let mut aw = ArgsWriter::new(&mut w).map_err(|e| bad(e.to_string()))?;
        for (i, v) in arguments.iter().enumerate() {
            aw.push(i as u8, v)
                .map_err(|e| bad(format!("argument {i}: {e}")))?;
        }
        aw.finish().map_err(|e| bad(e.to_string()))?;
        let n = w.len();
        let args = Args::decode(&mut osap_core::codec::Reader::new(&buf[..n]))
            .map_err(|e| bad(e.to_string()))?;
        let request = ManagerRequest::NewBlock {
            class: info.index,
            name,
            args,
        };
        // Never retried: a lost reply must not make a second block.
        let bytes = self.ask_manager(&at, "new block", &request, false).await?;
        let ManagerReply::Created { slot, offset } = Self::manager_reply(&at, "new block", &bytes)?
        else {
            return Err(malformed(&at, "new block"));
        };
        let port = at.port + offset;
        self.mark_slot(ri, port, 0, Some(name));
        let som = self.som().clone();
        let mut function = self.read_function(&som, ri, port).await?;
        // Its pipe ports follow its control port.
        self.mark_slot(ri, port, function.pipe_slots.into(), Some(name));
        function.pipe_ports = (1..=u16::from(function.pipe_slots))
            .map(|k| port + k)
            .collect();
        let block = SomBlock {
            name: name.to_string(),
            class: class.to_string(),
            slot,
            port,
            arguments: info
                .arguments
                .iter()
                .zip(arguments)
                .map(|(a, v)| SomBlockArgument {
                    name: a.name.clone(),
                    type_name: a.type_name.clone(),
                    value: value_text(v),
                })
                .collect(),
        };
        self.edit_runtime(ri, |rt| {
            rt.functions.push(function);
            rt.functions.sort_by_key(|f| f.port);
            rt.blocks.push(block.clone());
            rt.blocks.sort_by_key(|b| b.slot);
        });
        Ok(block)
    }

    /// Deletes the block `name` on `runtime`: first every pipe that leads
    /// into it (from any function in the model), then the block with its
    /// own pipes.
    pub async fn delete_block(&mut self, runtime: &str, name: &str) -> Result<SomBlock, SomError> {
        let (ri, at) = self.block_manager(runtime)?;
        let block = self.som().runtimes[ri]
            .blocks
            .iter()
            .find(|b| b.name == name)
            .cloned()
            .ok_or_else(|| SomError::Block {
                runtime: runtime.to_string(),
                request: "delete block",
                error: ManagerError::NoSuchBlock,
            })?;
        // Pipes into it: a later block in its slot must not receive them.
        let into: Vec<(FnRef, u8)> = self
            .som()
            .pipes
            .iter()
            .filter(|p| {
                p.destination
                    .as_ref()
                    .is_some_and(|d| d.runtime == ri && d.port == block.port)
            })
            .filter_map(|p| {
                let rt = &self.som().runtimes[p.source.runtime];
                let f = rt.functions.iter().find(|f| f.port == p.source.port)?;
                Some((FnRef::new(rt.record.name.clone(), f.name.clone()), p.slot))
            })
            .collect();
        for (source, slot) in into {
            let (_, src) = self.target_of(&source)?;
            self.control()
                .ask(&src, "wipe pipe", &Request::WipePipe(slot), true)
                .await?
                .body(&src, "wipe pipe", ControlKey::WipePipe)?;
            let si = self.runtime_index(&source.runtime)?;
            self.edit_function(si, &source.function, |f| f.pipes.retain(|p| p.slot != slot));
        }
        let request = ManagerRequest::DeleteBlock { name };
        let bytes = self
            .ask_manager(&at, "delete block", &request, true)
            .await?;
        match Self::manager_reply(&at, "delete block", &bytes) {
            Ok(ManagerReply::Deleted { .. }) => {}
            // Asked again after a lost reply: it is gone either way.
            Err(SomError::Block {
                error: ManagerError::NoSuchBlock,
                ..
            }) => {}
            Ok(_) => return Err(malformed(&at, "delete block")),
            Err(e) => return Err(e),
        }
        let pipes = self
            .som()
            .function(ri, name)
            .map_or(0, |f| u16::from(f.pipe_slots));
        self.mark_slot(ri, block.port, pipes, None);
        self.edit_runtime(ri, |rt| {
            rt.functions.retain(|f| f.port != block.port);
            rt.blocks.retain(|b| b.port != block.port);
        });
        Ok(block)
    }

    /// Rewrites the scan's record of a slot's control port at `port` and
    /// the `pipes` pipe ports after it: a block's (`Some` name) or free ones.
    fn mark_slot(&mut self, ri: usize, port: u16, pipes: u16, name: Option<&str>) {
        self.edit_runtime(ri, |rt| {
            for p in &mut rt.record.ports {
                if p.index < port || p.index > port + pipes {
                    continue;
                }
                (p.type_name, p.name) = match (name, p.index == port) {
                    (Some(n), true) => (BLOCK_PORT_TYPE.to_string(), n.to_string()),
                    (Some(_), false) => (PIPE_PORT_TYPE.to_string(), String::new()),
                    (None, _) => (FREE_PORT_TYPE.to_string(), String::new()),
                };
            }
        });
    }
}

fn malformed(at: &Target, request: &'static str) -> SomError {
    SomError::Malformed {
        function: at.function.clone(),
        request,
        detail: "the reply answers another request".into(),
    }
}
