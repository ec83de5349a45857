//! The learned clock rate, logged in its own flash sector.
//!
//! A module's clock learns a rate correction against its oscillator (see
//! osap-core's clock). Saved, it lets the next boot start from it (a hot
//! start, [`crate::hot_start`]). The rate lives in a sector of its own, not
//! beside the name (osap-firmware's `name_store`): a reset while a rate is being
//! written can then never cost the module its name.
//!
//! The sector is a log of fixed 16-byte records, appended one after the
//! other and erased only when it is full, so one erase cycle buys
//! `sector size / 16` saves (256 in a 4 KiB sector, 512 in an 8 KiB one):
//!
//! ```text
//! offset 0  magic "OSRT" (0x5452534F, little-endian)
//!        4  sequence number, u32 little-endian (one more than the newest)
//!        8  rate correction, ppb, i32 little-endian
//!       12  source link index (the lowest link the clock followed)
//!       13  source tier (the clock's own tier then)
//!       14  CRC-16/IBM-3740 of bytes 0..14, most significant byte first
//! ```
//!
//! On load the valid record with the highest sequence number wins; an
//! erased slot (all 0xFF), a torn write, a flipped bit or a record of
//! another layout fails the magic or CRC check and is skipped. A slot is
//! only ever written while erased: appends go after the last slot that is
//! not all 0xFF, torn ones included. A 16-byte record is one quad-word,
//! the SAMD51's smallest ECC-protected write.
//!
//! The flash itself is behind [`RateFlash`], so this logic runs and is
//! tested on the host, and the simulator runs it over [`RamRateFlash`];
//! each board crate implements it over its HAL's blocking flash driver.
//! Hardware-free, `no_std` and without allocation, it lives here, below
//! both the firmware and the simulator.
use osap_core::framing::crc16;

/// Magic word at the start of a valid record ("OSRT" in memory).
pub const MAGIC: u32 = 0x5452_534F;
/// Bytes in a record (and in a slot of the sector).
pub const RECORD_LEN: usize = 16;
/// Bytes covered by the CRC.
const BODY: usize = 14;

/// What a saved rate was learned against: the clock's time source, as far
/// as a module can tell it without a root id on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RateSource {
    /// The lowest index of the links whose neighbours the clock followed.
    pub link: u8,
    /// The clock's tier (its hops from the root).
    pub tier: u8,
}

/// One saved rate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RateRecord {
    /// Order of saves: the highest valid one is the newest.
    pub seq: u32,
    /// The clock's rate correction against the local oscillator, ppb.
    pub rate_ppb: i32,
    /// What it was learned against.
    pub source: RateSource,
}

impl RateRecord {
    /// The record's bytes.
    pub fn encode(&self) -> [u8; RECORD_LEN] {
        let mut out = [0u8; RECORD_LEN];
        out[..4].copy_from_slice(&MAGIC.to_le_bytes());
        out[4..8].copy_from_slice(&self.seq.to_le_bytes());
        out[8..12].copy_from_slice(&self.rate_ppb.to_le_bytes());
        out[12] = self.source.link;
        out[13] = self.source.tier;
        let crc = crc16(&out[..BODY]).to_be_bytes();
        out[BODY..].copy_from_slice(&crc);
        out
    }

    /// The record in `bytes`, if they hold a valid one.
    pub fn decode(bytes: &[u8; RECORD_LEN]) -> Option<RateRecord> {
        let word = |at: usize| [bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]];
        if u32::from_le_bytes(word(0)) != MAGIC {
            return None;
        }
        if bytes[BODY..] != crc16(&bytes[..BODY]).to_be_bytes() {
            return None;
        }
        Some(RateRecord {
            seq: u32::from_le_bytes(word(4)),
            rate_ppb: i32::from_le_bytes(word(8)),
            source: RateSource {
                link: bytes[12],
                tier: bytes[13],
            },
        })
    }
}

