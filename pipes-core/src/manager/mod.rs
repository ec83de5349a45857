//! Blocks made and deleted at run time: a device's block manager.
//!
//! A device offers **block classes**: a kind of function (a comparator, a
//! filter) whose blocks are made at run time from constructor arguments,
//! each a PIPES function of its own with a name the user gives. A
//! [`Blocks`] port holds the manager and a fixed pool of slots per class,
//! sized at compile time, so nothing is allocated: a full pool is a
//! refusal ([`ManagerError::PoolFull`]), never a panic.
//!
//! Its port indices are reserved when the device starts, so making a block
//! never moves another port: offset 0 is the manager (type
//! [`MANAGER_PORT_TYPE`]), then each slot takes `1 + PIPES` ports, its
//! control port first. A slot's control port is of type
//! [`BLOCK_PORT_TYPE`] named after its block while it holds one, and
//! [`FREE_PORT_TYPE`] while it is free. A block answers the function
//! protocol like any function (pipes, modes, calls); deleting it drops its
//! pipes and what they queued.
//!
//! The messages are in [`wire`] and `docs/pipes.md` §7. The classes come
//! from a [`BlockFactory`], which knows what its blocks reach on the
//! device (an axis to halt, a pin to set).

mod wire;

#[cfg(test)]
mod tests;

pub use wire::{
    parse_reply, write_block_entry, write_class_entry, BlockEntry, BlockName, ClassEntry,
    ClassPart, ManagerError, ManagerKey, ManagerReply, ManagerRequest, Page, BAD_ARGUMENT, END,
    MAX_NAME,
};

use core::fmt;

use osap_core::codec::{CodecError, Writer};
use osap_core::port::{Delivery, Port, PortInfo, PortTx};
use osap_core::transport::Transport;
use osap_core::Instant;

use crate::control::{InputMode, OutputMode};
use crate::convert::{convert, Converted};
use crate::function::{
    CallError, Implementation, PipesFunction, DEFAULT_REPLY_TTL, PIPE_PORT_TYPE,
};
use crate::signature::{Signature, SignatureError, MAX_ARGS};
use crate::value::Value;

/// Type name of a block manager's port in a network scan.
pub const MANAGER_PORT_TYPE: &str = "pipes_manager";
/// Type name of a block's control port: a PIPES function made at run time.
pub const BLOCK_PORT_TYPE: &str = "pipes_block";
/// Type name of a free slot's ports, reserved for a block.
pub const FREE_PORT_TYPE: &str = "pipes_free";

/// A class of blocks a device can make.
#[derive(Debug, Clone, Copy)]
pub struct BlockClass {
    /// The constructor: named after the class, its inputs the arguments a
    /// block is made with, no outputs. Arguments are scalars.
    pub constructor: &'static Signature,
    /// What each block takes and gives (named after the class; each block
    /// answers to its own name).
    pub block: &'static Signature,
    /// How many blocks of the class the device can hold at once.
    pub capacity: u8,
    /// The input mode a new block starts in.
    pub input_mode: InputMode,
    /// The output mode a new block starts in (an event source starts "on
    /// change", so it sends each event once).
    pub output_mode: OutputMode,
}

impl BlockClass {
    /// The class's name.
    pub fn name(&self) -> &'static str {
        self.constructor.name
    }
}

/// What a device makes its blocks with.
pub trait BlockFactory {
    /// A block: a function with a run-time name ([`Implementation::name`]).
    type Block: Implementation;

    /// The classes, by index.
    fn classes(&self) -> &'static [BlockClass];

    /// Makes a block of class `class` named `name`, for slot `slot`, from
    /// the constructor's inputs (already of their declared types), or
    /// refuses them with the class's own failure code.
    fn make(
        &mut self,
        class: usize,
        slot: u8,
        name: BlockName,
        inputs: &[Value<'_>],
    ) -> Result<Self::Block, CallError>;
}

/// Why a [`Blocks`] port could not be made.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum BlocksError {
    /// The classes' capacities do not add up to the pool's slots.
    Capacity {
        /// The sum of the capacities.
        classes: usize,
        /// The slots.
        slots: usize,
    },
    /// More than 254 slots or classes.
    TooMany,
    /// A class's signature is beyond the limits.
    Signature(SignatureError),
}

