//! Link models: what happens to a frame between two link gateways.
//!
//! A link joins end A and end B of two nodes. Each end owns a
//! [`Transmitter`] for the direction it sends in: the transmitter decides,
//! when the runtime hands it a frame, when the frame starts on the wire, when
//! its first byte and its end reach the far side, when the far side's
//! software can see it, and whether it is lost or corrupted on the way. The
//! simulator then only has to carry the resulting [`Transit`] to the other
//! end at the right time. Keeping each direction's randomness and wire state
//! with its sender makes the two directions independent, as they are on a
//! full-duplex wire.
//!
//! The kinds and their defaults:
//!
//! | kind | defaults |
//! |---|---|
//! | [`UartParams`] (`uart`, `rs485`) | 2 Mbaud, 10 bits per byte, no propagation delay, asymmetry, jitter, loss or corruption; a TX buffer of 2 frames |
//! | [`UsbParams`] (`usb_cdc`) | 12 Mbit/s, 1 ms frames at true time 0 + k ms, bulk slot U[10, 20] µs after SOF, 13 bytes of protocol overhead per 64-byte packet, host TX latency Exp(50 µs), host RX latency Exp(75 µs) |
//! | [`IpParams`] (`tcp`, `udp`) | loopback: 10 Gbit/s, one-way latency 15 µs + Exp(25 µs), no asymmetry or loss |
//!
//! RS-485 is modelled as a point-to-point full-duplex UART (no bus
//! turnaround, no multi-drop arbitration); only its type name differs.
//! USB IN and OUT transfers are modelled as independent directions (they
//! share the bus in reality; at the loads of clock sync this is immaterial).

use crate::error::SimError;
use crate::rng::{us_to_ns, Dist, Rng};
use crate::Nanos;
use std::collections::VecDeque;

/// Largest link MTU the simulated links support (bytes of packet); it sizes
/// the frame decoders.
pub const MAX_LINK_MTU: u16 = 1024;

/// Frames a receiving gateway buffers before the runtime reads them; more
/// are dropped and counted as receive overflows.
pub const RX_BUFFER_FRAMES: usize = 32;

/// Which end of a link: A is the first node named in the link's description.
/// On a USB link A is the host and B the device.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Side {
    /// The first node named.
    A,
    /// The second node named.
    B,
}

impl Side {
    /// The other end.
    pub fn other(self) -> Side {
        match self {
            Side::A => Side::B,
            Side::B => Side::A,
        }
    }

    /// 0 for A, 1 for B.
    pub fn index(self) -> usize {
        match self {
            Side::A => 0,
            Side::B => 1,
        }
    }
}

/// How a receiving gateway time-stamps frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StampMode {
    /// A receive interrupt stamps the first byte on the wire (a UART, or a
    /// USB device that knows its frame timing). A busy node whose interrupts
    /// can be pre-empted stamps late.
    Wire,
    /// The stamp is the local time at which software received the data (the
    /// host side of USB and of IP sockets).
    Software,
    /// No stamp: the runtime uses its poll time.
    None,
}

/// A UART or RS-485 line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UartParams {
    /// Symbol rate, baud.
    pub baud: u32,
    /// Bits on the wire per byte (start + 8 data + stop = 10).
    pub bits_per_byte: u32,
    /// Propagation delay, µs (≈ 0 for a board-to-board cable).
    pub propagation_us: f64,
    /// Extra fixed latency of one direction, µs: positive delays A→B,
    /// negative delays B→A (an isolator or level shifter on one path).
    pub asymmetry_us: f64,
    /// Random extra latency per frame, µs (frames never overtake each other).
    pub jitter: Dist,
    /// Probability that a whole frame is lost.
    pub loss: f64,
    /// Probability that a byte is corrupted (one bit flipped).
    pub corrupt_per_byte: f64,
    /// Frames the transmit buffer (FIFO/DMA) holds, the one on the wire
    /// included; the gateway is not clear to send while it is full.
    pub tx_buffer_frames: usize,
    /// Largest packet, bytes.
    pub mtu: u16,
}

impl Default for UartParams {
    fn default() -> Self {
        UartParams {
            baud: 2_000_000,
            bits_per_byte: 10,
            propagation_us: 0.0,
            asymmetry_us: 0.0,
            jitter: Dist::ZERO,
            loss: 0.0,
            corrupt_per_byte: 0.0,
            tx_buffer_frames: 2,
            mtu: 256,
        }
    }
}

