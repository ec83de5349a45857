//! The simulated link gateway: one end of a link, as a runtime sees it.
//!
//! [`SimLink`] implements [`LinkGateway`]. Sending frames the packet (COBS +
//! CRC on byte streams, exactly as on hardware) and hands it to the end's
//! [`Transmitter`], which decides its timing and fate; the simulator collects
//! the result with [`SimLink::take_outgoing`] after each poll and later
//! delivers the bytes to the far end's [`SimLink::deliver`]. Received bytes
//! go through a real [`FrameDecoder`], so corrupted frames fail COBS or the
//! CRC and are counted there, never handed to the runtime.
//!
//! The simulator sets the end's notion of the current true time with
//! [`SimLink::set_now`] before every poll, so `clear_to_send`,
//! `queue_delay` and `send` see the wire as it is at that instant.

use crate::medium::{
    LinkModel, Side, StampMode, Transit, Transmitter, MAX_LINK_MTU, RX_BUFFER_FRAMES,
};
use crate::rng::Rng;
use crate::Nanos;
use osap_core::framing::{encode_frame, max_frame_len, FrameCounters, FrameDecoder};
use osap_core::link::{LinkGateway, LinkInfo, LinkSendError, Received};
use osap_core::{Duration, Instant};
use std::collections::VecDeque;

/// Decoder buffer size: the largest frame of the largest link MTU.
const DECODER_LEN: usize = max_frame_len(MAX_LINK_MTU as usize);

/// What one end of a link counted.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LinkStats {
    /// Frames handed to the transmitter.
    pub frames_sent: u64,
    /// Bytes handed to the transmitter (framing included).
    pub bytes_sent: u64,
    /// Frames this end sent that were lost on the way.
    pub frames_lost: u64,
    /// Bytes this end sent that were corrupted on the way.
    pub bytes_corrupted: u64,
    /// Packets this end received and buffered for the runtime.
    pub packets_received: u64,
    /// Packets this end dropped because its receive buffer was full.
    pub rx_overflow: u64,
    /// Sends refused (not clear, oversize, or the link closed).
    pub send_refused: u64,
}

/// One end of a simulated link; the runtime's [`LinkGateway`].
#[derive(Debug)]
pub struct SimLink {
    link: usize,
    side: Side,
    name: String,
    /// False for a gateway that joins nothing ([`SimLink::unconnected`]).
    connected: bool,
    open: bool,
    now: Nanos,
    tx: Transmitter,
    stamp_mode: StampMode,
    outgoing: Vec<Transit>,
    inbox: VecDeque<(Vec<u8>, Option<Instant>)>,
    /// `None` on datagram links.
    decoder: Option<Box<FrameDecoder<DECODER_LEN>>>,
    /// Stamp of the first byte of the frame the decoder is in the middle of.
    partial_stamp: Option<Option<Instant>>,
    scratch: Vec<u8>,
    stats: LinkStats,
}

impl SimLink {
    /// End `side` of link number `link` of kind `model`, named `name`,
    /// drawing its randomness from `rng`.
    pub fn new(link: usize, side: Side, name: &str, model: LinkModel, rng: Rng) -> Self {
        SimLink {
            link,
            side,
            name: name.to_string(),
            connected: true,
            open: true,
            now: 0,
            tx: Transmitter::new(model, side, rng),
            stamp_mode: model.stamp_mode(side),
            outgoing: Vec::new(),
            inbox: VecDeque::new(),
            decoder: model
                .is_byte_stream()
                .then(|| Box::new(FrameDecoder::new())),
            partial_stamp: None,
            scratch: vec![0; DECODER_LEN],
            stats: LinkStats::default(),
        }
    }

    /// A gateway of kind `model` that joins nothing: closed for good (on
    /// USB, a device end). [`link_index`](Self::link_index) is `usize::MAX`.
    pub fn unconnected(model: LinkModel) -> Self {
        let mut link = SimLink::new(usize::MAX, Side::B, "", model, Rng::new(0));
        link.connected = false;
        link.open = false;
        link
    }

    /// The link's number in the simulation (`usize::MAX` if the gateway
    /// joins nothing).
    pub fn link_index(&self) -> usize {
        self.link
    }

    /// Whether a link joins this gateway to another node.
    pub fn is_connected(&self) -> bool {
        self.connected
    }

    /// Which end of the link this is.
    pub fn side(&self) -> Side {
        self.side
    }

    /// The link model.
    pub fn model(&self) -> &LinkModel {
        self.tx.model()
    }

    /// How this end stamps received frames.
    pub fn stamp_mode(&self) -> StampMode {
        self.stamp_mode
    }

    /// What this end counted.
    pub fn stats(&self) -> &LinkStats {
        &self.stats
    }

    /// The frame decoder's counters (byte-stream links only): frames that
    /// failed COBS or the CRC are counted here.
    pub fn frame_counters(&self) -> Option<FrameCounters> {
        self.decoder.as_ref().map(|d| *d.counters())
    }

    /// Opens or closes this end (a closed end neither sends nor receives;
    /// an unconnected one stays closed).
    pub fn set_open(&mut self, open: bool) {
        self.open = open && self.connected;
        if !open {
            self.inbox.clear();
            if let Some(d) = self.decoder.as_mut() {
                d.reset();
            }
            self.partial_stamp = None;
        }
    }

    /// Sets the true time the next gateway calls happen at.
    pub fn set_now(&mut self, now: Nanos) {
        self.now = now;
    }

    /// The transmitter of this end.
    pub fn transmitter(&self) -> &Transmitter {
        &self.tx
    }

