//! Simulated wire time: packets cross a link after the delay its model
//! gives them.
//!
//! Each direction of a link with latency has a *carrier* task: it takes the
//! packets the sending runtime queued on its [`ChannelLink`](osap_host::link::ChannelLink)
//! (through the [`LinkIo`] half), asks the link model
//! ([`crate::medium::Transmitter`], the discrete-event simulator's
//! model) when each would start onto the wire, reach the far end and become
//! visible there, and schedules its delivery. The model's transmit buffer
//! pushes back: the carrier takes the next packet only when the buffer has
//! room, so the rest wait in the sender's runtime, in deadline order. On a
//! flow-controlled link (USB CDC, TCP) the receiver pushes back too: the
//! carrier sends only while the far runtime's receive queue has room for
//! what is already in flight, as a device NAKs a full endpoint. A UART has
//! no such hand-shake, so a reader that falls behind loses frames there.
//!
//! Deliveries run on one [`Wire`] thread per machine rather than on tokio
//! timers, whose 1 ms granularity would swamp a UART's tens of µs: the
//! thread sleeps on a condition variable until just before the earliest
//! delivery is due and spins through the last [`SPIN`], so packets land
//! within a few µs of their time. In virtual time one [`Wire`] task per
//! machine keeps the same schedule on tokio's (paused) timer.

use super::faults::LinkFaults;
use crate::medium::{StampMode, Transmitter};
use crate::rng::Rng;
use osap_host::clock::HostClock;
use osap_host::link::LinkIo;
use std::cmp::Ordering as CmpOrdering;
use std::collections::BinaryHeap;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use tokio::sync::Notify;

/// The last stretch before a delivery that the wire thread spins through
/// instead of sleeping (OS timers overshoot by tens of µs).
pub(super) const SPIN: Duration = Duration::from_micros(80);

/// Bytes framing adds to a packet on a byte stream (COBS, CRC, delimiter).
const FRAMING_BYTES: usize = 4;

type Action = Box<dyn FnOnce() + Send>;

struct Event {
    at: Instant,
    seq: u64,
    action: Action,
}

impl PartialEq for Event {
    fn eq(&self, other: &Self) -> bool {
        (self.at, self.seq) == (other.at, other.seq)
    }
}
impl Eq for Event {}
impl PartialOrd for Event {
    fn partial_cmp(&self, other: &Self) -> Option<CmpOrdering> {
        Some(self.cmp(other))
    }
}
impl Ord for Event {
    fn cmp(&self, other: &Self) -> CmpOrdering {
        // Reversed: the heap's top is the earliest event.
        (other.at, other.seq).cmp(&(self.at, self.seq))
    }
}

#[derive(Default)]
struct Schedule {
    events: BinaryHeap<Event>,
    seq: u64,
    stop: bool,
}

#[derive(Default)]
pub(crate) struct WireShared {
    schedule: Mutex<Schedule>,
    changed: Condvar,
    /// Counts insertions, so a spinning wire thread notices them.
    version: AtomicU64,
}

impl WireShared {
    fn lock(&self) -> MutexGuard<'_, Schedule> {
        self.schedule.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// A handle to schedule actions: on a [`Wire`] thread in real time, or on
/// a [`Wire`] task on tokio's timer in virtual time (tokio's clock paused:
/// the task wakes at the ms tick of the earliest action and runs every
/// action due by then in time order, so a run is the same every time).
#[derive(Clone)]
pub(crate) enum WireHandle {
    Thread(Arc<WireShared>),
    Virtual(Arc<VirtualShared>),
}

/// A virtual-time wire's schedule and its task's wake-up.
#[derive(Default)]
pub(crate) struct VirtualShared {
    schedule: Mutex<Schedule>,
    /// Woken when an action becomes the earliest, or on stop.
    changed: Notify,
}

impl VirtualShared {
    fn lock(&self) -> MutexGuard<'_, Schedule> {
        self.schedule.lock().unwrap_or_else(|e| e.into_inner())
    }
}

