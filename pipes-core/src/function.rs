//! A PIPES function as a port: its control port answers the function
//! protocol ([`crate::control`]), and each of its pipe slots sends from a
//! port of its own.
//!
//! [`PipesFunction`] wraps an [`Implementation`] (the plain function: a
//! static [`Signature`] and a `call` over decoded values) with:
//! - one fixed store per input holding the last value received for it,
//!   already converted to the input's type, and a freshness bit;
//! - an [`InputMode`] that decides when dataflow runs the function and an
//!   [`OutputMode`] that decides when its outputs go down its pipes;
//! - a table of `PIPES` pipes, each with a queue of `Q` datagrams;
//! - counters for everything it refuses or drops.
//!
//! Port offsets: 0 is the control port (`pipes_function`, named after the
//! function), `1 + k` is the sending port of pipe slot `k` (`pipes_pipe`).
//! `B` is the byte size of each input store, of the output buffer and of each
//! queued datagram.
//!
//! An RPC call stores its arguments as the inputs (without making them
//! fresh), runs the function, replies with the outputs **and** sends them
//! down the pipes, so a script drives dataflow by calling.

use core::fmt;

use osap_core::codec::{Reader, Writer};
use osap_core::port::{Delivery, Port, PortInfo, PortTx, SendError};
use osap_core::segment::{Pump, SegmentSender, SegmentSource, Window};
use osap_core::transport::Transport;
use osap_core::{Duration, Instant};

use crate::control::{
    encode_described_reply, encode_error, ControlError, ControlKey, FailureCode, InputMode,
    OutputMode, Reply, ReplyBody, Request, ANY_SLOT,
};
use crate::convert::{convert, ConvertError};
use crate::docs::check_docs;
use crate::failure::{check_failures, tail_len, write_tail, Failure, SignatureParts};
use crate::message::{Args, ArgsWriter, MessageKey};
use crate::pipe::{AckStep, PipeConfig, PipeDelivery, PipeState};
use crate::signature::{Arg, Signature, SignatureError, MAX_ARGS};
use crate::value::Value;

/// Type name of a function's control port in a network scan.
pub const FUNCTION_PORT_TYPE: &str = "pipes_function";
/// Type name of a pipe's sending port in a network scan.
pub const PIPE_PORT_TYPE: &str = "pipes_pipe";
/// Default time-to-live of replies and error reports, µs.
pub const DEFAULT_REPLY_TTL: u16 = 20_000;
/// Time-to-live of a signature reply sent in segments, µs: the time its
/// segments have, together, to go out (the longest a `u16` says).
pub const SEGMENTED_REPLY_TTL: u16 = u16::MAX;

/// Why a function's `call` failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum CallError {
    /// The function's own failure, with its code ([`FailureCode::Other`]
    /// for a code of the function's own).
    Failed(FailureCode),
    /// It set an output index it does not declare.
    NoSuchOutput(u8),
    /// It set an output to a value that does not convert to the declared type.
    OutputType {
        /// The output index.
        index: u8,
        /// Why the value does not convert.
        error: ConvertError,
    },
    /// It set the same output twice.
    OutputTwice(u8),
    /// The output does not fit the output buffer (or cannot be encoded).
    OutputTooLarge(u8),
    /// It returned without setting this output.
    MissingOutput(u8),
}

impl CallError {
    /// The error reported on the wire.
    pub fn to_control(self) -> ControlError {
        match self {
            CallError::Failed(c) => ControlError::CallFailed(c),
            CallError::NoSuchOutput(i)
            | CallError::OutputType { index: i, .. }
            | CallError::OutputTwice(i)
            | CallError::OutputTooLarge(i)
            | CallError::MissingOutput(i) => ControlError::BadOutput(i),
        }
    }
}

impl fmt::Display for CallError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CallError::Failed(c) => write!(f, "the function failed with {c}"),
            CallError::NoSuchOutput(i) => write!(f, "no output {i}"),
            CallError::OutputType { index, error } => write!(f, "output {index}: {error}"),
            CallError::OutputTwice(i) => write!(f, "output {i} set twice"),
            CallError::OutputTooLarge(i) => write!(f, "output {i} does not fit"),
            CallError::MissingOutput(i) => write!(f, "output {i} was not set"),
        }
    }
}

impl core::error::Error for CallError {}

/// Where a function writes its outputs: an argument list keyed by output
/// index, each value converted to its declared type.
#[derive(Debug)]
pub struct Outputs<'a> {
    w: Writer<'a>,
    decl: &'static [Arg],
    count: u8,
    set: u16,
}

