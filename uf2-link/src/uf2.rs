//! The UF2 container of mass-storage bootloaders (the RP2040 boot ROM, the
//! SAMD51 boards' UF2 bootloader).
//!
//! A UF2 file is a sequence of independent 512-byte blocks, each carrying up
//! to 476 bytes of payload for one target address. The RP2040 boot ROM
//! accepts only 256-byte payloads at 256-byte aligned flash addresses, with
//! the family id of the RP2040 set, and writes each block's page as it
//! arrives; the SAMD51 bootloader takes the same 256-byte blocks with its
//! own family id. Layout of one block (all words little-endian):
//!
//! ```text
//! 0   magic 0x0A324655 ("UF2\n")   16  target address
//! 4   magic 0x9E5D5157             20  payload size (256)
//! 8   flags (0x2000: family id)    24  block number
//! 12  (flags, cont.) see above     28  number of blocks
//!                                  32  family id (e.g. 0xe48bff56)
//! 32..508 payload (256 used, rest zero)   508  final magic 0x0AB16F30
//! ```
//!
//! [`FlashImage`] writes such a file; [`inspect`] (and [`blocks`]) read one
//! back and check it block by block.

use std::collections::BTreeMap;

/// First magic word of every block.
pub const MAGIC_START0: u32 = 0x0A32_4655;
/// Second magic word of every block.
pub const MAGIC_START1: u32 = 0x9E5D_5157;
/// Last word of every block.
pub const MAGIC_END: u32 = 0x0AB1_6F30;
/// Flag: the family id field is present.
pub const FLAG_FAMILY_ID_PRESENT: u32 = 0x0000_2000;
/// Family id of the RP2040.
pub const RP2040_FAMILY_ID: u32 = 0xe48b_ff56;
/// Family id of the SAMD51.
pub const SAMD51_FAMILY_ID: u32 = 0x5511_4460;
/// Payload bytes per block the RP2040 boot ROM (and the SAMD51 UF2
/// bootloader) accept.
pub const PAYLOAD: usize = 256;
/// Size of one UF2 block.
pub const BLOCK: usize = 512;
/// The most payload a block can carry (the UF2 format's limit).
pub const MAX_PAYLOAD: usize = 476;

/// The family id of a chip name as the firmwares' scripts spell it
/// (`rp2040`, `samd51`).
pub fn family_by_name(name: &str) -> Option<u32> {
    match name {
        "rp2040" => Some(RP2040_FAMILY_ID),
        "samd51" => Some(SAMD51_FAMILY_ID),
        _ => None,
    }
}

/// The chip name of a family id, for messages (`RP2040`, `SAMD51`).
pub fn family_name(id: u32) -> Option<&'static str> {
    match id {
        RP2040_FAMILY_ID => Some("RP2040"),
        SAMD51_FAMILY_ID => Some("SAMD51"),
        _ => None,
    }
}

/// `RP2040 (0xe48bff56)`, or the bare id of an unknown family.
pub fn family_label(id: u32) -> String {
    match family_name(id) {
        Some(name) => format!("{name} ({id:#010x})"),
        None => format!("{id:#010x}"),
    }
}

/// Flash addresses an image may load to: `start..end`.
pub type Window = std::ops::Range<u32>;

