//! What the two byte-stream links (USB CDC-ACM and UART) share: the
//! hand-over between their I/O tasks and the runtime, the receive-side
//! framer that time-stamps packets, and the [`LinkGateway`] the runtime
//! polls.
//!
//! A board runs the I/O tasks on a link executor (an interrupt executor
//! above the runtime's thread-mode task), so a packet is stamped when its
//! bytes come in, not when the runtime next gets round to it. They meet the runtime in
//! a [`LinkShared`]: a queue of received packets (the receive task waits
//! when it is full, which on USB NAKs the host: real flow control) and a
//! pipe of encoded frames to send.

use core::sync::atomic::{AtomicBool, Ordering};

// thumbv6m has no atomic read-modify-write; portable-atomic does it in a
// critical section.
use portable_atomic::AtomicU32;

use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::Channel;
use embassy_sync::pipe::Pipe;
use osap_core::bus::{BusRole, Switchable};
use osap_core::framing::{encode_frame, max_frame_len};
use osap_core::link::{GatewayCounters, LinkGateway, LinkInfo, LinkSendError, Received};
use osap_core::{Duration, Instant};

pub use crate::framer::ChunkTime;
use crate::framer::{Next, RxFramer};
use crate::runtime::wake_runtime;

/// Largest packet either link carries (the runtime's slot size,
/// [`osap_module::sizes::MTU`]).
pub const MTU: usize = osap_module::sizes::MTU;
/// Largest frame of an MTU-sized packet, delimiter included.
pub const FRAME_MAX: usize = max_frame_len(MTU);
/// Received packets a link holds for the runtime.
const RX_PACKETS: usize = 4;
/// Bytes of frames a link holds to send: room for four full frames.
pub const TX_BYTES: usize = 4 * FRAME_MAX;

/// One received packet and its time stamp.
pub struct RxPacket {
    len: u16,
    stamp: Instant,
    data: [u8; MTU],
}

impl core::fmt::Debug for RxPacket {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("RxPacket")
            .field("len", &self.len)
            .field("stamp", &self.stamp)
            .finish_non_exhaustive()
    }
}

impl RxPacket {
    /// A copy of `packet` (which the framer has already limited to
    /// [`MTU`] bytes) stamped `stamp`.
    fn new(packet: &[u8], stamp: Instant) -> Self {
        let mut data = [0; MTU];
        let len = packet.len().min(MTU);
        data[..len].copy_from_slice(&packet[..len]);
        RxPacket {
            len: len as u16,
            stamp,
            data,
        }
    }
}

/// The state one link's I/O tasks share with its gateway.
pub struct LinkShared {
    rx: Channel<CriticalSectionRawMutex, RxPacket, RX_PACKETS>,
    tx: Pipe<CriticalSectionRawMutex, TX_BYTES>,
    open: AtomicBool,
    /// Frames dropped by the receive side (bad COBS or CRC, oversize).
    rx_errors: AtomicU32,
    /// Good frames received.
    frames: AtomicU32,
    /// Times the link went down.
    disconnects: AtomicU32,
}

impl core::fmt::Debug for LinkShared {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("LinkShared")
            .field("open", &self.is_open())
            .field("tx_queued", &self.tx_queued())
            .finish_non_exhaustive()
    }
}

impl LinkShared {
    /// A closed link with empty queues.
    pub const fn new() -> Self {
        LinkShared {
            rx: Channel::new(),
            tx: Pipe::new(),
            open: AtomicBool::new(false),
            rx_errors: AtomicU32::new(0),
            frames: AtomicU32::new(0),
            disconnects: AtomicU32::new(0),
        }
    }

    /// Marks the link up or down (and wakes the runtime, which forgets a
    /// closed link's clock-sync state and stops routing to it). Going up
    /// drops whatever was queued for a previous peer.
    pub fn set_open(&self, open: bool) {
        let was = self.open.load(Ordering::Relaxed);
        if open && !was {
            self.tx.clear();
            self.rx.clear();
        }
        if was && !open {
            self.disconnects.fetch_add(1, Ordering::Relaxed);
        }
        self.open.store(open, Ordering::Relaxed);
        wake_runtime();
    }

    /// Whether the link is up.
    pub fn is_open(&self) -> bool {
        self.open.load(Ordering::Relaxed)
    }

    /// Hands a received packet to the runtime; waits while the queue is
    /// full.
    async fn deliver(&self, packet: &[u8], stamp: Instant) {
        self.rx.send(RxPacket::new(packet, stamp)).await;
        wake_runtime();
    }

    /// Waits for frame bytes to send and copies some into `buf`.
    pub async fn take_tx(&self, buf: &mut [u8]) -> usize {
        let n = self.tx.read(buf).await;
        // Room in the pipe may let the runtime send a waiting packet.
        wake_runtime();
        n
    }

    /// Copies frame bytes to send into `buf` if there are any, at once.
    pub fn try_take_tx(&self, buf: &mut [u8]) -> usize {
        let n = self.tx.try_read(buf).unwrap_or(0);
        if n > 0 {
            wake_runtime();
        }
        n
    }

    /// Frames the receive side dropped since boot (bad COBS or CRC,
    /// oversize), wrapping.
    pub fn rx_errors(&self) -> u32 {
        self.rx_errors.load(Ordering::Relaxed)
    }

    /// Bytes queued to send.
    pub fn tx_queued(&self) -> usize {
        self.tx.len()
    }

