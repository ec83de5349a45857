//! Feeds arbitrary bytes, chunked arbitrarily, to a `FrameDecoder<256>`.
//!
//! The first input byte picks the chunking: 0 feeds the rest in one piece,
//! `k > 0` feeds chunks of pseudo-random sizes in `1..=k`. Checks:
//! - no panic, and `decode` only returns `None` with its input used up;
//! - the results do not depend on the chunking;
//! - every accepted packet re-encodes to a frame that decodes to itself;
//! - the counters agree with the results and with the bytes fed.

#![no_main]

use libfuzzer_sys::fuzz_target;
use osap_core::framing::{encode_frame, max_frame_len, FrameDecoder, FrameError};

const N: usize = 256;

fn run(stream: &[u8], max_chunk: u8) -> (Vec<Result<Vec<u8>, FrameError>>, FrameDecoder<N>) {
    let mut dec = FrameDecoder::<N>::new();
    let mut results = Vec::new();
    let mut rng = u32::from(max_chunk) | 0x1000;
    let mut rest = stream;
    while !rest.is_empty() {
        let size = if max_chunk == 0 {
            rest.len()
        } else {
            rng ^= rng << 13;
            rng ^= rng >> 17;
            rng ^= rng << 5;
            1 + (rng % u32::from(max_chunk)) as usize
        };
        let (mut chunk, tail) = rest.split_at(size.min(rest.len()));
        rest = tail;
        while let Some(r) = dec.decode(&mut chunk) {
            results.push(r.map(<[u8]>::to_vec));
        }
        assert!(chunk.is_empty(), "None returned with input left");
    }
    (results, dec)
}

fn check_round_trip(packet: &[u8]) {
    let mut frame = [0u8; max_frame_len(N)];
    let len = encode_frame(packet, &mut frame).expect("sized by max_frame_len");
    assert!(len <= N, "re-encoded frame longer than the one received");
    let mut dec = FrameDecoder::<N>::new();
    let mut input = &frame[..len];
    assert_eq!(dec.decode(&mut input), Some(Ok(packet)));
    assert!(input.is_empty());
    assert_eq!(dec.decode(&mut input), None);
}

fuzz_target!(|data: &[u8]| {
    let Some((&max_chunk, stream)) = data.split_first() else {
        return;
    };
    let (results, dec) = run(stream, max_chunk);

    let c = dec.counters();
    let count = |f: &dyn Fn(&Result<Vec<u8>, FrameError>) -> bool| {
        results.iter().filter(|r| f(r)).count() as u32
    };
    assert_eq!(c.frames_ok, count(&|r| r.is_ok()));
    assert_eq!(c.cobs_errors, count(&|r| *r == Err(FrameError::Cobs)));
    assert_eq!(c.crc_errors, count(&|r| *r == Err(FrameError::Crc)));
    assert_eq!(c.too_short, count(&|r| *r == Err(FrameError::TooShort)));
    assert_eq!(c.oversize, count(&|r| *r == Err(FrameError::Oversize)));
    assert_eq!(count(&|r| *r == Err(FrameError::OutputTooSmall)), 0);
    assert_eq!(c.bytes_in as usize, stream.len());
    let delimiters = stream.iter().filter(|&&b| b == 0).count();
    assert!(results.len() <= delimiters);

    for packet in results.iter().flatten() {
        check_round_trip(packet);
    }

    // The same bytes in one piece must give the same results.
    if max_chunk != 0 {
        let (whole, _) = run(stream, 0);
        assert_eq!(results, whole, "results depend on chunking");
    }
});