    /// When the transmit buffer next frees a place, if it is full now.
    pub fn next_tx_free(&self) -> Option<Nanos> {
        self.tx.next_free(self.now)
    }

    /// Takes the frames sent since the last call, with their fates.
    pub fn take_outgoing(&mut self) -> std::vec::Drain<'_, Transit> {
        self.outgoing.drain(..)
    }

    /// Packets waiting for the runtime.
    pub fn inbox_len(&self) -> usize {
        self.inbox.len()
    }

    /// Bytes (or a datagram) arrive from the far end. `stamp` is this end's
    /// local time stamp for the chunk's first byte, and `us_per_byte` the
    /// local µs per byte, used for frames that start inside the chunk.
    pub fn deliver(&mut self, bytes: &[u8], stamp: Option<Instant>, us_per_byte: f64) {
        if !self.open {
            return;
        }
        let Some(decoder) = self.decoder.as_mut() else {
            push_packet(&mut self.inbox, &mut self.stats, bytes, stamp);
            return;
        };
        let stamp_at =
            |i: usize| stamp.map(|s| s + Duration::from_micros((i as f64 * us_per_byte) as u64));
        let mut i = 0;
        while i < bytes.len() {
            let end = bytes[i..].iter().position(|&b| b == 0).map(|p| i + p);
            let body_end = end.unwrap_or(bytes.len());
            // A frame starts at the first non-delimiter byte after a
            // delimiter: that byte's arrival is the frame's stamp.
            if body_end > i && self.partial_stamp.is_none() {
                self.partial_stamp = Some(stamp_at(i));
            }
            let Some(end) = end else {
                let mut rest = &bytes[i..];
                let _ = decoder.decode(&mut rest);
                break;
            };
            let mut piece = &bytes[i..=end];
            let frame_stamp = self.partial_stamp.take().flatten();
            if let Some(Ok(packet)) = decoder.decode(&mut piece) {
                let n = packet.len();
                self.scratch[..n].copy_from_slice(packet);
                push_packet(
                    &mut self.inbox,
                    &mut self.stats,
                    &self.scratch[..n],
                    frame_stamp,
                );
            }
            i = end + 1;
        }
    }
}

fn push_packet(
    inbox: &mut VecDeque<(Vec<u8>, Option<Instant>)>,
    stats: &mut LinkStats,
    packet: &[u8],
    stamp: Option<Instant>,
) {
    if inbox.len() >= RX_BUFFER_FRAMES {
        stats.rx_overflow += 1;
        return;
    }
    stats.packets_received += 1;
    inbox.push_back((packet.to_vec(), stamp));
}

impl LinkGateway for SimLink {
    fn info(&self) -> LinkInfo<'_> {
        LinkInfo {
            type_name: self.tx.model().type_name(),
            name: &self.name,
        }
    }

    fn is_open(&self) -> bool {
        self.open
    }

    fn mtu(&self) -> u16 {
        self.tx.model().mtu()
    }

    fn clear_to_send(&self) -> bool {
        self.open && self.tx.clear_to_send(self.now)
    }

    fn send(&mut self, packet: &[u8]) -> Result<(), LinkSendError> {
        if !self.clear_to_send() || packet.len() > usize::from(self.mtu()) {
            self.stats.send_refused += 1;
            return Err(LinkSendError);
        }
        let bytes = if self.decoder.is_some() {
            let mut frame = vec![0u8; max_frame_len(packet.len())];
            let n = encode_frame(packet, &mut frame).map_err(|_| LinkSendError)?;
            frame.truncate(n);
            frame
        } else {
            packet.to_vec()
        };
        self.stats.frames_sent += 1;
        self.stats.bytes_sent += bytes.len() as u64;
        let transit = self.tx.transmit(self.now, bytes);
        self.stats.frames_lost += u64::from(transit.lost);
        self.stats.bytes_corrupted += u64::from(transit.corrupted);
        self.outgoing.push(transit);
        Ok(())
    }

    fn transmit_time(&self, len: usize) -> Duration {
        let bytes = if self.decoder.is_some() {
            max_frame_len(len)
        } else {
            len
        };
        Duration::from_micros(self.tx.wire_ns(bytes).div_ceil(1000))
    }

    fn queue_delay(&self) -> Duration {
        // True ns to local µs, rounded: the rate error (≤ 1e-4 of a wait of
        // at most a few ms) is below the counter's resolution, so it is
        // ignored.
        Duration::from_micros((self.tx.queue_delay_ns(self.now) + 500) / 1000)
    }

    fn counters(&self) -> Option<osap_core::counters::GatewayCounters> {
        let s = &self.stats;
        let frame_errors = self.frame_counters().map_or(0, |f| {
            f.cobs_errors
                .wrapping_add(f.crc_errors)
                .wrapping_add(f.too_short)
                .wrapping_add(f.oversize)
        });
        // The wire's counts, cut to the u32 they wrap at.
        Some(osap_core::counters::GatewayCounters {
            frames: s.packets_received as u32,
            frame_errors,
            rx_dropped: s.rx_overflow as u32,
            tx_dropped: 0,
            disconnects: 0,
        })
    }

    fn receive(&mut self, buf: &mut [u8]) -> Option<Received> {
        if !self.open {
            return None;
        }
        let (packet, timestamp) = self.inbox.pop_front()?;
        if let Some(dst) = buf.get_mut(..packet.len()) {
            dst.copy_from_slice(&packet);
        }
        Some(Received {
            len: packet.len(),
            timestamp,
        })
    }
}