impl fmt::Display for BlocksError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BlocksError::Capacity { classes, slots } => write!(
                f,
                "the block classes hold {classes} blocks but the pool has {slots} slots"
            ),
            BlocksError::TooMany => f.write_str("more than 254 block slots or classes"),
            BlocksError::Signature(e) => write!(f, "a block class's signature: {e}"),
        }
    }
}

impl core::error::Error for BlocksError {}

/// What a manager counted.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ManagerStats {
    /// Blocks made.
    pub created: u32,
    /// Blocks deleted.
    pub deleted: u32,
    /// Requests refused.
    pub refused: u32,
    /// Packets that could not be read, or that reached a free slot.
    pub malformed: u32,
    /// Replies that could not be sent.
    pub reply_drops: u32,
}

/// A block manager and its pool (see the module docs): `SLOTS` blocks in
/// all, each a function with `PIPES` pipe slots, `Q` queued datagrams per
/// pipe and `B`-byte stores.
pub struct Blocks<
    F: BlockFactory,
    const SLOTS: usize,
    const PIPES: usize,
    const Q: usize,
    const B: usize,
> {
    factory: F,
    slots: [Option<PipesFunction<F::Block, PIPES, Q, B>>; SLOTS],
    /// The arguments each slot's block was made with, as an argument list
    /// of the constructor's types (`docs/pipes.md` §2), and its length.
    made_with: [([u8; B], usize); SLOTS],
    /// Each slot's class.
    class_of: [u8; SLOTS],
    reply_ttl: u16,
    stats: ManagerStats,
}

impl<F: BlockFactory, const SLOTS: usize, const PIPES: usize, const Q: usize, const B: usize>
    fmt::Debug for Blocks<F, SLOTS, PIPES, Q, B>
{
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Blocks")
            .field("classes", &self.factory.classes().len())
            .field("used", &self.slots.iter().flatten().count())
            .field("slots", &SLOTS)
            .field("stats", &self.stats)
            .finish()
    }
}