/// The sector that holds the log.
pub trait RateFlash {
    /// The flash driver's error.
    type Error;
    /// The sector's size in bytes (the erase unit; a multiple of
    /// [`RECORD_LEN`]).
    fn size(&self) -> usize;
    /// Reads one record's bytes at `offset` from the sector's start.
    fn read(&mut self, offset: usize, buf: &mut [u8; RECORD_LEN]) -> Result<(), Self::Error>;
    /// Writes one record at `offset` (an erased slot).
    fn write(&mut self, offset: usize, record: &[u8; RECORD_LEN]) -> Result<(), Self::Error>;
    /// Erases the whole sector (every byte reads 0xFF after).
    fn erase(&mut self) -> Result<(), Self::Error>;
}

/// Why a rate could not be stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum RateStoreError<E> {
    /// The flash driver failed.
    Flash(E),
    /// The record read back differs from the one written (a worn or
    /// failing slot); the next save goes to the next slot.
    Verify,
}

impl<E: core::fmt::Debug> core::fmt::Display for RateStoreError<E> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            RateStoreError::Flash(e) => write!(f, "the flash driver failed: {e:?}"),
            RateStoreError::Verify => {
                f.write_str("the record read back differs from the one written")
            }
        }
    }
}

impl<E: core::fmt::Debug> core::error::Error for RateStoreError<E> {}

/// The rate log in one flash sector.
pub struct RateStore<F> {
    flash: F,
    /// The newest valid record.
    newest: Option<RateRecord>,
    /// The slot the next record goes to (past the end: erase first).
    next: usize,
    /// Sector erases by this store since it was opened.
    erases: u32,
}

impl<F> core::fmt::Debug for RateStore<F> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("RateStore")
            .field("newest", &self.newest)
            .field("erases", &self.erases)
            .finish_non_exhaustive()
    }
}

impl<F: RateFlash> RateStore<F> {
    /// Opens the log in `flash`: finds the newest valid record and the
    /// first slot after every written one. A failed read counts as a full
    /// sector, so the next save erases it.
    pub fn open(mut flash: F) -> Self {
        let slots = flash.size() / RECORD_LEN;
        let mut newest: Option<RateRecord> = None;
        let mut next = 0;
        let mut buf = [0u8; RECORD_LEN];
        for slot in 0..slots {
            if flash.read(slot * RECORD_LEN, &mut buf).is_err() {
                next = slots;
                continue;
            }
            if buf == [0xFF; RECORD_LEN] {
                continue;
            }
            next = slot + 1;
            if let Some(r) = RateRecord::decode(&buf) {
                // Later slots win ties (seq saturates at u32::MAX).
                if newest.is_none_or(|n| r.seq >= n.seq) {
                    newest = Some(r);
                }
            }
        }
        RateStore {
            flash,
            newest,
            next,
            erases: 0,
        }
    }

    /// The newest valid record, if any.
    pub fn newest(&self) -> Option<RateRecord> {
        self.newest
    }

    /// Sector erases since the store was opened.
    pub fn erases(&self) -> u32 {
        self.erases
    }

    /// Records the sector holds.
    pub fn slots(&self) -> usize {
        self.flash.size() / RECORD_LEN
    }

    /// The flash, back.
    pub fn into_inner(self) -> F {
        self.flash
    }

    /// Appends a record of `rate_ppb` learned against `source`, erasing the
    /// sector first if it is full, and reads it back. Returns the record.
    pub fn append(
        &mut self,
        rate_ppb: i32,
        source: RateSource,
    ) -> Result<RateRecord, RateStoreError<F::Error>> {
        let record = RateRecord {
            seq: self.newest.map_or(0, |n| n.seq.saturating_add(1)),
            rate_ppb,
            source,
        };
        if self.next >= self.slots() {
            self.erases = self.erases.wrapping_add(1);
            self.flash.erase().map_err(RateStoreError::Flash)?;
            self.next = 0;
        }
        let offset = self.next * RECORD_LEN;
        // Past this slot whatever happens: it may be partly written now.
        self.next += 1;
        let bytes = record.encode();
        self.flash
            .write(offset, &bytes)
            .map_err(RateStoreError::Flash)?;
        let mut back = [0u8; RECORD_LEN];
        self.flash
            .read(offset, &mut back)
            .map_err(RateStoreError::Flash)?;
        if back != bytes {
            return Err(RateStoreError::Verify);
        }
        self.newest = Some(record);
        Ok(record)
    }
}