/// Why an image cannot become a UF2 file, or why a file is not a UF2 file
/// a bootloader would take whole. Block numbers are 0-based positions in
/// the file (block `n` is bytes `512 n .. 512 (n + 1)`).
#[derive(Debug, PartialEq, Eq)]
pub enum Uf2Error {
    /// A loadable segment lies (partly) outside flash.
    OutsideFlash {
        /// Load address of the segment.
        addr: u32,
        /// Its length.
        len: usize,
        /// The flash window it had to fit in.
        window: Window,
    },
    /// Two segments load bytes to the same address.
    Overlap(u32),
    /// The file holds no block at all.
    Empty,
    /// The file's length is not a whole number of blocks: block `block` is
    /// cut short.
    Truncated {
        /// The partial block.
        block: usize,
        /// The file's length in bytes.
        len: usize,
    },
    /// A magic word is wrong: not a UF2 block, or a damaged one.
    BadMagic {
        /// The block.
        block: usize,
        /// Byte offset of the word in the block (0, 4 or 508).
        offset: usize,
        /// The word found there.
        found: u32,
    },
    /// The block does not carry a family id (flag 0x2000 clear), so no
    /// bootloader can tell it is meant for its chip.
    NoFamilyId {
        /// The block.
        block: usize,
    },
    /// The block's family id differs from the first block's.
    MixedFamilies {
        /// The block.
        block: usize,
        /// Its family id.
        found: u32,
        /// The first block's.
        expected: u32,
    },
    /// The payload size is 0, over 476, or not the 256 bytes the chip's
    /// bootloader accepts.
    BadPayloadSize {
        /// The block.
        block: usize,
        /// The size it claims.
        size: u32,
    },
    /// The target address is not 256-byte aligned, which the RP2040 and
    /// SAMD51 bootloaders require (they skip such a block).
    Misaligned {
        /// The block.
        block: usize,
        /// Its target address.
        addr: u32,
    },
    /// The payload runs past the end of the 32-bit address space.
    AddressOverflow {
        /// The block.
        block: usize,
        /// Its target address.
        addr: u32,
    },
    /// Block `block` is numbered `found` (they must count up from 0).
    BlockNumber {
        /// The block.
        block: usize,
        /// The number it carries.
        found: u32,
    },
    /// The block's total-blocks field is not the number of blocks in the
    /// file: a bootloader that counts blocks before resetting (the RP2040
    /// boot ROM does) would wait for blocks that never come.
    BlockCount {
        /// The block.
        block: usize,
        /// The count it carries.
        found: u32,
        /// The file's number of blocks.
        expected: u32,
    },
    /// The block writes bytes an earlier block already wrote.
    OverlappingBlocks {
        /// The block.
        block: usize,
        /// Its target address.
        addr: u32,
    },
}

impl std::fmt::Display for Uf2Error {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Uf2Error::OutsideFlash { addr, len, window } => write!(
                f,
                "segment at {addr:#010x} ({len} bytes) is not in flash ({:#010x}..{:#010x})",
                window.start, window.end
            ),
            Uf2Error::Overlap(addr) => write!(f, "two segments load to {addr:#010x}"),
            Uf2Error::Empty => write!(f, "the file is empty: no UF2 blocks"),
            Uf2Error::Truncated { block, len } => write!(
                f,
                "the file is {len} bytes, not a whole number of {BLOCK}-byte blocks: \
                 block {block} is cut short (an interrupted copy? rebuild it)"
            ),
            Uf2Error::BadMagic {
                block,
                offset,
                found,
            } => write!(
                f,
                "block {block}: wrong magic word at byte {offset} ({found:#010x}): \
                 not a UF2 file, or a damaged one"
            ),
            Uf2Error::NoFamilyId { block } => write!(
                f,
                "block {block}: no family id (flag {FLAG_FAMILY_ID_PRESENT:#x} clear)"
            ),
            Uf2Error::MixedFamilies {
                block,
                found,
                expected,
            } => write!(
                f,
                "block {block}: family {} where block 0 has {}",
                family_label(*found),
                family_label(*expected)
            ),
            Uf2Error::BadPayloadSize { block, size } => {
                write!(f, "block {block}: payload size {size} (want {PAYLOAD})")
            }
            Uf2Error::Misaligned { block, addr } => write!(
                f,
                "block {block}: target address {addr:#010x} is not {PAYLOAD}-byte aligned"
            ),
            Uf2Error::AddressOverflow { block, addr } => write!(
                f,
                "block {block}: payload at {addr:#010x} runs past the 32-bit address space"
            ),
            Uf2Error::BlockNumber { block, found } => {
                write!(f, "block {block}: numbered {found}, expected {block}")
            }
            Uf2Error::BlockCount {
                block,
                found,
                expected,
            } => write!(
                f,
                "block {block}: says the file has {found} blocks, it has {expected}"
            ),
            Uf2Error::OverlappingBlocks { block, addr } => write!(
                f,
                "block {block}: writes {addr:#010x} again (an earlier block wrote it)"
            ),
        }
    }
}