/// A full-speed USB CDC link between a host (end A) and a device (end B).
///
/// OUT (host → device): the host's software takes `host_tx_latency` to hand
/// the data to the host controller, which sends it in the next 1 ms frame,
/// `slot` after the frame's SOF. IN (device → host): while the host has an
/// IN transfer pending its controller keeps polling the bulk endpoint
/// (NAK-retrying), so data the device queues leaves after a short
/// `in_poll_delay` the device cannot predict; then `host_rx_latency` passes
/// before the host's software sees it. (`in_frame_aligned` instead makes IN
/// wait for the next frame too, as on controllers that poll once per frame.)
/// The frame grid is on the host's true time: `sof_phase_us + k·frame_us`.
/// The device knows it (from SOF), so its `queue_delay` includes any wait for
/// a frame and its receive stamps are exact; the host knows neither.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UsbParams {
    /// Bus bit rate, bit/s (full speed: 12 000 000).
    pub bit_rate: u32,
    /// Frame period, µs (1000 for full speed).
    pub frame_us: f64,
    /// True time of the first SOF, µs (the phase of the frame grid).
    pub sof_phase_us: f64,
    /// When in a frame a bulk transfer starts, µs after SOF.
    pub slot: Dist,
    /// Protocol bytes per USB packet (token, PID, CRC, handshake, gaps).
    pub overhead_bytes_per_packet: u32,
    /// Bytes of data per USB packet (64 for full-speed bulk).
    pub max_packet: u32,
    /// Whether OUT transfers wait for the next frame (the model described
    /// above). When false, an OUT transfer starts as soon as the host's
    /// software latency has passed and the bus is free, as on host
    /// controllers that service bulk endpoints throughout the frame; IN
    /// transfers still wait for the next frame.
    pub out_frame_aligned: bool,
    /// Whether IN transfers wait for the next frame's slot; when false they
    /// leave after `in_poll_delay`.
    pub in_frame_aligned: bool,
    /// Delay before a continuously polled IN endpoint is read, µs.
    pub in_poll_delay: Dist,
    /// Host software transmit latency, µs.
    pub host_tx_latency: Dist,
    /// Host software receive latency, µs.
    pub host_rx_latency: Dist,
    /// Whether the host stamps received frames with the time its software
    /// saw them (otherwise it gives no stamp).
    pub host_stamps: bool,
    /// Probability that a whole frame is lost (normally 0: USB retries).
    pub loss: f64,
    /// Frames the host's transmit queue holds.
    pub host_tx_buffer_frames: usize,
    /// Frames the device's IN endpoint buffer holds.
    pub device_tx_buffer_frames: usize,
    /// Largest packet, bytes.
    pub mtu: u16,
}

impl Default for UsbParams {
    fn default() -> Self {
        UsbParams {
            bit_rate: 12_000_000,
            frame_us: 1000.0,
            sof_phase_us: 0.0,
            slot: Dist::uniform(10.0, 20.0),
            overhead_bytes_per_packet: 13,
            max_packet: 64,
            out_frame_aligned: true,
            in_frame_aligned: false,
            in_poll_delay: Dist::uniform(0.0, 20.0),
            host_tx_latency: Dist::exp(0.0, 50.0),
            host_rx_latency: Dist::exp(0.0, 75.0),
            host_stamps: true,
            loss: 0.0,
            host_tx_buffer_frames: 16,
            device_tx_buffer_frames: 4,
            mtu: 256,
        }
    }
}

/// A TCP or UDP socket pair. Both ends are software: stamps (if any) are the
/// times the receiving software got the data.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IpParams {
    /// Bit rate of the path, bit/s.
    pub bit_rate: u64,
    /// One-way latency (stack, scheduling, network), µs.
    pub latency: Dist,
    /// Extra fixed latency of one direction, µs: positive delays A→B,
    /// negative B→A.
    pub asymmetry_us: f64,
    /// Probability that a datagram is lost (UDP only; TCP must be 0).
    pub loss: f64,
    /// Whether the receiver stamps data with the time it read it.
    pub stamps: bool,
    /// Frames the socket's send buffer holds before it pushes back.
    pub tx_buffer_frames: usize,
    /// Largest packet, bytes.
    pub mtu: u16,
}

impl IpParams {
    /// Sockets over the loopback interface.
    pub const LOOPBACK: IpParams = IpParams {
        bit_rate: 10_000_000_000,
        latency: Dist::exp(15.0, 25.0),
        asymmetry_us: 0.0,
        loss: 0.0,
        stamps: true,
        tx_buffer_frames: 64,
        mtu: 512,
    };

