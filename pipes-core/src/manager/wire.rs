//! The block manager's messages, byte by byte (`docs/pipes.md` §7): the
//! requests, the replies and the errors, each with its codec. Nothing here
//! panics on bytes from the wire.

use core::fmt;

use osap_core::codec::{CodecError, Reader, Writer};

use crate::control::{ControlError, DecodeError, FailureCode};
use crate::convert::ConvertError;
use crate::message::Args;
use crate::signature::{SignatureError, SignatureView};

/// The longest block name, bytes.
pub const MAX_NAME: usize = 24;

/// The failure code ([`ManagerError::Failed`]) with which a class
/// refuses a constructor argument that is not finite or is out of its
/// range. A class may add codes of its own above it.
pub const BAD_ARGUMENT: u8 = 1;

/// "No more": the `next` of the last page of a list.
pub const END: u8 = 0xff;

/// A manager request's key.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum ManagerKey {
    /// `[1][from]`: the classes, from class `from` on.
    ListClasses = 1,
    /// `[2][class][part]`: a class's constructor (part 0) or block (part 1)
    /// signature.
    GetClass = 2,
    /// `[3][class][name: str8][args]`: makes a block.
    NewBlock = 3,
    /// `[4][name: str8]`: deletes a block.
    DeleteBlock = 4,
    /// `[5][from]`: the blocks, from slot `from` on.
    ListBlocks = 5,
    /// `[6][slot]`: the block in a slot, with the arguments it was made
    /// with.
    GetBlock = 6,
}

impl ManagerKey {
    /// The key for byte `b`.
    pub fn from_u8(b: u8) -> Option<ManagerKey> {
        Some(match b {
            1 => ManagerKey::ListClasses,
            2 => ManagerKey::GetClass,
            3 => ManagerKey::NewBlock,
            4 => ManagerKey::DeleteBlock,
            5 => ManagerKey::ListBlocks,
            6 => ManagerKey::GetBlock,
            _ => return None,
        })
    }
}

/// Which signature of a class [`ManagerRequest::GetClass`] asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum ClassPart {
    /// The constructor: the class's name, the arguments a block is made
    /// with, no outputs.
    Constructor = 0,
    /// What each block of the class takes and gives (named after the class).
    Block = 1,
}

/// A block's name: 1 to [`MAX_NAME`] ASCII letters, digits and `_`, not
/// starting with a digit (so it is also an identifier in generated code).
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct BlockName {
    bytes: [u8; MAX_NAME],
    len: u8,
}

impl BlockName {
    /// `name`, if it is a valid block name.
    pub fn new(name: &str) -> Result<BlockName, ManagerError> {
        let b = name.as_bytes();
        let valid = !b.is_empty()
            && b.len() <= MAX_NAME
            && !b[0].is_ascii_digit()
            && b.iter().all(|c| c.is_ascii_alphanumeric() || *c == b'_');
        if !valid {
            return Err(ManagerError::BadName);
        }
        let mut bytes = [0; MAX_NAME];
        bytes[..b.len()].copy_from_slice(b);
        Ok(BlockName {
            bytes,
            len: b.len() as u8,
        })
    }

    /// The name.
    pub fn as_str(&self) -> &str {
        // Checked ASCII when made.
        core::str::from_utf8(&self.bytes[..usize::from(self.len)]).unwrap_or("")
    }
}

impl fmt::Debug for BlockName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Debug::fmt(self.as_str(), f)
    }
}

impl fmt::Display for BlockName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A request to a block manager (after the transport header).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ManagerRequest<'a> {
    /// The classes from index `from` on, as many as fit one reply.
    ListClasses {
        /// The first class to list.
        from: u8,
    },
    /// One signature of class `class`.
    GetClass {
        /// The class index.
        class: u8,
        /// Which signature.
        part: ClassPart,
    },
    /// Makes a block of class `class` named `name` from the constructor's
    /// arguments (every input exactly once, converted like a call's).
    NewBlock {
        /// The class index.
        class: u8,
        /// The new block's name.
        name: &'a str,
        /// The constructor's arguments, by input index.
        args: Args<'a>,
    },
    /// Deletes the block named `name`, with its pipes.
    DeleteBlock {
        /// The block's name.
        name: &'a str,
    },
    /// The blocks from slot `from` on, as many as fit one reply.
    ListBlocks {
        /// The first slot to list.
        from: u8,
    },
    /// The block in slot `slot`, with its constructor's arguments.
    GetBlock {
        /// The slot.
        slot: u8,
    },
}