impl std::error::Error for Uf2Error {}

/// A flash image assembled from loadable segments, page by page.
#[derive(Debug)]
pub struct FlashImage {
    /// Where segments may load.
    window: Window,
    /// 256-byte pages by page address; bytes no segment covers stay 0.
    pages: BTreeMap<u32, [u8; PAYLOAD]>,
    /// Which bytes of each page a segment wrote (to find overlaps).
    written: BTreeMap<u32, [bool; PAYLOAD]>,
}

impl FlashImage {
    /// An empty image whose segments must lie in `window` (the program's
    /// part of flash: a bootloader or data area outside it is never
    /// overwritten by a drag-and-drop copy).
    pub fn new(window: Window) -> Self {
        FlashImage {
            window,
            pages: BTreeMap::new(),
            written: BTreeMap::new(),
        }
    }

    /// Adds `data` to load at flash address `addr`.
    pub fn add(&mut self, addr: u32, data: &[u8]) -> Result<(), Uf2Error> {
        let end = u64::from(addr) + data.len() as u64;
        if addr < self.window.start || end > u64::from(self.window.end) {
            return Err(Uf2Error::OutsideFlash {
                addr,
                len: data.len(),
                window: self.window.clone(),
            });
        }
        for (i, &byte) in data.iter().enumerate() {
            let a = addr + i as u32;
            let page = a & !(PAYLOAD as u32 - 1);
            let offset = (a - page) as usize;
            let written = self.written.entry(page).or_insert([false; PAYLOAD]);
            if written[offset] {
                return Err(Uf2Error::Overlap(a));
            }
            written[offset] = true;
            self.pages.entry(page).or_insert([0; PAYLOAD])[offset] = byte;
        }
        Ok(())
    }

    /// Number of 256-byte pages (= UF2 blocks) the image covers.
    pub fn page_count(&self) -> usize {
        self.pages.len()
    }

    /// The image as a UF2 file for `family_id`.
    pub fn to_uf2(&self, family_id: u32) -> Vec<u8> {
        let count = self.pages.len() as u32;
        let mut out = Vec::with_capacity(self.pages.len() * BLOCK);
        for (number, (&addr, payload)) in self.pages.iter().enumerate() {
            out.extend_from_slice(&block(addr, payload, number as u32, count, family_id));
        }
        out
    }
}

/// One UF2 block carrying `payload` for `addr`.
pub fn block(
    addr: u32,
    payload: &[u8; PAYLOAD],
    number: u32,
    count: u32,
    family_id: u32,
) -> [u8; BLOCK] {
    let mut b = [0u8; BLOCK];
    let words = [
        MAGIC_START0,
        MAGIC_START1,
        FLAG_FAMILY_ID_PRESENT,
        addr,
        PAYLOAD as u32,
        number,
        count,
        family_id,
    ];
    for (i, w) in words.iter().enumerate() {
        b[i * 4..i * 4 + 4].copy_from_slice(&w.to_le_bytes());
    }
    b[32..32 + PAYLOAD].copy_from_slice(payload);
    b[BLOCK - 4..].copy_from_slice(&MAGIC_END.to_le_bytes());
    b
}

/// What a UF2 file holds, as [`inspect`] found it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Uf2Info {
    /// The family id every block carries.
    pub family_id: u32,
    /// Number of blocks (each block's total-blocks field agrees).
    pub block_count: u32,
    /// The address ranges the blocks write, ascending, adjacent blocks
    /// merged into one range (`u64` ends: a range may end at 2^32).
    pub ranges: Vec<std::ops::Range<u64>>,
}