/// A sector in RAM that behaves like NOR flash (writes only clear bits),
/// counts erases and can tear or fail writes: for tests, and for simulated
/// modules whose "flash" survives a simulated reboot.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RamRateFlash<const N: usize> {
    /// The sector's bytes.
    pub bytes: [u8; N],
    /// Erases since creation.
    pub erases: u32,
    /// Records written since creation.
    pub writes: u32,
    /// The next write stops after this many bytes (a reset mid-write),
    /// then the flag clears.
    pub tear_next_at: Option<usize>,
    /// Every operation fails.
    pub fail: bool,
}

impl<const N: usize> RamRateFlash<N> {
    /// An erased sector.
    pub const fn erased() -> Self {
        RamRateFlash {
            bytes: [0xFF; N],
            erases: 0,
            writes: 0,
            tear_next_at: None,
            fail: false,
        }
    }
}

impl<const N: usize> RateFlash for &mut RamRateFlash<N> {
    type Error = ();

    fn size(&self) -> usize {
        N
    }

    fn read(&mut self, offset: usize, buf: &mut [u8; RECORD_LEN]) -> Result<(), ()> {
        if self.fail {
            return Err(());
        }
        buf.copy_from_slice(self.bytes.get(offset..offset + RECORD_LEN).ok_or(())?);
        Ok(())
    }

    fn write(&mut self, offset: usize, record: &[u8; RECORD_LEN]) -> Result<(), ()> {
        if self.fail {
            return Err(());
        }
        let n = self
            .tear_next_at
            .take()
            .unwrap_or(RECORD_LEN)
            .min(RECORD_LEN);
        let slot = self.bytes.get_mut(offset..offset + RECORD_LEN).ok_or(())?;
        for (b, r) in slot.iter_mut().zip(record).take(n) {
            *b &= r;
        }
        self.writes = self.writes.wrapping_add(1);
        Ok(())
    }

