//! Link gateways for the host, whose I/O runs outside the runtime task.
//!
//! A [`ChannelLink`] is what the runtime sees: an `osap_core` link gateway
//! over two bounded queues. Its other half, [`LinkIo`], belongs to whatever
//! moves bytes: a serial-port task, a socket task, or (for in-process links)
//! another runtime's queue directly. Either side wakes the other through a
//! [`Notify`], so nothing polls on a timer.
//!
//! Link state changes (opened, closed: a cable pulled, a peer gone) are
//! reported through [`LinkIo::set_open`]; the runtime sees them on its next
//! poll, drops packets routed over a closed link (counted) and forgets the
//! clock samples of its neighbour there.

pub mod memory;
pub mod noise;
pub mod serial;
pub mod stream;
pub mod tcp;
pub mod udp;
#[cfg(unix)]
pub mod unix;

use crate::clock::HostClock;
use osap_core::link::{LinkGateway, LinkInfo, LinkSendError, Received};
use osap_core::{Duration, Instant};
use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard};
use tokio::sync::Notify;

/// How a link is described and sized.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LinkConfig {
    /// Type name reported to scans (`usb_cdc`, `uart`, `tcp`, `udp`, ...).
    pub type_name: String,
    /// Instance name reported to scans (a device path, an address).
    pub name: String,
    /// Largest packet, bytes.
    pub mtu: u16,
    /// Packets buffered each way.
    pub depth: usize,
    /// Wire speed, bits per second, for transmit-time estimates (0: unknown).
    pub bits_per_second: u32,
    /// Bits on the wire per byte (10 for 8N1 serial).
    pub bits_per_byte: u32,
}

impl LinkConfig {
    /// A link of the given type with defaults: 1 KiB MTU, 32 packets each
    /// way, unknown speed.
    pub fn new(type_name: &str, name: &str) -> Self {
        LinkConfig {
            type_name: type_name.to_string(),
            name: name.to_string(),
            mtu: crate::HOST_MTU as u16,
            depth: 32,
            bits_per_second: 0,
            bits_per_byte: 8,
        }
    }
}

/// Counts kept for a link.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LinkStats {
    /// Packets handed to the I/O side to transmit.
    pub sent: u64,
    /// Packets received from the I/O side.
    pub received: u64,
    /// Received packets dropped because the runtime's queue was full.
    pub rx_dropped: u64,
    /// Frames dropped by the I/O side (bad CRC, COBS, oversize).
    pub frame_errors: u64,
    /// Times the link went down.
    pub disconnects: u64,
    /// Packets dropped unsent: queued when the link went down (a
    /// connection closed, stalled or timed out), or sent to it after its
    /// send queue had been full too long (see
    /// [`LinkIo::set_drop_when_full_for`]).
    pub tx_dropped: u64,
    /// Connections closed because the peer stopped reading (a write could
    /// not complete within the stall bound).
    pub stalled: u64,
    /// Connections closed because nothing arrived within the idle timeout.
    pub idle_closed: u64,
}

#[derive(Debug)]
struct Queues {
    rx: VecDeque<(Vec<u8>, Instant)>,
    tx: VecDeque<Vec<u8>>,
    open: bool,
    /// Stop reading the peer while the send queue is full (accepted
    /// sockets).
    pause_reads: bool,
    /// Drop, rather than wait, once the send queue has been full this long.
    drop_after: Option<std::time::Duration>,
    /// Since when the send queue has been full, if it is.
    full_since: Option<std::time::Instant>,
    stats: LinkStats,
}

impl Queues {
    /// Whether packets for the link are dropped now: its send queue has
    /// been full for longer than it may be.
    fn dropping(&self) -> bool {
        match (self.drop_after, self.full_since) {
            (Some(after), Some(since)) => since.elapsed() >= after,
            _ => false,
        }
    }
}

