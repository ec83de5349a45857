//! Captures through a module's `sample_block` (see
//! [`osap_module::sampler`]): the module samples up to three of its
//! functions on its own timer into stamped blocks, one datagram each, and
//! numbers them, so every sample lost on the way is counted.
//!
//! [`plan`] picks, per module, the sources its `sample_block` can take;
//! [`Decoder`] turns the blocks that arrive into rows, counting what never
//! arrived; [`Recorder::wire_group`] and [`Recorder::unwire_group`] wire
//! and unwire one module's group.

use super::*;
use osap_core::codec::Reader;
use osap_host::som::model::SomRuntime;
use osap_module::sampler::{NO_SOURCE, SOURCES};
use pipes_core::control::OutputMode;
use pipes_core::Args;

/// The longest a sample waits in an open block on its module, µs: at low
/// rates a block closes by age before it fills.
pub const BLOCK_LATENCY_US: u32 = 20_000;

/// How long [`Recorder::finish`] waits for a module's last block, µs of
/// machine time, before it decodes the copy the closing call's reply
/// carries.
const LAST_BLOCK_WAIT: Duration = Duration::from_millis(200);

/// The name of the module function that samples in blocks.
pub(super) const SAMPLE_BLOCK: &str = "sample_block";

/// One module's sources sampled by its `sample_block`.
#[derive(Debug, Clone)]
pub(super) struct Group {
    /// The module's runtime.
    pub(super) runtime: String,
    /// Indices into the resolved sources, in the order the block records
    /// them.
    pub(super) members: Vec<usize>,
    /// Per member: its function's index in the module's table and its
    /// argument.
    pub(super) sources: Vec<(u8, u8)>,
}

/// Which sources go through a `sample_block` (one group per module) and
/// which are sampled one datagram at a time (a module without
/// `sample_block`, one whose `sample_block` another capture uses, a
/// source with an input other than one `u8`, a fourth source on a module).
#[derive(Debug, Clone, Default)]
pub(super) struct Plan {
    pub(super) groups: Vec<Group>,
    pub(super) singles: Vec<usize>,
}

impl Plan {
    /// Whether source `i` is sampled in blocks.
    pub(super) fn in_blocks(&self, i: usize) -> bool {
        self.groups.iter().any(|g| g.members.contains(&i))
    }
}

/// Whether `rt`'s `sample_block` is there, as this build knows it, and
/// free.
fn free_sampler(rt: &SomRuntime) -> bool {
    let Some(f) = rt.functions.iter().find(|f| f.name == SAMPLE_BLOCK) else {
        return false;
    };
    let names = |list: &[osap_host::som::model::SomArg]| {
        list.iter().map(|a| a.name.clone()).collect::<Vec<_>>()
    };
    let expected = osap_module::functions::signature::sample_block.outputs;
    f.pipes.is_empty()
        && f.inputs.len() == 8
        && names(&f.outputs)
            == expected
                .iter()
                .map(|a| a.name.to_string())
                .collect::<Vec<_>>()
}

/// The block-sampler's `(function index, argument)` of source `r` on `rt`,
/// if it can take it.
fn sampler_source(r: &Resolved, rt: &SomRuntime) -> Option<(u8, u8)> {
    let index = rt
        .built_functions()
        .position(|f| f.name == r.function.function)?;
    let index = u8::try_from(index).ok().filter(|i| *i != NO_SOURCE)?;
    let arg = match r.args.as_slice() {
        [] => 0,
        [(0, Value::U8(a))] => *a,
        _ => return None,
    };
    Some((index, arg))
}

/// Groups `resolved` by module where the module's `sample_block` can take
/// them.
pub(super) fn plan(resolved: &[Resolved], manager: &Manager) -> Plan {
    let som = manager.som();
    let mut plan = Plan::default();
    for (i, r) in resolved.iter().enumerate() {
        let rt = som
            .runtime_index(&r.function.runtime)
            .ok()
            .and_then(|ri| som.runtimes.get(ri))
            .filter(|rt| free_sampler(rt));
        let source = rt.and_then(|rt| sampler_source(r, rt));
        let group = plan
            .groups
            .iter_mut()
            .find(|g| g.runtime == r.function.runtime);
        match (source, group) {
            (Some(s), Some(g)) if g.members.len() < SOURCES => {
                g.members.push(i);
                g.sources.push(s);
            }
            (Some(s), None) => plan.groups.push(Group {
                runtime: r.function.runtime.clone(),
                members: vec![i],
                sources: vec![s],
            }),
            _ => plan.singles.push(i),
        }
    }
    plan
}

