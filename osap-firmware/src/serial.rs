//! Timing of an 8N1 serial line (the UART / RS-485 link): how long bytes
//! take on the wire, where on the wire a received chunk was, and
//! ([`SerialTiming`]) when what was handed to the transmitter will be out.

use core::cell::Cell;

use critical_section::Mutex;
use osap_core::framing::max_frame_len;
use osap_core::{Duration, Instant};

use crate::framer::ChunkTime;
use crate::link::WireTiming;

/// Bits on the wire per byte: start, 8 data, stop.
pub const BITS_PER_BYTE: u64 = 10;

/// When a UART's receive side hands bytes to software.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RxTrigger {
    /// The receive interrupt fires when the FIFO holds this many bytes
    /// (1 for a UART without a FIFO, which interrupts on every byte)...
    pub fifo_level: usize,
    /// ...or after this many idle bit times with fewer bytes waiting
    /// (0 when there is no such timeout).
    pub timeout_bits: u64,
}

impl RxTrigger {
    /// The RP2040's PL011 as embassy-rp sets it up: 7/8 of its 32-byte
    /// FIFO, or 32 idle bit times.
    pub const RP2040: RxTrigger = RxTrigger {
        fifo_level: 28,
        timeout_bits: 32,
    };
    /// A UART that interrupts on every received byte (the SAMD51's SERCOM,
    /// whose receive buffer is read a byte at a time).
    pub const PER_BYTE: RxTrigger = RxTrigger {
        fifo_level: 1,
        timeout_bits: 0,
    };
}

/// A serial line's timing at one baud rate, read through one kind of UART.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Serial {
    /// Bits per second.
    pub baud: u32,
    /// When the UART hands over received bytes.
    pub rx: RxTrigger,
}

impl Serial {
    /// Wire time of one byte, ns.
    pub const fn byte_ns(&self) -> u64 {
        BITS_PER_BYTE * 1_000_000_000 / self.baud as u64
    }

    /// Wire time of `bytes` bytes, µs, rounded up.
    pub const fn bytes_us(&self, bytes: u64) -> u64 {
        (bytes * self.byte_ns()).div_ceil(1000)
    }

    /// Wire time of `bytes` bytes, rounded up to the µs.
    pub const fn bytes_time(&self, bytes: u64) -> Duration {
        Duration::from_micros(self.bytes_us(bytes))
    }

    /// Where on the wire a chunk of `len` bytes was, read from the UART's
    /// receive buffer at local time `read_us`. A chunk shorter than the
    /// FIFO trigger level came with the receive timeout, that many idle bit
    /// times after its last byte; a longer one came with the level trigger,
    /// as its last byte landed. (Interrupt and task latency, a few µs, is
    /// not taken off.)
    pub fn chunk_time(&self, len: usize, read_us: u64) -> ChunkTime {
        let byte_ns = self.byte_ns();
        let mut last_end_ns = read_us * 1000;
        if len < self.rx.fifo_level {
            last_end_ns =
                last_end_ns.saturating_sub(self.rx.timeout_bits * byte_ns / BITS_PER_BYTE);
        }
        ChunkTime::Streamed {
            last_end_ns,
            byte_ns,
        }
    }
}

/// A serial link's wire timing: the line's rate, and when the transmitter
/// will have sent everything handed to it so far (kept by the board's
/// transmit task through [`SerialTiming::queue`]).
pub struct SerialTiming {
    line: Serial,
    /// Local time.
    wire_free_at: Mutex<Cell<Instant>>,
}

impl core::fmt::Debug for SerialTiming {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("SerialTiming")
            .field("line", &self.line)
            .finish_non_exhaustive()
    }
}

impl SerialTiming {
    /// An idle line.
    pub const fn new(line: Serial) -> Self {
        SerialTiming {
            line,
            wire_free_at: Mutex::new(Cell::new(Instant::ZERO)),
        }
    }

