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

/// Flash addresses an image may load to: `start..end`.
pub type Window = std::ops::Range<u32>;

/// Why an image cannot become a UF2 file.
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
}