    /// Sockets across a switched gigabit LAN.
    pub const LAN: IpParams = IpParams {
        bit_rate: 1_000_000_000,
        latency: Dist::exp(80.0, 60.0),
        asymmetry_us: 0.0,
        loss: 0.0,
        stamps: true,
        tx_buffer_frames: 64,
        mtu: 512,
    };
}

impl Default for IpParams {
    fn default() -> Self {
        IpParams::LOOPBACK
    }
}

/// What kind of link, with its parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LinkModel {
    /// A UART (type name `uart`).
    Uart(UartParams),
    /// An RS-485 line, modelled as a full-duplex UART (type name `rs485`).
    Rs485(UartParams),
    /// USB full-speed CDC; end A is the host (type name `usb_cdc`).
    UsbCdc(UsbParams),
    /// A TCP stream (type name `tcp`).
    Tcp(IpParams),
    /// UDP datagrams (type name `udp`).
    Udp(IpParams),
}

impl LinkModel {
    /// A UART at `baud` with the other defaults.
    pub fn uart(baud: u32) -> Self {
        LinkModel::Uart(UartParams {
            baud,
            ..UartParams::default()
        })
    }

    /// A USB CDC link with the defaults.
    pub fn usb_cdc() -> Self {
        LinkModel::UsbCdc(UsbParams::default())
    }

    /// A TCP stream over loopback.
    pub fn tcp() -> Self {
        LinkModel::Tcp(IpParams::LOOPBACK)
    }

    /// UDP over loopback.
    pub fn udp() -> Self {
        LinkModel::Udp(IpParams::LOOPBACK)
    }

