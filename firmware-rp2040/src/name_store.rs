//! The module's name in the last 4 KiB sector of the Pico's flash, through
//! the blocking flash driver. The record format and the fallback to a name
//! made from the board id are osap-firmware's (tested on the host);
//! this is only the flash access.
//!
//! Erasing and writing run from RAM with interrupts off for the whole
//! operation (a sector erase takes about 45 ms on the Pico's W25Q16JV):
//! the step generator stalls and restarts on a fresh anchor, and links
//! may lose bytes. A name is only written when the network sets a new one.

use embassy_rp::flash::{Blocking, Flash, ERASE_SIZE};
use embassy_rp::peripherals::FLASH;
use osap_firmware::name_store::NameFlash;

/// Size of the Pico's flash (W25Q16JV, 2 MiB).
pub(crate) const FLASH_SIZE: usize = 2 * 1024 * 1024;
/// Offset of the name sector: the last one, which memory.x keeps out of
/// the program's region.
pub(crate) const NAME_SECTOR: u32 = (FLASH_SIZE - ERASE_SIZE) as u32;

/// The flash driver.
pub(crate) type PicoFlash = Flash<'static, FLASH, Blocking, FLASH_SIZE>;

/// The name sector of the Pico's flash.
pub(crate) struct NameSector(pub PicoFlash);

impl NameFlash for NameSector {
    type Error = embassy_rp::flash::Error;

    fn read(&mut self, buf: &mut [u8]) -> Result<(), Self::Error> {
        self.0.blocking_read(NAME_SECTOR, buf)
    }

    fn erase_and_write(&mut self, record: &[u8]) -> Result<(), Self::Error> {
        self.0
            .blocking_erase(NAME_SECTOR, NAME_SECTOR + ERASE_SIZE as u32)?;
        self.0.blocking_write(NAME_SECTOR, record)
    }
}