impl<'a> Outputs<'a> {
    fn new(buf: &'a mut [u8], decl: &'static [Arg]) -> Outputs<'a> {
        let mut w = Writer::new(buf);
        // An empty buffer leaves the count unwritten; `finish` then fails.
        let _ = w.u8(0);
        Outputs {
            w,
            decl,
            count: 0,
            set: 0,
        }
    }

    /// Sets output `index` to `value`, converted to the declared type by the
    /// conversion table (so an `i32` may be given for an `f64` output, but
    /// never a value that would change).
    pub fn set(&mut self, index: u8, value: &Value<'_>) -> Result<(), CallError> {
        let arg = self
            .decl
            .get(usize::from(index))
            .ok_or(CallError::NoSuchOutput(index))?;
        let bit = 1u16 << index;
        if self.set & bit != 0 {
            return Err(CallError::OutputTwice(index));
        }
        let c = convert(value, &arg.ty).map_err(|error| CallError::OutputType { index, error })?;
        let len = c
            .encoded_len()
            .map_err(|_| CallError::OutputTooLarge(index))?;
        if 1 + len > self.w.remaining() {
            return Err(CallError::OutputTooLarge(index));
        }
        let start = self.w.len();
        let r = self
            .w
            .u8(index)
            .ok()
            .and_then(|_| c.encode(&mut self.w).ok());
        if r.is_none() {
            self.w.truncate(start);
            return Err(CallError::OutputTooLarge(index));
        }
        self.count += 1;
        self.set |= bit;
        Ok(())
    }

    /// The number of declared outputs.
    pub fn declared(&self) -> usize {
        self.decl.len()
    }

    /// Checks every output is set, patches the count in and returns the length.
    fn finish(mut self) -> Result<usize, CallError> {
        for i in 0..self.decl.len() {
            if self.set & (1 << i) == 0 {
                return Err(CallError::MissingOutput(i as u8));
            }
        }
        self.w
            .patch_u8(0, self.count)
            .map_err(|_| CallError::OutputTooLarge(0))?;
        Ok(self.w.len())
    }
}

/// Runs `imp` once on `inputs` (already of the declared types), outside
/// any runtime: a direct local call, as a host-side caller or a test makes
/// it. The outputs are written to `buf` and returned as an argument list.
pub fn call_direct<'b, I: Implementation>(
    imp: &mut I,
    inputs: &[Value<'_>],
    buf: &'b mut [u8],
) -> Result<Args<'b>, CallError> {
    let decl = imp.signature().outputs;
    let len = {
        let mut outputs = Outputs::new(buf, decl);
        imp.call(inputs, &mut outputs)?;
        outputs.finish()?
    };
    let mut r = Reader::new(&buf[..len]);
    Args::decode(&mut r).map_err(|_| CallError::OutputTooLarge(0))
}

/// A plain function: its signature and its body over decoded values.
pub trait Implementation {
    /// The function's signature (at most [`MAX_ARGS`] inputs and outputs).
    fn signature(&self) -> &'static Signature;

    /// The name the function answers to: its signature's, unless it was
    /// named at run time (a block made on a device, see
    /// [`crate::manager`]), at most 255 bytes.
    fn name(&self) -> &str {
        self.signature().name
    }

    /// Runs the function. `inputs[i]` is the value of input `i`, already of
    /// its declared type; every output must be [`set`](Outputs::set).
    fn call(&mut self, inputs: &[Value<'_>], outputs: &mut Outputs<'_>) -> Result<(), CallError>;

    /// The failure codes the function may refuse with, by name: sent with
    /// its signature when a host asks ([`crate::failure`]), so the host
    /// names a refusal from the function's own table. None by default.
    fn failures(&self) -> &'static [Failure] {
        &[]
    }

    /// The function's documentation, its `///` doc comment (the macros
    /// fill it in): sent with its signature when a host asks, the first
    /// sentence as its summary ([`crate::docs`]). In flash, never copied;
    /// at most [`MAX_DOCS`](crate::docs::MAX_DOCS) bytes. None by default.
    fn docs(&self) -> &'static str {
        ""
    }
}

/// An [`Implementation`] made of a signature and a closure or fn pointer.
pub struct FnImpl<F> {
    sig: &'static Signature,
    f: F,
}

impl<F> FnImpl<F>
where
    F: FnMut(&[Value<'_>], &mut Outputs<'_>) -> Result<(), CallError>,
{
    /// Wraps `f` as the body of `sig`.
    pub const fn new(sig: &'static Signature, f: F) -> Self {
        FnImpl { sig, f }
    }
}

impl<F> fmt::Debug for FnImpl<F> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("FnImpl")
            .field("sig", &self.sig.name)
            .finish()
    }
}

