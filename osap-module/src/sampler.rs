//! Samples batched on the module: `sample_block` runs up to [`SOURCES`]
//! of the module's read functions on its own timer, appends each sample
//! to a block, and sends the block down its pipes when the block is full
//! or its first sample is `latency_us` old, with a sequence number, so a
//! host that misses a block knows it, and how many samples it held.
//!
//! A capture at 1 kHz as one datagram per sample fills a module's pipe
//! queues (a function that also feeds the machine shares its port with
//! the machine's own pipe); a block of a dozen samples per datagram does
//! not.
//!
//! # How a host uses it
//! 1. Store the inputs (a pipe datagram's "push", which does not run it):
//!    `source0..2` the indices of the functions to sample in the module's
//!    function table ([`crate::functions::ALL`]; [`NO_SOURCE`] for none),
//!    `arg0..2` their one `u8` input (ignored by a function without one),
//!    `latency_us` the longest a sample waits in an open block, and
//!    `session` any number that differs from the previous capture's: a
//!    new session restarts the sequence.
//! 2. Pipe its outputs to the host, set its output mode to "on change" (a
//!    block goes down the pipes once, when it closes), and its input mode
//!    to a timer at the sampling period.
//! 3. At the end, set the timer off and call it once with `latency_us = 0`:
//!    the open block closes (without a new sample), goes down the pipes,
//!    and the reply carries it, so the host knows the last sequence
//!    number and counts every block it never received.
//!
//! # A block
//! Outputs `(seq, first, time, samples, session)`: `seq` counts the session's
//! blocks from 1 (0: none closed yet), `first` is the session's index of
//! the block's first sample (so samples lost with a block are `first` of
//! the next minus `first` of the last received, minus what it held),
//! `time` the synchronized time of the first sample, µs, and `session`
//! the session it was taken in (a host ignores another session's blocks:
//! an earlier capture's, sent before the new inputs arrived). `samples`
//! (an `arry_u8`) holds one record per sample:
//!
//! | bytes | what |
//! |---|---|
//! | 4 | `u32` little-endian: the sample's time after `time`, µs |
//! | per source | the source's outputs as an argument list (a count, then per output its index and its typed value, as a pipe datagram carries them); a source that failed gives an empty list (count 0) |
//!
//! The records use the message encoding of `docs/pipes.md`, so no new
//! byte layout: a host decodes them with the argument-list decoder.

use crate::board::Board;
use crate::functions::{call_on, FnId, ALL, SIGNATURES};
use crate::Module;
use osap_core::codec::Writer;
use pipes_core::export::{FromPipes, PipesType};
use pipes_core::function::{call_direct, CallError, Implementation, Outputs};
use pipes_core::signature::Signature;
use pipes_core::{Array, ScalarType, Type, Value};

/// Functions one block samples at once.
pub const SOURCES: usize = 3;

/// Bytes of records one block holds: a block's datagram (with its
/// sequence, first index and time) stays within a module's 256-byte
/// packet behind a route of several hops.
pub const BLOCK_BYTES: usize = 192;

/// A `source` input that names no function.
pub const NO_SOURCE: u8 = u8::MAX;

/// Bytes of a record's time offset.
const STAMP_BYTES: usize = 4;

/// Why `sample_block` refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
#[non_exhaustive]
pub enum SamplerError {
    /// A source is not one of the module's read functions: it must have
    /// outputs and at most one input, a `u8` (not `sample_block` itself).
    BadSource = 1,
    /// One sample of the sources does not fit a block.
    TooLarge = 2,
}

impl SamplerError {
    /// Every sampler error, in code order.
    pub const ALL: [SamplerError; 2] = [SamplerError::BadSource, SamplerError::TooLarge];

    /// The failure code.
    pub const fn code(self) -> u8 {
        self as u8
    }

    /// The error with failure code `code`.
    pub fn from_code(code: u8) -> Option<SamplerError> {
        Self::ALL.into_iter().find(|e| e.code() == code)
    }
}

impl core::fmt::Display for SamplerError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            SamplerError::BadSource => "a source is not one of the module's read functions",
            SamplerError::TooLarge => "one sample of the sources does not fit a block",
        })
    }
}