impl<F: BlockFactory, const SLOTS: usize, const PIPES: usize, const Q: usize, const B: usize>
    Blocks<F, SLOTS, PIPES, Q, B>
{
    /// Ports each slot takes.
    const SLOT_PORTS: u16 = 1 + PIPES as u16;

    /// The manager of `factory`'s classes: the capacities must add up to
    /// `SLOTS`, and every signature must be within the limits.
    pub fn new(factory: F) -> Result<Self, BlocksError> {
        let classes = factory.classes();
        if SLOTS > 254 || classes.len() > 254 {
            return Err(BlocksError::TooMany);
        }
        let total: usize = classes.iter().map(|c| usize::from(c.capacity)).sum();
        if total != SLOTS {
            return Err(BlocksError::Capacity {
                classes: total,
                slots: SLOTS,
            });
        }
        for c in classes {
            c.constructor.check().map_err(BlocksError::Signature)?;
            c.block.check().map_err(BlocksError::Signature)?;
        }
        let mut class_of = [0u8; SLOTS];
        let mut slot = 0;
        for (i, c) in classes.iter().enumerate() {
            for _ in 0..c.capacity {
                class_of[slot] = i as u8;
                slot += 1;
            }
        }
        Ok(Blocks {
            factory,
            slots: core::array::from_fn(|_| None),
            made_with: [([0; B], 0); SLOTS],
            class_of,
            reply_ttl: DEFAULT_REPLY_TTL,
            stats: ManagerStats::default(),
        })
    }

    /// The factory.
    pub fn factory(&self) -> &F {
        &self.factory
    }

    /// The counters.
    pub fn stats(&self) -> &ManagerStats {
        &self.stats
    }

    /// The block named `name`, if there is one.
    pub fn block(&self, name: &str) -> Option<&PipesFunction<F::Block, PIPES, Q, B>> {
        self.slots
            .iter()
            .flatten()
            .find(|b| b.implementation().name() == name)
    }

    /// The blocks, by slot.
    pub fn slots(&self) -> &[Option<PipesFunction<F::Block, PIPES, Q, B>>] {
        &self.slots
    }

    /// The control port offset of slot `slot`, from the manager's port.
    pub fn slot_offset(slot: usize) -> u16 {
        1 + slot as u16 * Self::SLOT_PORTS
    }

    /// Makes a block of class `class` named `name` (see
    /// [`ManagerRequest::NewBlock`]); returns its slot.
    pub fn create(
        &mut self,
        class: u8,
        name: &str,
        args: &crate::message::Args<'_>,
    ) -> Result<u8, ManagerError> {
        let info = *self
            .factory
            .classes()
            .get(usize::from(class))
            .ok_or(ManagerError::NoSuchClass(class))?;
        let name = BlockName::new(name)?;
        if self.block(name.as_str()).is_some() {
            return Err(ManagerError::NameTaken);
        }
        let slot = (0..SLOTS)
            .find(|&s| self.class_of[s] == class && self.slots[s].is_none())
            .ok_or(ManagerError::PoolFull(class))?;
        let ctor = info.constructor;
        let expected = ctor.inputs.len() as u8;
        if args.len() != ctor.inputs.len() {
            return Err(ManagerError::WrongArgCount {
                expected,
                got: args.len() as u8,
            });
        }
        let mut given: [Value<'_>; MAX_ARGS] = core::array::from_fn(|_| Value::Null);
        for (index, v) in args.iter() {
            let slot = given
                .get_mut(usize::from(index))
                .filter(|_| usize::from(index) < ctor.inputs.len())
                .ok_or(ManagerError::NoSuchInput(index))?;
            *slot = v;
        }
        let mut inputs: [Value<'_>; MAX_ARGS] = core::array::from_fn(|_| Value::Null);
        for (index, (arg, v)) in ctor.inputs.iter().zip(&given).enumerate() {
            let index = index as u8;
            match convert(v, &arg.ty).map_err(|error| ManagerError::Convert { index, error })? {
                Converted::Value(c) => inputs[usize::from(index)] = c,
                // Constructor arguments are scalars; an array for one is
                // a client's mistake the conversion lets through.
                _ => return Err(ManagerError::NoSuchInput(index)),
            }
        }
        let block = self
            .factory
            .make(
                usize::from(class),
                slot as u8,
                name,
                &inputs[..ctor.inputs.len()],
            )
            .map_err(|e| match e {
                CallError::Failed(code) => ManagerError::Failed(code),
                _ => ManagerError::Internal,
            })?;
        let mut f = PipesFunction::new(block)?;
        f.set_input_mode(info.input_mode);
        f.set_output_mode(info.output_mode);
        let (buf, len) = &mut self.made_with[slot];
        *len = made_with(buf, &inputs[..ctor.inputs.len()]).ok_or(ManagerError::Internal)?;
        self.slots[slot] = Some(f);
        self.stats.created = self.stats.created.wrapping_add(1);
        Ok(slot as u8)
    }

    /// Deletes the block named `name` with its pipes; returns its slot.
    pub fn delete(&mut self, name: &str) -> Result<u8, ManagerError> {
        let slot = self
            .slots
            .iter()
            .position(|s| {
                s.as_ref()
                    .is_some_and(|b| b.implementation().name() == name)
            })
            .ok_or(ManagerError::NoSuchBlock)?;
        self.slots[slot] = None;
        self.stats.deleted = self.stats.deleted.wrapping_add(1);
        Ok(slot as u8)
    }

    /// The arguments the block in `slot` was made with.
    pub fn made_with(&self, slot: usize) -> Option<crate::message::Args<'_>> {
        self.slots.get(slot)?.as_ref()?;
        let (buf, len) = self.made_with.get(slot)?;
        let mut r = osap_core::codec::Reader::new(buf.get(..*len)?);
        crate::message::Args::decode(&mut r).ok()
    }

    /// The slot and offset-within-slot of port `offset` (not 0).
    fn locate(offset: u16) -> (usize, u16) {
        let o = offset - 1;
        (usize::from(o / Self::SLOT_PORTS), o % Self::SLOT_PORTS)
    }

    fn on_request(
        &mut self,
        req: ManagerRequest<'_>,
        w: &mut Writer<'_>,
    ) -> Result<(), ManagerError> {
        let no_room = |_: CodecError| ManagerError::Internal;
        match req {
            ManagerRequest::ListClasses { from } => {
                let classes = self.factory.classes();
                let used = |i: usize| {
                    (0..SLOTS)
                        .filter(|&s| usize::from(self.class_of[s]) == i && self.slots[s].is_some())
                        .count() as u8
                };
                let entries = (usize::from(from)..classes.len()).map(|i| ClassEntry {
                    class: i as u8,
                    name: classes[i].name(),
                    capacity: classes[i].capacity,
                    used: used(i),
                });
                write_page(w, entries, write_class_entry).map_err(no_room)
            }
            ManagerRequest::GetClass { class, part } => {
                let info = self
                    .factory
                    .classes()
                    .get(usize::from(class))
                    .ok_or(ManagerError::NoSuchClass(class))?;
                let sig = match part {
                    ClassPart::Constructor => info.constructor,
                    ClassPart::Block => info.block,
                };
                w.u8(class).map_err(no_room)?;
                w.u8(part as u8).map_err(no_room)?;
                sig.encode(w).map_err(|_| ManagerError::Internal)
            }
            ManagerRequest::NewBlock { class, name, args } => {
                let slot = self.create(class, name, &args)?;
                w.u8(slot).map_err(no_room)?;
                w.u16(Self::slot_offset(usize::from(slot))).map_err(no_room)
            }
            ManagerRequest::DeleteBlock { name } => {
                let slot = self.delete(name)?;
                w.u8(slot).map_err(no_room)
            }
            ManagerRequest::GetBlock { slot } => {
                w.u8(slot).map_err(no_room)?;
                let s = usize::from(slot);
                match (
                    self.slots.get(s).and_then(Option::as_ref),
                    self.made_with(s),
                ) {
                    (Some(b), Some(args)) => (|| {
                        w.u8(1)?;
                        w.u8(self.class_of[s])?;
                        w.u16(Self::slot_offset(s))?;
                        w.str8(b.implementation().name())?;
                        args.encode(w)
                    })()
                    .map_err(no_room),
                    _ => w.u8(0).map_err(no_room),
                }
            }
            ManagerRequest::ListBlocks { from } => {
                let entries = (usize::from(from)..SLOTS).filter_map(|s| {
                    let b = self.slots[s].as_ref()?;
                    Some(BlockEntry {
                        slot: s as u8,
                        class: self.class_of[s],
                        offset: Self::slot_offset(s),
                        name: b.implementation().name(),
                    })
                });
                write_page(w, entries, write_block_entry).map_err(no_room)
            }
        }
    }

    /// Answers a request to the manager's port.
    fn on_manager(&mut self, d: &Delivery<'_>, tx: &mut PortTx<'_>) {
        let (seq, body) = match Transport::decode(d.payload) {
            Ok((Transport::Request(seq), body)) => (seq, body),
            _ => {
                self.stats.malformed = self.stats.malformed.wrapping_add(1);
                return;
            }
        };
        let key = body.first().copied().unwrap_or(0);
        // Made, deleted or refused before the reply is written: a reply
        // that cannot be sent does not undo the request.
        let mut out = [0u8; 96];
        let mut result = Err(ManagerError::Malformed);
        let mut len = 0;
        {
            let mut w = Writer::new(&mut out);
            if w.u8(key).and_then(|_| w.u8(0)).is_ok() {
                result = ManagerRequest::parse(body).and_then(|req| self.on_request(req, &mut w));
                len = w.len();
            }
        }
        if let Err(e) = &result {
            self.stats.refused = self.stats.refused.wrapping_add(1);
            let mut w = Writer::new(&mut out);
            // Nothing to send if even the refusal does not fit.
            len = w
                .u8(key)
                .and_then(|_| e.encode(&mut w).map(|_| w.len()))
                .unwrap_or_default();
        }
        let reply = &out[..len];
        let sent = tx.send_with(0, &d.reply_route, d.source_port, self.reply_ttl, |buf| {
            let h = Transport::Reply(seq).encode(buf)?;
            let room = buf.get_mut(h..h + reply.len())?;
            room.copy_from_slice(reply);
            Some(h + reply.len())
        });
        if sent.is_err() || len == 0 {
            self.stats.reply_drops = self.stats.reply_drops.wrapping_add(1);
        }
    }
}

/// Writes `inputs` as an argument list into `buf`; its length, or `None`
/// if it does not fit.
fn made_with(buf: &mut [u8], inputs: &[Value<'_>]) -> Option<usize> {
    let mut w = Writer::new(buf);
    let mut a = crate::message::ArgsWriter::new(&mut w).ok()?;
    for (i, v) in inputs.iter().enumerate() {
        a.push(i as u8, v).ok()?;
    }
    a.finish().ok()?;
    Some(w.len())
}

/// Bytes of entries in one page of a list: with the transport, the
/// reply's header and the page's own two bytes a reply stays under 48
/// bytes, which any route carries.
const PAGE: usize = 40;

/// Writes `[next][count]` and the entries that fit one page.
fn write_page<E: Indexed>(
    w: &mut Writer<'_>,
    entries: impl Iterator<Item = E>,
    write: fn(&mut Writer<'_>, &E) -> Result<(), CodecError>,
) -> Result<(), CodecError> {
    let next_at = w.len();
    w.u8(END)?;
    let count_at = w.len();
    w.u8(0)?;
    let start = w.len();
    let mut count = 0u8;
    for e in entries {
        let before = w.len();
        if write(w, &e).is_err() || w.len() - start > PAGE {
            w.truncate(before);
            w.patch_u8(next_at, e.index())?;
            break;
        }
        count += 1;
    }
    w.patch_u8(count_at, count)
}

/// An entry's place in its list, where the next page starts.
trait Indexed {
    fn index(&self) -> u8;
}

impl Indexed for ClassEntry<'_> {
    fn index(&self) -> u8 {
        self.class
    }
}

impl Indexed for BlockEntry<'_> {
    fn index(&self) -> u8 {
        self.slot
    }
}

impl<F: BlockFactory, const SLOTS: usize, const PIPES: usize, const Q: usize, const B: usize> Port
    for Blocks<F, SLOTS, PIPES, Q, B>
{
    fn port_count(&self) -> u16 {
        1 + SLOTS as u16 * Self::SLOT_PORTS
    }

    fn info(&self, offset: u16) -> PortInfo<'_> {
        if offset == 0 {
            return PortInfo {
                type_name: MANAGER_PORT_TYPE,
                name: "",
            };
        }
        let (slot, sub) = Self::locate(offset);
        match self.slots.get(slot).and_then(Option::as_ref) {
            Some(b) if sub == 0 => PortInfo {
                type_name: BLOCK_PORT_TYPE,
                name: b.implementation().name(),
            },
            Some(_) => PortInfo {
                type_name: PIPE_PORT_TYPE,
                name: "",
            },
            None => PortInfo {
                type_name: FREE_PORT_TYPE,
                name: "",
            },
        }
    }

    fn clear_to_receive(&self, offset: u16) -> bool {
        if offset == 0 {
            return true;
        }
        let (slot, sub) = Self::locate(offset);
        match self.slots.get(slot).and_then(Option::as_ref) {
            Some(b) => b.clear_to_receive(sub),
            None => true,
        }
    }

    fn on_packet(&mut self, d: Delivery<'_>, tx: &mut PortTx<'_>) {
        if d.offset == 0 {
            self.on_manager(&d, tx);
            return;
        }
        let (slot, sub) = Self::locate(d.offset);
        let base = Self::slot_offset(slot);
        match self.slots.get_mut(slot).and_then(Option::as_mut) {
            Some(b) => {
                let d = Delivery { offset: sub, ..d };
                let _ = tx.with_sub(base, Self::SLOT_PORTS, |tx| b.on_packet(d, tx));
            }
            // A late packet for a deleted block.
            None => self.stats.malformed = self.stats.malformed.wrapping_add(1),
        }
    }

    fn poll(&mut self, tx: &mut PortTx<'_>) {
        for (slot, b) in self.slots.iter_mut().enumerate() {
            if let Some(b) = b {
                let base = Self::slot_offset(slot);
                let _ = tx.with_sub(base, Self::SLOT_PORTS, |tx| b.poll(tx));
            }
        }
    }

    fn wake_at(&self) -> Option<Instant> {
        self.slots
            .iter()
            .flatten()
            .filter_map(|b| b.wake_at())
            .min()
    }
}