impl<'a> ManagerRequest<'a> {
    /// Parses a whole request.
    pub fn parse(bytes: &'a [u8]) -> Result<ManagerRequest<'a>, ManagerError> {
        let mut r = Reader::new(bytes);
        let k = r.u8().map_err(|_| ManagerError::Malformed)?;
        let key = ManagerKey::from_u8(k).ok_or(ManagerError::UnknownKey(k))?;
        let m = |_| ManagerError::Malformed;
        let req = match key {
            ManagerKey::ListClasses => ManagerRequest::ListClasses {
                from: r.u8().map_err(m)?,
            },
            ManagerKey::GetClass => ManagerRequest::GetClass {
                class: r.u8().map_err(m)?,
                part: match r.u8().map_err(m)? {
                    0 => ClassPart::Constructor,
                    1 => ClassPart::Block,
                    _ => return Err(ManagerError::Malformed),
                },
            },
            ManagerKey::NewBlock => ManagerRequest::NewBlock {
                class: r.u8().map_err(m)?,
                name: r.str8().map_err(m)?,
                args: Args::decode(&mut r).map_err(|_| ManagerError::Malformed)?,
            },
            ManagerKey::DeleteBlock => ManagerRequest::DeleteBlock {
                name: r.str8().map_err(m)?,
            },
            ManagerKey::ListBlocks => ManagerRequest::ListBlocks {
                from: r.u8().map_err(m)?,
            },
            ManagerKey::GetBlock => ManagerRequest::GetBlock {
                slot: r.u8().map_err(m)?,
            },
        };
        if !r.is_empty() {
            return Err(ManagerError::Malformed);
        }
        Ok(req)
    }

    /// The request's key.
    pub fn key(&self) -> ManagerKey {
        match self {
            ManagerRequest::ListClasses { .. } => ManagerKey::ListClasses,
            ManagerRequest::GetClass { .. } => ManagerKey::GetClass,
            ManagerRequest::NewBlock { .. } => ManagerKey::NewBlock,
            ManagerRequest::DeleteBlock { .. } => ManagerKey::DeleteBlock,
            ManagerRequest::ListBlocks { .. } => ManagerKey::ListBlocks,
            ManagerRequest::GetBlock { .. } => ManagerKey::GetBlock,
        }
    }

    /// Writes the request. On error nothing is written.
    pub fn encode(&self, w: &mut Writer<'_>) -> Result<(), CodecError> {
        let start = w.len();
        let r = (|| {
            w.u8(self.key() as u8)?;
            match self {
                ManagerRequest::ListClasses { from } | ManagerRequest::ListBlocks { from } => {
                    w.u8(*from)
                }
                ManagerRequest::GetBlock { slot } => w.u8(*slot),
                ManagerRequest::GetClass { class, part } => {
                    w.u8(*class)?;
                    w.u8(*part as u8)
                }
                ManagerRequest::NewBlock { class, name, args } => {
                    w.u8(*class)?;
                    w.str8(name)?;
                    args.encode(w)
                }
                ManagerRequest::DeleteBlock { name } => w.str8(name),
            }
        })();
        if r.is_err() {
            w.truncate(start);
        }
        r
    }
}

/// Why a manager refused a request: the reply's status and body.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub enum ManagerError {
    /// Status 1, body `[key]`: the key is not defined.
    UnknownKey(u8),
    /// Status 2: the request could not be read.
    Malformed,
    /// Status 3, body `[expected][got]`: the constructor takes every
    /// argument exactly once.
    WrongArgCount {
        /// The constructor's number of inputs.
        expected: u8,
        /// The number given.
        got: u8,
    },
    /// Status 4, body `[index]`: the constructor has no such input.
    NoSuchInput(u8),
    /// Status 5, as a function's (`docs/pipes.md` §5): an argument does
    /// not convert to the constructor's type.
    Convert {
        /// The input index.
        index: u8,
        /// What went wrong.
        error: ConvertError,
    },
    /// Status 10, body `[code]`: the class refused the arguments, with
    /// its own code.
    Failed(FailureCode),
    /// Status 20, body `[class]`: no class has this index.
    NoSuchClass(u8),
    /// Status 21, body `[class]`: every block of this class is in use.
    PoolFull(u8),
    /// Status 22: a block of this name exists on the device.
    NameTaken,
    /// Status 23: the name is not 1 to 24 letters, digits or `_`, or
    /// starts with a digit.
    BadName,
    /// Status 24: no block has this name.
    NoSuchBlock,
    /// Status 25: the device could not make the block although the class
    /// took its arguments (a defect in the device's block set).
    Internal,
}