    fn erase(&mut self) -> Result<(), ()> {
        if self.fail {
            return Err(());
        }
        self.bytes = [0xFF; N];
        self.erases = self.erases.wrapping_add(1);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const USB: RateSource = RateSource { link: 0, tier: 1 };
    type Sector = RamRateFlash<256>; // 16 slots

    #[test]
    fn golden_record_and_round_trip() {
        let r = RateRecord {
            seq: 7,
            rate_ppb: -12_345,
            source: USB,
        };
        let b = r.encode();
        assert_eq!(&b[..4], b"OSRT");
        assert_eq!(b[4..8], [7, 0, 0, 0]);
        assert_eq!(b[8..12], (-12_345i32).to_le_bytes());
        assert_eq!(b[12..14], [0, 1]);
        assert_eq!(b[14..], crc16(&b[..14]).to_be_bytes());
        assert_eq!(RateRecord::decode(&b), Some(r));
    }

    #[test]
    fn corrupt_wrong_magic_and_erased_are_rejected() {
        assert_eq!(RateRecord::decode(&[0xFF; RECORD_LEN]), None);
        assert_eq!(RateRecord::decode(&[0; RECORD_LEN]), None);
        let good = RateRecord {
            seq: 1,
            rate_ppb: 40_000,
            source: USB,
        }
        .encode();
        for byte in 0..RECORD_LEN {
            for bit in 0..8 {
                let mut bad = good;
                bad[byte] ^= 1 << bit;
                assert_eq!(RateRecord::decode(&bad), None, "flip {byte}.{bit}");
            }
        }
        // Another magic with a matching CRC (e.g. the name store's).
        let mut other = good;
        other[..4].copy_from_slice(b"OSNM");
        let crc = crc16(&other[..14]).to_be_bytes();
        other[14..].copy_from_slice(&crc);
        assert_eq!(RateRecord::decode(&other), None);
    }

    #[test]
    fn erased_sector_has_nothing_and_round_trips() {
        let mut sector = Sector::erased();
        let mut store = RateStore::open(&mut sector);
        assert_eq!(store.newest(), None);
        let r = store.append(-3_000, USB).unwrap();
        assert_eq!(r.seq, 0);
        let _ = store.into_inner();
        let store = RateStore::open(&mut sector);
        assert_eq!(store.newest(), Some(r));
    }

    #[test]
    fn newest_wins_and_appends_continue() {
        let mut sector = Sector::erased();
        let mut store = RateStore::open(&mut sector);
        for k in 0..5 {
            store.append(1_000 * k, USB).unwrap();
        }
        let _ = store.into_inner();
        let mut store = RateStore::open(&mut sector);
        assert_eq!(
            store.newest().map(|r| (r.seq, r.rate_ppb)),
            Some((4, 4_000))
        );
        store
            .append(9_000, RateSource { link: 1, tier: 2 })
            .unwrap();
        let _ = store.into_inner();
        assert_eq!(sector.writes, 6);
        assert_eq!(sector.erases, 0);
        let store = RateStore::open(&mut sector);
        let n = store.newest().unwrap();
        assert_eq!((n.seq, n.rate_ppb, n.source.link), (5, 9_000, 1));
    }

    #[test]
    fn torn_write_is_skipped_and_never_written_over() {
        let mut sector = Sector::erased();
        let mut store = RateStore::open(&mut sector);
        store.append(100, USB).unwrap();
        let _ = store.into_inner();
        // A reset 9 bytes into the second record.
        sector.tear_next_at = Some(9);
        let mut store = RateStore::open(&mut sector);
        assert_eq!(store.append(200, USB), Err(RateStoreError::Verify));
        let _ = store.into_inner();
        let mut store = RateStore::open(&mut sector);
        assert_eq!(store.newest().map(|r| r.rate_ppb), Some(100));
        // The next record goes after the torn slot, which stays as it is.
        let r = store.append(300, USB).unwrap();
        assert_eq!(r.seq, 1);
        let _ = store.into_inner();
        assert_ne!(sector.bytes[16..32], [0xFF; 16]);
        assert_eq!(
            RateRecord::decode(&sector.bytes[32..48].try_into().unwrap()),
            Some(r)
        );
        assert_eq!(RateStore::open(&mut sector).newest(), Some(r));
    }

    #[test]
    fn full_sector_is_erased_and_the_log_continues() {
        let mut sector = Sector::erased();
        let mut store = RateStore::open(&mut sector);
        assert_eq!(store.slots(), 16);
        for k in 0..16 {
            store.append(k, USB).unwrap();
        }
        assert_eq!(store.erases(), 0);
        let r = store.append(16, USB).unwrap();
        assert_eq!((r.seq, store.erases()), (16, 1));
        let _ = store.into_inner();
        assert_eq!(sector.erases, 1);
        // After the erase the new record sits alone in slot 0.
        assert_eq!(
            RateRecord::decode(&sector.bytes[..16].try_into().unwrap()),
            Some(r)
        );
        assert_eq!(sector.bytes[16..], [0xFF; 240]);
        let mut store = RateStore::open(&mut sector);
        assert_eq!(store.newest(), Some(r));
        // 16 more appends, one more erase: one erase per 16 saves.
        for k in 0..16 {
            store.append(100 + k, USB).unwrap();
        }
        assert_eq!(store.erases(), 1);
        let _ = store.into_inner();
        assert_eq!(sector.erases, 2);
    }

    #[test]
    fn garbage_and_failures_do_not_panic() {
        // A sector of garbage: nothing valid, the next save erases.
        let mut sector = Sector::erased();
        for (i, b) in sector.bytes.iter_mut().enumerate() {
            *b = (i * 37 % 251) as u8;
        }
        let mut store = RateStore::open(&mut sector);
        assert_eq!(store.newest(), None);
        let r = store.append(5, USB).unwrap();
        assert_eq!(store.erases(), 1);
        let _ = store.into_inner();
        assert_eq!(RateStore::open(&mut sector).newest(), Some(r));
        // A failing driver: nothing loads, saves report the error.
        sector.fail = true;
        let mut store = RateStore::open(&mut sector);
        assert_eq!(store.newest(), None);
        assert_eq!(store.append(1, USB), Err(RateStoreError::Flash(())));
    }
}