impl<F> Implementation for FnImpl<F>
where
    F: FnMut(&[Value<'_>], &mut Outputs<'_>) -> Result<(), CallError>,
{
    fn signature(&self) -> &'static Signature {
        self.sig
    }
    fn call(&mut self, inputs: &[Value<'_>], outputs: &mut Outputs<'_>) -> Result<(), CallError> {
        (self.f)(inputs, outputs)
    }
}

/// What a function counted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FunctionStats {
    /// Times the function ran successfully (calls and dataflow).
    pub runs: u32,
    /// RPC calls answered successfully.
    pub calls: u32,
    /// Pipe datagrams accepted.
    pub datagrams: u32,
    /// Requests and datagrams refused with an error.
    pub refused: u32,
    /// Runs whose `call` failed.
    pub run_errors: u32,
    /// Outputs not sent because they had not changed (on-change mode).
    pub suppressed: u32,
    /// Replies and error reports that could not be sent.
    pub reply_drops: u32,
    /// Packets that could not be read at all (transport header, stray replies).
    pub malformed: u32,
    /// Signature replies too long for the route's MTU, sent in segments.
    pub segmented_replies: u32,
}

/// What a handled request answers with.
enum Answer {
    Body(ReplyBody<'static>),
    Signature(SignatureParts),
    Outputs,
}

/// A PIPES function with `PIPES` pipe slots, `Q` queued datagrams per pipe
/// and `B`-byte stores (see the module docs).
pub struct PipesFunction<I, const PIPES: usize = 2, const Q: usize = 2, const B: usize = 64> {
    imp: I,
    sig: &'static Signature,
    inputs: [[u8; B]; MAX_ARGS],
    input_len: [usize; MAX_ARGS],
    fresh: u16,
    input_mode: InputMode,
    output_mode: OutputMode,
    next_timer: Option<Instant>,
    out: [u8; B],
    out_len: usize,
    last_sent: [u8; B],
    last_sent_len: Option<usize>,
    pipes: [Option<PipeState<Q, B>>; PIPES],
    reply_ttl: u16,
    stats: FunctionStats,
    last_error: Option<ControlError>,
    /// Sends a signature reply longer than one packet, over several loops.
    seg: SegmentSender,
    /// The transport header of the signature reply `seg` is sending.
    seg_reply: Transport,
    /// The parts of the description that reply carries.
    seg_parts: SignatureParts,
    /// The function's failure table (checked).
    failures: &'static [Failure],
}

/// A signature reply, `[transport][2][0][signature][tail]`, read a window
/// at a time so that it can go out in segments without a buffer of its own.
struct SignatureReply<'a> {
    transport: Transport,
    name: &'a str,
    sig: &'static Signature,
    parts: SignatureParts,
    failures: &'static [Failure],
    docs: &'static str,
}

impl SegmentSource for SignatureReply<'_> {
    fn len(&self) -> usize {
        self.transport.encoded_len()
            + 2
            + self.sig.encoded_len_named(self.name)
            + tail_len(self.parts, self.failures, self.docs)
    }

    fn read_at(&self, offset: usize, out: &mut [u8]) -> usize {
        let mut w = Window::new(offset, out);
        let mut head = [0u8; 3];
        let n = self.transport.encode(&mut head).unwrap_or(0);
        w.put(&head[..n]);
        w.put(&[ControlKey::GetSignature.to_u8(), 0]);
        self.sig.write_pieces_named(self.name, &mut w);
        write_tail(&mut w, self.parts, self.failures, self.docs);
        w.written()
    }
}

impl<I, const PIPES: usize, const Q: usize, const B: usize> fmt::Debug
    for PipesFunction<I, PIPES, Q, B>
{
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("PipesFunction")
            .field("name", &self.sig.name)
            .field("input_mode", &self.input_mode)
            .field("output_mode", &self.output_mode)
            .field("stats", &self.stats)
            .finish()
    }
}

