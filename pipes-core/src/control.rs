//! The function protocol: messages to and from a function's control port.
//!
//! Every message starts with a one-byte key ([`ControlKey`]); key 1 is the
//! dataflow message of [`crate::message`] (`pipe_datagram`), reused as is.
//! Requests travel in the sequential transport of `osap_core::transport`
//! (transport key 1 and a `u16` sequence number), replies echo the sequence
//! number (transport key 2). Pipe datagrams travel raw (transport key 0);
//! a function that refuses one reports why to the pipe's sending port with a
//! raw [`ControlKey::PipeError`] message. An acknowledged pipe sends its
//! datagrams as requests instead, and the reply (ok or the refusal) is its
//! acknowledgement (see [`crate::pipe`]).
//!
//! A reply is `[key][status: u8][body]`: status 0 is success and the body is
//! the key's result; any other status is a [`ControlError`] code and the body
//! its details. Layouts are in `docs/pipes.md` §5.

use core::fmt;

use osap_core::codec::{CodecError, Reader, Writer};

use crate::convert::{ConvertError, ConvertReason};
use crate::failure::{encode_tail, Failure, SignatureParts};
use crate::message::{Args, ArgsWriter, MessageError, MessageKey};
use crate::pipe::{PipeConfig, PipeStats};
use crate::signature::{Signature, SignatureError, SignatureView};
use crate::types::Type;

/// The first byte of a function-protocol message.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum ControlKey {
    /// Values for some inputs (the dataflow message, [`MessageKey::PipeDatagram`]).
    PipeDatagram = MessageKey::PipeDatagram as u8,
    /// Asks for the function's signature.
    GetSignature = 2,
    /// Runs the function on a full set of inputs; the reply carries the outputs.
    Call = 3,
    /// Asks how many pipe slots the function has, and how many are in use.
    GetPipeCount = 4,
    /// Asks for one pipe slot.
    GetPipe = 5,
    /// Sets one pipe slot (or the first free one).
    SetPipe = 6,
    /// Empties one pipe slot (or all).
    WipePipe = 7,
    /// Asks when the function runs on dataflow.
    GetInputMode = 8,
    /// Sets when the function runs on dataflow.
    SetInputMode = 9,
    /// Asks when the function sends its outputs.
    GetOutputMode = 10,
    /// Sets when the function sends its outputs.
    SetOutputMode = 11,
    /// A raw report, to a pipe's sending port, that its datagram was refused.
    PipeError = 12,
    /// Asks for one pipe's counters (sent, dropped, errors).
    GetPipeStats = 13,
}

impl ControlKey {
    /// The key with wire value `b`, if defined.
    pub const fn from_u8(b: u8) -> Option<ControlKey> {
        Some(match b {
            1 => ControlKey::PipeDatagram,
            2 => ControlKey::GetSignature,
            3 => ControlKey::Call,
            4 => ControlKey::GetPipeCount,
            5 => ControlKey::GetPipe,
            6 => ControlKey::SetPipe,
            7 => ControlKey::WipePipe,
            8 => ControlKey::GetInputMode,
            9 => ControlKey::SetInputMode,
            10 => ControlKey::GetOutputMode,
            11 => ControlKey::SetOutputMode,
            12 => ControlKey::PipeError,
            13 => ControlKey::GetPipeStats,
            _ => return None,
        })
    }

    /// The wire value.
    pub const fn to_u8(self) -> u8 {
        self as u8
    }
}

/// Pipe slot number that means "the first free slot" (set pipe) or "every
/// slot" (wipe pipe).
pub const ANY_SLOT: u8 = 0xff;

/// A function's failure code: the byte a [`ControlError::CallFailed`]
/// reply carries (status 10), by name where pipes-core knows it.
///
/// The codes pipes-core's generated wrappers use are named; every other
/// byte is [`FailureCode::Other`]: a code of the function's own (its
/// meaning depends on the function; osap-module names its own codes), or one
/// a newer firmware sends. [`FailureCode::from_code`] takes any byte, and
/// [`FailureCode::code`] gives the same byte back, so the wire is unchanged.
/// Equality and hashing go by the code: `Other(255)` equals
/// [`FailureCode::InputDecodeFailed`].
#[derive(Debug, Clone, Copy)]
#[non_exhaustive]
pub enum FailureCode {
    /// Code 255 ([`crate::export::INPUT_DECODE_FAILED`]): an input was
    /// missing or not of its declared type (a bug in the machinery).
    InputDecodeFailed,
    /// Code 254 ([`crate::export::STATE_BUSY`]): a class member ran while the
    /// class's state was borrowed elsewhere.
    StateBusy,
    /// Code 253 ([`crate::export::NO_SUCH_MEMBER`]): a class was asked for a
    /// member it does not have.
    NoSuchMember,
    /// Any other code: the function's own, or one from a newer firmware.
    Other(u8),
}

