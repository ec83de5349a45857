//! Framing of OSAP packets on byte-stream links.
//!
//! Links such as UARTs, RS-485, USB-CDC, TCP streams, pipes and PTYs deliver an
//! undivided stream of bytes, so each packet is wrapped in a frame that the
//! receiver can find again on its own:
//!
//! ```text
//! frame = COBS(packet || crc16(packet)) || 0x00
//! ```
//!
//! - The packet gets a 16-bit CRC appended, most significant byte first. The
//!   CRC is CRC-16/IBM-3740 (often called CCITT-FALSE): polynomial `0x1021`,
//!   initial value `0xFFFF`, no bit reflection, no final XOR.
//! - Packet and CRC together are COBS-encoded, which removes every `0x00` byte
//!   for the cost of at most one extra byte per 254 bytes, plus one.
//! - A single `0x00` ends the frame. Because it cannot occur inside a frame, a
//!   receiver that starts listening mid-stream, or that loses bytes, is back in
//!   step at the next `0x00`.
//!
//! A run of several `0x00` bytes is legal: the empty frames between them are
//! ignored, so a sender may emit a lone `0x00` to mark a frame boundary on an
//! idle line or after a reconnect.
//!
//! [`encode_frame`] writes one frame into a caller-provided buffer.
//! [`FrameDecoder`] splits an incoming byte stream into packets, however the
//! stream is chunked, and drops (and counts) any frame that fails COBS
//! decoding or the CRC, so corrupted data never reaches the packet stack.
//!
//! Nothing here allocates; the decoder keeps one fixed-size buffer and decodes
//! in place.

use core::fmt;

/// How the CRC is computed. Small targets get the one 512-byte table; 64-bit
/// targets (hosts, where memory is plentiful) get the 8 KiB slice-by-16
/// tables, about 9x faster, so a busy host link is not CRC-bound.
#[cfg(not(target_pointer_width = "64"))]
type CrcImpl = crc::Table<1>;
#[cfg(target_pointer_width = "64")]
type CrcImpl = crc::Table<16>;

/// The CRC algorithm of the wire format. A `static` so the lookup table
/// exists once rather than once per use.
static CRC16: crc::Crc<u16, CrcImpl> = crc::Crc::<u16, CrcImpl>::new(&crc::CRC_16_IBM_3740);

/// Bytes of CRC appended to every packet.
const CRC_LEN: usize = 2;

/// Longest run of non-zero bytes one COBS block can carry.
const COBS_MAX_RUN: usize = 254;

/// The frame delimiter.
const DELIMITER: u8 = 0x00;

/// Computes the CRC-16/IBM-3740 of `data` as used by the framing (poly
/// `0x1021`, init `0xFFFF`, not reflected, no final XOR). The check value, the
/// CRC of the ASCII string `"123456789"`, is `0x29B1`.
pub fn crc16(data: &[u8]) -> u16 {
    CRC16.checksum(data)
}

/// The largest frame, delimiter included, that [`encode_frame`] can produce
/// for a packet of `packet_len` bytes.
///
/// This is the size to give the output buffer of [`encode_frame`], and the
/// `N` to give a [`FrameDecoder`] that must accept packets of up to
/// `packet_len` bytes.
pub const fn max_frame_len(packet_len: usize) -> usize {
    corncobs::max_encoded_len(packet_len + CRC_LEN)
}

/// Why a frame could not be encoded or decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum FrameError {
    /// The frame is not valid COBS (a block runs past the end of the frame).
    Cobs,
    /// The frame decoded, but its CRC does not match its contents.
    Crc,
    /// The frame decoded to fewer bytes than the CRC alone needs.
    TooShort,
    /// The frame was longer than the decoder's buffer; it was discarded up to
    /// its delimiter.
    Oversize,
    /// The encoder's output buffer is smaller than
    /// [`max_frame_len`]`(packet.len())`.
    OutputTooSmall,
}

impl fmt::Display for FrameError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            FrameError::Cobs => "frame is not valid COBS",
            FrameError::Crc => "frame CRC mismatch",
            FrameError::TooShort => "frame too short to hold a CRC",
            FrameError::Oversize => "frame longer than the receive buffer",
            FrameError::OutputTooSmall => "output buffer too small for the frame",
        })
    }
}