impl<I: Implementation, const PIPES: usize, const Q: usize, const B: usize>
    PipesFunction<I, PIPES, Q, B>
{
    /// Wraps `imp`; refuses a signature beyond the limits.
    pub fn new(imp: I) -> Result<Self, SignatureError> {
        const {
            assert!(PIPES < ANY_SLOT as usize, "at most 254 pipe slots");
            assert!(B >= 8, "stores must hold at least 8 bytes");
        }
        let sig = imp.signature();
        sig.check()?;
        let failures = imp.failures();
        check_failures(failures)?;
        // Checked here, read from `imp` when sent: no copy, not even of
        // the pointer.
        check_docs(imp.docs())?;
        Ok(PipesFunction {
            imp,
            sig,
            inputs: [[0; B]; MAX_ARGS],
            input_len: [0; MAX_ARGS],
            fresh: 0,
            input_mode: InputMode::default(),
            output_mode: OutputMode::default(),
            next_timer: None,
            out: [0; B],
            out_len: 0,
            last_sent: [0; B],
            last_sent_len: None,
            pipes: core::array::from_fn(|_| None),
            reply_ttl: DEFAULT_REPLY_TTL,
            stats: FunctionStats::default(),
            last_error: None,
            seg: SegmentSender::new(),
            seg_reply: Transport::Raw,
            seg_parts: SignatureParts::NONE,
            failures,
        })
    }

    /// The same function with replies that live `ttl` µs.
    pub fn with_reply_ttl(mut self, ttl: u16) -> Self {
        self.reply_ttl = ttl;
        self
    }

    /// The signature.
    pub fn signature(&self) -> &'static Signature {
        self.sig
    }

    /// The implementation.
    pub fn implementation(&self) -> &I {
        &self.imp
    }

    /// The implementation, mutably.
    pub fn implementation_mut(&mut self) -> &mut I {
        &mut self.imp
    }

    /// The counters.
    pub fn stats(&self) -> &FunctionStats {
        &self.stats
    }

    /// The last error the function reported or hit.
    pub fn last_error(&self) -> Option<ControlError> {
        self.last_error
    }

    /// The input mode.
    pub fn input_mode(&self) -> InputMode {
        self.input_mode
    }

    /// Sets the input mode (a timer restarts from the next poll).
    pub fn set_input_mode(&mut self, mode: InputMode) {
        self.input_mode = mode;
        self.next_timer = None;
    }

    /// The output mode.
    pub fn output_mode(&self) -> OutputMode {
        self.output_mode
    }

    /// Sets the output mode.
    pub fn set_output_mode(&mut self, mode: OutputMode) {
        self.output_mode = mode;
        self.last_sent_len = None;
    }

    /// The value stored for input `index`, if it holds one.
    pub fn input(&self, index: usize) -> Option<Value<'_>> {
        let n = *self.input_len.get(index)?;
        let bytes = self.inputs.get(index)?.get(..n)?;
        if n == 0 {
            return None;
        }
        Value::from_bytes(bytes).ok()
    }

    /// Whether input `index` got a value since the function last ran.
    pub fn is_fresh(&self, index: usize) -> bool {
        index < MAX_ARGS && self.fresh & (1 << index) != 0
    }

    /// The outputs of the last successful run.
    pub fn last_outputs(&self) -> Option<Args<'_>> {
        let b = self.out.get(..self.out_len).filter(|b| !b.is_empty())?;
        Args::decode(&mut Reader::new(b)).ok()
    }

    /// Pipe slot `slot`, if it holds a pipe.
    pub fn pipe(&self, slot: usize) -> Option<&PipeState<Q, B>> {
        self.pipes.get(slot)?.as_ref()
    }

    /// Sets pipe slot `slot` ([`ANY_SLOT`]: the first free one) and returns
    /// the slot used. The pipe starts with an empty queue and zero counters.
    pub fn set_pipe(&mut self, slot: u8, pipe: PipeConfig) -> Result<u8, ControlError> {
        if let Some(p) = pipe
            .argmap()
            .iter()
            .find(|p| usize::from(p.output) >= self.sig.outputs.len())
        {
            return Err(ControlError::BadArgmap(p.output));
        }
        let slot = if slot == ANY_SLOT {
            self.pipes
                .iter()
                .position(Option::is_none)
                .ok_or(ControlError::PipeTableFull)? as u8
        } else {
            slot
        };
        let entry = self
            .pipes
            .get_mut(usize::from(slot))
            .ok_or(ControlError::NoSuchPipe(slot))?;
        *entry = Some(PipeState::new(pipe));
        Ok(slot)
    }

    /// Sets how the acknowledged pipe in slot `slot` retransmits: wait
    /// `timeout` for each reply, send again at most `retries` times.
    /// Pipes start with [`DEFAULT_ACK_TIMEOUT`] and
    /// [`DEFAULT_ACK_RETRIES`]; setting the slot again resets them. (A
    /// best-effort pipe keeps the setting but does not use it.)
    ///
    /// [`DEFAULT_ACK_TIMEOUT`]: crate::pipe::DEFAULT_ACK_TIMEOUT
    /// [`DEFAULT_ACK_RETRIES`]: crate::pipe::DEFAULT_ACK_RETRIES
    pub fn set_ack_policy(
        &mut self,
        slot: u8,
        timeout: Duration,
        retries: u8,
    ) -> Result<(), ControlError> {
        let p = self
            .pipes
            .get_mut(usize::from(slot))
            .and_then(Option::as_mut)
            .ok_or(ControlError::NoSuchPipe(slot))?;
        p.ack_timeout = timeout;
        p.max_retries = retries;
        Ok(())
    }

    /// Empties pipe slot `slot` ([`ANY_SLOT`]: every slot), dropping what
    /// its queue held.
    pub fn wipe_pipe(&mut self, slot: u8) -> Result<(), ControlError> {
        if slot == ANY_SLOT {
            self.pipes.iter_mut().for_each(|p| *p = None);
            return Ok(());
        }
        let entry = self
            .pipes
            .get_mut(usize::from(slot))
            .ok_or(ControlError::NoSuchPipe(slot))?;
        *entry = None;
        Ok(())
    }

    fn all_inputs_mask(&self) -> u16 {
        ((1u32 << self.sig.inputs.len()) - 1) as u16
    }

    fn all_inputs_held(&self) -> bool {
        self.input_len
            .iter()
            .take(self.sig.inputs.len())
            .all(|n| *n > 0)
    }

    /// Checks a whole argument list against the inputs, then stores it.
    fn store(&mut self, args: &Args<'_>, fresh: bool) -> Result<(), ControlError> {
        for (index, v) in args.iter() {
            let arg = self
                .sig
                .inputs
                .get(usize::from(index))
                .ok_or(ControlError::NoSuchInput(index))?;
            let c = convert(&v, &arg.ty).map_err(|error| ControlError::Convert { index, error })?;
            if c.encoded_len().map_or(true, |n| n > B) {
                return Err(ControlError::TooLarge(index));
            }
        }
        for (index, v) in args.iter() {
            let i = usize::from(index);
            let (Some(arg), Some(buf)) = (self.sig.inputs.get(i), self.inputs.get_mut(i)) else {
                continue;
            };
            let Ok(c) = convert(&v, &arg.ty) else {
                continue;
            };
            let mut w = Writer::new(buf);
            let n = match c.encode(&mut w) {
                Ok(()) => w.len(),
                Err(_) => 0,
            };
            if let Some(l) = self.input_len.get_mut(i) {
                *l = n;
            }
            if fresh && n > 0 {
                self.fresh |= 1 << index;
            }
        }
        Ok(())
    }

    /// Runs the function on the stored inputs, leaving its outputs in `out`.
    fn run(&mut self) -> Result<(), ControlError> {
        let Self {
            imp,
            sig,
            inputs,
            input_len,
            out,
            out_len,
            ..
        } = self;
        let mut vals = [const { Value::Null }; MAX_ARGS];
        for (i, v) in vals.iter_mut().enumerate().take(sig.inputs.len()) {
            let n = input_len.get(i).copied().unwrap_or(0);
            let bytes = inputs.get(i).and_then(|b| b.get(..n)).unwrap_or(&[]);
            *v = Value::from_bytes(bytes).map_err(|_| ControlError::NoSuchInput(i as u8))?;
        }
        let inputs = vals.get(..sig.inputs.len()).unwrap_or(&[]);
        let mut o = Outputs::new(out, sig.outputs);
        let r = imp.call(inputs, &mut o).and_then(|()| o.finish());
        self.fresh = 0;
        match r {
            Ok(n) => {
                *out_len = n;
                self.stats.runs = self.stats.runs.wrapping_add(1);
                Ok(())
            }
            Err(e) => {
                self.out_len = 0;
                self.stats.run_errors = self.stats.run_errors.wrapping_add(1);
                let e = e.to_control();
                self.last_error = Some(e);
                Err(e)
            }
        }
    }

    /// Queues the last outputs on every pipe, unless on-change mode finds
    /// them unchanged.
    fn push_outputs(&mut self) {
        let Some(out) = self.out.get(..self.out_len) else {
            return;
        };
        if self.output_mode == OutputMode::OnChange {
            if self.last_sent_len.and_then(|n| self.last_sent.get(..n)) == Some(out) {
                self.stats.suppressed = self.stats.suppressed.wrapping_add(1);
                return;
            }
            if let Some(dst) = self.last_sent.get_mut(..out.len()) {
                dst.copy_from_slice(out);
                self.last_sent_len = Some(out.len());
            }
        }
        let Ok(outputs) = Args::decode(&mut Reader::new(out)) else {
            return;
        };
        for pipe in self.pipes.iter_mut().flatten() {
            let map = pipe.config;
            // An acknowledged pipe's datagram is a request; its sequence
            // number is written when it is first sent.
            let header = match map.delivery {
                PipeDelivery::BestEffort => Transport::Raw,
                PipeDelivery::Acked => Transport::Request(0),
            };
            pipe.push_with(|buf| {
                let h = header.encode(buf)?;
                let mut w = Writer::new(buf.get_mut(h..)?);
                let mut m = ArgsWriter::message(&mut w, MessageKey::PipeDatagram).ok()?;
                for p in map.argmap() {
                    let v = outputs.get(p.output)?;
                    m.push(p.input, &v).ok()?;
                }
                m.finish().ok()?;
                Some(h + w.len())
            });
        }
    }

    /// Sends what the pipes' queues hold while their ports are clear.
    fn flush(&mut self, tx: &mut PortTx<'_>) {
        for (slot, pipe) in self.pipes.iter_mut().enumerate() {
            let Some(pipe) = pipe else { continue };
            let offset = 1 + slot as u16;
            if pipe.config.delivery == PipeDelivery::Acked {
                flush_acked(pipe, offset, tx);
                continue;
            }
            while tx.clear_to_send_from(offset) {
                let Some(dgram) = pipe.front() else { break };
                let c = &pipe.config;
                match tx.send_from(offset, &c.route, c.port, c.ttl, dgram) {
                    Ok(()) => pipe.stats.sent = pipe.stats.sent.wrapping_add(1),
                    Err(SendError::NotClear(_)) => break,
                    Err(_) => pipe.stats.send_errors = pipe.stats.send_errors.wrapping_add(1),
                }
                pipe.pop();
            }
        }
    }

    /// Runs on dataflow and sends the outputs if the run succeeded.
    fn fire(&mut self) {
        if self.run().is_ok() {
            self.push_outputs();
        }
    }

    fn refuse(&mut self, e: ControlError) -> ControlError {
        self.stats.refused = self.stats.refused.wrapping_add(1);
        self.last_error = Some(e);
        e
    }

    /// Stores a pipe datagram's values and runs the function if the input
    /// mode says so.
    fn on_datagram(&mut self, args: &Args<'_>) -> Result<(), ControlError> {
        self.store(args, true).map_err(|e| self.refuse(e))?;
        self.stats.datagrams = self.stats.datagrams.wrapping_add(1);
        let all = self.all_inputs_mask();
        let go = match self.input_mode {
            InputMode::OnAnyFresh => self.fresh != 0 && self.all_inputs_held(),
            InputMode::OnAllFresh => self.fresh & all == all,
            InputMode::OnTimer(_) => false,
        };
        if go {
            self.fire();
        }
        Ok(())
    }

    fn on_request(&mut self, req: Request<'_>) -> Result<Answer, ControlError> {
        use ReplyBody as R;
        Ok(Answer::Body(match req {
            Request::PipeDatagram(a) => {
                self.on_datagram(&a)?;
                R::Done
            }
            Request::GetSignature => return Ok(Answer::Signature(SignatureParts::NONE)),
            Request::Describe(parts) => return Ok(Answer::Signature(parts)),
            Request::Call(a) => {
                let expected = self.sig.inputs.len() as u8;
                if a.len() != usize::from(expected) {
                    let got = a.len() as u8;
                    return Err(self.refuse(ControlError::WrongArgCount { expected, got }));
                }
                self.store(&a, false).map_err(|e| self.refuse(e))?;
                self.run()?;
                self.stats.calls = self.stats.calls.wrapping_add(1);
                self.push_outputs();
                return Ok(Answer::Outputs);
            }
            Request::GetPipeCount => R::PipeCount {
                slots: PIPES as u8,
                used: self.pipes.iter().flatten().count() as u8,
            },
            Request::GetPipe(slot) => {
                let Some(p) = self.pipes.get(usize::from(slot)) else {
                    return Err(self.refuse(ControlError::NoSuchPipe(slot)));
                };
                R::Pipe {
                    slot,
                    pipe: p.as_ref().map(|p| p.config),
                }
            }
            Request::GetPipeStats(slot) => {
                let Some(p) = self.pipes.get(usize::from(slot)).and_then(Option::as_ref) else {
                    return Err(self.refuse(ControlError::NoSuchPipe(slot)));
                };
                R::PipeStats {
                    slot,
                    stats: p.stats(),
                }
            }
            Request::SetPipe { slot, pipe } => {
                R::PipeSet(self.set_pipe(slot, pipe).map_err(|e| self.refuse(e))?)
            }
            Request::WipePipe(slot) => {
                self.wipe_pipe(slot).map_err(|e| self.refuse(e))?;
                R::Done
            }
            Request::GetInputMode => R::InputMode(self.input_mode),
            Request::SetInputMode(m) => {
                self.set_input_mode(m);
                R::Done
            }
            Request::GetOutputMode => R::OutputMode(self.output_mode),
            Request::SetOutputMode(m) => {
                self.set_output_mode(m);
                R::Done
            }
        }))
    }

    /// Sends `[transport][key][...]` back to the sender from the control port.
    fn answer(
        &mut self,
        tx: &mut PortTx<'_>,
        d: &Delivery<'_>,
        transport: Transport,
        key: u8,
        result: Result<Answer, ControlError>,
    ) {
        let (sig, failures, docs) = (self.sig, self.failures, self.imp.docs());
        let name = self.imp.name();
        let out = self.out.get(..self.out_len).unwrap_or(&[]);
        let r = tx.send_with(0, &d.reply_route, d.source_port, self.reply_ttl, |buf| {
            if let Ok(Answer::Signature(parts)) = &result {
                if name != sig.name {
                    // Named at run time: the reply is written with the
                    // name, as a segmented one would be.
                    let reply = SignatureReply {
                        transport,
                        name,
                        sig,
                        parts: *parts,
                        failures,
                        docs,
                    };
                    let len = reply.len();
                    return (len <= buf.len()).then(|| reply.read_at(0, buf));
                }
            }
            let h = transport.encode(buf)?;
            let mut w = Writer::new(buf.get_mut(h..)?);
            let ok = match &result {
                Err(e) => encode_error(&mut w, key, e),
                Ok(Answer::Signature(parts)) => {
                    encode_described_reply(&mut w, sig, *parts, failures, docs)
                }
                Ok(Answer::Outputs) => (|| {
                    w.u8(key)?;
                    w.u8(0)?;
                    w.bytes(out)
                })()
                .map_err(Into::into),
                Ok(Answer::Body(b)) => Reply {
                    key,
                    result: Ok(*b),
                }
                .encode(&mut w),
            };
            ok.ok()?;
            Some(h + w.len())
        });
        match (r, &result) {
            (Ok(()), _) => {}
            (Err(SendError::TooLong), Ok(Answer::Signature(parts))) => {
                // Longer than the route allows: send it in segments.
                self.stats.segmented_replies = self.stats.segmented_replies.wrapping_add(1);
                self.seg_reply = transport;
                self.seg_parts = *parts;
                let len = self.signature_reply().len();
                // With its docs, a reply may take dozens of segments (2 KiB
                // of text on a 64-byte link): it gets the longest time to
                // live, whatever the function's reply TTL, to go out whole.
                let ttl = SEGMENTED_REPLY_TTL;
                self.seg
                    .start(tx.now(), &d.reply_route, d.source_port, ttl, len);
                self.send_segments(tx);
            }
            (Err(_), _) => self.stats.reply_drops = self.stats.reply_drops.wrapping_add(1),
        }
    }

    fn signature_reply(&self) -> SignatureReply<'_> {
        SignatureReply {
            transport: self.seg_reply,
            name: self.imp.name(),
            sig: self.sig,
            parts: self.seg_parts,
            failures: self.failures,
            docs: self.imp.docs(),
        }
    }

    /// Sends what the port is clear to send of a segmented reply.
    fn send_segments(&mut self, tx: &mut PortTx<'_>) {
        if !self.seg.is_busy() {
            return;
        }
        // Built from the fields (not `signature_reply`): the sender is
        // borrowed mutably beside them.
        let src = SignatureReply {
            transport: self.seg_reply,
            name: self.imp.name(),
            sig: self.sig,
            parts: self.seg_parts,
            failures: self.failures,
            docs: self.imp.docs(),
        };
        if let Pump::Abandoned(_) = self.seg.pump(tx, 0, &src) {
            self.stats.reply_drops = self.stats.reply_drops.wrapping_add(1);
        }
    }

    /// What the sender of segmented replies counted.
    pub fn segment_stats(&self) -> &osap_core::segment::SenderStats {
        self.seg.stats()
    }

    fn on_control(&mut self, d: &Delivery<'_>, tx: &mut PortTx<'_>) {
        let Ok((transport, body)) = Transport::decode(d.payload) else {
            self.stats.malformed = self.stats.malformed.wrapping_add(1);
            return;
        };
        match transport {
            Transport::Raw => {
                let r = match Request::parse(body) {
                    Ok(Request::PipeDatagram(a)) => self.on_datagram(&a),
                    Ok(_) => {
                        // Only datagrams travel raw; anything else has no way to be answered.
                        self.stats.malformed = self.stats.malformed.wrapping_add(1);
                        Ok(())
                    }
                    Err(e) => Err(self.refuse(e.to_control())),
                };
                if let Err(e) = r {
                    self.answer(tx, d, Transport::Raw, ControlKey::PipeError.to_u8(), Err(e));
                }
            }
            Transport::Request(seq) => {
                let key = body.first().copied().unwrap_or(0);
                let result = match Request::parse(body) {
                    Ok(req) => self.on_request(req),
                    Err(e) => Err(self.refuse(e.to_control())),
                };
                self.answer(tx, d, Transport::Reply(seq), key, result);
            }
            Transport::Reply(_) => {
                self.stats.malformed = self.stats.malformed.wrapping_add(1);
            }
        }
    }

    fn on_pipe_port(&mut self, slot: usize, d: &Delivery<'_>) {
        // A reply to an acknowledged pipe's datagram.
        if let Ok((Transport::Reply(seq), body)) = Transport::decode(d.payload) {
            let reply = Reply::parse(body)
                .ok()
                .filter(|r| r.key == ControlKey::PipeDatagram.to_u8());
            match (reply, self.pipes.get_mut(slot).and_then(Option::as_mut)) {
                (Some(r), Some(p)) => {
                    // A duplicate or late reply changes nothing.
                    let _ = p.on_reply(seq, r.result.map(|_| ()));
                }
                _ => self.stats.malformed = self.stats.malformed.wrapping_add(1),
            }
            return;
        }
        let report = Transport::decode(d.payload)
            .ok()
            .filter(|(t, _)| *t == Transport::Raw)
            .and_then(|(_, b)| Reply::parse(b).ok())
            .filter(|r| r.key == ControlKey::PipeError.to_u8());
        match (report, self.pipes.get_mut(slot).and_then(Option::as_mut)) {
            (Some(Reply { result: Err(e), .. }), Some(p)) => {
                p.stats.remote_errors = p.stats.remote_errors.wrapping_add(1);
                p.stats.last_remote_error = Some(e);
            }
            _ => self.stats.malformed = self.stats.malformed.wrapping_add(1),
        }
    }
}