impl Uf2Info {
    /// Payload bytes the file writes.
    pub fn bytes(&self) -> u64 {
        self.ranges.iter().map(|r| r.end - r.start).sum()
    }
}

impl std::fmt::Display for Uf2Info {
    /// `RP2040 (0xe48bff56), 451 blocks at 0x10000000..0x1001c300`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let ranges = self
            .ranges
            .iter()
            .map(|r| format!("{:#010x}..{:#010x}", r.start, r.end))
            .collect::<Vec<_>>()
            .join(", ");
        write!(
            f,
            "{}, {} blocks at {ranges}",
            family_label(self.family_id),
            self.block_count
        )
    }
}

/// One block of a UF2 file, as [`blocks`] read it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Uf2Block<'a> {
    /// Flags word.
    pub flags: u32,
    /// Target address.
    pub addr: u32,
    /// Block number (its position in the file).
    pub number: u32,
    /// Total blocks, as the block says.
    pub count: u32,
    /// Family id.
    pub family_id: u32,
    /// The payload (`payload size` bytes).
    pub payload: &'a [u8],
}

fn word_at(b: &[u8], at: usize) -> u32 {
    let mut w = [0u8; 4];
    w.copy_from_slice(&b[at..at + 4]);
    u32::from_le_bytes(w)
}

/// Reads and checks every block of a UF2 file: the three magic words, a
/// family id present and the same in every block, a payload size the
/// bootloader takes (256 bytes at 256-byte aligned addresses for the
/// RP2040 and SAMD51, at most 476 bytes for any other family), blocks
/// numbered 0, 1, 2 … in file order, each one's total equal to the
/// file's block count, no two blocks writing the same byte. A file that
/// breaks any of these is an error naming the first bad block.
pub fn blocks(bytes: &[u8]) -> Result<Vec<Uf2Block<'_>>, Uf2Error> {
    if bytes.is_empty() {
        return Err(Uf2Error::Empty);
    }
    if !bytes.len().is_multiple_of(BLOCK) {
        return Err(Uf2Error::Truncated {
            block: bytes.len() / BLOCK,
            len: bytes.len(),
        });
    }
    let total = bytes.len() / BLOCK;
    let expected_count = u32::try_from(total).unwrap_or(u32::MAX);
    let mut out: Vec<Uf2Block<'_>> = Vec::with_capacity(total);
    for (block, b) in bytes.chunks_exact(BLOCK).enumerate() {
        for (offset, magic) in [(0, MAGIC_START0), (4, MAGIC_START1), (508, MAGIC_END)] {
            let found = word_at(b, offset);
            if found != magic {
                return Err(Uf2Error::BadMagic {
                    block,
                    offset,
                    found,
                });
            }
        }
        let flags = word_at(b, 8);
        let addr = word_at(b, 12);
        let size = word_at(b, 16);
        let number = word_at(b, 20);
        let count = word_at(b, 24);
        let family_id = word_at(b, 28);
        if flags & FLAG_FAMILY_ID_PRESENT == 0 {
            return Err(Uf2Error::NoFamilyId { block });
        }
        if let Some(first) = out.first() {
            if family_id != first.family_id {
                return Err(Uf2Error::MixedFamilies {
                    block,
                    found: family_id,
                    expected: first.family_id,
                });
            }
        }
        // Both bootloaders skip any other block silently; better to refuse
        // the file than to flash a partial image.
        let strict = family_name(family_id).is_some();
        if size == 0 || size as usize > MAX_PAYLOAD || (strict && size as usize != PAYLOAD) {
            return Err(Uf2Error::BadPayloadSize { block, size });
        }
        if strict && !addr.is_multiple_of(PAYLOAD as u32) {
            return Err(Uf2Error::Misaligned { block, addr });
        }
        if u64::from(addr) + u64::from(size) > 1 << 32 {
            return Err(Uf2Error::AddressOverflow { block, addr });
        }
        if number as usize != block {
            return Err(Uf2Error::BlockNumber {
                block,
                found: number,
            });
        }
        // Counts are compared among blocks here and with the file's length
        // after the loop, so a block missing from the middle shows as a gap
        // in the numbering (the clearer message), not as a wrong count.
        if let Some(first) = out.first() {
            if count != first.count {
                let (block, found) = if count != expected_count {
                    (block, count)
                } else {
                    (0, first.count)
                };
                return Err(Uf2Error::BlockCount {
                    block,
                    found,
                    expected: expected_count,
                });
            }
        }
        out.push(Uf2Block {
            flags,
            addr,
            number,
            count,
            family_id,
            payload: &b[32..32 + size as usize],
        });
    }
    if let Some(first) = out.first().filter(|b| b.count != expected_count) {
        return Err(Uf2Error::BlockCount {
            block: 0,
            found: first.count,
            expected: expected_count,
        });
    }
    // Overlaps: sort by address, then each block must start at or after
    // the end of the one before it.
    let mut order: Vec<usize> = (0..out.len()).collect();
    order.sort_by_key(|&i| (out[i].addr, i));
    for pair in order.windows(2) {
        let (a, b) = (&out[pair[0]], &out[pair[1]]);
        if u64::from(a.addr) + a.payload.len() as u64 > u64::from(b.addr) {
            return Err(Uf2Error::OverlappingBlocks {
                block: pair[0].max(pair[1]),
                addr: b.addr,
            });
        }
    }
    Ok(out)
}