impl FailureCode {
    /// The failure named by wire byte `code` ([`FailureCode::Other`] for a
    /// code pipes-core does not name).
    pub const fn from_code(code: u8) -> FailureCode {
        match code {
            crate::export::INPUT_DECODE_FAILED => FailureCode::InputDecodeFailed,
            crate::export::STATE_BUSY => FailureCode::StateBusy,
            crate::export::NO_SUCH_MEMBER => FailureCode::NoSuchMember,
            c => FailureCode::Other(c),
        }
    }

    /// The wire byte.
    pub const fn code(self) -> u8 {
        match self {
            FailureCode::InputDecodeFailed => crate::export::INPUT_DECODE_FAILED,
            FailureCode::StateBusy => crate::export::STATE_BUSY,
            FailureCode::NoSuchMember => crate::export::NO_SUCH_MEMBER,
            FailureCode::Other(c) => c,
        }
    }
}

impl From<u8> for FailureCode {
    fn from(code: u8) -> Self {
        FailureCode::from_code(code)
    }
}

impl From<FailureCode> for u8 {
    fn from(code: FailureCode) -> Self {
        code.code()
    }
}

impl PartialEq for FailureCode {
    fn eq(&self, other: &Self) -> bool {
        self.code() == other.code()
    }
}

impl Eq for FailureCode {}

impl core::hash::Hash for FailureCode {
    fn hash<H: core::hash::Hasher>(&self, state: &mut H) {
        self.code().hash(state);
    }
}

impl fmt::Display for FailureCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FailureCode::InputDecodeFailed => f.write_str("code 255 (input decode failed)"),
            FailureCode::StateBusy => f.write_str("code 254 (class state busy)"),
            FailureCode::NoSuchMember => f.write_str("code 253 (no such class member)"),
            FailureCode::Other(c) => write!(f, "code {c}"),
        }
    }
}

/// An error a function reports on the wire (reply status ≠ 0).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum ControlError {
    /// Status 1, body `[key]`: the message key is not defined.
    UnknownKey(u8),
    /// Status 2, no body: the request could not be read.
    Malformed,
    /// Status 3, body `[expected][got]`: a call must give every input once.
    WrongArgCount {
        /// The function's number of inputs.
        expected: u8,
        /// The number of arguments given.
        got: u8,
    },
    /// Status 4, body `[index]`: the function has no input with this index.
    NoSuchInput(u8),
    /// Status 5, body `[index][from key][to key][reason][element: u32]`: the
    /// value for input `index` does not convert to the input's type. Reason
    /// 0 lossy, 1 out of range, 2 impossible; element `0xffffffff` is none.
    Convert {
        /// The input index.
        index: u8,
        /// What went wrong.
        error: ConvertError,
    },
    /// Status 6, body `[slot]`: no such pipe slot.
    NoSuchPipe(u8),
    /// Status 7, no body: every pipe slot is in use.
    PipeTableFull,
    /// Status 8, no body: the request asks for something this function does
    /// not do.
    Unsupported,
    /// Status 9, body `[output]`: a pipe's argmap names an output the
    /// function does not have.
    BadArgmap(u8),
    /// Status 10, body `[code]`: the function itself failed, with its own code.
    CallFailed(FailureCode),
    /// Status 11, body `[output]`: the function produced a missing, mistyped
    /// or oversized output.
    BadOutput(u8),
    /// Status 12, body `[index]`: the value for input `index` is larger than
    /// the function's store for it.
    TooLarge(u8),
}

impl ControlError {
    /// The status byte.
    pub const fn status(&self) -> u8 {
        match self {
            ControlError::UnknownKey(_) => 1,
            ControlError::Malformed => 2,
            ControlError::WrongArgCount { .. } => 3,
            ControlError::NoSuchInput(_) => 4,
            ControlError::Convert { .. } => 5,
            ControlError::NoSuchPipe(_) => 6,
            ControlError::PipeTableFull => 7,
            ControlError::Unsupported => 8,
            ControlError::BadArgmap(_) => 9,
            ControlError::CallFailed(_) => 10,
            ControlError::BadOutput(_) => 11,
            ControlError::TooLarge(_) => 12,
        }
    }

    /// Writes `[status][body]`. On error nothing is written.
    pub fn encode(&self, w: &mut Writer<'_>) -> Result<(), DecodeError> {
        let start = w.len();
        let r = (|| -> Result<(), CodecError> {
            w.u8(self.status())?;
            match *self {
                ControlError::UnknownKey(b)
                | ControlError::NoSuchInput(b)
                | ControlError::NoSuchPipe(b)
                | ControlError::BadArgmap(b)
                | ControlError::BadOutput(b)
                | ControlError::TooLarge(b) => w.u8(b),
                ControlError::CallFailed(code) => w.u8(code.code()),
                ControlError::WrongArgCount { expected, got } => {
                    w.u8(expected)?;
                    w.u8(got)
                }
                ControlError::Convert { index, error } => {
                    w.u8(index)?;
                    w.u8(error.from.key())?;
                    w.u8(error.to.key())?;
                    w.u8(match error.reason {
                        ConvertReason::Lossy => 0,
                        ConvertReason::OutOfRange => 1,
                        ConvertReason::Impossible => 2,
                    })?;
                    let e = error
                        .element
                        .and_then(|e| u32::try_from(e).ok())
                        .filter(|e| *e != u32::MAX)
                        .unwrap_or(u32::MAX);
                    w.u32(e)
                }
                ControlError::Malformed
                | ControlError::PipeTableFull
                | ControlError::Unsupported => Ok(()),
            }
        })();
        r.map_err(|_| {
            w.truncate(start);
            DecodeError::NoSpace
        })
    }