impl ManagerError {
    /// The status byte.
    pub fn status(&self) -> u8 {
        match self {
            ManagerError::UnknownKey(_) => 1,
            ManagerError::Malformed => 2,
            ManagerError::WrongArgCount { .. } => 3,
            ManagerError::NoSuchInput(_) => 4,
            ManagerError::Convert { .. } => 5,
            ManagerError::Failed(_) => 10,
            ManagerError::NoSuchClass(_) => 20,
            ManagerError::PoolFull(_) => 21,
            ManagerError::NameTaken => 22,
            ManagerError::BadName => 23,
            ManagerError::NoSuchBlock => 24,
            ManagerError::Internal => 25,
        }
    }

    /// The function protocol's form of the statuses the two share.
    fn as_control(&self) -> Option<ControlError> {
        Some(match *self {
            ManagerError::UnknownKey(k) => ControlError::UnknownKey(k),
            ManagerError::Malformed => ControlError::Malformed,
            ManagerError::WrongArgCount { expected, got } => {
                ControlError::WrongArgCount { expected, got }
            }
            ManagerError::NoSuchInput(i) => ControlError::NoSuchInput(i),
            ManagerError::Convert { index, error } => ControlError::Convert { index, error },
            ManagerError::Failed(c) => ControlError::CallFailed(c),
            _ => return None,
        })
    }

    /// Writes `[status][body]`. On error nothing is written.
    pub fn encode(&self, w: &mut Writer<'_>) -> Result<(), CodecError> {
        if let Some(c) = self.as_control() {
            return c.encode(w).map_err(|_| CodecError::NoSpace);
        }
        let start = w.len();
        let r = (|| {
            w.u8(self.status())?;
            match *self {
                ManagerError::NoSuchClass(c) | ManagerError::PoolFull(c) => w.u8(c),
                _ => Ok(()),
            }
        })();
        if r.is_err() {
            w.truncate(start);
        }
        r
    }

    /// Reads the body of status `status` (not 0).
    pub fn decode_body(status: u8, r: &mut Reader<'_>) -> Result<ManagerError, DecodeError> {
        Ok(match status {
            20 => ManagerError::NoSuchClass(r.u8()?),
            21 => ManagerError::PoolFull(r.u8()?),
            22 => ManagerError::NameTaken,
            23 => ManagerError::BadName,
            24 => ManagerError::NoSuchBlock,
            25 => ManagerError::Internal,
            s => match ControlError::decode_body(s, r)? {
                ControlError::UnknownKey(k) => ManagerError::UnknownKey(k),
                ControlError::Malformed => ManagerError::Malformed,
                ControlError::WrongArgCount { expected, got } => {
                    ManagerError::WrongArgCount { expected, got }
                }
                ControlError::NoSuchInput(i) => ManagerError::NoSuchInput(i),
                ControlError::Convert { index, error } => ManagerError::Convert { index, error },
                ControlError::CallFailed(c) => ManagerError::Failed(c),
                _ => return Err(DecodeError::UnknownStatus(s)),
            },
        })
    }
}