    /// The type name reported to scans (`docs/protocol.md`).
    pub fn type_name(&self) -> &'static str {
        match self {
            LinkModel::Uart(_) => "uart",
            LinkModel::Rs485(_) => "rs485",
            LinkModel::UsbCdc(_) => "usb_cdc",
            LinkModel::Tcp(_) => "tcp",
            LinkModel::Udp(_) => "udp",
        }
    }

    /// Whether the receiver pushes back on the sender: a USB device NAKs
    /// while its receive queue is full, and a TCP receive window closes, so
    /// nothing is lost to a slow reader. A UART, an RS-485 line and UDP have
    /// no such hand-shake: a reader that falls behind loses frames.
    pub fn is_flow_controlled(&self) -> bool {
        matches!(self, LinkModel::UsbCdc(_) | LinkModel::Tcp(_))
    }

    /// Whether packets travel as COBS/CRC frames on a byte stream (all but
    /// UDP, which carries bare packets).
    pub fn is_byte_stream(&self) -> bool {
        !matches!(self, LinkModel::Udp(_))
    }

    /// Largest packet, bytes.
    pub fn mtu(&self) -> u16 {
        match self {
            LinkModel::Uart(p) | LinkModel::Rs485(p) => p.mtu,
            LinkModel::UsbCdc(p) => p.mtu,
            LinkModel::Tcp(p) | LinkModel::Udp(p) => p.mtu,
        }
    }

    /// How end `side` stamps what it receives.
    pub fn stamp_mode(&self, side: Side) -> StampMode {
        match self {
            LinkModel::Uart(_) | LinkModel::Rs485(_) => StampMode::Wire,
            LinkModel::UsbCdc(p) => match side {
                Side::B => StampMode::Wire,
                Side::A if p.host_stamps => StampMode::Software,
                Side::A => StampMode::None,
            },
            LinkModel::Tcp(p) | LinkModel::Udp(p) => {
                if p.stamps {
                    StampMode::Software
                } else {
                    StampMode::None
                }
            }
        }
    }

    /// Checks every parameter; `link` names the link in the error.
    pub fn validate(&self, link: &str) -> Result<(), SimError> {
        let err = |m: String| Err(SimError::config(format!("link {link}: {m}")));
        let prob = |p: f64| (0.0..=1.0).contains(&p);
        let mtu = self.mtu();
        if !(16..=MAX_LINK_MTU).contains(&mtu) {
            return err(format!("mtu {mtu} must be within 16..={MAX_LINK_MTU}"));
        }
        match self {
            LinkModel::Uart(p) | LinkModel::Rs485(p) => {
                if !(1_200..=50_000_000).contains(&p.baud) {
                    return err(format!("baud {} must be within 1200..=50000000", p.baud));
                }
                if !(8..=12).contains(&p.bits_per_byte) {
                    return err(format!("bits_per_byte {} must be 8..=12", p.bits_per_byte));
                }
                if !(p.propagation_us.is_finite() && p.propagation_us >= 0.0) {
                    return err("propagation_us must be finite and >= 0".into());
                }
                if !p.asymmetry_us.is_finite() {
                    return err("asymmetry_us must be finite".into());
                }
                p.jitter.validate(&format!("link {link}: jitter"))?;
                if !prob(p.loss) || !prob(p.corrupt_per_byte) {
                    return err("loss and corrupt_per_byte must be probabilities in [0, 1]".into());
                }
                if p.tx_buffer_frames == 0 {
                    return err("tx_buffer_frames must be at least 1".into());
                }
            }
            LinkModel::UsbCdc(p) => {
                if p.bit_rate == 0 || p.max_packet == 0 {
                    return err("bit_rate and max_packet must be positive".into());
                }
                if !(p.frame_us.is_finite() && p.frame_us >= 1.0) {
                    return err("frame_us must be finite and >= 1".into());
                }
                if !(p.sof_phase_us.is_finite() && p.sof_phase_us >= 0.0) {
                    return err("sof_phase_us must be finite and >= 0".into());
                }
                p.slot.validate(&format!("link {link}: slot"))?;
                if p.slot.mean_us() >= p.frame_us {
                    return err("slot must lie within the frame".into());
                }
                p.host_tx_latency
                    .validate(&format!("link {link}: host_tx_latency"))?;
                p.host_rx_latency
                    .validate(&format!("link {link}: host_rx_latency"))?;
                if !prob(p.loss) {
                    return err("loss must be a probability in [0, 1]".into());
                }
                if p.host_tx_buffer_frames == 0 || p.device_tx_buffer_frames == 0 {
                    return err("transmit buffers must hold at least 1 frame".into());
                }
            }
            LinkModel::Tcp(p) | LinkModel::Udp(p) => {
                if p.bit_rate == 0 {
                    return err("bit_rate must be positive".into());
                }
                p.latency.validate(&format!("link {link}: latency"))?;
                if !p.asymmetry_us.is_finite() {
                    return err("asymmetry_us must be finite".into());
                }
                if !prob(p.loss) {
                    return err("loss must be a probability in [0, 1]".into());
                }
                if matches!(self, LinkModel::Tcp(_)) && p.loss != 0.0 {
                    return err("a TCP stream does not lose data: loss must be 0".into());
                }
                if p.tx_buffer_frames == 0 {
                    return err("tx_buffer_frames must be at least 1".into());
                }
            }
        }
        Ok(())
    }
}

/// One frame on its way across a link, as decided by the sender's
/// [`Transmitter`]. All times are true time, ns.
#[derive(Debug, Clone, PartialEq)]
pub struct Transit {
    /// When the runtime handed it to the gateway.
    pub sent_ns: Nanos,
    /// When it started onto the wire at the sender.
    pub start_ns: Nanos,
    /// When its first byte reached the receiver.
    pub first_byte_ns: Nanos,
    /// When its last byte reached the receiver.
    pub complete_ns: Nanos,
    /// When the receiver's software can see it (after the host's receive
    /// latency on USB; the same as `complete_ns` elsewhere).
    pub visible_ns: Nanos,
    /// Wire time of one byte, ns (to stamp frames that a corrupted
    /// delimiter made start in the middle of this chunk).
    pub ns_per_byte: f64,
    /// The bytes as they arrive (framed and possibly corrupted on byte
    /// streams; the bare packet on datagram links).
    pub bytes: Vec<u8>,
    /// Lost on the way: never delivered.
    pub lost: bool,
    /// Bytes corrupted on the way.
    pub corrupted: u32,
}

/// The sending half of one link end: wire state and randomness of the
/// direction from this end to the other.
#[derive(Debug, Clone)]
pub struct Transmitter {
    model: LinkModel,
    side: Side,
    rng: Rng,
    /// When the wire (or bus direction) is free for the next frame.
    wire_free: Nanos,
    /// When the last frame was ready to go (keeps a stream in order).
    last_ready: Nanos,
    /// When the last frame finished arriving (keeps a stream in order).
    last_arrival: Nanos,
    /// When the last frame became visible (keeps a stream in order).
    last_visible: Nanos,
    /// End times of the frames in the transmit buffer, oldest first.
    buffer: VecDeque<Nanos>,
}