    /// Reads the body of status `status` (not 0).
    pub fn decode_body(status: u8, r: &mut Reader<'_>) -> Result<ControlError, DecodeError> {
        Ok(match status {
            1 => ControlError::UnknownKey(r.u8()?),
            2 => ControlError::Malformed,
            3 => ControlError::WrongArgCount {
                expected: r.u8()?,
                got: r.u8()?,
            },
            4 => ControlError::NoSuchInput(r.u8()?),
            5 => {
                let index = r.u8()?;
                let ty = |k| Type::from_key(k).map_err(|_| DecodeError::BadType(k));
                let from = ty(r.u8()?)?;
                let to = ty(r.u8()?)?;
                let reason = match r.u8()? {
                    0 => ConvertReason::Lossy,
                    1 => ConvertReason::OutOfRange,
                    2 => ConvertReason::Impossible,
                    x => return Err(DecodeError::BadReason(x)),
                };
                let e = r.u32()?;
                let element = (e != u32::MAX).then_some(e as usize);
                ControlError::Convert {
                    index,
                    error: ConvertError {
                        from,
                        to,
                        reason,
                        element,
                    },
                }
            }
            6 => ControlError::NoSuchPipe(r.u8()?),
            7 => ControlError::PipeTableFull,
            8 => ControlError::Unsupported,
            9 => ControlError::BadArgmap(r.u8()?),
            10 => ControlError::CallFailed(FailureCode::from_code(r.u8()?)),
            11 => ControlError::BadOutput(r.u8()?),
            12 => ControlError::TooLarge(r.u8()?),
            s => return Err(DecodeError::UnknownStatus(s)),
        })
    }
}

impl fmt::Display for ControlError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ControlError::UnknownKey(k) => write!(f, "message key {k} is not defined"),
            ControlError::Malformed => f.write_str("the request could not be read"),
            ControlError::WrongArgCount { expected, got } => {
                write!(f, "expected {expected} arguments, got {got}")
            }
            ControlError::NoSuchInput(i) => write!(f, "no input {i}"),
            ControlError::Convert { index, error } => write!(f, "input {index}: {error}"),
            ControlError::NoSuchPipe(s) => write!(f, "no pipe slot {s}"),
            ControlError::PipeTableFull => f.write_str("every pipe slot is in use"),
            ControlError::Unsupported => f.write_str("not supported by this function"),
            ControlError::BadArgmap(o) => {
                write!(f, "argmap names output {o}, which does not exist")
            }
            ControlError::CallFailed(c) => write!(f, "the function failed with {c}"),
            ControlError::BadOutput(o) => write!(f, "the function produced a bad output {o}"),
            ControlError::TooLarge(i) => write!(f, "the value for input {i} is too large"),
        }
    }
}

impl core::error::Error for ControlError {}

/// Why a function-protocol message could not be read or written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum DecodeError {
    /// The message ended early.
    Truncated,
    /// The output buffer is too small.
    NoSpace,
    /// Bytes were left over after the message.
    TrailingBytes,
    /// The message key is not defined.
    UnknownKey(u8),
    /// The reply status is not defined.
    UnknownStatus(u8),
    /// A pipe's route does not parse.
    BadRoute,
    /// A pipe's flags hold undefined bits.
    BadFlags(u8),
    /// A pipe's argmap has more than [`MAX_ARGMAP`](crate::pipe::MAX_ARGMAP) pairs.
    ArgmapTooLong(u8),
    /// A pipe's argmap names a destination input twice.
    DuplicateInput(u8),
    /// An input or output mode byte is not defined (or a timer interval is 0).
    BadMode(u8),
    /// A type key in an error report names no type.
    BadType(u8),
    /// A conversion reason in an error report is not defined.
    BadReason(u8),
    /// A boolean byte is neither 0 nor 1.
    BadBool(u8),
    /// An argument list is malformed.
    Args(MessageError),
    /// A signature is malformed.
    Signature(SignatureError),
}

impl DecodeError {
    /// The error a function reports for a request it could not read.
    pub fn to_control(self) -> ControlError {
        match self {
            DecodeError::UnknownKey(k) => ControlError::UnknownKey(k),
            _ => ControlError::Malformed,
        }
    }
}

impl From<CodecError> for DecodeError {
    fn from(e: CodecError) -> Self {
        match e {
            CodecError::NoSpace => DecodeError::NoSpace,
            _ => DecodeError::Truncated,
        }
    }
}