/// What a block's records hold of one source.
#[derive(Debug, Clone)]
struct Member {
    /// The source's outputs: its time first when stamped, then the
    /// recorded ones (output indices of its function).
    outputs: Vec<u8>,
    stamped: bool,
    first_series: u16,
    /// The newest time written.
    last: Option<u64>,
}

/// A module's blocks turned into rows, in order, with what was lost.
pub(super) struct Decoder {
    /// The session the capture set: another's blocks are not its.
    session: u32,
    members: Vec<Member>,
    tx: SyncSender<Row>,
    shared: Arc<Shared>,
    /// The sequence number the next block should carry.
    next_seq: u32,
    /// The index its first sample should have.
    next_first: u32,
    /// Blocks that would not decode.
    malformed: u64,
}

impl std::fmt::Debug for Decoder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Decoder")
            .field("next_seq", &self.next_seq)
            .field("next_first", &self.next_first)
            .finish_non_exhaustive()
    }
}

/// A block as `sample_block` sends it.
#[derive(Debug, Clone, Copy)]
pub(super) struct BlockIn<'a> {
    pub(super) session: u32,
    pub(super) seq: u32,
    pub(super) first: u32,
    pub(super) time: u64,
    pub(super) records: &'a [u8],
}

impl<'a> BlockIn<'a> {
    /// The block in `sample_block`'s outputs (or a pipe's inputs, in the
    /// same order).
    pub(super) fn from_values(v: &'a [Value<'static>]) -> Option<BlockIn<'a>> {
        match v {
            [Value::U32(seq), Value::U32(first), Value::U64(time), Value::Array(a), Value::U32(session), ..]
                if a.elem() == ScalarType::U8 =>
            {
                Some(BlockIn {
                    session: *session,
                    seq: *seq,
                    first: *first,
                    time: *time,
                    records: a.bytes(),
                })
            }
            _ => None,
        }
    }
}

impl Decoder {
    /// The blocks of `resolved`'s sources `members` (their series from
    /// `first_series[i]`), into `tx`.
    fn new(
        session: u32,
        resolved: &[Resolved],
        members: &[usize],
        first_series: &[u16],
        tx: SyncSender<Row>,
        shared: Arc<Shared>,
    ) -> Decoder {
        Decoder {
            session,
            members: members
                .iter()
                .map(|&i| Member {
                    outputs: resolved[i].outputs.clone(),
                    stamped: resolved[i].stamped,
                    first_series: first_series[i],
                    last: None,
                })
                .collect(),
            tx,
            shared,
            next_seq: 1,
            next_first: 0,
            malformed: 0,
        }
    }

    /// Samples the module took this session that were decoded or counted
    /// lost: the index the next block's first sample should have.
    #[cfg(test)]
    fn accounted(&self) -> u32 {
        self.next_first
    }

    /// Whether block `seq` was taken already.
    pub(super) fn has(&self, seq: u32) -> bool {
        seq < self.next_seq
    }

    /// Takes one block: samples between the last block and this one are
    /// counted lost, then every record becomes rows. Block 0 (none closed
    /// yet), blocks already taken and another session's blocks change
    /// nothing.
    pub(super) fn take(&mut self, b: BlockIn<'_>) {
        if b.session != self.session || b.seq == 0 || self.has(b.seq) {
            return;
        }
        self.lose(b.first.wrapping_sub(self.next_first));
        let mut r = Reader::new(b.records);
        let mut n = 0u32;
        while !r.is_empty() {
            match self.record(&mut r, b.time) {
                Some(()) => n += 1,
                None => {
                    // The rest cannot be framed: counted lost below by the
                    // next block's `first`.
                    self.malformed += 1;
                    tracing::warn!("capture: a malformed block from a module's sample_block");
                    break;
                }
            }
        }
        self.next_seq = b.seq.wrapping_add(1);
        let next = b.first.wrapping_add(n);
        let taken = next.wrapping_sub(self.next_first);
        if taken < u32::MAX / 2 {
            let taken = u64::from(taken) * self.members.len() as u64;
            self.shared.taken.fetch_add(taken, Ordering::Relaxed);
        }
        self.next_first = next;
    }