/// Margin at the end of a USB frame in which no transfer starts, ns.
const USB_EOF_MARGIN_NS: Nanos = 10_000;

impl Transmitter {
    /// The transmitter of end `side` of a link of kind `model`.
    pub fn new(model: LinkModel, side: Side, rng: Rng) -> Self {
        Transmitter {
            model,
            side,
            rng,
            wire_free: 0,
            last_ready: 0,
            last_arrival: 0,
            last_visible: 0,
            buffer: VecDeque::new(),
        }
    }

    /// The link model.
    pub fn model(&self) -> &LinkModel {
        &self.model
    }

    /// Which end this is.
    pub fn side(&self) -> Side {
        self.side
    }

    /// How many frames the transmit buffer holds.
    pub fn buffer_limit(&self) -> usize {
        match &self.model {
            LinkModel::Uart(p) | LinkModel::Rs485(p) => p.tx_buffer_frames,
            LinkModel::UsbCdc(p) => match self.side {
                Side::A => p.host_tx_buffer_frames,
                Side::B => p.device_tx_buffer_frames,
            },
            LinkModel::Tcp(p) | LinkModel::Udp(p) => p.tx_buffer_frames,
        }
    }

    /// Frames still in the transmit buffer at `now` (not yet fully sent).
    pub fn buffered(&self, now: Nanos) -> usize {
        // End times are non-decreasing, so count from the back.
        self.buffer
            .iter()
            .rev()
            .take_while(|&&end| end > now)
            .count()
    }

    /// Whether another frame fits in the transmit buffer at `now`.
    pub fn clear_to_send(&self, now: Nanos) -> bool {
        self.buffered(now) < self.buffer_limit()
    }

    /// When the transmit buffer next frees a place, if it is full at `now`.
    pub fn next_free(&self, now: Nanos) -> Option<Nanos> {
        if self.clear_to_send(now) {
            return None;
        }
        self.buffer.iter().copied().find(|&end| end > now)
    }

    /// Wire time of `bytes` bytes as this link carries them, ns.
    pub fn wire_ns(&self, bytes: usize) -> Nanos {
        let bytes = bytes as u128;
        let ns = match &self.model {
            LinkModel::Uart(p) | LinkModel::Rs485(p) => {
                let baud = u128::from(p.baud);
                (bytes * u128::from(p.bits_per_byte) * 1_000_000_000 + baud / 2) / baud
            }
            LinkModel::UsbCdc(p) => {
                let max = u128::from(p.max_packet);
                let packets = bytes.div_ceil(max).max(1);
                let bits = (bytes + packets * u128::from(p.overhead_bytes_per_packet)) * 8;
                let rate = u128::from(p.bit_rate);
                (bits * 1_000_000_000 + rate / 2) / rate
            }
            LinkModel::Tcp(p) | LinkModel::Udp(p) => {
                let rate = u128::from(p.bit_rate);
                (bytes * 8 * 1_000_000_000 + rate / 2) / rate
            }
        };
        ns.min(u128::from(u64::MAX)) as Nanos
    }

    /// How long until a frame handed over at `now` would start onto the
    /// wire, as far as this end can know, ns: the drain time of the buffer
    /// ahead of it, and on a USB device the wait for the next frame's
    /// transfer slot (the device knows SOF timing; its slot position is taken
    /// at the mean of `slot`). The USB host cannot know and says 0.
    pub fn queue_delay_ns(&self, now: Nanos) -> Nanos {
        let drain = self.wire_free.saturating_sub(now);
        match (&self.model, self.side) {
            (LinkModel::UsbCdc(_), Side::A) => 0,
            (LinkModel::UsbCdc(p), Side::B) if p.in_frame_aligned => {
                let slot = self.next_sof(p, now) + us_to_ns(p.slot.mean_us());
                slot.max(self.wire_free).saturating_sub(now)
            }
            _ => drain,
        }
    }

    /// The first SOF at or after `t`.
    fn next_sof(&self, p: &UsbParams, t: Nanos) -> Nanos {
        let frame = us_to_ns(p.frame_us).max(1);
        let phase = us_to_ns(p.sof_phase_us);
        if t <= phase {
            return phase;
        }
        phase + (t - phase).div_ceil(frame) * frame
    }