impl fmt::Display for DecodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DecodeError::Truncated => f.write_str("message is truncated"),
            DecodeError::NoSpace => f.write_str("output buffer is too small"),
            DecodeError::TrailingBytes => f.write_str("bytes left over after the message"),
            DecodeError::UnknownKey(k) => write!(f, "message key {k} is not defined"),
            DecodeError::UnknownStatus(s) => write!(f, "reply status {s} is not defined"),
            DecodeError::BadRoute => f.write_str("pipe route does not parse"),
            DecodeError::BadFlags(b) => write!(f, "pipe flags {b:#04x} hold undefined bits"),
            DecodeError::ArgmapTooLong(n) => write!(f, "argmap of {n} pairs is too long"),
            DecodeError::DuplicateInput(i) => write!(f, "argmap names input {i} twice"),
            DecodeError::BadMode(m) => write!(f, "mode {m} is not defined"),
            DecodeError::BadType(k) => write!(f, "type key {k:#04x} names no type"),
            DecodeError::BadReason(r) => write!(f, "conversion reason {r} is not defined"),
            DecodeError::BadBool(b) => write!(f, "flag byte {b:#04x} is neither 0 nor 1"),
            DecodeError::Args(e) => write!(f, "arguments: {e}"),
            DecodeError::Signature(e) => write!(f, "signature: {e}"),
        }
    }
}

impl core::error::Error for DecodeError {}

/// When a function runs on dataflow.
///
/// Wire form: `[0]` on any fresh, `[1]` on all fresh, `[2][interval µs: u32]`
/// on timer (interval ≥ 1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum InputMode {
    /// Whenever a datagram brings a fresh value for any input, once every
    /// input holds a value.
    #[default]
    OnAnyFresh,
    /// When every input has received a fresh value since the last run.
    OnAllFresh,
    /// Every `interval` µs, once every input holds a value (fresh or not).
    /// A function without inputs runs on its timer alone: a source.
    OnTimer(u32),
}

impl InputMode {
    fn encode(&self, w: &mut Writer<'_>) -> Result<(), CodecError> {
        match *self {
            InputMode::OnAnyFresh => w.u8(0),
            InputMode::OnAllFresh => w.u8(1),
            InputMode::OnTimer(us) => {
                if w.remaining() < 5 {
                    return Err(CodecError::NoSpace);
                }
                w.u8(2)?;
                w.u32(us)
            }
        }
    }

    fn decode(r: &mut Reader<'_>) -> Result<InputMode, DecodeError> {
        match r.u8()? {
            0 => Ok(InputMode::OnAnyFresh),
            1 => Ok(InputMode::OnAllFresh),
            2 => match r.u32()? {
                0 => Err(DecodeError::BadMode(2)),
                us => Ok(InputMode::OnTimer(us)),
            },
            m => Err(DecodeError::BadMode(m)),
        }
    }
}

/// When a function sends its outputs down its pipes.
///
/// Wire form: `[0]` always, `[1]` on change.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum OutputMode {
    /// After every run.
    #[default]
    Always,
    /// Only when the outputs differ (byte for byte) from the last ones sent.
    OnChange,
}

impl OutputMode {
    fn decode(r: &mut Reader<'_>) -> Result<OutputMode, DecodeError> {
        match r.u8()? {
            0 => Ok(OutputMode::Always),
            1 => Ok(OutputMode::OnChange),
            m => Err(DecodeError::BadMode(m)),
        }
    }

    fn to_u8(self) -> u8 {
        match self {
            OutputMode::Always => 0,
            OutputMode::OnChange => 1,
        }
    }
}

