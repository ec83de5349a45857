//! A module's name, persisted in one flash sector.
//!
//! The runtime's name is what a user set over the network (a scan shows it
//! and scripts find modules by it), so it must survive a reset. It is kept
//! as one small record at the start of a dedicated flash sector:
//!
//! ```text
//! offset 0  magic "OSNM" (0x4D4E534F, little-endian)
//!        4  length n (1..=31)
//!        5  n bytes of UTF-8 name
//!      5+n  CRC-16/IBM-3740 of bytes 0..5+n, most significant byte first
//! ```
//!
//! Anything else there (an erased sector reads all 0xFF, a torn write, a
//! record of another layout) fails the magic, length, UTF-8 or CRC check,
//! and the module falls back to a default name made from its type and the
//! board's unique id, e.g. `stepper-1a2b3c`, so two fresh modules on one
//! network still have different names.
//!
//! The same sector keeps the module's bus role on its UART (off, head, or
//! a drop address; [`BusRole`]) in a second record right after the room
//! for the longest name record, at [`BUS_OFFSET`]:
//!
//! ```text
//! offset 0  magic "OSBR" (0x5242534F, little-endian)
//!        4  role: [0, 0] off, [1, max_drop] head, [2, drop] drop
//!        6  CRC-16/IBM-3740 of bytes 0..6, most significant byte first
//! ```
//!
//! A sector written before bus roles existed reads 0xFF there: the role is
//! off. Each save rewrites both records, keeping the one it does not
//! change.
//!
//! The flash itself is behind [`NameFlash`], so this logic runs and is tested
//! on the host; the firmware implements it over its HAL's blocking flash
//! driver.
use core::fmt::Write;
use heapless::String;
use osap_core::bus::BusRole;
use osap_core::framing::crc16;
use osap_core::netresponder::NAME_MAX;

/// A module name (at most [`NAME_MAX`] bytes).
pub type Name = String<NAME_MAX>;

/// Magic word at the start of a valid record ("OSNM" in memory).
pub const MAGIC: u32 = 0x4D4E_534F;
/// Bytes before the name: magic and length.
const HEADER: usize = 5;
/// Bytes of CRC after the name.
const CRC: usize = 2;
/// The longest record, in bytes.
pub const RECORD_MAX: usize = HEADER + NAME_MAX + CRC;
/// Magic word of the bus role record ("OSBR" in memory).
pub const BUS_MAGIC: u32 = 0x5242_534F;
/// Where the bus role record starts in the sector.
pub const BUS_OFFSET: usize = RECORD_MAX;
/// Length of the bus role record.
pub const BUS_RECORD: usize = 8;
/// The bytes of the sector the store reads and writes.
const IMAGE: usize = BUS_OFFSET + BUS_RECORD;

/// The sector that holds the record.
pub trait NameFlash {
    /// The flash driver's error.
    type Error;
    /// Reads `buf.len()` bytes from the start of the sector.
    fn read(&mut self, buf: &mut [u8]) -> Result<(), Self::Error>;
    /// Erases the sector and writes `record` at its start.
    fn erase_and_write(&mut self, record: &[u8]) -> Result<(), Self::Error>;
}

/// Why a name could not be stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum StoreError<E> {
    /// The name is empty or longer than [`NAME_MAX`] bytes.
    BadName,
    /// The flash driver failed.
    Flash(E),
}

impl<E: core::fmt::Debug> core::fmt::Display for StoreError<E> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            StoreError::BadName => write!(f, "the name is empty or longer than {NAME_MAX} bytes"),
            StoreError::Flash(e) => write!(f, "the flash driver failed: {e:?}"),
        }
    }
}

impl<E: core::fmt::Debug> core::error::Error for StoreError<E> {}

/// Writes the record of `name` to the start of `out` and returns its
/// length, or `None` if the name is empty or too long.
pub fn encode(name: &str, out: &mut [u8; RECORD_MAX]) -> Option<usize> {
    let n = name.len();
    if n == 0 || n > NAME_MAX {
        return None;
    }
    out[..4].copy_from_slice(&MAGIC.to_le_bytes());
    out[4] = n as u8;
    out[HEADER..HEADER + n].copy_from_slice(name.as_bytes());
    let crc = crc16(&out[..HEADER + n]).to_be_bytes();
    out[HEADER + n..HEADER + n + CRC].copy_from_slice(&crc);
    Some(HEADER + n + CRC)
}