/// Checks a UF2 file (see [`blocks`] for what is checked) and reports its
/// family id, block count and the address ranges it writes. Never panics:
/// a malformed file is an error naming the first bad block.
pub fn inspect(bytes: &[u8]) -> Result<Uf2Info, Uf2Error> {
    let blocks = blocks(bytes)?;
    let mut spans: Vec<(u64, u64)> = blocks
        .iter()
        .map(|b| {
            let start = u64::from(b.addr);
            (start, start + b.payload.len() as u64)
        })
        .collect();
    spans.sort_unstable();
    let mut ranges: Vec<std::ops::Range<u64>> = Vec::new();
    for (start, end) in spans {
        match ranges.last_mut() {
            Some(last) if last.end == start => last.end = end,
            _ => ranges.push(start..end),
        }
    }
    Ok(Uf2Info {
        family_id: blocks[0].family_id,
        block_count: blocks.len() as u32,
        ranges,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The RP2040's XIP flash window (16 MiB).
    const RP2040: Window = 0x1000_0000..0x1100_0000;
    /// A SAMD51J19's program flash: after the 16 KiB bootloader, before
    /// the last 8 KiB block (the firmware's name record).
    const SAMD51: Window = 0x4000..0x7_E000;

    fn word(b: &[u8], at: usize) -> u32 {
        u32::from_le_bytes(b[at..at + 4].try_into().unwrap())
    }

    #[test]
    fn block_layout() {
        let mut payload = [0u8; PAYLOAD];
        for (i, p) in payload.iter_mut().enumerate() {
            *p = i as u8;
        }
        let b = block(0x1000_0100, &payload, 3, 7, RP2040_FAMILY_ID);
        assert_eq!(word(&b, 0), 0x0A32_4655);
        assert_eq!(word(&b, 4), 0x9E5D_5157);
        assert_eq!(word(&b, 8), 0x2000);
        assert_eq!(word(&b, 12), 0x1000_0100);
        assert_eq!(word(&b, 16), 256);
        assert_eq!(word(&b, 20), 3);
        assert_eq!(word(&b, 24), 7);
        assert_eq!(word(&b, 28), 0xe48b_ff56);
        assert_eq!(&b[32..288], &payload[..]);
        assert!(b[288..508].iter().all(|&x| x == 0));
        assert_eq!(word(&b, 508), 0x0AB1_6F30);
        // The start magic spells "UF2\n".
        assert_eq!(&b[..4], b"UF2\n");
    }

    #[test]
    fn segments_become_aligned_pages() {
        let mut img = FlashImage::new(RP2040);
        // A 0x100-byte boot2 at the base, a vector table right after it,
        // then code that starts mid-page and crosses a page boundary.
        img.add(0x1000_0000, &[0xAA; 0x100]).unwrap();
        img.add(0x1000_0100, &[0xBB; 0xC0]).unwrap();
        img.add(0x1000_01C0, &[0xCC; 0x80]).unwrap();
        assert_eq!(img.page_count(), 3);
        let uf2 = img.to_uf2(RP2040_FAMILY_ID);
        assert_eq!(uf2.len(), 3 * BLOCK);
        let addrs: Vec<u32> = uf2.chunks(BLOCK).map(|b| word(b, 12)).collect();
        assert_eq!(addrs, [0x1000_0000, 0x1000_0100, 0x1000_0200]);
        for (i, b) in uf2.chunks(BLOCK).enumerate() {
            assert_eq!(word(b, 20), i as u32);
            assert_eq!(word(b, 24), 3);
        }
        let second = &uf2[BLOCK + 32..BLOCK + 32 + PAYLOAD];
        assert!(second[..0xC0].iter().all(|&x| x == 0xBB));
        assert!(second[0xC0..].iter().all(|&x| x == 0xCC));
        let third = &uf2[2 * BLOCK + 32..2 * BLOCK + 32 + PAYLOAD];
        assert!(third[..0x40].iter().all(|&x| x == 0xCC));
        // Bytes no segment covers are zero.
        assert!(third[0x40..].iter().all(|&x| x == 0));
    }

    #[test]
    fn sparse_pages_are_skipped() {
        let mut img = FlashImage::new(RP2040);
        img.add(0x1000_0000, &[1]).unwrap();
        img.add(0x1010_0000, &[2]).unwrap();
        let uf2 = img.to_uf2(RP2040_FAMILY_ID);
        assert_eq!(uf2.len(), 2 * BLOCK);
        assert_eq!(word(&uf2[BLOCK..], 12), 0x1010_0000);
    }

    #[test]
    fn rejects_ram_and_overlap() {
        let mut img = FlashImage::new(RP2040);
        assert_eq!(
            img.add(0x2000_0000, &[0; 4]),
            Err(Uf2Error::OutsideFlash {
                addr: 0x2000_0000,
                len: 4,
                window: RP2040
            })
        );
        assert!(img.add(0x10FF_FFFF, &[0; 2]).is_err());
        img.add(0x1000_0000, &[0; 8]).unwrap();
        assert_eq!(
            img.add(0x1000_0004, &[0; 8]),
            Err(Uf2Error::Overlap(0x1000_0004))
        );
    }

    #[test]
    fn samd51_image_after_the_bootloader() {
        let mut img = FlashImage::new(SAMD51);
        // Vector table at the start of the program area, then code.
        img.add(0x4000, &[0x11; 0x260]).unwrap();
        img.add(0x4260, &[0x22; 0x10]).unwrap();
        let uf2 = img.to_uf2(SAMD51_FAMILY_ID);
        assert_eq!(uf2.len(), 3 * BLOCK);
        let addrs: Vec<u32> = uf2.chunks(BLOCK).map(|b| word(b, 12)).collect();
        assert_eq!(addrs, [0x4000, 0x4100, 0x4200]);
        assert!(uf2.chunks(BLOCK).all(|b| word(b, 28) == 0x5511_4460));
        assert!(uf2
            .chunks(BLOCK)
            .all(|b| word(b, 8) == FLAG_FAMILY_ID_PRESENT));
        // The ELF headers at 0 (a link without --nmagic) would overwrite
        // the bootloader; a segment in the name block would erase the name.
        assert!(matches!(
            img.add(0x0, &[0; 0x34]),
            Err(Uf2Error::OutsideFlash { addr: 0, .. })
        ));
        assert!(img.add(0x7_DFFF, &[0; 2]).is_err());
        assert!(img.add(0x7_E000, &[0; 1]).is_err());
        img.add(0x7_DFFF, &[0; 1]).unwrap();
    }

    #[test]
    fn empty_image_is_empty_file() {
        assert!(FlashImage::new(RP2040).to_uf2(RP2040_FAMILY_ID).is_empty());
    }

    /// An RP2040 image of two separate runs: boot2 and code at the base,
    /// and one page 1 MiB up.
    fn rp2040_uf2() -> Vec<u8> {
        let mut img = FlashImage::new(RP2040);
        img.add(0x1000_0000, &[0xAA; 0x100]).unwrap();
        img.add(0x1000_0100, &[0xBB; 0x150]).unwrap();
        img.add(0x1010_0000, &[0xCC; 4]).unwrap();
        img.to_uf2(RP2040_FAMILY_ID)
    }

    fn set_word(b: &mut [u8], at: usize, w: u32) {
        b[at..at + 4].copy_from_slice(&w.to_le_bytes());
    }

    #[test]
    fn inspect_reads_what_the_writer_wrote() {
        let info = inspect(&rp2040_uf2()).unwrap();
        assert_eq!(
            info,
            Uf2Info {
                family_id: RP2040_FAMILY_ID,
                block_count: 4,
                ranges: vec![0x1000_0000..0x1000_0300, 0x1010_0000..0x1010_0100],
            }
        );
        assert_eq!(info.bytes(), 4 * 256);
        assert_eq!(
            info.to_string(),
            "RP2040 (0xe48bff56), 4 blocks at 0x10000000..0x10000300, 0x10100000..0x10100100"
        );
        let uf2 = rp2040_uf2();
        let blocks = blocks(&uf2).unwrap();
        assert_eq!(blocks[1].addr, 0x1000_0100);
        assert_eq!(blocks[1].payload, &[0xBB; 256][..]);

        let mut img = FlashImage::new(SAMD51);
        img.add(0x4000, &[1; 0x1000]).unwrap();
        let info = inspect(&img.to_uf2(SAMD51_FAMILY_ID)).unwrap();
        assert_eq!(info.family_id, SAMD51_FAMILY_ID);
        assert_eq!(info.block_count, 16);
        assert_eq!(info.ranges, vec![0x4000..0x5000]);
    }

    #[test]
    fn inspect_refuses_bad_magic() {
        for (block, offset) in [(0, 0), (2, 4), (3, 508)] {
            let mut uf2 = rp2040_uf2();
            uf2[block * BLOCK + offset] ^= 0xFF;
            assert!(
                matches!(inspect(&uf2), Err(Uf2Error::BadMagic { block: b, offset: o, .. }) if b == block && o == offset),
                "{block} {offset}: {:?}",
                inspect(&uf2)
            );
        }
        let text = vec![b'x'; BLOCK];
        let e = inspect(&text).unwrap_err();
        assert!(e
            .to_string()
            .starts_with("block 0: wrong magic word at byte 0"));
    }

    #[test]
    fn inspect_refuses_wrong_numbering() {
        // Two blocks swapped: numbers 1, 0.
        let mut uf2 = rp2040_uf2();
        let (a, b) = uf2.split_at_mut(BLOCK);
        a.swap_with_slice(&mut b[..BLOCK]);
        assert_eq!(
            inspect(&uf2),
            Err(Uf2Error::BlockNumber { block: 0, found: 1 })
        );
        // A block count that disagrees with the file.
        let mut uf2 = rp2040_uf2();
        set_word(&mut uf2[2 * BLOCK..], 24, 5);
        assert_eq!(
            inspect(&uf2),
            Err(Uf2Error::BlockCount {
                block: 2,
                found: 5,
                expected: 4
            })
        );
        // A block missing from the middle: numbers run 0, 1, 3.
        let mut uf2 = rp2040_uf2();
        uf2.drain(2 * BLOCK..3 * BLOCK);
        assert!(matches!(
            inspect(&uf2),
            Err(Uf2Error::BlockNumber { block: 2, found: 3 })
        ));
        // The same file cut by whole blocks: numbering fine, count not.
        let mut uf2 = rp2040_uf2();
        uf2.truncate(2 * BLOCK);
        assert_eq!(
            inspect(&uf2),
            Err(Uf2Error::BlockCount {
                block: 0,
                found: 4,
                expected: 2
            })
        );
    }

    #[test]
    fn inspect_refuses_truncated_and_empty_files() {
        let uf2 = rp2040_uf2();
        assert_eq!(
            inspect(&uf2[..3 * BLOCK + 100]),
            Err(Uf2Error::Truncated {
                block: 3,
                len: 3 * BLOCK + 100
            })
        );
        assert!(inspect(&uf2[..10])
            .unwrap_err()
            .to_string()
            .contains("block 0 is cut short"));
        assert_eq!(inspect(&[]), Err(Uf2Error::Empty));
    }

    #[test]
    fn inspect_refuses_bad_fields() {
        let mutate = |at: usize, w: u32| {
            let mut uf2 = rp2040_uf2();
            set_word(&mut uf2[BLOCK..], at, w);
            inspect(&uf2)
        };
        assert_eq!(mutate(8, 0), Err(Uf2Error::NoFamilyId { block: 1 }));
        assert_eq!(
            mutate(28, SAMD51_FAMILY_ID),
            Err(Uf2Error::MixedFamilies {
                block: 1,
                found: SAMD51_FAMILY_ID,
                expected: RP2040_FAMILY_ID
            })
        );
        assert_eq!(
            mutate(16, 128),
            Err(Uf2Error::BadPayloadSize {
                block: 1,
                size: 128
            })
        );
        assert_eq!(
            mutate(16, 477),
            Err(Uf2Error::BadPayloadSize {
                block: 1,
                size: 477
            })
        );
        assert_eq!(
            mutate(16, u32::MAX),
            Err(Uf2Error::BadPayloadSize {
                block: 1,
                size: u32::MAX
            })
        );
        assert_eq!(
            mutate(12, 0x1000_0180),
            Err(Uf2Error::Misaligned {
                block: 1,
                addr: 0x1000_0180
            })
        );
        assert_eq!(
            mutate(12, 0x1000_0000),
            Err(Uf2Error::OverlappingBlocks {
                block: 1,
                addr: 0x1000_0000
            })
        );
        assert_eq!(
            mutate(12, 0xFFFF_FF00).map(|i| i.ranges.last().cloned()),
            Ok(Some(0xFFFF_FF00..0x1_0000_0000))
        );
    }

    #[test]
    fn inspect_takes_other_families_up_to_476_bytes() {
        // An unknown family: any payload size up to 476, any alignment.
        let mut b = block(0x2000_0003, &[7; PAYLOAD], 0, 1, 0x1234_5678);
        set_word(&mut b, 16, 476);
        let info = inspect(&b).unwrap();
        assert_eq!(info.ranges, vec![0x2000_0003..0x2000_0003 + 476]);
        set_word(&mut b, 12, 0xFFFF_FFF0);
        assert_eq!(
            inspect(&b),
            Err(Uf2Error::AddressOverflow {
                block: 0,
                addr: 0xFFFF_FFF0
            })
        );
    }

    #[test]
    fn family_names() {
        assert_eq!(family_by_name("rp2040"), Some(RP2040_FAMILY_ID));
        assert_eq!(family_by_name("samd51"), Some(SAMD51_FAMILY_ID));
        assert_eq!(family_by_name("RP2040"), None);
        assert_eq!(family_name(SAMD51_FAMILY_ID), Some("SAMD51"));
        assert_eq!(family_label(1), "0x00000001");
    }
}