    /// Feeds one received chunk through `framer` and hands each good
    /// packet to the runtime; counts bad frames.
    pub async fn receive_chunk(&self, framer: &mut Framer, chunk: &[u8], time: ChunkTime) {
        let mut rest = chunk;
        loop {
            match framer.next(&mut rest, time) {
                Next::Packet(packet, stamp) => {
                    self.frames.fetch_add(1, Ordering::Relaxed);
                    self.deliver(packet, Instant::from_micros(stamp)).await
                }
                Next::Bad(_) => {
                    self.rx_errors.fetch_add(1, Ordering::Relaxed);
                }
                Next::Empty => {}
                Next::End => return,
            }
        }
    }
}

impl Default for LinkShared {
    fn default() -> Self {
        Self::new()
    }
}

/// The receive framer of both links.
pub type Framer = RxFramer<FRAME_MAX>;

/// Per-link wire timing the runtime asks a gateway about.
pub trait WireTiming {
    /// Time to put a packet of `len` bytes on the wire.
    fn transmit_time(&self, len: usize) -> Duration;
    /// Time until a packet sent now starts onto the wire, given the bytes
    /// already queued ahead of it.
    fn queue_delay(&self, queued: usize) -> Duration;
}

/// The runtime's side of a byte-stream link.
pub struct FramedGateway<W: WireTiming + 'static> {
    shared: &'static LinkShared,
    info: LinkInfo<'static>,
    wire: &'static W,
    frame: [u8; FRAME_MAX],
}

impl<W: WireTiming> core::fmt::Debug for FramedGateway<W> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("FramedGateway")
            .field("info", &self.info)
            .field("shared", &self.shared)
            .finish_non_exhaustive()
    }
}

/// A link the runtime loop drives: a gateway, and the state it shares
/// with its I/O tasks (whose receive errors the loop reports).
pub trait FirmwareLink: LinkGateway {
    /// The link's shared state.
    fn shared(&self) -> &'static LinkShared;

    /// Takes a bus role at once; false if the link cannot (only a
    /// [`Switchable`] link can).
    fn set_bus_role(&mut self, role: BusRole) -> bool {
        let _ = role;
        false
    }
}

impl<W: WireTiming> FirmwareLink for FramedGateway<W> {
    fn shared(&self) -> &'static LinkShared {
        self.shared
    }
}

impl<W: WireTiming, const N: usize> FirmwareLink for Switchable<FramedGateway<W>, N> {
    fn shared(&self) -> &'static LinkShared {
        self.lower.shared
    }

    fn set_bus_role(&mut self, role: BusRole) -> bool {
        self.set_role(role);
        true
    }
}

impl<W: WireTiming> FramedGateway<W> {
    /// The gateway of the link behind `shared`, reported to scans as
    /// `type_name`.
    pub fn new(shared: &'static LinkShared, type_name: &'static str, wire: &'static W) -> Self {
        FramedGateway {
            shared,
            info: LinkInfo {
                type_name,
                name: "",
            },
            wire,
            frame: [0; FRAME_MAX],
        }
    }
}

impl<W: WireTiming> LinkGateway for FramedGateway<W> {
    fn info(&self) -> LinkInfo<'_> {
        self.info
    }

    fn is_open(&self) -> bool {
        self.shared.is_open()
    }

    fn mtu(&self) -> u16 {
        MTU as u16
    }

    fn clear_to_send(&self) -> bool {
        // Only this gateway writes the pipe, so the room seen here stays.
        self.shared.tx.free_capacity() >= FRAME_MAX
    }

    fn send(&mut self, packet: &[u8]) -> Result<(), LinkSendError> {
        let n = encode_frame(packet, &mut self.frame).map_err(|_| LinkSendError)?;
        // `try_write` fills only the contiguous free part of the pipe's
        // ring, so a frame that straddles the wrap takes two calls; the
        // room clear_to_send saw is there for the whole frame.
        let mut rest = &self.frame[..n];
        while !rest.is_empty() {
            match self.shared.tx.try_write(rest) {
                Ok(written) => rest = &rest[written..],
                // Cannot happen after clear_to_send. The torn frame has no
                // delimiter; the peer drops it, and the one after it, by CRC.
                Err(_) => return Err(LinkSendError),
            }
        }
        Ok(())
    }

    fn transmit_time(&self, len: usize) -> Duration {
        self.wire.transmit_time(len)
    }

    fn queue_delay(&self) -> Duration {
        self.wire.queue_delay(self.shared.tx_queued())
    }

    fn counters(&self) -> Option<GatewayCounters> {
        // The receive queue waits rather than drops, and so does the send
        // pipe: those counts stay 0.
        Some(GatewayCounters {
            frames: self.shared.frames.load(Ordering::Relaxed),
            frame_errors: self.shared.rx_errors(),
            rx_dropped: 0,
            tx_dropped: 0,
            disconnects: self.shared.disconnects.load(Ordering::Relaxed),
        })
    }

    fn receive(&mut self, buf: &mut [u8]) -> Option<Received> {
        let packet = self.shared.rx.try_receive().ok()?;
        let len = usize::from(packet.len);
        // A buffer too small leaves it uncopied; the runtime sees the
        // length and counts the packet as oversize.
        if let Some(dst) = buf.get_mut(..len) {
            dst.copy_from_slice(&packet.data[..len]);
        }
        Some(Received {
            len,
            timestamp: Some(packet.stamp),
        })
    }
}