/// The name in a record at the start of `bytes`, if the record is valid.
pub fn decode(bytes: &[u8]) -> Option<&str> {
    let magic = u32::from_le_bytes(bytes.get(..4)?.try_into().ok()?);
    if magic != MAGIC {
        return None;
    }
    let n = usize::from(*bytes.get(4)?);
    if n == 0 || n > NAME_MAX {
        return None;
    }
    let body = bytes.get(..HEADER + n)?;
    let crc = bytes.get(HEADER + n..HEADER + n + CRC)?;
    if crc != crc16(body).to_be_bytes() {
        return None;
    }
    core::str::from_utf8(&body[HEADER..]).ok()
}

/// The bus role record of `role`.
pub fn encode_bus(role: BusRole) -> [u8; BUS_RECORD] {
    let mut out = [0u8; BUS_RECORD];
    out[..4].copy_from_slice(&BUS_MAGIC.to_le_bytes());
    out[4..6].copy_from_slice(&role.to_bytes());
    let crc = crc16(&out[..6]).to_be_bytes();
    out[6..].copy_from_slice(&crc);
    out
}

/// The role in a bus role record at the start of `bytes`, if the record
/// is valid.
pub fn decode_bus(bytes: &[u8]) -> Option<BusRole> {
    let rec = bytes.get(..BUS_RECORD)?;
    if rec[..4] != BUS_MAGIC.to_le_bytes() || rec[6..] != crc16(&rec[..6]).to_be_bytes() {
        return None;
    }
    BusRole::from_bytes([rec[4], rec[5]]).ok()
}

/// The name of a fresh module: `type_name`, a dash, and the last three
/// bytes of the board's unique id in hex (`stepper-1a2b3c`). The type name
/// is shortened if the whole would not fit.
pub fn default_name(type_name: &str, unique_id: &[u8]) -> Name {
    const SUFFIX: usize = 7; // "-" and six hex digits
    let mut keep = type_name.len().min(NAME_MAX - SUFFIX);
    while !type_name.is_char_boundary(keep) {
        keep -= 1;
    }
    let mut name = Name::new();
    // Cannot fail: at most NAME_MAX - 7 bytes of prefix plus 7.
    let _ = name.push_str(&type_name[..keep]);
    let _ = name.push('-');
    let tail = &unique_id[unique_id.len().saturating_sub(3)..];
    for b in tail {
        let _ = write!(name, "{b:02x}");
    }
    name
}

/// The name record in flash.
pub struct NameStore<F> {
    flash: F,
}

impl<F> core::fmt::Debug for NameStore<F> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("NameStore").finish_non_exhaustive()
    }
}

impl<F: NameFlash> NameStore<F> {
    /// A store over `flash`.
    pub fn new(flash: F) -> Self {
        NameStore { flash }
    }

    /// The flash, back.
    pub fn into_inner(self) -> F {
        self.flash
    }

    /// The records' bytes at the start of the sector.
    fn image(&mut self) -> Option<[u8; IMAGE]> {
        let mut buf = [0u8; IMAGE];
        self.flash.read(&mut buf).ok()?;
        Some(buf)
    }

    /// The stored name, if the sector holds a valid record.
    pub fn load(&mut self) -> Option<Name> {
        let buf = self.image()?;
        decode(&buf).and_then(|s| Name::try_from(s).ok())
    }

    /// The stored bus role; off if none is stored (or the record is bad).
    pub fn load_bus(&mut self) -> BusRole {
        self.image()
            .and_then(|buf| decode_bus(&buf[BUS_OFFSET..]))
            .unwrap_or_default()
    }

    /// Stores `role`, keeping the stored name. Writes nothing if the role
    /// is already stored. Returns whether the flash was written.
    pub fn save_bus(&mut self, role: BusRole) -> Result<bool, StoreError<F::Error>> {
        if self.load_bus() == role {
            return Ok(false);
        }
        let mut image = [0xFF; IMAGE];
        if let Some(name) = self.load() {
            let mut record = [0u8; RECORD_MAX];
            if let Some(len) = encode(&name, &mut record) {
                image[..len].copy_from_slice(&record[..len]);
            }
        }
        image[BUS_OFFSET..].copy_from_slice(&encode_bus(role));
        self.flash
            .erase_and_write(&image)
            .map_err(StoreError::Flash)?;
        Ok(true)
    }

    /// The stored name, or the default one for this board.
    pub fn load_or_default(&mut self, type_name: &str, unique_id: &[u8]) -> Name {
        self.load()
            .unwrap_or_else(|| default_name(type_name, unique_id))
    }

