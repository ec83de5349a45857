//! A simulated UF2 bootloader: what a simulated module's board does when
//! osap-module's `enter_bootloader` comes due (`Board::reboot_to_bootloader`),
//! `[module.bootloader]` in a topology file.
//!
//! The module goes off the network, as a board rebooting into its
//! bootloader does, and its **drive** (a directory standing for the USB
//! mass-storage drive the bootloader presents) gets an `INFO_UF2.TXT` like
//! the real one's: the RP2040 boot ROM's (`Board-ID: RPI-RP2`) or Adafruit's
//! SAMD51 bootloader's (`Board-ID: SAMD51J19A-Metro-v0`). A `.uf2` file
//! written into the drive is read as the bootloader reads one: once all its
//! blocks are there it is checked ([`uf2_link::uf2::inspect`]); a good file
//! of the board's family is "flashed": the file and `INFO_UF2.TXT` go (the
//! drive unmounts) and, after a simulated reboot, the module is back on the
//! network, the same simulated firmware with the name it had (a real board
//! keeps a name in flash). A file of another family, or one that is not a
//! valid UF2, is refused: it is removed, the module stays in its bootloader,
//! and the refusal is logged (a warning) and counted ([`BootStats`]).
//!
//! None of this is module logic: osap-module only arms the request and,
//! once due, calls the board, exactly as on hardware.

use crate::topology::{BootloaderSpec, Chip};
use std::io;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;
use uf2_link::uf2::{self, Uf2Info};

/// The file that marks a UF2 bootloader's drive.
pub const INFO_FILE: &str = "INFO_UF2.TXT";

/// How long an incomplete `.uf2` file may stay unchanged before it is
/// refused (a copy that stopped half way).
pub const STALLED_COPY: Duration = Duration::from_secs(5);

/// What a simulated bootloader has done since its machine started.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct BootStats {
    /// Times the module rebooted into its bootloader.
    pub entered: u32,
    /// UF2 files taken: the module rebooted into them.
    pub flashed: u32,
    /// `.uf2` files refused (another family, not a valid UF2, a copy that
    /// stopped): each left the module in its bootloader.
    pub rejected: u32,
    /// Why the latest file was refused.
    pub last_rejection: Option<String>,
}

/// What the board calls to reboot into its bootloader: set by the
/// simulated machine, which takes the module off the network.
#[derive(Clone)]
pub struct BootHook(Arc<dyn Fn() + Send + Sync>);

impl BootHook {
    /// A hook that runs `f`.
    pub(crate) fn new(f: impl Fn() + Send + Sync + 'static) -> Self {
        BootHook(Arc::new(f))
    }

    /// Asks for the reboot.
    pub(crate) fn call(&self) {
        (self.0)()
    }
}

impl std::fmt::Debug for BootHook {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("BootHook")
    }
}

/// What arrived on the drive.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum Arrival {
    /// A complete UF2 of the board's family: flash it and reboot.
    Flashed(Uf2Info),
    /// A file refused, and why.
    Rejected(String),
}

/// A `.uf2` file still being copied: its length and since when it has had
/// it.
#[derive(Debug)]
struct Copying {
    path: PathBuf,
    len: usize,
    since: std::time::Instant,
}

/// The bootloader's drive while the module is in its bootloader.
#[derive(Debug)]
pub(crate) struct Drive {
    dir: PathBuf,
    chip: Chip,
    copying: Option<Copying>,
}

impl Drive {
    /// Mounts the drive: creates its directory if needed and writes its
    /// `INFO_UF2.TXT`.
    pub(crate) fn mount(spec: &BootloaderSpec) -> io::Result<Drive> {
        std::fs::create_dir_all(&spec.drive)?;
        // Whole or not at all, as a drive appears when it is mounted: a
        // reader polling for it never sees half a file.
        let partial = spec.drive.join(".INFO_UF2.TXT.partial");
        std::fs::write(&partial, spec.chip.info_text())?;
        std::fs::rename(&partial, spec.drive.join(INFO_FILE))?;
        Ok(Drive {
            dir: spec.drive.clone(),
            chip: spec.chip,
            copying: None,
        })
    }

    /// The drive's directory.
    pub(crate) fn dir(&self) -> &Path {
        &self.dir
    }

    /// Unmounts the drive: its `INFO_UF2.TXT` goes.
    pub(crate) fn unmount(&self) {
        let _ = std::fs::remove_file(self.dir.join(INFO_FILE));
    }

    /// Looks at the drive: the first `.uf2` file that is complete (all its
    /// blocks there) or refused, removed from the drive; `None` while there
    /// is none, or one is still being copied.
    pub(crate) fn poll(&mut self) -> Option<Arrival> {
        let mut files: Vec<PathBuf> = std::fs::read_dir(&self.dir)
            .ok()?
            .filter_map(Result::ok)
            .map(|e| e.path())
            .filter(|p| p.is_file() && p.extension().is_some_and(|e| e.eq_ignore_ascii_case("uf2")))
            .collect();
        files.sort();
        for path in files {
            let Ok(bytes) = std::fs::read(&path) else {
                continue;
            };
            let arrival = match self.check(&path, &bytes) {
                Some(a) => a,
                None => continue,
            };
            let _ = std::fs::remove_file(&path);
            self.copying = None;
            return Some(arrival);
        }
        None
    }