/// A request to a function's control port (after the transport header).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Request<'a> {
    /// `[1][args]`: values for some inputs (as a request, it is answered).
    PipeDatagram(Args<'a>),
    /// `[2]`: the signature alone.
    GetSignature,
    /// `[2][parts]`: the signature and the parts of its description
    /// `parts` asks for, appended ([`crate::failure`]); `parts` 0 is sent
    /// as `[2]`. A function from before the tail refuses `[2][parts]` as
    /// [`ControlError::Malformed`].
    Describe(SignatureParts),
    /// `[3][args]`: every input, once.
    Call(Args<'a>),
    /// `[4]`.
    GetPipeCount,
    /// `[5][slot]`.
    GetPipe(u8),
    /// `[6][slot][pipe]`; slot [`ANY_SLOT`] takes the first free one.
    SetPipe {
        /// The slot.
        slot: u8,
        /// The pipe.
        pipe: PipeConfig,
    },
    /// `[7][slot]`; slot [`ANY_SLOT`] wipes every pipe.
    WipePipe(u8),
    /// `[8]`.
    GetInputMode,
    /// `[9][mode]`.
    SetInputMode(InputMode),
    /// `[10]`.
    GetOutputMode,
    /// `[11][mode]`.
    SetOutputMode(OutputMode),
    /// `[13][slot]`: the pipe's counters; an empty or missing slot is
    /// refused with [`ControlError::NoSuchPipe`].
    GetPipeStats(u8),
}

impl<'a> Request<'a> {
    /// The request's key.
    pub fn key(&self) -> ControlKey {
        match self {
            Request::PipeDatagram(_) => ControlKey::PipeDatagram,
            Request::GetSignature | Request::Describe(_) => ControlKey::GetSignature,
            Request::Call(_) => ControlKey::Call,
            Request::GetPipeCount => ControlKey::GetPipeCount,
            Request::GetPipe(_) => ControlKey::GetPipe,
            Request::SetPipe { .. } => ControlKey::SetPipe,
            Request::WipePipe(_) => ControlKey::WipePipe,
            Request::GetInputMode => ControlKey::GetInputMode,
            Request::SetInputMode(_) => ControlKey::SetInputMode,
            Request::GetOutputMode => ControlKey::GetOutputMode,
            Request::SetOutputMode(_) => ControlKey::SetOutputMode,
            Request::GetPipeStats(_) => ControlKey::GetPipeStats,
        }
    }

    /// Parses a whole request.
    pub fn parse(bytes: &'a [u8]) -> Result<Request<'a>, DecodeError> {
        let mut r = Reader::new(bytes);
        let k = r.u8()?;
        let key = ControlKey::from_u8(k).ok_or(DecodeError::UnknownKey(k))?;
        let req = match key {
            ControlKey::PipeDatagram => Request::PipeDatagram(args(&mut r)?),
            ControlKey::GetSignature if r.is_empty() => Request::GetSignature,
            // Parts 0 would ask for nothing: that request is `[2]`.
            ControlKey::GetSignature => match r.u8()? {
                0 => return Err(DecodeError::TrailingBytes),
                p => Request::Describe(SignatureParts(p)),
            },
            ControlKey::Call => Request::Call(args(&mut r)?),
            ControlKey::GetPipeCount => Request::GetPipeCount,
            ControlKey::GetPipe => Request::GetPipe(r.u8()?),
            ControlKey::SetPipe => Request::SetPipe {
                slot: r.u8()?,
                pipe: PipeConfig::decode(&mut r)?,
            },
            ControlKey::WipePipe => Request::WipePipe(r.u8()?),
            ControlKey::GetInputMode => Request::GetInputMode,
            ControlKey::SetInputMode => Request::SetInputMode(InputMode::decode(&mut r)?),
            ControlKey::GetOutputMode => Request::GetOutputMode,
            ControlKey::SetOutputMode => Request::SetOutputMode(OutputMode::decode(&mut r)?),
            ControlKey::GetPipeStats => Request::GetPipeStats(r.u8()?),
            ControlKey::PipeError => return Err(DecodeError::UnknownKey(k)),
        };
        if !r.is_empty() {
            return Err(DecodeError::TrailingBytes);
        }
        Ok(req)
    }

    /// Writes the request. On error nothing is written.
    pub fn encode(&self, w: &mut Writer<'_>) -> Result<(), DecodeError> {
        let start = w.len();
        let r = (|| -> Result<(), DecodeError> {
            w.u8(self.key().to_u8())?;
            match self {
                Request::PipeDatagram(a) | Request::Call(a) => copy_args(w, a)?,
                Request::GetPipe(s) | Request::WipePipe(s) | Request::GetPipeStats(s) => {
                    w.u8(*s)?
                }
                Request::SetPipe { slot, pipe } => {
                    w.u8(*slot)?;
                    pipe.encode(w)?;
                }
                Request::SetInputMode(m) => m.encode(w)?,
                Request::SetOutputMode(m) => w.u8(m.to_u8())?,
                // Parts 0 is `[2]` (see `parse`).
                Request::Describe(p) if p.0 != 0 => w.u8(p.0)?,
                Request::Describe(_) => {}
                Request::GetSignature
                | Request::GetPipeCount
                | Request::GetInputMode
                | Request::GetOutputMode => {}
            }
            Ok(())
        })();
        if r.is_err() {
            w.truncate(start);
        }
        r
    }
}

fn args<'a>(r: &mut Reader<'a>) -> Result<Args<'a>, DecodeError> {
    Args::decode(r).map_err(|e| match e {
        MessageError::Truncated => DecodeError::Truncated,
        e => DecodeError::Args(e),
    })
}

fn copy_args(w: &mut Writer<'_>, a: &Args<'_>) -> Result<(), DecodeError> {
    let mut aw = ArgsWriter::new(w).map_err(|_| DecodeError::NoSpace)?;
    for (i, v) in a.iter() {
        aw.push(i, &v).map_err(|e| match e {
            MessageError::NoSpace => DecodeError::NoSpace,
            e => DecodeError::Args(e),
        })?;
    }
    aw.finish().map_err(|_| DecodeError::NoSpace)
}