impl core::error::Error for FrameError {}

/// Encodes `packet` as one complete frame, trailing `0x00` included, at the
/// start of `out` and returns the frame's length.
///
/// `out` must be at least [`max_frame_len`]`(packet.len())` bytes long, even
/// if the actual frame would be shorter; otherwise nothing useful is written
/// and [`FrameError::OutputTooSmall`] is returned. The function never panics
/// and needs no buffer besides `out` and 255 bytes of stack.
pub fn encode_frame(packet: &[u8], out: &mut [u8]) -> Result<usize, FrameError> {
    if out.len() < max_frame_len(packet.len()) {
        return Err(FrameError::OutputTooSmall);
    }
    let crc = crc16(packet).to_be_bytes();

    // corncobs only encodes one contiguous slice, and copying the whole packet
    // next to its CRC would need a scratch buffer as large as the largest
    // packet. COBS output is a sequence of independent blocks, though, so
    // the packet is split where a block must end anyway: `head` is encoded
    // straight from the caller's slice, and only the last partial block
    // (under 254 bytes) is copied next to the CRC and encoded after it.
    //
    // A block ends after each 0x00 and after every 254 non-zero bytes, so
    // the split goes after the last 0x00 plus all full 254-byte chunks of the
    // zero-free run that follows it.
    let run_start = packet
        .iter()
        .rposition(|&b| b == DELIMITER)
        .map_or(0, |i| i + 1);
    let run_len = packet.len() - run_start;
    let split = run_start + run_len / COBS_MAX_RUN * COBS_MAX_RUN;
    // `split <= packet.len()` and `tail.len() < 254` by construction; the
    // checked forms below just keep every path panic-free.
    let (head, tail) = packet
        .split_at_checked(split)
        .ok_or(FrameError::OutputTooSmall)?;

    let mut pos = 0;
    if !head.is_empty() {
        let n = corncobs::encode_buf(head, out);
        // Drop the delimiter. If `head` ends in 0x00, corncobs also ended it
        // with an empty block (0x01), there only so that the zero before it
        // is not the end of the data; the tail's blocks take its place.
        let dropped = if head.last() == Some(&DELIMITER) {
            2
        } else {
            1
        };
        pos = n.saturating_sub(dropped);
    }

    let mut scratch = [0u8; COBS_MAX_RUN - 1 + CRC_LEN];
    let last_len = tail.len() + CRC_LEN;
    let last = scratch
        .get_mut(..last_len)
        .ok_or(FrameError::OutputTooSmall)?;
    let (last_data, last_crc) = last.split_at_mut(tail.len());
    last_data.copy_from_slice(tail);
    last_crc.copy_from_slice(&crc);

    // Room check for the second half. It always passes when `out` holds
    // `max_frame_len`: `head`'s blocks cost at most one byte per full 254
    // bytes of `head`, which is what the bound budgets for them. Kept so that
    // a flaw in that argument cannot turn into a panic inside corncobs.
    let rest = out
        .get_mut(pos..)
        .filter(|r| r.len() >= corncobs::max_encoded_len(last_len))
        .ok_or(FrameError::OutputTooSmall)?;
    let n = corncobs::encode_buf(last, rest);
    Ok(pos + n)
}

/// Running statistics of a [`FrameDecoder`]. All counts wrap on overflow.
///
/// Every result that [`FrameDecoder::decode`] returns increments exactly one
/// of `frames_ok`, `cobs_errors`, `crc_errors`, `too_short` and `oversize`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FrameCounters {
    /// Frames decoded and delivered with a valid CRC.
    pub frames_ok: u32,
    /// Frames dropped because they were not valid COBS.
    pub cobs_errors: u32,
    /// Frames dropped because the CRC did not match.
    pub crc_errors: u32,
    /// Frames dropped because they decoded to fewer than two bytes.
    pub too_short: u32,
    /// Frames dropped because they did not fit the decoder's buffer.
    pub oversize: u32,
    /// Bytes consumed from the input, delimiters included.
    pub bytes_in: u32,
}