impl fmt::Display for ManagerError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ManagerError::NoSuchClass(c) => write!(f, "the device has no block class {c}"),
            ManagerError::PoolFull(c) => write!(
                f,
                "every block of class {c} is in use: delete one, or build the firmware with a larger pool"
            ),
            ManagerError::NameTaken => {
                f.write_str("a block of this name exists on the device: pick another name")
            }
            ManagerError::BadName => write!(
                f,
                "a block name is 1 to {MAX_NAME} letters, digits or '_', not starting with a digit"
            ),
            ManagerError::NoSuchBlock => f.write_str("the device has no block of this name"),
            ManagerError::Internal => f.write_str(
                "the device took the arguments but could not make the block (a defect in its firmware)",
            ),
            ManagerError::Failed(c) if c.code() == BAD_ARGUMENT => write!(
                f,
                "the class refused its arguments (code {BAD_ARGUMENT}): one is not finite or is out of its range"
            ),
            other => match other.as_control() {
                Some(c) => fmt::Display::fmt(&c, f),
                None => write!(f, "status {}", other.status()),
            },
        }
    }
}

impl core::error::Error for ManagerError {}

/// One class in a [`ManagerReply::Classes`] page.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ClassEntry<'a> {
    /// The class index.
    pub class: u8,
    /// Its name.
    pub name: &'a str,
    /// How many blocks of it the device can hold.
    pub capacity: u8,
    /// How many exist.
    pub used: u8,
}

/// One block in a [`ManagerReply::Blocks`] page.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BlockEntry<'a> {
    /// Its slot.
    pub slot: u8,
    /// Its class's index.
    pub class: u8,
    /// Its control port, as an offset from the manager's port.
    pub offset: u16,
    /// Its name.
    pub name: &'a str,
}

/// A page of a list: checked entries, read in place.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Page<'a> {
    /// Where the next page starts ([`END`]: this is the last).
    pub next: u8,
    count: u8,
    bytes: &'a [u8],
}

impl<'a> Page<'a> {
    pub(super) fn decode(
        r: &mut Reader<'a>,
        entry: fn(&mut Reader<'a>) -> Result<(), CodecError>,
    ) -> Result<Page<'a>, CodecError> {
        let next = r.u8()?;
        let count = r.u8()?;
        let start = r.rest();
        for _ in 0..count {
            entry(r)?;
        }
        let used = start.len() - r.rest().len();
        Ok(Page {
            next,
            count,
            bytes: start.get(..used).unwrap_or(&[]),
        })
    }

    /// The number of entries.
    pub fn len(&self) -> usize {
        usize::from(self.count)
    }

    /// Whether the page is empty.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// The entries of a class page.
    pub fn classes(&self) -> impl Iterator<Item = ClassEntry<'a>> + 'a {
        let mut r = Reader::new(self.bytes);
        (0..self.count).map_while(move |_| {
            Some(ClassEntry {
                class: r.u8().ok()?,
                name: r.str8().ok()?,
                capacity: r.u8().ok()?,
                used: r.u8().ok()?,
            })
        })
    }

    /// The entries of a block page.
    pub fn blocks(&self) -> impl Iterator<Item = BlockEntry<'a>> + 'a {
        let mut r = Reader::new(self.bytes);
        (0..self.count).map_while(move |_| {
            Some(BlockEntry {
                slot: r.u8().ok()?,
                class: r.u8().ok()?,
                offset: r.u16().ok()?,
                name: r.str8().ok()?,
            })
        })
    }
}

fn class_entry(r: &mut Reader<'_>) -> Result<(), CodecError> {
    r.u8()?;
    r.str8()?;
    r.u8()?;
    r.u8()?;
    Ok(())
}

fn block_entry(r: &mut Reader<'_>) -> Result<(), CodecError> {
    r.u8()?;
    r.u8()?;
    r.u16()?;
    r.str8()?;
    Ok(())
}