/// A successful reply's body.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ReplyBody<'a> {
    /// To `PipeDatagram`, `WipePipe`, `SetInputMode`, `SetOutputMode`: no body.
    Done,
    /// To `GetSignature`: the signature.
    Signature(SignatureView<'a>),
    /// To `Call`: the outputs, by output index.
    Returned(Args<'a>),
    /// To `GetPipeCount`: `[slots][used]`.
    PipeCount {
        /// How many pipe slots the function has.
        slots: u8,
        /// How many hold a pipe.
        used: u8,
    },
    /// To `GetPipe`: `[slot][used: 0/1]` then the pipe if used.
    Pipe {
        /// The slot.
        slot: u8,
        /// Its pipe, if it holds one.
        pipe: Option<PipeConfig>,
    },
    /// To `SetPipe`: `[slot]`, the slot that now holds the pipe.
    PipeSet(u8),
    /// To `GetInputMode`: the mode.
    InputMode(InputMode),
    /// To `GetOutputMode`: the mode.
    OutputMode(OutputMode),
    /// To `GetPipeStats`: `[slot]` then the pipe's counters.
    PipeStats {
        /// The slot.
        slot: u8,
        /// Its counters.
        stats: PipeStats,
    },
}

/// A reply from a function's control port (after the transport header), or
/// a [`ControlKey::PipeError`] report.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reply<'a> {
    /// The key of the request it answers (or `PipeError`); for
    /// [`ControlError::UnknownKey`] the undefined key itself.
    pub key: u8,
    /// The result.
    pub result: Result<ReplyBody<'a>, ControlError>,
}