/// State shared by a link's two halves.
#[derive(Debug)]
struct Shared {
    config: LinkConfig,
    queues: Mutex<Queues>,
    /// Wakes the runtime task (shared by all of a host's links and ports).
    runtime: Arc<Notify>,
    /// Wakes the I/O side: a packet to send, or room to receive.
    io: Notify,
    clock: HostClock,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, Queues> {
        // A panic elsewhere while holding the lock leaves the queues
        // consistent (every operation is a single push or pop), so go on.
        self.queues.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// The runtime's side of a link.
#[derive(Debug)]
pub struct ChannelLink {
    shared: Arc<Shared>,
    /// An in-process peer: packets go straight into its receive queue.
    peer: Option<Arc<Shared>>,
}

/// The I/O side of a link: hands received packets to the runtime and takes
/// the packets it sends.
#[derive(Debug, Clone)]
pub struct LinkIo {
    shared: Arc<Shared>,
}

/// Makes the two halves of a link. `runtime` is the wake-up of the task
/// that polls the runtime owning the [`ChannelLink`] (a host's, or another
/// runtime's, as a simulated module's in `osap_sim::machine`); `clock`
/// stamps what the [`LinkIo`] side delivers. A host's own links come from
/// [`Host::make_link`](crate::Host::make_link), which passes its wake-up
/// and clock.
pub fn channel(
    config: LinkConfig,
    runtime: Arc<Notify>,
    clock: HostClock,
) -> (ChannelLink, LinkIo) {
    let shared = Arc::new(Shared {
        config,
        queues: Mutex::new(Queues {
            rx: VecDeque::new(),
            tx: VecDeque::new(),
            open: false,
            pause_reads: false,
            drop_after: None,
            full_since: None,
            stats: LinkStats::default(),
        }),
        runtime,
        io: Notify::new(),
        clock,
    });
    (
        ChannelLink {
            shared: shared.clone(),
            peer: None,
        },
        LinkIo { shared },
    )
}

impl LinkIo {
    /// The link's configuration.
    pub fn config(&self) -> &LinkConfig {
        &self.shared.config
    }

    /// Marks the link up or down and wakes the runtime. Going down drops
    /// whatever was queued either way (it belonged to the old connection:
    /// received packets left over would otherwise reach the runtime as if
    /// the next connection had sent them).
    pub fn set_open(&self, open: bool) {
        let mut q = self.shared.lock();
        if q.open && !open {
            q.stats.disconnects += 1;
            q.stats.tx_dropped += q.tx.len() as u64;
            q.tx.clear();
            q.full_since = None;
            let stale = q.rx.len() as u64;
            q.stats.rx_dropped += stale;
            q.rx.clear();
        }
        q.open = open;
        drop(q);
        self.shared.runtime.notify_one();
        self.shared.io.notify_waiters();
    }

    /// Whether the link is up.
    pub fn is_open(&self) -> bool {
        self.shared.lock().open
    }

    /// Hands a received packet to the runtime, stamped now. Returns false
    /// (and counts a drop) if the runtime's queue is full.
    pub fn deliver(&self, packet: Vec<u8>) -> bool {
        let stamp = self.shared.clock.now();
        self.deliver_stamped(packet, stamp)
    }

    /// [`deliver`](Self::deliver) with an explicit receive stamp (host
    /// clock, when the first byte arrived).
    pub fn deliver_stamped(&self, packet: Vec<u8>, stamp: Instant) -> bool {
        let mut q = self.shared.lock();
        if q.rx.len() >= self.shared.config.depth {
            q.stats.rx_dropped += 1;
            return false;
        }
        q.rx.push_back((packet, stamp));
        q.stats.received += 1;
        drop(q);
        self.shared.runtime.notify_one();
        true
    }

    /// Waits until the runtime has room for a received packet (for stream
    /// links, which can push back by not reading). A link set to
    /// [`pause reads`](Self::set_pause_reads_when_full) also waits while its
    /// send queue is full.
    pub async fn rx_ready(&self) {
        loop {
            let notified = self.shared.io.notified();
            {
                let q = self.shared.lock();
                let depth = self.shared.config.depth;
                let unread = q.pause_reads && q.tx.len() >= depth;
                if q.rx.len() < depth && !unread {
                    return;
                }
            }
            notified.await;
        }
    }

    /// Waits until the runtime's receive queue has room for one more packet
    /// beyond `in_flight` already on their way to it: how a flow-controlled
    /// wire (USB, TCP) holds its sender back instead of losing packets.
    pub async fn rx_room(&self, in_flight: &std::sync::atomic::AtomicUsize) {
        use std::sync::atomic::Ordering;
        loop {
            let notified = self.shared.io.notified();
            {
                let q = self.shared.lock();
                if !q.open
                    || q.rx.len() + in_flight.load(Ordering::Acquire) < self.shared.config.depth
                {
                    return;
                }
            }
            notified.await;
        }
    }

    /// Takes the next packet to transmit, waiting for one. Returns `None`
    /// when the link is closed (the I/O task should reconnect or stop).
    pub async fn next_tx(&self) -> Option<Vec<u8>> {
        loop {
            let notified = self.shared.io.notified();
            {
                let mut q = self.shared.lock();
                if !q.open {
                    return None;
                }
                if let Some(p) = q.tx.pop_front() {
                    q.full_since = None;
                    drop(q);
                    // Room to send again: the runtime may have packets
                    // waiting, and the reader may wait for the peer to read.
                    self.shared.runtime.notify_one();
                    self.shared.io.notify_waiters();
                    return Some(p);
                }
            }
            notified.await;
        }
    }

    /// Counts frames the I/O side had to drop.
    pub fn count_frame_errors(&self, n: u64) {
        self.shared.lock().stats.frame_errors += n;
    }

    /// Whether to stop reading the peer while the link's send queue is
    /// full (off unless set). Listeners set it on the connections they
    /// accept: a client that sends requests and does not read the replies
    /// is then not read either, so it cannot keep the runtime busy nor keep
    /// refilling its packet slots with replies that wait for it; the stall
    /// bound closes the connection if it never reads again. (Only one end
    /// of a link may pause: two that both did could wait on each other.)
    pub fn set_pause_reads_when_full(&self, pause: bool) {
        self.shared.lock().pause_reads = pause;
    }

    /// Drop packets sent to the link once its send queue has been full for
    /// `after` (counted in [`LinkStats::tx_dropped`]), instead of leaving
    /// them in the runtime's stack until room comes (`None`, the default:
    /// right for a wire that drains at its own pace, and for a peer that
    /// may fall behind for a while but reads everything in the end).
    pub fn set_drop_when_full_for(&self, after: Option<std::time::Duration>) {
        self.shared.lock().drop_after = after;
    }

    /// Counts a connection closed because its peer stopped reading.
    pub(crate) fn count_stalled(&self) {
        self.shared.lock().stats.stalled += 1;
    }

    /// Counts a connection closed for being idle.
    pub(crate) fn count_idle(&self) {
        self.shared.lock().stats.idle_closed += 1;
    }

    /// The link's counts.
    pub fn stats(&self) -> LinkStats {
        self.shared.lock().stats
    }

    /// The host clock, for receive stamps.
    pub fn clock(&self) -> HostClock {
        self.shared.clock
    }
}

impl ChannelLink {
    /// Joins two links in one process: each one's sends land directly in
    /// the other's receive queue (their [`LinkIo`] sides are bypassed).
    /// Used for in-process links with no wire time, e.g. between a host
    /// and simulated modules.
    pub fn join(a: &mut ChannelLink, b: &mut ChannelLink) {
        a.peer = Some(b.shared.clone());
        b.peer = Some(a.shared.clone());
    }

    /// The link's counts.
    pub fn stats(&self) -> LinkStats {
        self.shared.lock().stats
    }
}

impl LinkGateway for ChannelLink {
    fn info(&self) -> LinkInfo<'_> {
        LinkInfo {
            type_name: &self.shared.config.type_name,
            name: &self.shared.config.name,
        }
    }

    fn is_open(&self) -> bool {
        self.shared.lock().open
    }

    fn mtu(&self) -> u16 {
        self.shared.config.mtu
    }

    fn clear_to_send(&self) -> bool {
        match &self.peer {
            Some(peer) => {
                let q = peer.lock();
                q.open && q.rx.len() < peer.config.depth
            }
            None => {
                let q = self.shared.lock();
                q.open && (q.tx.len() < self.shared.config.depth || q.dropping())
            }
        }
    }

    fn send(&mut self, packet: &[u8]) -> Result<(), LinkSendError> {
        match &self.peer {
            Some(peer) => {
                let stamp = peer.clock.now();
                let mut q = peer.lock();
                if !q.open || q.rx.len() >= peer.config.depth {
                    return Err(LinkSendError);
                }
                q.rx.push_back((packet.to_vec(), stamp));
                q.stats.received += 1;
                drop(q);
                peer.runtime.notify_one();
            }
            None => {
                let mut q = self.shared.lock();
                if !q.open {
                    return Err(LinkSendError);
                }
                if q.tx.len() >= self.shared.config.depth {
                    if q.dropping() {
                        q.stats.tx_dropped += 1;
                    }
                    return Err(LinkSendError);
                }
                q.tx.push_back(packet.to_vec());
                if q.tx.len() >= self.shared.config.depth && q.full_since.is_none() {
                    q.full_since = Some(std::time::Instant::now());
                }
                drop(q);
                self.shared.io.notify_waiters();
            }
        }
        self.shared.lock().stats.sent += 1;
        Ok(())
    }

    fn transmit_time(&self, len: usize) -> Duration {
        let c = &self.shared.config;
        if c.bits_per_second == 0 {
            return Duration::ZERO;
        }
        // COBS + CRC + delimiter: about 4 bytes more than the packet.
        let bits = (len as u64 + 4) * u64::from(c.bits_per_byte);
        Duration::from_micros((bits * 1_000_000).div_ceil(u64::from(c.bits_per_second)))
    }

    fn counters(&self) -> Option<osap_core::counters::GatewayCounters> {
        // The wire's counts, cut to the u32 they wrap at.
        let s = self.shared.lock().stats;
        let c = |v: u64| v as u32;
        Some(osap_core::counters::GatewayCounters {
            frames: c(s.received),
            frame_errors: c(s.frame_errors),
            rx_dropped: c(s.rx_dropped),
            tx_dropped: c(s.tx_dropped),
            disconnects: c(s.disconnects),
        })
    }

    fn receive(&mut self, buf: &mut [u8]) -> Option<Received> {
        let (packet, stamp) = self.shared.lock().rx.pop_front()?;
        // Room again: a stream link may be waiting to read more.
        self.shared.io.notify_waiters();
        if let Some(dst) = buf.get_mut(..packet.len()) {
            dst.copy_from_slice(&packet);
        }
        Some(Received {
            len: packet.len(),
            timestamp: Some(stamp),
        })
    }
}