/// Sends an acknowledged pipe's front datagram (one in flight at a time, so
/// order is kept), sends it again when its reply is late, and drops it after
/// the last retry.
fn flush_acked<const Q: usize, const B: usize>(
    pipe: &mut PipeState<Q, B>,
    offset: u16,
    tx: &mut PortTx<'_>,
) {
    let c = pipe.config;
    loop {
        let now = tx.now();
        match pipe.ack_step(now) {
            AckStep::Wait => return,
            AckStep::GiveUp => {
                pipe.give_up();
                continue;
            }
            AckStep::Resend => {
                let Some(seq) = pipe.in_flight_seq() else {
                    return;
                };
                if !tx.clear_to_send_from(offset) {
                    return;
                }
                let Some(dgram) = pipe.front() else { return };
                match tx.send_from(offset, &c.route, c.port, c.ttl, dgram) {
                    Ok(()) => pipe.mark_sent(seq, now),
                    Err(SendError::NotClear(_)) => {}
                    Err(_) => {
                        pipe.stats.send_errors = pipe.stats.send_errors.wrapping_add(1);
                        pipe.pop();
                        continue;
                    }
                }
                return;
            }
            AckStep::SendNew => {
                if !tx.clear_to_send_from(offset) {
                    return;
                }
                let Some((seq, dgram)) = pipe.front_as_new_request() else {
                    // Nothing waits, or the datagram is not a request
                    // (queued before the pipe was set acknowledged): drop it.
                    if pipe.front().is_none() {
                        return;
                    }
                    pipe.stats.send_errors = pipe.stats.send_errors.wrapping_add(1);
                    pipe.pop();
                    continue;
                };
                match tx.send_from(offset, &c.route, c.port, c.ttl, dgram) {
                    Ok(()) => {
                        pipe.mark_sent(seq, now);
                        return;
                    }
                    Err(SendError::NotClear(_)) => return,
                    Err(_) => {
                        pipe.stats.send_errors = pipe.stats.send_errors.wrapping_add(1);
                        pipe.pop();
                    }
                }
            }
        }
    }
}