impl<'a> Reply<'a> {
    /// Parses a whole reply.
    pub fn parse(bytes: &'a [u8]) -> Result<Reply<'a>, DecodeError> {
        let mut r = Reader::new(bytes);
        let k = r.u8()?;
        let status = r.u8()?;
        let result = if status != 0 {
            Err(ControlError::decode_body(status, &mut r)?)
        } else {
            let key = ControlKey::from_u8(k).ok_or(DecodeError::UnknownKey(k))?;
            Ok(match key {
                ControlKey::PipeDatagram
                | ControlKey::WipePipe
                | ControlKey::SetInputMode
                | ControlKey::SetOutputMode => ReplyBody::Done,
                ControlKey::GetSignature => ReplyBody::Signature(
                    SignatureView::decode_described(&mut r).map_err(DecodeError::Signature)?,
                ),
                ControlKey::Call => ReplyBody::Returned(args(&mut r)?),
                ControlKey::GetPipeCount => ReplyBody::PipeCount {
                    slots: r.u8()?,
                    used: r.u8()?,
                },
                ControlKey::GetPipe => {
                    let slot = r.u8()?;
                    let pipe = match r.u8()? {
                        0 => None,
                        1 => Some(PipeConfig::decode(&mut r)?),
                        b => return Err(DecodeError::BadBool(b)),
                    };
                    ReplyBody::Pipe { slot, pipe }
                }
                ControlKey::SetPipe => ReplyBody::PipeSet(r.u8()?),
                ControlKey::GetInputMode => ReplyBody::InputMode(InputMode::decode(&mut r)?),
                ControlKey::GetOutputMode => ReplyBody::OutputMode(OutputMode::decode(&mut r)?),
                ControlKey::GetPipeStats => ReplyBody::PipeStats {
                    slot: r.u8()?,
                    stats: PipeStats::decode(&mut r)?,
                },
                ControlKey::PipeError => return Err(DecodeError::UnknownStatus(0)),
            })
        };
        if !r.is_empty() {
            return Err(DecodeError::TrailingBytes);
        }
        Ok(Reply { key: k, result })
    }

    /// Writes the reply. On error nothing is written.
    pub fn encode(&self, w: &mut Writer<'_>) -> Result<(), DecodeError> {
        let start = w.len();
        let r = (|| -> Result<(), DecodeError> {
            w.u8(self.key)?;
            let body = match &self.result {
                Err(e) => return e.encode(w),
                Ok(b) => b,
            };
            w.u8(0)?;
            match body {
                ReplyBody::Done => {}
                ReplyBody::Signature(s) => {
                    w.bytes(s.as_bytes())?;
                    w.bytes(s.tail_bytes())?;
                }
                ReplyBody::Returned(a) => copy_args(w, a)?,
                ReplyBody::PipeCount { slots, used } => {
                    w.u8(*slots)?;
                    w.u8(*used)?;
                }
                ReplyBody::Pipe { slot, pipe } => {
                    w.u8(*slot)?;
                    match pipe {
                        None => w.u8(0)?,
                        Some(p) => {
                            w.u8(1)?;
                            p.encode(w)?;
                        }
                    }
                }
                ReplyBody::PipeSet(s) => w.u8(*s)?,
                ReplyBody::InputMode(m) => m.encode(w)?,
                ReplyBody::OutputMode(m) => w.u8(m.to_u8())?,
                ReplyBody::PipeStats { slot, stats } => {
                    w.u8(*slot)?;
                    stats.encode(w)?;
                }
            }
            Ok(())
        })();
        if r.is_err() {
            w.truncate(start);
        }
        r
    }
}

/// Writes the success reply to "get signature" from a static signature.
/// On error nothing is written.
pub fn encode_signature_reply(w: &mut Writer<'_>, sig: &Signature) -> Result<(), DecodeError> {
    if w.remaining() < 2 + sig.encoded_len() {
        return Err(DecodeError::NoSpace);
    }
    w.u8(ControlKey::GetSignature.to_u8())?;
    w.u8(0)?;
    let start = w.len() - 2;
    sig.encode(w).map_err(|e| {
        w.truncate(start);
        DecodeError::Signature(e)
    })
}

/// Writes the success reply to "get signature" with the parts `parts`
/// asks for appended: `failures` is the function's table, `docs` its
/// documentation ([`crate::docs`]). On error nothing is written.
pub fn encode_described_reply(
    w: &mut Writer<'_>,
    sig: &Signature,
    parts: SignatureParts,
    failures: &[Failure],
    docs: &str,
) -> Result<(), DecodeError> {
    let start = w.len();
    encode_signature_reply(w, sig)?;
    encode_tail(w, parts, failures, docs).map_err(|e| {
        w.truncate(start);
        DecodeError::Signature(e.into())
    })
}

/// Writes an error report `[key][status][body]` (a failed reply, or a
/// [`ControlKey::PipeError`] message). On error nothing is written.
pub fn encode_error(w: &mut Writer<'_>, key: u8, error: &ControlError) -> Result<(), DecodeError> {
    Reply {
        key,
        result: Err(*error),
    }
    .encode(w)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::types::ScalarType;
    use crate::value::Value;
    use osap_core::route::Route;
    use std::string::ToString;

    #[test]
    fn failure_codes_round_trip_and_unknown_codes_are_other() {
        for byte in 0..=u8::MAX {
            let code = FailureCode::from_code(byte);
            assert_eq!(code.code(), byte);
            assert_eq!(u8::from(FailureCode::from(byte)), byte);
        }
        assert_eq!(FailureCode::from_code(7), FailureCode::Other(7));
        assert!(matches!(FailureCode::from_code(7), FailureCode::Other(7)));
        assert!(matches!(
            FailureCode::from_code(crate::export::STATE_BUSY),
            FailureCode::StateBusy
        ));
        // Equality goes by the code, however the value was made.
        assert_eq!(FailureCode::Other(255), FailureCode::InputDecodeFailed);
        // The wire byte is the code, as before it had a name.
        let (b, n) = enc(|w| ControlError::CallFailed(FailureCode::Other(42)).encode(w));
        assert_eq!(&b[..n], &[10, 42]);
        let (b, n) = enc(|w| ControlError::CallFailed(FailureCode::NoSuchMember).encode(w));
        assert_eq!(&b[..n], &[10, 253]);
    }

    #[test]
    fn failure_errors_display() {
        assert_eq!(FailureCode::Other(9).to_string(), "code 9");
        assert_eq!(
            ControlError::CallFailed(FailureCode::StateBusy).to_string(),
            "the function failed with code 254 (class state busy)"
        );
        assert_eq!(
            crate::function::CallError::Failed(FailureCode::Other(3)).to_string(),
            "the function failed with code 3"
        );
    }

    fn enc(f: impl FnOnce(&mut Writer<'_>) -> Result<(), DecodeError>) -> ([u8; 96], usize) {
        let mut b = [0u8; 96];
        let mut w = Writer::new(&mut b);
        f(&mut w).unwrap();
        let n = w.len();
        (b, n)
    }

    #[test]
    fn requests_round_trip() {
        let pipe = PipeConfig::new(Route::through_links(&[2]).unwrap(), 1, 1000)
            .with(0, 1)
            .unwrap();
        let (ab, an) = enc(|w| {
            let mut a = ArgsWriter::new(w).map_err(DecodeError::Args)?;
            a.push(0, &Value::F32(1.0)).map_err(DecodeError::Args)?;
            a.finish().map_err(DecodeError::Args)
        });
        let a = Args::decode(&mut Reader::new(&ab[..an])).unwrap();
        for req in [
            Request::PipeDatagram(a),
            Request::GetSignature,
            Request::Call(a),
            Request::GetPipeCount,
            Request::GetPipe(3),
            Request::SetPipe {
                slot: ANY_SLOT,
                pipe,
            },
            Request::WipePipe(1),
            Request::GetInputMode,
            Request::SetInputMode(InputMode::OnTimer(1000)),
            Request::SetInputMode(InputMode::OnAllFresh),
            Request::GetOutputMode,
            Request::SetOutputMode(OutputMode::OnChange),
            Request::GetPipeStats(1),
        ] {
            let (b, n) = enc(|w| req.encode(w));
            assert_eq!(Request::parse(&b[..n]), Ok(req), "{req:?}");
            for cut in 0..n {
                assert!(Request::parse(&b[..cut]).is_err());
            }
        }
        assert_eq!(Request::parse(&[0]), Err(DecodeError::UnknownKey(0)));
        assert_eq!(Request::parse(&[12]), Err(DecodeError::UnknownKey(12)));
        assert_eq!(Request::parse(&[2, 0]), Err(DecodeError::TrailingBytes));
        // Asking for the failure table; parts 0 asks for nothing and is `[2]`.
        let describe = Request::Describe(SignatureParts::FAILURES);
        let (b, n) = enc(|w| describe.encode(w));
        assert_eq!(&b[..n], &[2, 1]);
        assert_eq!(Request::parse(&b[..n]), Ok(describe));
        assert_eq!(Request::parse(&[2, 1, 0]), Err(DecodeError::TrailingBytes));
        let (b, n) = enc(|w| Request::Describe(SignatureParts::NONE).encode(w));
        assert_eq!(Request::parse(&b[..n]), Ok(Request::GetSignature));
        assert_eq!(
            Request::parse(&[9, 2, 0, 0, 0, 0]),
            Err(DecodeError::BadMode(2))
        );
        assert_eq!(Request::parse(&[11, 2]), Err(DecodeError::BadMode(2)));
    }

    #[test]
    fn replies_round_trip() {
        let pipe = PipeConfig::new(Route::local(), 4, 100).with(1, 0).unwrap();
        let ce = ConvertError {
            from: Type::Scalar(ScalarType::F64),
            to: Type::Scalar(ScalarType::F32),
            reason: ConvertReason::Lossy,
            element: None,
        };
        let ce2 = ConvertError {
            element: Some(7),
            from: Type::Array(ScalarType::I32),
            to: Type::Array(ScalarType::U8),
            reason: ConvertReason::OutOfRange,
        };
        let errors = [
            ControlError::UnknownKey(200),
            ControlError::Malformed,
            ControlError::WrongArgCount {
                expected: 2,
                got: 1,
            },
            ControlError::NoSuchInput(5),
            ControlError::Convert {
                index: 1,
                error: ce,
            },
            ControlError::Convert {
                index: 0,
                error: ce2,
            },
            ControlError::NoSuchPipe(9),
            ControlError::PipeTableFull,
            ControlError::Unsupported,
            ControlError::BadArgmap(3),
            ControlError::CallFailed(FailureCode::Other(42)),
            ControlError::CallFailed(FailureCode::StateBusy),
            ControlError::BadOutput(0),
            ControlError::TooLarge(2),
        ];
        let bodies = [
            ReplyBody::Done,
            ReplyBody::PipeCount { slots: 4, used: 1 },
            ReplyBody::Pipe {
                slot: 0,
                pipe: None,
            },
            ReplyBody::Pipe {
                slot: 1,
                pipe: Some(pipe),
            },
            ReplyBody::PipeSet(2),
            ReplyBody::InputMode(InputMode::OnTimer(5)),
            ReplyBody::OutputMode(OutputMode::OnChange),
            ReplyBody::PipeStats {
                slot: 1,
                stats: PipeStats::default(),
            },
            ReplyBody::PipeStats {
                slot: 0,
                stats: PipeStats {
                    sent: 7,
                    overflows: 2,
                    send_errors: 1,
                    remote_errors: 3,
                    acked: 9,
                    retries: 4,
                    failures: 1,
                    last_remote_error: Some(ControlError::Convert {
                        index: 1,
                        error: ce,
                    }),
                },
            },
        ];
        let keys = [1u8, 4, 5, 5, 6, 8, 10, 13, 13];
        for (k, b) in keys.iter().zip(bodies) {
            let rep = Reply {
                key: *k,
                result: Ok(b),
            };
            let (buf, n) = enc(|w| rep.encode(w));
            assert_eq!(Reply::parse(&buf[..n]), Ok(rep));
            for cut in 0..n {
                assert!(Reply::parse(&buf[..cut]).is_err(), "{rep:?} cut at {cut}");
            }
        }
        for e in errors {
            let (buf, n) = enc(|w| encode_error(w, 3, &e));
            assert_eq!(
                Reply::parse(&buf[..n]),
                Ok(Reply {
                    key: 3,
                    result: Err(e)
                })
            );
            for cut in 0..n {
                assert!(Reply::parse(&buf[..cut]).is_err());
            }
        }
        assert_eq!(Reply::parse(&[3, 99]), Err(DecodeError::UnknownStatus(99)));
        assert_eq!(Reply::parse(&[5, 0, 0, 2]), Err(DecodeError::BadBool(2)));
        assert_eq!(
            Reply::parse(&[4, 0, 1, 1, 0]),
            Err(DecodeError::TrailingBytes)
        );
    }

    #[test]
    fn signature_reply() {
        static S: Signature = Signature {
            name: "f",
            inputs: &[],
            outputs: &[crate::signature::Arg::new(
                "x",
                Type::Scalar(ScalarType::U8),
            )],
        };
        let (b, n) = enc(|w| encode_signature_reply(w, &S));
        assert_eq!(&b[..n], &[2, 0, 1, b'f', 0, 1, 1, b'x', 24]);
        let rep = Reply::parse(&b[..n]).unwrap();
        let Ok(ReplyBody::Signature(v)) = rep.result else {
            panic!("{rep:?}")
        };
        assert!(S.matches(&v));
        let (b2, n2) = enc(|w| rep.encode(w));
        assert_eq!(&b2[..n2], &b[..n]);
        let mut small = [0u8; 5];
        let mut w = Writer::new(&mut small);
        assert_eq!(
            encode_signature_reply(&mut w, &S),
            Err(DecodeError::NoSpace)
        );
        assert_eq!(w.len(), 0);
    }
}