    /// What `bytes` (the file at `path`, as far as it has been written)
    /// make: `None` while its copy is still coming.
    fn check(&mut self, path: &Path, bytes: &[u8]) -> Option<Arrival> {
        let name = path
            .file_name()
            .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
        let expected = expected_len(bytes);
        let complete = matches!(expected, Some(Ok(n)) if bytes.len() >= n);
        if let Some(Err(why)) = expected {
            return Some(Arrival::Rejected(format!("{name}: {why}")));
        }
        if !complete {
            // Still coming, unless it stopped.
            let now = std::time::Instant::now();
            match &self.copying {
                Some(c) if c.path == path && c.len == bytes.len() => {
                    if now.duration_since(c.since) >= STALLED_COPY {
                        let blocks = bytes.len() / uf2::BLOCK;
                        return Some(Arrival::Rejected(format!(
                            "{name}: the copy stopped after {blocks} block(s) of {}",
                            expected
                                .and_then(Result::ok)
                                .map_or_else(|| "?".into(), |n| (n / uf2::BLOCK).to_string())
                        )));
                    }
                }
                _ => {
                    self.copying = Some(Copying {
                        path: path.to_path_buf(),
                        len: bytes.len(),
                        since: now,
                    })
                }
            }
            return None;
        }
        Some(match uf2::inspect(bytes) {
            Err(e) => Arrival::Rejected(format!("{name}: not a valid UF2: {e}")),
            Ok(info) if info.family_id != self.chip.family_id() => Arrival::Rejected(format!(
                "{name}: UF2 family {} but this board ({}) takes {}; its blocks are ignored",
                uf2::family_label(info.family_id),
                self.chip.name(),
                uf2::family_label(self.chip.family_id())
            )),
            Ok(info) => Arrival::Flashed(info),
        })
    }
}

/// How long a UF2 file whose first block is `bytes[..512]` is, from that
/// block's total-blocks field: `None` before the first block is there, an
/// error if it is not a UF2 block.
fn expected_len(bytes: &[u8]) -> Option<Result<usize, String>> {
    let first = bytes.get(..uf2::BLOCK)?;
    let word = |at: usize| {
        let mut w = [0u8; 4];
        w.copy_from_slice(&first[at..at + 4]);
        u32::from_le_bytes(w)
    };
    if word(0) != uf2::MAGIC_START0 || word(4) != uf2::MAGIC_START1 {
        return Some(Err(
            "not a UF2 file (no UF2 magic in its first block)".into()
        ));
    }
    let count = word(24) as usize;
    if count == 0 {
        return Some(Err("not a valid UF2: its first block says 0 blocks".into()));
    }
    Some(Ok(count.saturating_mul(uf2::BLOCK)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use uf2_link::uf2::{RP2040_FAMILY_ID, SAMD51_FAMILY_ID};

    fn image(family: u32, blocks: u32) -> Vec<u8> {
        let payload = [0xA5u8; uf2::PAYLOAD];
        (0..blocks)
            .flat_map(|i| {
                uf2::block(
                    0x1000_0000 + i * uf2::PAYLOAD as u32,
                    &payload,
                    i,
                    blocks,
                    family,
                )
            })
            .collect()
    }

    fn temp_drive(tag: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("osap-sim-bootloader-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        dir
    }

    #[test]
    fn a_drive_takes_its_family_and_refuses_others() {
        let dir = temp_drive("family");
        let mut drive = Drive::mount(&BootloaderSpec::new(&dir, Chip::Rp2040)).unwrap();
        let info = std::fs::read_to_string(dir.join(INFO_FILE)).unwrap();
        assert!(info.contains("Board-ID: RPI-RP2"), "{info}");
        assert_eq!(drive.poll(), None, "nothing there yet");

        // Half a copy: wait for the rest.
        let good = image(RP2040_FAMILY_ID, 4);
        std::fs::write(dir.join("fw.uf2"), &good[..2 * uf2::BLOCK]).unwrap();
        assert_eq!(drive.poll(), None);
        std::fs::write(dir.join("fw.uf2"), &good).unwrap();
        match drive.poll() {
            Some(Arrival::Flashed(info)) => assert_eq!(info.block_count, 4),
            other => panic!("{other:?}"),
        }
        assert!(!dir.join("fw.uf2").exists(), "the drive keeps no file");

        std::fs::write(dir.join("other.UF2"), image(SAMD51_FAMILY_ID, 2)).unwrap();
        match drive.poll() {
            Some(Arrival::Rejected(why)) => assert!(why.contains("SAMD51"), "{why}"),
            other => panic!("{other:?}"),
        }
        std::fs::write(dir.join("junk.uf2"), [0u8; 1024]).unwrap();
        assert!(matches!(drive.poll(), Some(Arrival::Rejected(_))));
        assert_eq!(drive.poll(), None);
        drive.unmount();
        assert!(!dir.join(INFO_FILE).exists());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_samd51_drive_says_so() {
        let text = Chip::Samd51.info_text();
        assert!(text.contains("Board-ID: SAMD51J19A-Metro-v0"), "{text}");
        assert_eq!(Chip::Samd51.family_id(), SAMD51_FAMILY_ID);
        assert!(BootloaderSpec::new("", Chip::Rp2040).check().is_err());
    }
}