impl WireHandle {
    /// Runs `action` at `at`.
    pub(crate) fn at(&self, at: Instant, action: impl FnOnce() + Send + 'static) {
        match self {
            WireHandle::Thread(shared) => {
                if schedule(&mut shared.lock(), at, Box::new(action)) {
                    shared.version.fetch_add(1, Ordering::AcqRel);
                    shared.changed.notify_one();
                }
            }
            WireHandle::Virtual(shared) => {
                if schedule(&mut shared.lock(), at, Box::new(action)) {
                    shared.changed.notify_one();
                }
            }
        }
    }
}

/// Adds `action` at `at` to `s`; returns whether it is now the earliest
/// (the wire must wake earlier). Nothing is added once the wire stopped.
fn schedule(s: &mut Schedule, at: Instant, action: Action) -> bool {
    if s.stop {
        return false;
    }
    let seq = s.seq;
    s.seq += 1;
    let earliest = s.events.peek().is_none_or(|e| at < e.at);
    s.events.push(Event { at, seq, action });
    earliest
}

/// What carries out a machine's scheduled deliveries: a thread in real
/// time, a task in virtual time. Stopped when dropped (what is still
/// scheduled is dropped: in flight when the machine went away).
pub(crate) enum Wire {
    Thread {
        shared: Arc<WireShared>,
        thread: Option<JoinHandle<()>>,
    },
    Virtual {
        shared: Arc<VirtualShared>,
        task: tokio::task::JoinHandle<()>,
    },
}

impl Wire {
    /// A wire thread, for real time.
    pub(crate) fn start() -> std::io::Result<Wire> {
        let shared = Arc::new(WireShared::default());
        let run = shared.clone();
        let thread = std::thread::Builder::new()
            .name("osap-sim-wire".into())
            .spawn(move || run_wire(&run))?;
        Ok(Wire::Thread {
            shared,
            thread: Some(thread),
        })
    }

    /// A wire task on the current tokio runtime, for virtual time: one
    /// timer for the whole machine, where a task and a timer per delivery
    /// cost a spawn, a timer registration and a wake-up each.
    pub(crate) fn start_virtual() -> Wire {
        let shared = Arc::new(VirtualShared::default());
        let task = tokio::spawn(run_virtual(shared.clone()));
        Wire::Virtual { shared, task }
    }

    pub(crate) fn handle(&self) -> WireHandle {
        match self {
            Wire::Thread { shared, .. } => WireHandle::Thread(shared.clone()),
            Wire::Virtual { shared, .. } => WireHandle::Virtual(shared.clone()),
        }
    }
}

impl Drop for Wire {
    fn drop(&mut self) {
        match self {
            Wire::Thread { shared, thread } => {
                shared.lock().stop = true;
                shared.changed.notify_all();
                if let Some(t) = thread.take() {
                    let _ = t.join();
                }
            }
            Wire::Virtual { shared, task } => {
                let mut s = shared.lock();
                s.stop = true;
                let dropped = std::mem::take(&mut s.events);
                drop(s);
                drop(dropped);
                task.abort();
            }
        }
    }
}

/// The virtual-time wire: sleeps until the earliest action's time (tokio
/// rounds it up to its next ms tick), then runs every action due by the
/// clock, earliest first (ties in the order they were scheduled).
async fn run_virtual(shared: Arc<VirtualShared>) {
    let sleep = tokio::time::sleep_until(tokio::time::Instant::now());
    tokio::pin!(sleep);
    let mut armed: Option<Instant> = None;
    loop {
        let changed = shared.changed.notified();
        let next = {
            let s = shared.lock();
            if s.stop {
                return;
            }
            s.events.peek().map(|e| e.at)
        };
        let Some(next) = next else {
            changed.await;
            continue;
        };
        let now = tokio::time::Instant::now().into_std();
        if next <= now {
            let mut due = Vec::new();
            {
                let mut s = shared.lock();
                while s.events.peek().is_some_and(|e| e.at <= now) {
                    if let Some(e) = s.events.pop() {
                        due.push(e.action);
                    }
                }
            }
            for action in due {
                action();
            }
            continue;
        }
        if armed != Some(next) {
            sleep.as_mut().reset(tokio::time::Instant::from_std(next));
            armed = Some(next);
        }
        tokio::select! {
            biased;
            _ = changed => {}
            _ = sleep.as_mut() => {}
        }
    }
}