impl<I: Implementation, const PIPES: usize, const Q: usize, const B: usize> Port
    for PipesFunction<I, PIPES, Q, B>
{
    fn port_count(&self) -> u16 {
        1 + PIPES as u16
    }

    fn info(&self, offset: u16) -> PortInfo<'_> {
        if offset == 0 {
            PortInfo {
                type_name: FUNCTION_PORT_TYPE,
                name: self.imp.name(),
            }
        } else {
            PortInfo {
                type_name: PIPE_PORT_TYPE,
                name: "",
            }
        }
    }

    fn on_packet(&mut self, d: Delivery<'_>, tx: &mut PortTx<'_>) {
        if d.offset == 0 {
            self.on_control(&d, tx);
        } else {
            self.on_pipe_port(usize::from(d.offset - 1), &d);
        }
        self.flush(tx);
        self.send_segments(tx);
    }

    fn wake_at(&self) -> Option<Instant> {
        let timer = match (self.input_mode, self.next_timer) {
            // Not started yet: the first poll starts it.
            (InputMode::OnTimer(_), None) => Some(Instant::ZERO),
            (InputMode::OnTimer(_), Some(t)) => Some(t),
            _ => None,
        };
        let acks = self
            .pipes
            .iter()
            .flatten()
            .filter_map(|p| p.ack_deadline())
            .min();
        [timer, acks, self.seg.wake_at()]
            .into_iter()
            .flatten()
            .min()
    }

    fn poll(&mut self, tx: &mut PortTx<'_>) {
        if let InputMode::OnTimer(iv) = self.input_mode {
            let now = tx.now();
            let iv = Duration::from_micros(iv.into());
            match self.next_timer {
                None => self.next_timer = Some(now + iv),
                Some(t) if now >= t => {
                    // Catch up without bursts after a long gap.
                    let next = t + iv;
                    self.next_timer = Some(if next <= now { now + iv } else { next });
                    if self.all_inputs_held() {
                        self.fire();
                    }
                }
                Some(_) => {}
            }
        }
        self.flush(tx);
        self.send_segments(tx);
    }
}
