//! Timing of an 8N1 serial line (the UART / RS-485 link).

use crate::framer::ChunkTime;

/// Bits on the wire per byte: start, 8 data, stop.
pub const BITS_PER_BYTE: u64 = 10;

/// The RP2040 UART's receive interrupt fires when its FIFO holds this many
/// bytes (7/8 of 32, as embassy-rp sets it)...
pub const RX_FIFO_LEVEL: usize = 28;
/// ...or after this many idle bit times with bytes waiting.
pub const RX_TIMEOUT_BITS: u64 = 32;

/// A serial line's timing at one baud rate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Serial {
    /// Bits per second.
    pub baud: u32,
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

    /// Where on the wire a chunk of `len` bytes was, read from the UART's
    /// receive buffer at local time `read_us`. A chunk shorter than the
    /// FIFO trigger level came with the receive timeout, 32 idle bit times
    /// after its last byte; a longer one came with the level trigger, as
    /// its last byte landed. (Interrupt and task latency, a few µs, is not
    /// taken off.)
    pub fn chunk_time(&self, len: usize, read_us: u64) -> ChunkTime {
        let byte_ns = self.byte_ns();
        let mut last_end_ns = read_us * 1000;
        if len < RX_FIFO_LEVEL {
            last_end_ns = last_end_ns.saturating_sub(RX_TIMEOUT_BITS * byte_ns / BITS_PER_BYTE);
        }
        ChunkTime::Streamed {
            last_end_ns,
            byte_ns,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn byte_times() {
        let s = Serial { baud: 1_000_000 };
        assert_eq!(s.byte_ns(), 10_000);
        assert_eq!(s.bytes_us(19), 190);
        let fast = Serial { baud: 3_000_000 };
        assert_eq!(fast.byte_ns(), 3_333);
        // Rounded up: 3 bytes are 9.999 µs on the wire.
        assert_eq!(fast.bytes_us(3), 10);
    }

    #[test]
    fn short_chunks_came_with_the_timeout() {
        let s = Serial { baud: 1_000_000 };
        match s.chunk_time(19, 5_000) {
            // 32 bit times of 1 µs before the read.
            ChunkTime::Streamed {
                last_end_ns,
                byte_ns,
            } => assert_eq!((last_end_ns, byte_ns), (4_968_000, 10_000)),
            ChunkTime::Completed(_) => panic!("serial chunks are streamed"),
        }
        match s.chunk_time(28, 5_000) {
            ChunkTime::Streamed { last_end_ns, .. } => assert_eq!(last_end_ns, 5_000_000),
            ChunkTime::Completed(_) => panic!("serial chunks are streamed"),
        }
    }
}
