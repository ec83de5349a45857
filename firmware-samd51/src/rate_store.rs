//! The learned clock rate's log in the 8 KiB NVM block below the name
//! block (0x0007C000, kept out of the program by memory.x), through the
//! HAL's NVMCTRL driver. The record format, the log and the hot start
//! policy are osap-firmware's (tested on the host); this is only the
//! flash access.
//!
//! A record is 16 bytes, one quad-word (the SAMD51's smallest write, so
//! ECC never spans two records), so a block erase comes every 512 saves.
//! Like the name block, this one lies in the upper flash bank while the
//! program runs from the lower, so a write blocks only the runtime task.

use atsamd_hal::nvm::{Nvm, WriteGranularity, BLOCKSIZE};
use atsamd_hal::pac::Nvmctrl;
use osap_firmware::rate_store::{RateFlash, RECORD_LEN};

/// Address of the rate block.
pub(crate) const RATE_BLOCK: u32 = 0x0007_C000;

/// The rate block of the SAMD51's flash.
pub(crate) struct RateBlock(Nvm);

impl RateBlock {
    /// A second NVMCTRL driver for the rate block.
    ///
    /// # Safety
    /// The name block's driver and this one must never be used at the
    /// same time: both live in the runtime task, which uses one at a time.
    /// The HAL's `Nvm` keeps no state beyond the register block, so two of
    /// them in turn behave as one.
    pub(crate) unsafe fn steal() -> Self {
        // SAFETY: see above; the caller keeps the two drivers apart.
        RateBlock(Nvm::new(unsafe { Nvmctrl::steal() }))
    }
}

impl RateFlash for RateBlock {
    type Error = atsamd_hal::nvm::Error;

    fn size(&self) -> usize {
        BLOCKSIZE as usize
    }

    fn read(&mut self, offset: usize, buf: &mut [u8; RECORD_LEN]) -> Result<(), Self::Error> {
        for (i, b) in buf.iter_mut().enumerate() {
            // SAFETY: the rate block is readable flash, kept out of the
            // program by memory.x; reads of it have no side effects. The
            // log never passes an offset beyond the block's size.
            *b = unsafe {
                core::ptr::read_volatile((RATE_BLOCK as usize + offset + i) as *const u8)
            };
        }
        Ok(())
    }

    fn write(&mut self, offset: usize, record: &[u8; RECORD_LEN]) -> Result<(), Self::Error> {
        let mut words = [0u32; RECORD_LEN / 4];
        for (w, b) in words.iter_mut().zip(record.chunks_exact(4)) {
            *w = u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        }
        // SAFETY: the block holds no code or data of the program (memory.x
        // ends FLASH before it), and `offset` is a 16-byte slot inside it.
        unsafe {
            self.0.write_flash_from_slice(
                (RATE_BLOCK as usize + offset) as *mut u32,
                &words,
                WriteGranularity::QuadWord,
            )
        }
    }

    fn erase(&mut self) -> Result<(), Self::Error> {
        // SAFETY: as for `write`: nothing of the program lives there.
        unsafe { self.0.erase_flash(RATE_BLOCK as *mut u32, 1) }
    }
}
