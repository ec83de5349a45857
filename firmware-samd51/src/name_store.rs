//! The module's name in the last 8 KiB NVM block of the SAMD51's flash
//! (0x0007E000, kept out of the program by memory.x), through the HAL's
//! NVMCTRL driver. The record format and the fallback to a name made from
//! the chip's serial number are osap-firmware's (tested on the host); this
//! is only the flash access.
//!
//! What a write blocks: the runtime task (thread mode) busy-waits on
//! NVMCTRL for one block erase and one quad-word write per 16 bytes of
//! record (three at most), milliseconds in all (see the NVM timing
//! characteristics in the SAMD5x data sheet). Nothing else waits: the
//! block lies in the upper flash bank (0x40000..0x80000) while the
//! program runs from the lower one, and the SAMD51 reads one bank while
//! it writes the other, so interrupts, step ticks and link I/O go on. A
//! name is only written when the network sets a new one.

use atsamd_hal::nvm::{Nvm, WriteGranularity};
use osap_firmware::name_store::{NameFlash, RECORD_MAX};

/// Address of the name block.
pub(crate) const NAME_BLOCK: u32 = 0x0007_E000;
/// Words written: the record, padded to whole quad-words.
const WORDS: usize = RECORD_MAX.div_ceil(16) * 4;

/// The name block of the SAMD51's flash.
pub(crate) struct NameBlock(pub Nvm);

impl NameFlash for NameBlock {
    type Error = atsamd_hal::nvm::Error;

    fn read(&mut self, buf: &mut [u8]) -> Result<(), Self::Error> {
        for (i, b) in buf.iter_mut().enumerate() {
            // SAFETY: the name block is readable flash, kept out of the
            // program by memory.x; reads of it have no side effects.
            *b = unsafe { core::ptr::read_volatile((NAME_BLOCK as usize + i) as *const u8) };
        }
        Ok(())
    }

    fn erase_and_write(&mut self, record: &[u8]) -> Result<(), Self::Error> {
        let mut words = [u32::MAX; WORDS];
        for (i, b) in record.iter().take(WORDS * 4).enumerate() {
            let shift = 8 * (i % 4);
            words[i / 4] = (words[i / 4] & !(0xFF << shift)) | (u32::from(*b) << shift);
        }
        // SAFETY: the block holds no code or data of the program (memory.x
        // ends FLASH before it), so erasing and writing it changes nothing
        // the program runs from.
        unsafe {
            self.0.erase_flash(NAME_BLOCK as *mut u32, 1)?;
            self.0.write_flash_from_slice(
                NAME_BLOCK as *mut u32,
                &words,
                WriteGranularity::QuadWord,
            )
        }
    }
}