impl FrameCounters {
    const fn new() -> Self {
        FrameCounters {
            frames_ok: 0,
            cobs_errors: 0,
            crc_errors: 0,
            too_short: 0,
            oversize: 0,
            bytes_in: 0,
        }
    }
}

/// Incremental decoder that turns a byte stream into packets.
///
/// `N` is the longest frame it accepts, counting the trailing `0x00`; to
/// accept every packet of up to `P` bytes use `N = max_frame_len(P)`. The
/// decoder holds an `[u8; N]` buffer and decodes frames in place in it.
///
/// ```
/// use osap_core::framing::{encode_frame, max_frame_len, FrameDecoder};
///
/// let mut frame = [0u8; max_frame_len(3)];
/// let len = encode_frame(&[1, 0, 2], &mut frame).unwrap();
///
/// let mut dec = FrameDecoder::<{ max_frame_len(64) }>::new();
/// let mut input = &frame[..len];
/// while let Some(result) = dec.decode(&mut input) {
///     assert_eq!(result, Ok(&[1u8, 0, 2][..]));
/// }
/// ```
#[derive(Debug, Clone)]
pub struct FrameDecoder<const N: usize> {
    buf: [u8; N],
    /// Encoded bytes of the current frame held in `buf`.
    len: usize,
    /// The current frame overflowed `buf`; skip to its delimiter.
    discarding: bool,
    counters: FrameCounters,
}

impl<const N: usize> Default for FrameDecoder<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> FrameDecoder<N> {
    /// Largest encoded frame body (without the delimiter) that fits.
    const MAX_BODY: usize = N.saturating_sub(1);

    /// Creates a decoder with an empty buffer and zeroed counters.
    pub const fn new() -> Self {
        FrameDecoder {
            buf: [0; N],
            len: 0,
            discarding: false,
            counters: FrameCounters::new(),
        }
    }

    /// The decoder's statistics since it was created.
    pub fn counters(&self) -> &FrameCounters {
        &self.counters
    }

    /// Forgets any partially received frame, e.g. when the link reconnects,
    /// so that its bytes are not glued to the start of the next frame.
    /// Counters are kept.
    pub fn reset(&mut self) {
        self.len = 0;
        self.discarding = false;
    }

