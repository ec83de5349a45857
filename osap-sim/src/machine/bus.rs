//! A simulated RS-485 bus: one pair that every station hears, carrying one
//! transmission at a time at the bus's baud.
//!
//! Each station's [`LinkIo`] feeds a task that puts its frames on the pair
//! one after another. A frame occupies the pair for its wire time (bus
//! header, packet and framing at 10 bits a byte) and reaches every other
//! station when its last byte has, stamped with its first byte's time. If
//! a station starts while another station's frame is on the pair, both are
//! garbled: neither is delivered, and the collision is counted. The
//! polling arbitration of `osap_core::bus` should leave that count at 0.

use super::wire::WireHandle;
use osap_host::clock::HostClock;
use osap_host::link::LinkIo;
use std::collections::{HashSet, VecDeque};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::Notify;

/// Bytes the byte-stream framing adds to a bus frame (COBS overhead,
/// CRC-16, delimiter).
const FRAMING_BYTES: u64 = 4;

/// Frames a station's UART holds to send back to back.
const TX_FRAMES: usize = 2;

/// What a simulated bus counted.
#[derive(Debug, Default)]
pub struct BusStats {
    /// Frames carried.
    pub frames: AtomicU64,
    /// Bytes on the pair, framing included.
    pub bytes: AtomicU64,
    /// Transmissions that overlapped another (both lost).
    pub collisions: AtomicU64,
}

#[derive(Default)]
struct Pair {
    /// True ns until which the pair is occupied, and by whom.
    busy_until: u64,
    sender: Option<usize>,
    seq: u64,
    /// Frames garbled by a collision after they were scheduled.
    garbled: HashSet<u64>,
}

/// One bus: its pair and its stations' I/O halves.
pub(crate) struct SimBus {
    pub(crate) stations: Vec<LinkIo>,
    pub(crate) baud: u32,
    pub(crate) wire: WireHandle,
    pub(crate) epoch: Instant,
    pub(crate) host_clock: HostClock,
    pub(crate) stats: Arc<BusStats>,
}

impl SimBus {
    /// Opens every station and starts carrying frames (tasks end when the
    /// stations' links close).
    pub(crate) fn start(self) {
        let pair = Arc::new(Mutex::new(Pair::default()));
        let stations = Arc::new(self.stations);
        for io in stations.iter() {
            io.set_open(true);
        }
        for me in 0..stations.len() {
            let station = Station {
                me,
                stations: stations.clone(),
                pair: pair.clone(),
                ns_per_byte: 10_000_000_000 / u64::from(self.baud.max(1)),
                wire: self.wire.clone(),
                epoch: self.epoch,
                host_clock: self.host_clock,
                stats: self.stats.clone(),
            };
            tokio::spawn(station.run());
        }
    }
}

struct Station {
    me: usize,
    stations: Arc<Vec<LinkIo>>,
    pair: Arc<Mutex<Pair>>,
    ns_per_byte: u64,
    wire: WireHandle,
    epoch: Instant,
    host_clock: HostClock,
    stats: Arc<BusStats>,
}

impl Station {
    fn true_ns(&self, t: Instant) -> u64 {
        t.saturating_duration_since(self.epoch).as_nanos() as u64
    }

    async fn run(self) {
        let room = Arc::new(Notify::new());
        // End times of our frames still on the wire or waiting for it: a
        // UART's transmit buffer holds [`TX_FRAMES`], sent back to back.
        let mut in_flight: VecDeque<u64> = VecDeque::new();
        loop {
            let now = self.true_ns(osap_host::clock::now());
            while in_flight.front().is_some_and(|&end| end <= now) {
                in_flight.pop_front();
            }
            if let (true, Some(&first)) = (in_flight.len() >= TX_FRAMES, in_flight.front()) {
                // The transmit buffer is full until its first frame is out.
                let room2 = room.clone();
                self.wire
                    .at(self.epoch + Duration::from_nanos(first), move || {
                        room2.notify_one()
                    });
                room.notified().await;
                continue;
            }
            let Some(frame) = self.stations[self.me].next_tx().await else {
                return;
            };
            let now = self.true_ns(osap_host::clock::now());
            let wire_ns = (frame.len() as u64 + FRAMING_BYTES) * self.ns_per_byte;
            let (start, end, seq) = {
                let mut p = self.pair.lock().unwrap_or_else(|e| e.into_inner());
                if p.busy_until > now && p.sender != Some(self.me) {
                    // Two drivers on the pair: both frames are garbage.
                    let seq = p.seq;
                    p.garbled.insert(seq);
                    self.stats.collisions.fetch_add(1, Ordering::Relaxed);
                    in_flight.push_back(now + wire_ns);
                    continue;
                }
                let start = now.max(p.busy_until);
                let end = start + wire_ns;
                p.busy_until = end;
                p.sender = Some(self.me);
                p.seq += 1;
                (start, end, p.seq)
            };
            in_flight.push_back(end);
            self.stats.frames.fetch_add(1, Ordering::Relaxed);
            self.stats
                .bytes
                .fetch_add(frame.len() as u64 + FRAMING_BYTES, Ordering::Relaxed);
            let stamp = self.host_clock.at(self.epoch + Duration::from_nanos(start));
            let stations = self.stations.clone();
            let pair = self.pair.clone();
            let me = self.me;
            self.wire
                .at(self.epoch + Duration::from_nanos(end), move || {
                    let garbled = pair
                        .lock()
                        .unwrap_or_else(|e| e.into_inner())
                        .garbled
                        .remove(&seq);
                    if garbled {
                        return;
                    }
                    for (i, io) in stations.iter().enumerate() {
                        if i != me {
                            io.deliver_stamped(frame.clone(), stamp);
                        }
                    }
                });
        }
    }
}