fn run_wire(shared: &WireShared) {
    let mut s = shared.lock();
    loop {
        if s.stop {
            return;
        }
        let Some(next) = s.events.peek().map(|e| e.at) else {
            s = shared.changed.wait(s).unwrap_or_else(|e| e.into_inner());
            continue;
        };
        let now = Instant::now();
        if next <= now {
            let mut due = Vec::new();
            while s.events.peek().is_some_and(|e| e.at <= now) {
                if let Some(e) = s.events.pop() {
                    due.push(e.action);
                }
            }
            drop(s);
            for action in due {
                action();
            }
            s = shared.lock();
            continue;
        }
        let left = next - now;
        if left > SPIN {
            s = shared
                .changed
                .wait_timeout(s, left - SPIN)
                .unwrap_or_else(|e| e.into_inner())
                .0;
        } else {
            // Spin without yielding: a yield behind busy threads can cost a
            // whole time slice. Stop early if something new was scheduled.
            let version = shared.version.load(Ordering::Acquire);
            drop(s);
            while Instant::now() < next && shared.version.load(Ordering::Acquire) == version {
                std::hint::spin_loop();
            }
            s = shared.lock();
        }
    }
}

/// One direction of a link with latency.
pub(crate) struct Carrier {
    pub(crate) from: LinkIo,
    pub(crate) to: LinkIo,
    pub(crate) transmitter: Transmitter,
    /// How the receiving end stamps what arrives.
    pub(crate) stamp: StampMode,
    pub(crate) wire: WireHandle,
    /// True time zero of the link models (the machine's start).
    pub(crate) epoch: Instant,
    pub(crate) host_clock: HostClock,
    /// The link's generation when this carrier started; a delivery made
    /// after the link went down (and maybe up again) is dropped.
    pub(crate) generation: Arc<AtomicU64>,
    pub(crate) started: u64,
    /// Injected corruption, applied through the real framing.
    pub(crate) faults: Arc<LinkFaults>,
    pub(crate) fault_rng: Rng,
    /// Whether the receiver pushes back (USB, TCP): the carrier then sends
    /// only while the far runtime's receive queue has room for what is
    /// already on the wire plus one more, as a device NAKs a full endpoint.
    pub(crate) flow_controlled: bool,
}

impl Carrier {
    fn true_ns(&self, t: Instant) -> u64 {
        t.saturating_duration_since(self.epoch).as_nanos() as u64
    }

    fn instant(&self, ns: u64) -> Instant {
        self.epoch + Duration::from_nanos(ns)
    }