/// Writes a class entry (`[class][name: str8][capacity][used]`).
pub fn write_class_entry(w: &mut Writer<'_>, e: &ClassEntry<'_>) -> Result<(), CodecError> {
    w.u8(e.class)?;
    w.str8(e.name)?;
    w.u8(e.capacity)?;
    w.u8(e.used)
}

/// Writes a block entry (`[slot][class][offset: u16][name: str8]`).
pub fn write_block_entry(w: &mut Writer<'_>, e: &BlockEntry<'_>) -> Result<(), CodecError> {
    w.u8(e.slot)?;
    w.u8(e.class)?;
    w.u16(e.offset)?;
    w.str8(e.name)
}

/// A successful reply's body.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ManagerReply<'a> {
    /// `[next][count] count × [class][name: str8][capacity][used]`.
    Classes(Page<'a>),
    /// `[class][part][signature]`.
    Class {
        /// The class index.
        class: u8,
        /// Which signature.
        part: ClassPart,
        /// The signature.
        signature: SignatureView<'a>,
    },
    /// `[slot][offset: u16]`: the new block's slot, and its control port
    /// as an offset from the manager's port.
    Created {
        /// The slot.
        slot: u8,
        /// The control port's offset from the manager's port.
        offset: u16,
    },
    /// `[slot]`: the slot the deleted block held.
    Deleted {
        /// The slot.
        slot: u8,
    },
    /// `[next][count] count × [slot][class][offset: u16][name: str8]`.
    Blocks(Page<'a>),
    /// `[slot][0]` for a free slot, or `[slot][1][class][offset: u16]
    /// [name: str8][args]`: the block, and the constructor's arguments it
    /// was made with (each of its declared type).
    Block {
        /// The slot.
        slot: u8,
        /// The block, if the slot holds one.
        block: Option<(BlockEntry<'a>, Args<'a>)>,
    },
}

/// Parses a whole reply `[key][status][body]`: the key it answers, and the
/// body or the device's refusal.
pub fn parse_reply(
    bytes: &[u8],
) -> Result<(u8, Result<ManagerReply<'_>, ManagerError>), DecodeError> {
    let mut r = Reader::new(bytes);
    let k = r.u8()?;
    let status = r.u8()?;
    let result = if status != 0 {
        Err(ManagerError::decode_body(status, &mut r)?)
    } else {
        let key = ManagerKey::from_u8(k).ok_or(DecodeError::UnknownKey(k))?;
        Ok(match key {
            ManagerKey::ListClasses => ManagerReply::Classes(Page::decode(&mut r, class_entry)?),
            ManagerKey::GetClass => {
                let class = r.u8()?;
                let part = match r.u8()? {
                    0 => ClassPart::Constructor,
                    1 => ClassPart::Block,
                    b => return Err(DecodeError::BadBool(b)),
                };
                let signature = SignatureView::decode(&mut r).map_err(DecodeError::Signature)?;
                ManagerReply::Class {
                    class,
                    part,
                    signature,
                }
            }
            ManagerKey::NewBlock => ManagerReply::Created {
                slot: r.u8()?,
                offset: r.u16()?,
            },
            ManagerKey::DeleteBlock => ManagerReply::Deleted { slot: r.u8()? },
            ManagerKey::ListBlocks => ManagerReply::Blocks(Page::decode(&mut r, block_entry)?),
            ManagerKey::GetBlock => {
                let slot = r.u8()?;
                let block = match r.u8()? {
                    0 => None,
                    1 => {
                        let entry = BlockEntry {
                            slot,
                            class: r.u8()?,
                            offset: r.u16()?,
                            name: r.str8()?,
                        };
                        Some((entry, Args::decode(&mut r).map_err(DecodeError::Args)?))
                    }
                    b => return Err(DecodeError::BadBool(b)),
                };
                ManagerReply::Block { slot, block }
            }
        })
    };
    if !r.is_empty() {
        return Err(DecodeError::TrailingBytes);
    }
    Ok((k, result))
}

impl From<SignatureError> for ManagerError {
    fn from(_: SignatureError) -> Self {
        ManagerError::Internal
    }
}