impl From<SamplerError> for pipes_core::FailureCode {
    fn from(e: SamplerError) -> Self {
        pipes_core::FailureCode::Other(e.code())
    }
}

impl From<SamplerError> for CallError {
    fn from(e: SamplerError) -> Self {
        CallError::Failed(e.into())
    }
}

/// A block's records, as a PIPES `arry_u8`.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Block {
    len: u8,
    bytes: [u8; BLOCK_BYTES],
}

impl Block {
    /// The records.
    pub fn bytes(&self) -> &[u8] {
        &self.bytes[..usize::from(self.len)]
    }

    /// A block of `bytes` (`None` past [`BLOCK_BYTES`]).
    pub fn from_bytes(bytes: &[u8]) -> Option<Block> {
        let mut b = Block::default();
        b.bytes.get_mut(..bytes.len())?.copy_from_slice(bytes);
        b.len = u8::try_from(bytes.len()).ok()?;
        Some(b)
    }
}

impl Default for Block {
    fn default() -> Self {
        Block {
            len: 0,
            bytes: [0; BLOCK_BYTES],
        }
    }
}

impl core::fmt::Debug for Block {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "Block({} bytes)", self.len)
    }
}

impl PipesType for Block {
    const TYPE: Type = Type::Array(ScalarType::U8);

    fn to_value(&self) -> Value<'_> {
        // u8 elements: any byte count is whole elements.
        Array::new(ScalarType::U8, self.bytes())
            .map(Value::Array)
            .unwrap_or(Value::Null)
    }
}

impl FromPipes<'_> for Block {
    fn from_value(v: &Value<'_>) -> Option<Self> {
        match v {
            Value::Array(a) if a.elem() == ScalarType::U8 => Block::from_bytes(a.bytes()),
            _ => None,
        }
    }
}

/// What the sampler samples: its inputs but `latency_us`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Config {
    sources: [(u8, u8); SOURCES],
    session: u32,
}

/// A block closed: `sample_block`'s outputs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Closed {
    /// The session it belongs to (the `session` input it was taken
    /// under), so a host tells a new capture's blocks from an old one's.
    pub session: u32,
    /// The block's number in its session, from 1 (0: none yet).
    pub seq: u32,
    /// The session's index of its first sample.
    pub first: u32,
    /// The synchronized time of its first sample, µs.
    pub time: u64,
    /// Its records.
    pub block: Block,
}

/// The sampler's state (one per module).
#[derive(Debug, Default)]
pub struct Sampler {
    config: Option<Config>,
    /// Samples taken this session.
    taken: u32,
    /// The open block: its first sample's index and time, and its records.
    open_first: u32,
    open_time: u64,
    open: Block,
    /// The latest closed block.
    closed: Closed,
}

impl Sampler {
    /// A sampler with no session.
    pub fn new() -> Self {
        Sampler::default()
    }

    /// The latest closed block.
    pub fn closed(&self) -> &Closed {
        &self.closed
    }

    /// Samples taken this session.
    pub fn taken(&self) -> u32 {
        self.taken
    }

    fn close(&mut self) {
        if self.open.len == 0 {
            return;
        }
        self.closed = Closed {
            session: self.config.map_or(0, |c| c.session),
            seq: self.closed.seq.wrapping_add(1),
            first: self.open_first,
            time: self.open_time,
            block: self.open,
        };
        self.open.len = 0;
    }

    /// Starts a session with `config` unless it is the one running.
    fn begin(&mut self, config: Config) {
        if self.config != Some(config) {
            *self = Sampler {
                config: Some(config),
                closed: Closed {
                    session: config.session,
                    ..Closed::default()
                },
                ..Sampler::default()
            };
        }
    }
}

/// Whether `id` may be sampled: a read function (outputs, and no input or
/// one `u8` input), not the sampler.
fn sampleable(id: FnId) -> bool {
    let sig = SIGNATURES[id as usize];
    let input_ok = match sig.inputs {
        [] => true,
        [one] => one.ty == <u8 as PipesType>::TYPE,
        _ => false,
    };
    id != FnId::sample_block && !sig.outputs.is_empty() && input_ok
}

/// One of the module's functions, called on the module in hand (the
/// sampler runs inside the module's own lock).
struct Direct<'m, B> {
    module: &'m mut Module<B>,
    id: FnId,
}