    /// Moves packets until the sending side closes (or the task is
    /// aborted, when the link goes down).
    pub(crate) async fn run(mut self) {
        let room = Arc::new(Notify::new());
        let in_flight = Arc::new(AtomicUsize::new(0));
        loop {
            let now = self.true_ns(osap_host::clock::now());
            if let Some(free) = self.transmitter.next_free(now) {
                let room2 = room.clone();
                self.wire.at(self.instant(free), move || room2.notify_one());
                room.notified().await;
                continue;
            }
            if self.flow_controlled {
                self.to.rx_room(&in_flight).await;
            }
            let Some(mut packet) = self.from.next_tx().await else {
                return;
            };
            let len = packet.len();
            packet.resize(len + FRAMING_BYTES, 0);
            let now = self.true_ns(osap_host::clock::now());
            let transit = self.transmitter.transmit(now, packet);
            if transit.lost {
                continue;
            }
            if self.flow_controlled {
                in_flight.fetch_add(1, Ordering::AcqRel);
            }
            let mut bytes = transit.bytes;
            bytes.truncate(len);
            let stamp_ns = match self.stamp {
                StampMode::Wire => transit.first_byte_ns,
                StampMode::Software | StampMode::None => transit.visible_ns,
            };
            let stamp = self.host_clock.at(self.instant(stamp_ns));
            let (packets, frame_errors) = self.faults.pass(&mut self.fault_rng, bytes);
            let to = self.to.clone();
            let generation = self.generation.clone();
            let started = self.started;
            let faults = self.faults.clone();
            let landing = self.flow_controlled.then(|| in_flight.clone());
            self.wire.at(self.instant(transit.visible_ns), move || {
                let arrived = generation.load(Ordering::Acquire) == started;
                if frame_errors > 0 {
                    faults.landed(frame_errors, arrived);
                }
                if arrived {
                    if frame_errors > 0 {
                        to.count_frame_errors(frame_errors);
                    }
                    for packet in packets {
                        to.deliver_stamped(packet, stamp);
                    }
                }
                // Off the wire only once in the queue: the sender never
                // sees room that is not there.
                if let Some(n) = landing {
                    n.fetch_sub(1, Ordering::AcqRel);
                }
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::medium::{LinkModel, Side};
    use osap_core::link::LinkGateway;
    use osap_host::link::{channel, LinkConfig};

    /// 20 packets sent over one carrier to a runtime that reads nothing for
    /// 50 ms, then everything. Returns (packets waiting at 50 ms, dropped at
    /// the receiver, packets read in the end).
    fn slow_reader(model: LinkModel) -> (usize, u64, usize) {
        crate::machine::virtual_runtime()
            .unwrap()
            .block_on(async move {
                let clock = HostClock::new();
                let cfg = LinkConfig {
                    depth: 4,
                    ..LinkConfig::new(model.type_name(), "t")
                };
                let (mut tx, tx_io) = channel(cfg.clone(), Arc::new(Notify::new()), clock);
                let (mut rx, rx_io) = channel(cfg, Arc::new(Notify::new()), clock);
                let wire = Wire::start_virtual();
                tx_io.set_open(true);
                rx_io.set_open(true);
                let carrier = Carrier {
                    from: tx_io,
                    to: rx_io.clone(),
                    transmitter: Transmitter::new(model, Side::A, Rng::new(1)),
                    stamp: model.stamp_mode(Side::B),
                    wire: wire.handle(),
                    epoch: osap_host::clock::now(),
                    host_clock: clock,
                    generation: Arc::new(AtomicU64::new(0)),
                    started: 0,
                    faults: Arc::default(),
                    fault_rng: Rng::new(2),
                    flow_controlled: model.is_flow_controlled(),
                };
                tokio::spawn(carrier.run());
                tokio::spawn(async move {
                    for k in 0..20u8 {
                        while !tx.clear_to_send() {
                            tokio::time::sleep(Duration::from_micros(100)).await;
                        }
                        tx.send(&[k; 40]).unwrap();
                    }
                });
                tokio::time::sleep(Duration::from_millis(50)).await;
                let mut buf = [0u8; 64];
                let mut waiting = 0;
                while rx.receive(&mut buf).is_some() {
                    waiting += 1;
                }
                let mut read = waiting;
                for _ in 0..200 {
                    tokio::time::sleep(Duration::from_millis(1)).await;
                    while rx.receive(&mut buf).is_some() {
                        read += 1;
                    }
                }
                (waiting, rx_io.stats().rx_dropped, read)
            })
    }

    #[test]
    fn usb_and_tcp_hold_the_sender_back_while_the_reader_is_full() {
        for model in [LinkModel::usb_cdc(), LinkModel::tcp()] {
            let (waiting, dropped, read) = slow_reader(model);
            assert_eq!(
                (waiting, dropped, read),
                (4, 0, 20),
                "{}",
                model.type_name()
            );
        }
    }

    #[test]
    fn a_uart_loses_what_a_full_reader_cannot_take() {
        let (waiting, dropped, read) = slow_reader(LinkModel::uart(2_000_000));
        assert_eq!(waiting, 4);
        assert_eq!(dropped, 16);
        assert_eq!(read, 4);
    }
}