    /// When a USB transfer of `dur` ns, ready at `ready`, starts on the bus:
    /// at its slot in the next frame, after whatever is already scheduled in
    /// that frame, moving to a later frame if it would run into the end of
    /// the frame.
    fn usb_start(&mut self, p: &UsbParams, ready: Nanos, dur: Nanos) -> Nanos {
        let frame = us_to_ns(p.frame_us).max(1);
        let mut sof = self.next_sof(p, ready);
        // Bounded: a transfer longer than a frame starts in the first frame
        // it can and runs over.
        for _ in 0..1000 {
            let slot = sof + p.slot.sample_ns(&mut self.rng);
            let start = slot.max(self.wire_free);
            if start + dur + USB_EOF_MARGIN_NS <= sof + frame || start == slot {
                return start;
            }
            sof += frame;
        }
        sof
    }

    /// Extra latency of this direction from the asymmetry setting, ns.
    fn asymmetry_ns(&self, asymmetry_us: f64) -> Nanos {
        let signed = match self.side {
            Side::A => asymmetry_us,
            Side::B => -asymmetry_us,
        };
        us_to_ns(signed.max(0.0))
    }

    /// Takes a frame (already framed on byte streams) handed over at `now`
    /// and decides its fate.
    pub fn transmit(&mut self, now: Nanos, mut bytes: Vec<u8>) -> Transit {
        let dur = self.wire_ns(bytes.len());
        let ns_per_byte = if bytes.is_empty() {
            0.0
        } else {
            dur as f64 / bytes.len() as f64
        };
        let model = self.model;
        let (start, first, complete, visible, loss, corrupt) = match &model {
            LinkModel::Uart(p) | LinkModel::Rs485(p) => {
                let start = now.max(self.wire_free);
                let latency = us_to_ns(p.propagation_us)
                    + self.asymmetry_ns(p.asymmetry_us)
                    + p.jitter.sample_ns(&mut self.rng);
                // A wire does not reorder: a frame starts arriving no
                // earlier than the previous one finished.
                let first = (start + latency).max(self.last_arrival);
                let complete = first + dur;
                (start, first, complete, complete, p.loss, p.corrupt_per_byte)
            }
            LinkModel::UsbCdc(p) => match self.side {
                Side::A => {
                    let ready =
                        (now + p.host_tx_latency.sample_ns(&mut self.rng)).max(self.last_ready);
                    self.last_ready = ready;
                    let start = if p.out_frame_aligned {
                        self.usb_start(p, ready, dur)
                    } else {
                        ready.max(self.wire_free)
                    };
                    (start, start, start + dur, start + dur, p.loss, 0.0)
                }
                Side::B => {
                    let start = if p.in_frame_aligned {
                        self.usb_start(p, now, dur)
                    } else {
                        (now + p.in_poll_delay.sample_ns(&mut self.rng)).max(self.wire_free)
                    };
                    let complete = start + dur;
                    let visible = (complete + p.host_rx_latency.sample_ns(&mut self.rng))
                        .max(self.last_visible);
                    (start, start, complete, visible, p.loss, 0.0)
                }
            },
            LinkModel::Tcp(p) | LinkModel::Udp(p) => {
                let start = now.max(self.wire_free);
                let latency =
                    p.latency.sample_ns(&mut self.rng) + self.asymmetry_ns(p.asymmetry_us);
                let mut complete = start + dur + latency;
                if matches!(model, LinkModel::Tcp(_)) {
                    complete = complete.max(self.last_arrival);
                }
                let first = complete - dur;
                (start, first, complete, complete, p.loss, 0.0)
            }
        };
        self.wire_free = start + dur;
        self.last_arrival = self.last_arrival.max(complete);
        self.last_visible = self.last_visible.max(visible);
        // The buffer holds the frame until its last byte has left.
        while self.buffer.front().is_some_and(|&end| end <= now) {
            self.buffer.pop_front();
        }
        self.buffer.push_back(start + dur);
        let lost = self.rng.chance(loss);
        let mut corrupted = 0;
        if corrupt > 0.0 {
            for b in bytes.iter_mut() {
                if self.rng.chance(corrupt) {
                    *b ^= 1 << self.rng.below(8);
                    corrupted += 1;
                }
            }
        }
        Transit {
            sent_ns: now,
            start_ns: start,
            first_byte_ns: first,
            complete_ns: complete,
            visible_ns: visible,
            ns_per_byte,
            bytes,
            lost,
            corrupted,
        }
    }
}