    /// Stores `name`. Writes nothing if it is already stored, so renaming a
    /// module to its own name costs no erase cycle (and no pause: erasing
    /// a sector stalls execution from flash for tens of milliseconds).
    /// Returns whether the flash was written.
    pub fn save(&mut self, name: &str) -> Result<bool, StoreError<F::Error>> {
        let mut record = [0u8; RECORD_MAX];
        let len = encode(name, &mut record).ok_or(StoreError::BadName)?;
        if self.load().as_deref() == Some(name) {
            return Ok(false);
        }
        // Keep a bus role other than off; without one, the sector holds the
        // name record alone, as before bus roles existed.
        let role = self.load_bus();
        let mut image = [0xFF; IMAGE];
        image[..len].copy_from_slice(&record[..len]);
        let written = if role == BusRole::Off {
            len
        } else {
            image[BUS_OFFSET..].copy_from_slice(&encode_bus(role));
            IMAGE
        };
        self.flash
            .erase_and_write(&image[..written])
            .map_err(StoreError::Flash)?;
        Ok(true)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A sector in RAM that counts erases and can fail or tear writes.
    struct RamSector {
        bytes: [u8; 4096],
        erases: u32,
        fail: bool,
        /// Stop writing after this many bytes (a reset mid-write).
        tear_at: Option<usize>,
    }

    impl RamSector {
        fn erased() -> Self {
            RamSector {
                bytes: [0xFF; 4096],
                erases: 0,
                fail: false,
                tear_at: None,
            }
        }
    }

    impl NameFlash for &mut RamSector {
        type Error = ();
        fn read(&mut self, buf: &mut [u8]) -> Result<(), ()> {
            buf.copy_from_slice(&self.bytes[..buf.len()]);
            Ok(())
        }
        fn erase_and_write(&mut self, record: &[u8]) -> Result<(), ()> {
            if self.fail {
                return Err(());
            }
            self.bytes = [0xFF; 4096];
            self.erases += 1;
            let n = self.tear_at.unwrap_or(record.len()).min(record.len());
            self.bytes[..n].copy_from_slice(&record[..n]);
            Ok(())
        }
    }

    const UID: [u8; 8] = [0xE6, 0x60, 0x58, 0x38, 0x83, 0x1a, 0x2b, 0x3c];

    #[test]
    fn golden_record() {
        let mut out = [0u8; RECORD_MAX];
        let n = encode("ab", &mut out).unwrap();
        let crc = crc16(&[0x4F, 0x53, 0x4E, 0x4D, 2, b'a', b'b']).to_be_bytes();
        assert_eq!(
            out[..n],
            [0x4F, 0x53, 0x4E, 0x4D, 2, b'a', b'b', crc[0], crc[1]]
        );
        assert_eq!(&out[..4], b"OSNM");
        assert_eq!(decode(&out[..n]), Some("ab"));
    }

    #[test]
    fn round_trip_every_length() {
        let long = "abcdefghijklmnopqrstuvwxyz01234567";
        for n in 1..=NAME_MAX {
            let mut out = [0u8; RECORD_MAX];
            let len = encode(&long[..n], &mut out).unwrap();
            assert_eq!(len, n + 7);
            assert_eq!(decode(&out), Some(&long[..n]));
        }
        let mut out = [0u8; RECORD_MAX];
        assert_eq!(encode("", &mut out), None);
        assert_eq!(encode(&long[..NAME_MAX + 1], &mut out), None);
    }

    #[test]
    fn erased_and_corrupt_records_are_rejected() {
        assert_eq!(decode(&[0xFF; RECORD_MAX]), None);
        assert_eq!(decode(&[0x00; RECORD_MAX]), None);
        assert_eq!(decode(&[]), None);
        let mut out = [0u8; RECORD_MAX];
        let n = encode("stepper-x", &mut out).unwrap();
        // Every single-bit flip in the record is caught.
        for byte in 0..n {
            for bit in 0..8 {
                let mut bad = out;
                bad[byte] ^= 1 << bit;
                assert_eq!(decode(&bad), None, "flip {byte}.{bit}");
            }
        }
        // A length past NAME_MAX, even with a matching CRC.
        let mut big = [0u8; 64];
        big[..4].copy_from_slice(&MAGIC.to_le_bytes());
        big[4] = NAME_MAX as u8 + 1;
        let crc = crc16(&big[..HEADER + NAME_MAX + 1]).to_be_bytes();
        big[HEADER + NAME_MAX + 1..HEADER + NAME_MAX + 3].copy_from_slice(&crc);
        assert_eq!(decode(&big), None);
        // Invalid UTF-8 with a good CRC.
        let mut bin = [0u8; RECORD_MAX];
        bin[..4].copy_from_slice(&MAGIC.to_le_bytes());
        bin[4] = 1;
        bin[5] = 0xC3;
        let crc = crc16(&bin[..6]).to_be_bytes();
        bin[6..8].copy_from_slice(&crc);
        assert_eq!(decode(&bin), None);
    }

    #[test]
    fn default_names() {
        assert_eq!(default_name("stepper", &UID).as_str(), "stepper-1a2b3c");
        assert_eq!(default_name("io", &[0xab]).as_str(), "io-ab");
        let long = default_name("a-very-long-module-type-name-indeed", &UID);
        assert_eq!(long.len(), NAME_MAX);
        assert!(long.ends_with("-1a2b3c"));
        // A multi-byte character is not split.
        let wide = default_name("ééééééééééééé", &UID);
        assert!(wide.ends_with("-1a2b3c") && wide.len() <= NAME_MAX);
    }

    #[test]
    fn fresh_module_gets_default_then_keeps_its_name() {
        let mut sector = RamSector::erased();
        let mut store = NameStore::new(&mut sector);
        assert_eq!(store.load(), None);
        assert_eq!(
            store.load_or_default("stepper", &UID).as_str(),
            "stepper-1a2b3c"
        );
        assert_eq!(store.save("x-axis"), Ok(true));
        // "Reset": a new store over the same flash.
        let _ = store.into_inner();
        let mut store = NameStore::new(&mut sector);
        assert_eq!(store.load_or_default("stepper", &UID).as_str(), "x-axis");
        // Same name again: no erase.
        assert_eq!(store.save("x-axis"), Ok(false));
        assert_eq!(store.save("y-axis"), Ok(true));
        assert_eq!(store.load().as_deref(), Some("y-axis"));
        let _ = store.into_inner();
        assert_eq!(sector.erases, 2);
    }

    #[test]
    fn torn_write_and_failures_fall_back() {
        let mut sector = RamSector::erased();
        sector.tear_at = Some(6);
        let mut store = NameStore::new(&mut sector);
        assert_eq!(store.save("x-axis"), Ok(true));
        assert_eq!(
            store.load_or_default("stepper", &UID).as_str(),
            "stepper-1a2b3c"
        );
        let _ = store.into_inner();
        sector.tear_at = None;
        sector.fail = true;
        let mut store = NameStore::new(&mut sector);
        assert_eq!(store.save("x-axis"), Err(StoreError::Flash(())));
        assert_eq!(store.save(""), Err(StoreError::BadName));
        assert_eq!(
            store.save("0123456789012345678901234567890123"),
            Err(StoreError::BadName)
        );
    }

    #[test]
    fn the_bus_role_is_kept_beside_the_name_and_each_save_keeps_the_other() {
        let mut sector = RamSector::erased();
        let mut store = NameStore::new(&mut sector);
        // A fresh sector, and one written before bus roles: off.
        assert_eq!(store.load_bus(), BusRole::Off);
        assert_eq!(store.save("x-axis"), Ok(true));
        assert_eq!(store.load_bus(), BusRole::Off);
        // Setting the role keeps the name; setting it again writes nothing.
        assert_eq!(store.save_bus(BusRole::Drop(4)), Ok(true));
        assert_eq!(store.save_bus(BusRole::Drop(4)), Ok(false));
        assert_eq!(store.load_bus(), BusRole::Drop(4));
        assert_eq!(store.load().as_deref(), Some("x-axis"));
        // Renaming keeps the role.
        assert_eq!(store.save("y-axis"), Ok(true));
        assert_eq!(store.load_bus(), BusRole::Drop(4));
        assert_eq!(store.load().as_deref(), Some("y-axis"));
        // A role with no name stored leaves the default name in force.
        let _ = store.into_inner();
        let mut blank = RamSector::erased();
        let mut store = NameStore::new(&mut blank);
        assert_eq!(store.save_bus(BusRole::Head { max_drop: 8 }), Ok(true));
        assert_eq!(store.load(), None);
        assert_eq!(store.load_bus(), BusRole::Head { max_drop: 8 });
        let _ = store.into_inner();
        assert_eq!(blank.erases, 1);
        // A torn or corrupted role record reads as off.
        blank.bytes[BUS_OFFSET + 5] ^= 1;
        assert_eq!(NameStore::new(&mut blank).load_bus(), BusRole::Off);
        assert_eq!(
            decode_bus(&encode_bus(BusRole::Drop(9))),
            Some(BusRole::Drop(9))
        );
        assert_eq!(decode_bus(&[0xFF; BUS_RECORD]), None);
        assert_eq!(decode_bus(&[0; 3]), None);
    }
}
