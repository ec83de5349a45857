//! The learned clock rate's log in the second-to-last 4 KiB sector of the
//! Pico's flash (the name has the last), through the blocking flash
//! driver. The record format, the log and the hot start policy are
//! osap-firmware's (tested on the host); this is only the flash access.
//!
//! A record is 16 bytes, so one sector erase (about 45 ms on the Pico's
//! W25Q16JV, with interrupts off and the step generator stalled) comes
//! every 256 saves; a save itself programs 16 bytes (well under a
//! millisecond, also with execute-in-place off). The policy saves only
//! while no motion is queued, at most once per 10 min of uptime.

use embassy_rp::flash::{Blocking, Flash, ERASE_SIZE};
use embassy_rp::peripherals::FLASH;
use osap_firmware::rate_store::{RateFlash, RECORD_LEN};

use crate::name_store::{PicoFlash, FLASH_SIZE};

/// Offset of the rate sector: the one below the name sector, which
/// memory.x keeps out of the program's region too.
pub(crate) const RATE_SECTOR: u32 = (FLASH_SIZE - 2 * ERASE_SIZE) as u32;

/// The rate sector of the Pico's flash.
pub(crate) struct RateSector(PicoFlash);

impl RateSector {
    /// A second driver of the flash for the rate sector.
    ///
    /// # Safety
    /// The name sector's driver and this one must never be used at the
    /// same time: both live in the runtime task, which uses one at a time.
    /// A blocking driver keeps no state of its own (no DMA channel), so two
    /// of them in turn behave as one.
    pub(crate) unsafe fn steal() -> Self {
        // SAFETY: see above; the caller keeps the two drivers apart.
        let flash: Flash<'static, FLASH, Blocking, FLASH_SIZE> =
            Flash::new_blocking(unsafe { FLASH::steal() });
        RateSector(flash)
    }
}

impl RateFlash for RateSector {
    type Error = embassy_rp::flash::Error;

    fn size(&self) -> usize {
        ERASE_SIZE
    }

    fn read(&mut self, offset: usize, buf: &mut [u8; RECORD_LEN]) -> Result<(), Self::Error> {
        self.0.blocking_read(RATE_SECTOR + offset as u32, buf)
    }

    fn write(&mut self, offset: usize, record: &[u8; RECORD_LEN]) -> Result<(), Self::Error> {
        self.0.blocking_write(RATE_SECTOR + offset as u32, record)
    }

    fn erase(&mut self) -> Result<(), Self::Error> {
        self.0
            .blocking_erase(RATE_SECTOR, RATE_SECTOR + ERASE_SIZE as u32)
    }
}