    /// The line.
    pub const fn line(&self) -> Serial {
        self.line
    }

    /// Notes `bytes` handed to the transmitter at local time `now`; returns
    /// when they will all be out.
    pub fn queue(&self, now: Instant, bytes: usize) -> Instant {
        critical_section::with(|cs| {
            let cell = self.wire_free_at.borrow(cs);
            let end = cell.get().max(now) + self.line.bytes_time(bytes as u64);
            cell.set(end);
            end
        })
    }

    /// Time from `now` until a packet sent now starts onto the wire, with
    /// `queued` bytes waiting ahead of it besides what the transmitter has.
    pub fn queue_delay_at(&self, now: Instant, queued: usize) -> Duration {
        let free_at = critical_section::with(|cs| self.wire_free_at.borrow(cs).get());
        (free_at - now) + self.line.bytes_time(queued as u64)
    }
}

impl WireTiming for SerialTiming {
    fn transmit_time(&self, len: usize) -> Duration {
        self.line.bytes_time(max_frame_len(len) as u64)
    }

    fn queue_delay(&self, queued: usize) -> Duration {
        self.queue_delay_at(crate::local_now(), queued)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_transmitter_queue_drains_at_the_line_rate() {
        let t = SerialTiming::new(RP);
        // 10 bytes at 1 Mbaud: 100 µs; a second burst queues behind it.
        assert_eq!(
            t.queue(Instant::from_micros(1_000), 10),
            Instant::from_micros(1_100)
        );
        assert_eq!(
            t.queue(Instant::from_micros(1_050), 5),
            Instant::from_micros(1_150)
        );
        assert_eq!(
            t.queue_delay_at(Instant::from_micros(1_100), 0),
            Duration::from_micros(50)
        );
        assert_eq!(
            t.queue_delay_at(Instant::from_micros(1_100), 3),
            Duration::from_micros(80)
        );
        // Once it has drained, a new burst starts from its own time.
        assert_eq!(
            t.queue_delay_at(Instant::from_micros(2_000), 0),
            Duration::ZERO
        );
        assert_eq!(
            t.queue(Instant::from_micros(2_000), 1),
            Instant::from_micros(2_010)
        );
    }

    const RP: Serial = Serial {
        baud: 1_000_000,
        rx: RxTrigger::RP2040,
    };

    #[test]
    fn byte_times() {
        assert_eq!(RP.byte_ns(), 10_000);
        assert_eq!(RP.bytes_us(19), 190);
        let fast = Serial {
            baud: 3_000_000,
            ..RP
        };
        assert_eq!(fast.byte_ns(), 3_333);
        // Rounded up: 3 bytes are 9.999 µs on the wire.
        assert_eq!(fast.bytes_us(3), 10);
    }

    #[test]
    fn short_chunks_came_with_the_timeout() {
        match RP.chunk_time(19, 5_000) {
            // 32 bit times of 1 µs before the read.
            ChunkTime::Streamed {
                last_end_ns,
                byte_ns,
            } => assert_eq!((last_end_ns, byte_ns), (4_968_000, 10_000)),
            ChunkTime::Completed(_) => panic!("serial chunks are streamed"),
        }
        match RP.chunk_time(28, 5_000) {
            ChunkTime::Streamed { last_end_ns, .. } => assert_eq!(last_end_ns, 5_000_000),
            ChunkTime::Completed(_) => panic!("serial chunks are streamed"),
        }
    }

    #[test]
    fn per_byte_uarts_stamp_as_the_byte_lands() {
        let s = Serial {
            baud: 1_000_000,
            rx: RxTrigger::PER_BYTE,
        };
        for len in [1, 5] {
            match s.chunk_time(len, 7_000) {
                ChunkTime::Streamed { last_end_ns, .. } => assert_eq!(last_end_ns, 7_000_000),
                ChunkTime::Completed(_) => panic!("serial chunks are streamed"),
            }
        }
    }
}