    /// Consumes bytes from the front of `input` up to and including the next
    /// frame delimiter, advancing `input` past them.
    ///
    /// Returns
    /// - `Some(Ok(packet))` when a valid frame ended; `packet` excludes the
    ///   CRC and borrows the decoder's buffer until the next call;
    /// - `Some(Err(e))` when a bad frame ended (it has been dropped and
    ///   counted);
    /// - `None` when `input` ran out before a delimiter; `input` is then
    ///   empty and the partial frame is kept for the next call.
    ///
    /// Empty frames (consecutive `0x00` bytes) are skipped silently. Call it
    /// in a loop, `while let Some(r) = dec.decode(&mut input) { .. }`, to
    /// drain a chunk of input. Never panics, whatever the bytes.
    pub fn decode<'a>(&'a mut self, input: &mut &[u8]) -> Option<Result<&'a [u8], FrameError>> {
        loop {
            let Some(end) = input.iter().position(|&b| b == DELIMITER) else {
                self.absorb(input);
                *input = &[];
                return None;
            };
            let (body, rest) = input.split_at(end);
            *input = rest.get(1..).unwrap_or_default();
            self.absorb(body);
            self.counters.bytes_in = self.counters.bytes_in.wrapping_add(1);

            let frame_len = core::mem::replace(&mut self.len, 0);
            if core::mem::replace(&mut self.discarding, false) {
                self.counters.oversize = self.counters.oversize.wrapping_add(1);
                return Some(Err(FrameError::Oversize));
            }
            if frame_len == 0 {
                continue;
            }
            return Some(self.finish(frame_len));
        }
    }

    /// Appends frame bytes (no delimiter) to the buffer, or switches to
    /// discarding if they do not fit.
    fn absorb(&mut self, bytes: &[u8]) {
        // usize -> u32 truncation only affects a wrapping statistic.
        self.counters.bytes_in = self.counters.bytes_in.wrapping_add(bytes.len() as u32);
        if self.discarding || bytes.is_empty() {
            return;
        }
        let new_len = self.len.saturating_add(bytes.len());
        match self.buf.get_mut(self.len..new_len) {
            Some(dst) if new_len <= Self::MAX_BODY => {
                dst.copy_from_slice(bytes);
                self.len = new_len;
            }
            _ => {
                self.len = 0;
                self.discarding = true;
            }
        }
    }

    /// Decodes and checks the `frame_len` encoded bytes in the buffer, and
    /// counts the outcome.
    fn finish(&mut self, frame_len: usize) -> Result<&[u8], FrameError> {
        let c = &mut self.counters;
        let decoded = match self.buf.get_mut(..frame_len).map(corncobs::decode_in_place) {
            Some(Ok(n)) => self.buf.get(..n).unwrap_or_default(),
            // `frame_len <= N` always holds, so `None` cannot happen.
            Some(Err(_)) | None => {
                c.cobs_errors = c.cobs_errors.wrapping_add(1);
                return Err(FrameError::Cobs);
            }
        };
        let Some(split) = decoded.len().checked_sub(CRC_LEN) else {
            c.too_short = c.too_short.wrapping_add(1);
            return Err(FrameError::TooShort);
        };
        let (packet, crc) = decoded.split_at(split);
        if crc != crc16(packet).to_be_bytes() {
            c.crc_errors = c.crc_errors.wrapping_add(1);
            return Err(FrameError::Crc);
        }
        c.frames_ok = c.frames_ok.wrapping_add(1);
        Ok(packet)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Decodes all of `stream` and collects the results (packets copied).
    fn decode_all<const N: usize>(
        dec: &mut FrameDecoder<N>,
        mut stream: &[u8],
    ) -> heapless::Vec<Result<heapless::Vec<u8, 512>, FrameError>, 32> {
        let mut results = heapless::Vec::new();
        while let Some(r) = dec.decode(&mut stream) {
            let r = r.map(|p| heapless::Vec::from_slice(p).unwrap());
            results.push(r).unwrap();
        }
        results
    }

    fn frame(packet: &[u8]) -> heapless::Vec<u8, 600> {
        let mut out = [0u8; 600];
        let n = encode_frame(packet, &mut out).unwrap();
        heapless::Vec::from_slice(&out[..n]).unwrap()
    }

    const GOLDEN_PACKET: [u8; 10] = [0x05, 0xe8, 0x03, 0x00, 0x01, 0xc0, 0x00, 0x01, 0x00, 0x2a];
    // CRC-16/IBM-3740 of the packet is 0x4154; the COBS blocks of
    // packet||41 54 are [05 e8 03] [01 c0] [01] [2a 41 54].
    const GOLDEN_FRAME: [u8; 14] = [
        0x04, 0x05, 0xe8, 0x03, 0x03, 0x01, 0xc0, 0x02, 0x01, 0x04, 0x2a, 0x41, 0x54, 0x00,
    ];

    #[test]
    fn crc_check_value() {
        assert_eq!(crc16(b"123456789"), 0x29B1);
        assert_eq!(crc16(&GOLDEN_PACKET), 0x4154);
    }

    #[test]
    fn golden_vector_encodes() {
        assert_eq!(frame(&GOLDEN_PACKET)[..], GOLDEN_FRAME[..]);
    }

    #[test]
    fn golden_vector_decodes() {
        let mut dec = FrameDecoder::<64>::new();
        let mut input = &GOLDEN_FRAME[..];
        assert_eq!(dec.decode(&mut input), Some(Ok(&GOLDEN_PACKET[..])));
        assert!(input.is_empty());
        assert_eq!(dec.decode(&mut input), None);
        assert_eq!(dec.counters().frames_ok, 1);
        assert_eq!(dec.counters().bytes_in, 14);
    }

    #[test]
    fn empty_packet_round_trips() {
        // CRC of nothing is the init value 0xFFFF.
        assert_eq!(frame(&[])[..], [0x03, 0xff, 0xff, 0x00]);
        let mut dec = FrameDecoder::<8>::new();
        let mut input = &[0x03, 0xff, 0xff, 0x00][..];
        assert_eq!(dec.decode(&mut input), Some(Ok(&[][..])));
    }

    /// Packets whose last block boundaries sit at or near 254-byte runs, the
    /// tricky cases for the split encoder, must match a one-shot COBS of
    /// packet||crc.
    #[test]
    fn encoder_matches_one_shot_cobs_at_block_edges() {
        let mut packet = [0u8; 600];
        let mut joined = [0u8; 602];
        let mut expected = [0u8; 700];
        let mut out = [0u8; 700];
        for len in (0usize..20).chain(240..270).chain(490..530).chain(590..600) {
            for zero_at in [
                None,
                Some(0),
                Some(1),
                Some(len / 2),
                Some(len.saturating_sub(1)),
            ] {
                for fill in [0x01u8, 0xff] {
                    let p = &mut packet[..len];
                    p.fill(fill);
                    if let Some(z) = zero_at.filter(|&z| z < len) {
                        p[z] = 0;
                    }
                    let crc = crc16(p).to_be_bytes();
                    joined[..len].copy_from_slice(p);
                    joined[len..len + 2].copy_from_slice(&crc);
                    let n_exp = corncobs::encode_buf(&joined[..len + 2], &mut expected);
                    let n = encode_frame(p, &mut out[..max_frame_len(len)]).unwrap();
                    assert_eq!(out[..n], expected[..n_exp], "len {len} zero_at {zero_at:?}");
                }
            }
        }
    }

    #[test]
    fn crc_containing_zero_bytes() {
        // Find packets whose CRC has a 0x00 high or low byte, so the COBS
        // split has to handle zeros inside the appended CRC.
        let mut found = [false; 2];
        for i in 0u16..=u16::MAX {
            let p = i.to_le_bytes();
            let crc = crc16(&p).to_be_bytes();
            for (k, f) in found.iter_mut().enumerate() {
                if crc[k] == 0 && !*f {
                    *f = true;
                    let fr = frame(&p);
                    let mut dec = FrameDecoder::<16>::new();
                    assert_eq!(
                        decode_all(&mut dec, &fr)[..],
                        [Ok(heapless::Vec::from_slice(&p).unwrap())]
                    );
                }
            }
        }
        assert_eq!(found, [true, true]);
    }

    #[test]
    fn output_too_small() {
        let mut out = [0u8; 13];
        assert_eq!(
            encode_frame(&GOLDEN_PACKET, &mut out),
            Err(FrameError::OutputTooSmall)
        );
        assert_eq!(encode_frame(&[], &mut []), Err(FrameError::OutputTooSmall));
    }

    #[test]
    fn empty_frames_are_skipped() {
        let mut stream = heapless::Vec::<u8, 64>::new();
        stream.extend_from_slice(&[0, 0, 0]).unwrap();
        stream.extend_from_slice(&GOLDEN_FRAME).unwrap();
        stream.extend_from_slice(&[0, 0]).unwrap();
        stream.extend_from_slice(&GOLDEN_FRAME).unwrap();
        stream.extend_from_slice(&[0]).unwrap();
        let mut dec = FrameDecoder::<64>::new();
        let r = decode_all(&mut dec, &stream);
        assert_eq!(r.len(), 2);
        assert!(r.iter().all(|r| r.as_deref() == Ok(&GOLDEN_PACKET[..])));
        let c = dec.counters();
        assert_eq!(
            (
                c.frames_ok,
                c.cobs_errors,
                c.crc_errors,
                c.too_short,
                c.oversize
            ),
            (2, 0, 0, 0, 0)
        );
        assert_eq!(c.bytes_in as usize, stream.len());
    }

    #[test]
    fn byte_by_byte_feed() {
        let mut dec = FrameDecoder::<64>::new();
        let mut got = 0;
        for b in GOLDEN_FRAME.iter().chain(GOLDEN_FRAME.iter()) {
            let mut input = core::slice::from_ref(b);
            while let Some(r) = dec.decode(&mut input) {
                assert_eq!(r, Ok(&GOLDEN_PACKET[..]));
                got += 1;
            }
        }
        assert_eq!(got, 2);
    }

    #[test]
    fn bad_crc_is_reported_once() {
        let mut bad = GOLDEN_FRAME;
        bad[2] ^= 0x10; // a data byte, still non-zero: COBS stays valid
        let mut dec = FrameDecoder::<64>::new();
        let r = decode_all(&mut dec, &bad);
        assert_eq!(r[..], [Err(FrameError::Crc)]);
        assert_eq!(dec.counters().crc_errors, 1);
    }

    #[test]
    fn bad_cobs_and_too_short() {
        let mut dec = FrameDecoder::<64>::new();
        // A block claiming 4 data bytes with only 1 present.
        assert_eq!(
            decode_all(&mut dec, &[0x05, 0xaa, 0x00])[..],
            [Err(FrameError::Cobs)]
        );
        // Decodes to a single byte: no room for a CRC.
        assert_eq!(
            decode_all(&mut dec, &[0x02, 0xaa, 0x00])[..],
            [Err(FrameError::TooShort)]
        );
        assert_eq!(
            decode_all(&mut dec, &[0x01, 0x00])[..],
            [Err(FrameError::TooShort)]
        );
        let c = dec.counters();
        assert_eq!((c.cobs_errors, c.too_short), (1, 2));
    }

    #[test]
    fn oversize_frame_is_discarded_and_reported_once() {
        // The golden frame is 14 bytes with its delimiter.
        let mut exact = FrameDecoder::<14>::new();
        assert_eq!(decode_all(&mut exact, &GOLDEN_FRAME)[..].len(), 1);
        assert_eq!(exact.counters().frames_ok, 1);

        let mut dec = FrameDecoder::<13>::new();
        let mut stream = heapless::Vec::<u8, 64>::new();
        stream.extend_from_slice(&GOLDEN_FRAME).unwrap();
        stream.extend_from_slice(&frame(&[7, 8])).unwrap();
        // Whole stream at once, then byte by byte (overflow noticed before
        // the delimiter arrives).
        let r = decode_all(&mut dec, &stream);
        assert_eq!(r[0], Err(FrameError::Oversize));
        assert_eq!(r[1].as_deref(), Ok(&[7u8, 8][..]));
        assert_eq!(r.len(), 2);
        for b in stream.iter() {
            let r = decode_all(&mut dec, core::slice::from_ref(b));
            assert!(r.len() <= 1);
        }
        let c = dec.counters();
        assert_eq!((c.oversize, c.frames_ok), (2, 2));
    }

    #[test]
    fn zero_capacity_decoder_never_accepts() {
        let mut dec = FrameDecoder::<0>::new();
        let r = decode_all(&mut dec, &GOLDEN_FRAME);
        assert_eq!(r[..], [Err(FrameError::Oversize)]);
        assert_eq!(decode_all(&mut dec, &[0, 0, 0]).len(), 0);
    }

    #[test]
    fn garbage_resyncs_at_next_delimiter() {
        let mut stream = heapless::Vec::<u8, 64>::new();
        // Tail end of a frame we joined mid-way, then a good frame.
        stream
            .extend_from_slice(&[0x37, 0xfe, 0x12, 0x99, 0x00])
            .unwrap();
        stream.extend_from_slice(&GOLDEN_FRAME).unwrap();
        let mut dec = FrameDecoder::<64>::new();
        let r = decode_all(&mut dec, &stream);
        assert_eq!(r.len(), 2);
        assert!(r[0].is_err());
        assert_eq!(r[1].as_deref(), Ok(&GOLDEN_PACKET[..]));
    }

    #[test]
    fn reset_drops_partial_frame() {
        let mut dec = FrameDecoder::<64>::new();
        let mut input = &GOLDEN_FRAME[..7];
        assert_eq!(dec.decode(&mut input), None);
        dec.reset();
        let r = decode_all(&mut dec, &GOLDEN_FRAME);
        assert_eq!(r.len(), 1);
        assert_eq!(r[0].as_deref(), Ok(&GOLDEN_PACKET[..]));
    }

    #[test]
    fn decoder_is_const_constructible() {
        static _DEC: FrameDecoder<32> = FrameDecoder::new();
        let d: FrameDecoder<4> = FrameDecoder::default();
        assert_eq!(*d.counters(), FrameCounters::default());
    }
}
