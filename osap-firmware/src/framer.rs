//! Splitting a received byte stream into packets, each stamped with when
//! it arrived.
//!
//! A link's receive task hands the framer chunks as they come (a USB bulk
//! packet, or what a UART's ring buffer held) with how the chunk relates to
//! time ([`ChunkTime`]); the framer finds the frames (WIRE.md §5, decoded by
//! osap-core's [`FrameDecoder`]) and stamps each with the start of its
//! first byte, as near as the link can tell.

use osap_core::framing::{FrameDecoder, FrameError};

/// How a received chunk of bytes relates to local time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ChunkTime {
    /// The chunk arrived whole at this local time, µs (a USB packet's
    /// completion); a frame is stamped with the arrival of the chunk it
    /// started in.
    Completed(u64),
    /// The chunk's bytes came back-to-back off a serial line, the last
    /// one's stop bit ending at `last_end_ns` (local time, ns), `byte_ns`
    /// apart; a frame is stamped with the start of its first byte, counted
    /// back from its delimiter. (Senders write frames back-to-back; a
    /// sender that pauses inside a frame makes its stamp late.)
    Streamed {
        /// End of the chunk's last byte, local ns.
        last_end_ns: u64,
        /// Wire time of one byte, ns.
        byte_ns: u64,
    },
}

/// What [`RxFramer::next`] found.
#[derive(Debug, PartialEq, Eq)]
pub enum Next<'a> {
    /// A good packet and its time stamp (local µs).
    Packet(&'a [u8], u64),
    /// A bad frame, dropped.
    Bad(FrameError),
    /// An empty frame (a lone delimiter): nothing to deliver.
    Empty,
    /// The chunk is used up.
    End,
}

/// Splits a received byte stream into packets and stamps each. `N` is the
/// longest frame accepted, delimiter included (`max_frame_len(MTU)`).
#[derive(Debug)]
pub struct RxFramer<const N: usize> {
    decoder: FrameDecoder<N>,
    /// Bytes of the current partial frame seen in earlier chunks.
    carried: usize,
    /// Arrival of the chunk the partial frame started in (completed chunks).
    partial_start: Option<u64>,
}

impl<const N: usize> Default for RxFramer<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> RxFramer<N> {
    /// A framer waiting for the start of a frame.
    pub const fn new() -> Self {
        RxFramer {
            decoder: FrameDecoder::new(),
            carried: 0,
            partial_start: None,
        }
    }

    /// Forgets a partial frame (after a line error or a reconnect).
    pub fn reset(&mut self) {
        self.decoder.reset();
        self.carried = 0;
        self.partial_start = None;
    }

    /// Takes bytes from the front of `rest` (the unread tail of a chunk)
    /// up to and including the next frame delimiter and says what they
    /// were; call until it returns [`Next::End`]. A frame left incomplete
    /// at the end of the chunk is kept for the next one.
    pub fn next(&mut self, rest: &mut &[u8], time: ChunkTime) -> Next<'_> {
        let Some(pos) = rest.iter().position(|&b| b == 0) else {
            if !rest.is_empty() {
                self.carried += rest.len();
                if let ChunkTime::Completed(t) = time {
                    self.partial_start.get_or_insert(t);
                }
            }
            let mut tail = *rest;
            *rest = &[];
            // No delimiter: the decoder only buffers the bytes.
            let _ = self.decoder.decode(&mut tail);
            return Next::End;
        };
        let (segment, after) = rest.split_at(pos + 1);
        *rest = after;
        let frame_bytes = self.carried + segment.len();
        let stamp = match time {
            ChunkTime::Completed(t) => self.partial_start.unwrap_or(t),
            ChunkTime::Streamed {
                last_end_ns,
                byte_ns,
            } => {
                // Back from the end of the chunk's last byte over the bytes
                // after the delimiter, then over the whole frame.
                let back = (after.len() + frame_bytes) as u64 * byte_ns;
                last_end_ns.saturating_sub(back) / 1000
            }
        };
        self.carried = 0;
        self.partial_start = None;
        let mut input = segment;
        match self.decoder.decode(&mut input) {
            Some(Ok(packet)) => Next::Packet(packet, stamp),
            Some(Err(e)) => Next::Bad(e),
            None => Next::Empty,
        }
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use osap_core::framing::{encode_frame, max_frame_len};
    use std::vec::Vec;

    const FRAME: usize = max_frame_len(64);

    fn frame(packet: &[u8]) -> Vec<u8> {
        let mut out = [0u8; FRAME];
        let n = encode_frame(packet, &mut out).unwrap();
        out[..n].to_vec()
    }