    /// Counts `n` samples lost (each is one sample of every source).
    pub(super) fn lose(&mut self, n: u32) {
        // A gap beyond half the range is a module that restarted its
        // session (a reboot): nothing this capture can count.
        if n > 0 && n < u32::MAX / 2 {
            let n = u64::from(n) * self.members.len() as u64;
            self.shared.lost.fetch_add(n, Ordering::Relaxed);
        }
    }

    /// One record: its stamp, then each source's outputs.
    fn record(&mut self, r: &mut Reader<'_>, time: u64) -> Option<()> {
        let stamp = time.saturating_add(u64::from(r.u32().ok()?));
        for k in 0..self.members.len() {
            let args = Args::decode(r).ok()?;
            if args.is_empty() {
                // The source failed on the module this time.
                self.shared.lost.fetch_add(1, Ordering::Relaxed);
                continue;
            }
            self.emit(k, &args, stamp);
        }
        Some(())
    }

    fn emit(&mut self, k: usize, args: &Args<'_>, stamp: u64) {
        let m = &mut self.members[k];
        let time = if m.stamped {
            match m.outputs.first().and_then(|o| args.get(*o)) {
                Some(Value::U64(t)) => t,
                _ => {
                    self.malformed += 1;
                    return;
                }
            }
        } else {
            stamp
        };
        if m.last.is_some_and(|l| time <= l) {
            self.shared.stale.fetch_add(1, Ordering::Relaxed);
            return;
        }
        m.last = Some(time);
        let recorded = &m.outputs[usize::from(m.stamped)..];
        for (j, out) in recorded.iter().enumerate() {
            let value = args
                .get(*out)
                .map(|v| v.to_owned_value())
                .and_then(|v| v.as_f64().or_else(|| lossy_f64(&v)))
                .unwrap_or(f64::NAN);
            let row = Row {
                time_us: time,
                series: m.first_series + j as u16,
                value,
            };
            match self.tx.try_send(row) {
                Ok(()) => self.shared.received.fetch_add(1, Ordering::Relaxed),
                Err(TrySendError::Full(_)) => self.shared.dropped.fetch_add(1, Ordering::Relaxed),
                Err(TrySendError::Disconnected(_)) => return,
            };
        }
    }
}

/// A wired group: what finishing it needs.
pub(super) struct GroupWired {
    pub(super) decoder: Arc<Mutex<Decoder>>,
    /// `sample_block`'s inputs, latency included.
    pub(super) inputs: Vec<Value<'static>>,
    /// Its input mode before the capture.
    pub(super) mode: InputMode,
}

/// A session number no earlier capture of this process used, and unlikely
/// to be another process's.
fn session(id: u32) -> u32 {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.subsec_nanos());
    nanos ^ std::process::id().rotate_left(16) ^ id.rotate_left(8)
}

fn lock(d: &Mutex<Decoder>) -> std::sync::MutexGuard<'_, Decoder> {
    d.lock().unwrap_or_else(|p| p.into_inner())
}