impl<B: Board> Implementation for Direct<'_, B> {
    fn signature(&self) -> &'static Signature {
        SIGNATURES[self.id as usize]
    }

    fn call(&mut self, inputs: &[Value<'_>], outputs: &mut Outputs<'_>) -> Result<(), CallError> {
        call_on(self.id, self.module, inputs, outputs)
    }
}

impl<B: Board> Module<B> {
    /// `sample_block`: see [`crate::sampler`] and its table entry.
    pub(crate) fn run_sampler(
        &mut self,
        sources: [(u8, u8); SOURCES],
        latency_us: u32,
        session: u32,
    ) -> Result<Closed, CallError> {
        let mut ids = [None; SOURCES];
        for (slot, (source, _)) in ids.iter_mut().zip(sources) {
            if source == NO_SOURCE {
                continue;
            }
            let id = ALL
                .get(usize::from(source))
                .copied()
                .filter(|id| sampleable(*id))
                .ok_or(SamplerError::BadSource)?;
            *slot = Some(id);
        }
        if ids.iter().all(Option::is_none) {
            return Err(SamplerError::BadSource.into());
        }
        let mut sampler = core::mem::take(&mut self.sampler);
        sampler.begin(Config { sources, session });
        let result = if latency_us == 0 {
            sampler.close();
            Ok(())
        } else {
            self.take_sample(&mut sampler, &ids, &sources, latency_us)
        };
        let closed = sampler.closed;
        self.sampler = sampler;
        result.map(|()| closed)
    }

    /// Appends one sample of `ids` to the open block, closing it first if
    /// the record does not fit, and after if it is due.
    fn take_sample(
        &mut self,
        s: &mut Sampler,
        ids: &[Option<FnId>; SOURCES],
        sources: &[(u8, u8); SOURCES],
        latency_us: u32,
    ) -> Result<(), CallError> {
        let now = self.system_now().as_micros();
        let mut record = [0u8; BLOCK_BYTES];
        let mut len = STAMP_BYTES;
        for (id, (_, arg)) in ids.iter().zip(sources) {
            let Some(id) = *id else { continue };
            let rest = record.get_mut(len..).ok_or(SamplerError::TooLarge)?;
            len += self.sample_one(id, *arg, rest)?;
        }
        if s.open.len > 0 && usize::from(s.open.len) + len > BLOCK_BYTES {
            s.close();
        }
        if s.open.len == 0 {
            s.open_first = s.taken;
            s.open_time = now;
        }
        let offset = u32::try_from(now.saturating_sub(s.open_time)).unwrap_or(u32::MAX);
        record[..STAMP_BYTES].copy_from_slice(&offset.to_le_bytes());
        let at = usize::from(s.open.len);
        s.open
            .bytes
            .get_mut(at..at + len)
            .ok_or(SamplerError::TooLarge)?
            .copy_from_slice(&record[..len]);
        s.open.len += len as u8;
        s.taken = s.taken.wrapping_add(1);
        // Due: the next record (as large as this one) would not fit, or
        // the first sample has waited its latency.
        let full = usize::from(s.open.len) + len > BLOCK_BYTES;
        let old = now.saturating_sub(s.open_time) >= u64::from(latency_us);
        if full || old {
            s.close();
        }
        Ok(())
    }

    /// Runs source `id` (with `arg` if it takes an input) and writes its
    /// outputs as an argument list into `out`, returning the bytes
    /// written; a source that fails writes an empty list.
    fn sample_one(&mut self, id: FnId, arg: u8, out: &mut [u8]) -> Result<usize, CallError> {
        let takes_arg = !SIGNATURES[id as usize].inputs.is_empty();
        let inputs = [Value::U8(arg)];
        let inputs = if takes_arg { &inputs[..] } else { &[] };
        // One function's outputs fit its store.
        let mut buf = [0u8; crate::ports::FN_STORE];
        let mut direct = Direct { module: self, id };
        let mut w = Writer::new(out);
        let written = match call_direct(&mut direct, inputs, &mut buf) {
            Ok(args) => args.encode(&mut w),
            Err(_) => w.u8(0),
        };
        written.map_err(|_| SamplerError::TooLarge)?;
        Ok(w.len())
    }
}