    /// Everything the framer makes of one chunk, packets copied.
    fn run(f: &mut RxFramer<FRAME>, chunk: &[u8], time: ChunkTime) -> Vec<(Vec<u8>, u64)> {
        let mut rest = chunk;
        let mut out = Vec::new();
        loop {
            match f.next(&mut rest, time) {
                Next::Packet(p, t) => out.push((p.to_vec(), t)),
                Next::Bad(_) | Next::Empty => {}
                Next::End => return out,
            }
        }
    }

    #[test]
    fn completed_chunks_stamp_the_chunk_a_frame_started_in() {
        let mut f = RxFramer::<FRAME>::new();
        let a = frame(&[1, 2, 3, 4, 5, 6, 7, 8, 9, 10]);
        let b = frame(&[11, 0, 12]);
        // `a` split over two packets, `b` whole in the second.
        let (head, tail) = a.split_at(4);
        assert_eq!(run(&mut f, head, ChunkTime::Completed(100)), []);
        let mut second = tail.to_vec();
        second.extend_from_slice(&b);
        assert_eq!(
            run(&mut f, &second, ChunkTime::Completed(1100)),
            [
                ((1..=10).collect::<Vec<u8>>(), 100),
                (std::vec![11, 0, 12], 1100)
            ]
        );
        // Nothing carried over into the next chunk.
        let c = frame(&[7]);
        assert_eq!(
            run(&mut f, &c, ChunkTime::Completed(2100)),
            [(std::vec![7], 2100)]
        );
    }

    #[test]
    fn streamed_chunks_count_back_from_the_last_byte() {
        let mut f = RxFramer::<FRAME>::new();
        let a = frame(&[1, 2, 3]); // 3 + 2 CRC + 1 overhead + delimiter = 7 bytes
        let b = frame(&[4, 5, 6, 7, 8]); // 9 bytes
        assert_eq!((a.len(), b.len()), (7, 9));
        let mut chunk = a.clone();
        chunk.extend_from_slice(&b);
        // 1 Mbaud: 10 µs a byte; the last byte's stop bit ended at 1000 µs.
        let time = ChunkTime::Streamed {
            last_end_ns: 1_000_000,
            byte_ns: 10_000,
        };
        assert_eq!(
            run(&mut f, &chunk, time),
            [
                // `a` started 16 bytes before the end, `b` 9 bytes.
                (std::vec![1, 2, 3], 840),
                (std::vec![4, 5, 6, 7, 8], 910)
            ]
        );
    }

    #[test]
    fn streamed_frame_over_two_chunks() {
        let mut f = RxFramer::<FRAME>::new();
        let a = frame(&[9; 20]);
        assert_eq!(a.len(), 24);
        let (head, tail) = a.split_at(10);
        let t = |end_us: u64| ChunkTime::Streamed {
            last_end_ns: end_us * 1000,
            byte_ns: 10_000,
        };
        assert_eq!(run(&mut f, head, t(500)), []);
        // The frame's 24 bytes end at 650 µs: it started at 410.
        assert_eq!(run(&mut f, tail, t(650)), [(std::vec![9; 20], 410)]);
    }

    #[test]
    fn bad_and_empty_frames_are_reported_and_skipped() {
        let mut f = RxFramer::<FRAME>::new();
        let mut bad = frame(&[1, 2, 3]);
        bad[2] ^= 0x40;
        let mut chunk = std::vec![0, 0];
        chunk.extend_from_slice(&bad);
        chunk.extend_from_slice(&frame(&[5]));
        let mut rest = &chunk[..];
        let time = ChunkTime::Completed(7);
        assert_eq!(f.next(&mut rest, time), Next::Empty);
        assert_eq!(f.next(&mut rest, time), Next::Empty);
        assert_eq!(f.next(&mut rest, time), Next::Bad(FrameError::Crc));
        assert_eq!(f.next(&mut rest, time), Next::Packet(&[5], 7));
        assert_eq!(f.next(&mut rest, time), Next::End);
    }

    #[test]
    fn reset_drops_a_partial_frame() {
        let mut f = RxFramer::<FRAME>::new();
        let a = frame(&[1, 2, 3, 4]);
        assert_eq!(run(&mut f, &a[..3], ChunkTime::Completed(1)), []);
        f.reset();
        let b = frame(&[6]);
        assert_eq!(
            run(&mut f, &b, ChunkTime::Completed(2)),
            [(std::vec![6], 2)]
        );
    }

    #[test]
    fn oversize_frames_are_bad() {
        let mut f = RxFramer::<8>::new();
        let a = frame(&[1; 20]);
        let mut rest = &a[..];
        assert_eq!(
            f.next(&mut rest, ChunkTime::Completed(0)),
            Next::Bad(FrameError::Oversize)
        );
    }
}