impl Recorder {
    /// Wires one module's group: a host function that decodes its blocks,
    /// a pipe from `sample_block` to it, the sources as its inputs, and its
    /// timer.
    pub(super) async fn wire_group(
        &mut self,
        group: &Group,
        resolved: &[Resolved],
        first_series: &[u16],
        tx: SyncSender<Row>,
        period_us: u32,
    ) -> Result<(), CaptureError> {
        let source = FnRef::new(group.runtime.clone(), SAMPLE_BLOCK);
        let module = &resolved[group.members[0]].spec.module;
        let name = format!("capture{}.{module}.{SAMPLE_BLOCK}", self.id);
        let session = session(self.id);
        let decoder = Arc::new(Mutex::new(Decoder::new(
            session,
            resolved,
            &group.members,
            first_series,
            tx,
            self.shared.clone(),
        )));
        let body = {
            let decoder = decoder.clone();
            move |ins: &[Value<'static>]| {
                let block = BlockIn::from_values(ins).ok_or_else(HostFnError::bad_input)?;
                lock(&decoder).take(block);
                Ok(Vec::new())
            }
        };
        let inputs = [
            ("seq", Type::Scalar(ScalarType::U32)),
            ("first", Type::Scalar(ScalarType::U32)),
            ("time", Type::Scalar(ScalarType::U64)),
            ("samples", Type::Array(ScalarType::U8)),
            ("session", Type::Scalar(ScalarType::U32)),
        ];
        let function = HostFunction::new(&name, &inputs, &[], body)?;
        let (mut manager, dest, port) = define_sink(&self.machine, &name, function).await?;
        let mode = manager
            .som()
            .runtime_index(&source.runtime)
            .ok()
            .and_then(|ri| manager.som().function(ri, SAMPLE_BLOCK))
            .map(|f| InputMode::from(f.input_mode))
            .unwrap_or_default();
        let mut values = Vec::new();
        for k in 0..SOURCES {
            let (f, a) = group.sources.get(k).copied().unwrap_or((NO_SOURCE, 0));
            values.push(Value::U8(f));
            values.push(Value::U8(a));
        }
        values.push(Value::U32(BLOCK_LATENCY_US));
        values.push(Value::U32(session));
        self.wired.push(Wired {
            source: source.clone(),
            dest: dest.clone(),
            port,
            slot: None,
            group: Some(GroupWired {
                decoder,
                inputs: values.clone(),
                mode,
            }),
        });
        let pipe = manager
            .connect(
                &source,
                &dest,
                &[0, 1, 2, 3, 4],
                &[0, 1, 2, 3, 4],
                PipeOptions::default(),
            )
            .await?;
        if let Some(w) = self.wired.last_mut() {
            w.slot = Some(pipe.slot);
        }
        // The timer first: with it, the push below stores the inputs
        // without a run (a run before the timer's first period would be a
        // sample off the grid), and the timer runs nothing until every
        // input is held.
        manager
            .set_output_mode(&source, OutputMode::OnChange)
            .await?;
        manager
            .set_input_mode(&source, InputMode::OnTimer(period_us))
            .await?;
        let pushed: Vec<(u8, Value<'static>)> = values
            .into_iter()
            .enumerate()
            .map(|(i, v)| (i as u8, v))
            .collect();
        manager.function(&source)?.push(&pushed).await?;
        Ok(())
    }

    /// Stops a group's timer and closes its open block; the samples the
    /// module took that never arrived are counted lost.
    pub(super) async fn unwire_group(&self, manager: &mut Manager, w: &Wired, g: &GroupWired) {
        if let Err(e) = manager.set_input_mode(&w.source, g.mode).await {
            tracing::warn!("capture: {}: timer not restored: {e}", w.source);
        }
        let mut closing = g.inputs.clone();
        if let Some(latency) = closing.get_mut(2 * SOURCES) {
            *latency = Value::U32(0);
        }
        let last = match manager.function(&w.source) {
            Ok(f) => f.call(&closing).await,
            Err(e) => Err(e),
        };
        let last = match last {
            Ok(v) => v,
            Err(e) => {
                // What it took after the last block that arrived is unknown.
                tracing::warn!("capture: {}: last block not closed: {e}", w.source);
                return;
            }
        };
        let Some(block) = BlockIn::from_values(&last) else {
            tracing::warn!(
                "capture: {}: the closing call's reply is not a block",
                w.source
            );
            return;
        };
        // The block also went down the pipe: wait for it, and what it
        // follows, a while.
        let waited = tokio::time::Instant::now();
        while !lock(&g.decoder).has(block.seq) && waited.elapsed() < LAST_BLOCK_WAIT {
            tokio::time::sleep(Duration::from_millis(2)).await;
        }
        lock(&g.decoder).take(block);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decoder(stamped: bool) -> (Decoder, Receiver<Row>, Arc<Shared>) {
        let (tx, rx) = std::sync::mpsc::sync_channel(1000);
        let shared = Arc::new(Shared::default());
        let d = Decoder {
            session: 9,
            members: vec![Member {
                outputs: if stamped { vec![0, 1] } else { vec![0] },
                stamped,
                first_series: 0,
                last: None,
            }],
            tx,
            shared: shared.clone(),
            next_seq: 1,
            next_first: 0,
            malformed: 0,
        };
        (d, rx, shared)
    }

    /// Records of `get_position`'s outputs `(time, position)` at `times`.
    /// Block `seq` of capture session `session`, its first sample's
    /// index `first`, stamped `time`.
    fn block(session: u32, seq: u32, first: u32, time: u64, records: &[u8]) -> BlockIn<'_> {
        BlockIn {
            session,
            seq,
            first,
            time,
            records,
        }
    }

    fn records(block_time: u64, times: &[u64]) -> Vec<u8> {
        let mut out = vec![0u8; 512];
        let mut w = osap_core::codec::Writer::new(&mut out);
        for (k, t) in times.iter().enumerate() {
            w.u32((t - block_time) as u32).unwrap();
            let mut a = pipes_core::ArgsWriter::new(&mut w).unwrap();
            a.push(0, &Value::U64(*t)).unwrap();
            a.push(1, &Value::F32(k as f32)).unwrap();
            a.finish().unwrap();
        }
        let n = w.len();
        out.truncate(n);
        out
    }

    #[test]
    fn blocks_become_rows_and_a_missing_block_is_counted() {
        let (mut d, rx, shared) = decoder(true);
        let one = records(1_000, &[1_000, 2_000, 3_000]);
        d.take(block(9, 1, 0, 1_000, &one));
        // Block 2 (samples 3, 4) never arrives.
        let three = records(6_000, &[6_000, 7_000]);
        d.take(block(9, 3, 5, 6_000, &three));
        let rows: Vec<Row> = rx.try_iter().collect();
        let times: Vec<u64> = rows.iter().map(|r| r.time_us).collect();
        assert_eq!(times, [1_000, 2_000, 3_000, 6_000, 7_000]);
        assert_eq!(shared.lost.load(Ordering::Relaxed), 2);
        assert_eq!(shared.taken.load(Ordering::Relaxed), 7);
        assert_eq!(d.accounted(), 7);
        // A duplicate, and the "none yet" block, change nothing.
        d.take(block(9, 3, 5, 6_000, &three));
        d.take(block(9, 0, 0, 0, &[]));
        // An earlier capture's block (another session) is not this one's.
        d.take(block(8, 40, 200, 9_000, &three));
        assert_eq!(rx.try_iter().count(), 0);
        assert_eq!(shared.lost.load(Ordering::Relaxed), 2);
    }

    #[test]
    fn unstamped_sources_take_the_modules_stamp_and_failures_count_as_lost() {
        let (mut d, rx, shared) = decoder(false);
        let mut out = vec![0u8; 64];
        let mut w = osap_core::codec::Writer::new(&mut out);
        w.u32(0).unwrap();
        let mut a = pipes_core::ArgsWriter::new(&mut w).unwrap();
        a.push(0, &Value::I64(-5)).unwrap();
        a.finish().unwrap();
        w.u32(250).unwrap();
        w.u8(0).unwrap(); // the source failed
        let n = w.len();
        d.take(block(9, 1, 0, 10_000, &out[..n]));
        let rows: Vec<Row> = rx.try_iter().collect();
        assert_eq!(rows.len(), 1);
        assert_eq!((rows[0].time_us, rows[0].value), (10_000, -5.0));
        assert_eq!(shared.lost.load(Ordering::Relaxed), 1);
        assert_eq!(d.accounted(), 2);
    }
}
