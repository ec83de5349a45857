//! Finding a mounted UF2 bootloader drive and copying a UF2 file onto it.
//!
//! A board in its UF2 bootloader shows up as a small USB drive whose root
//! holds `INFO_UF2.TXT`, e.g. for the RP2040's boot ROM
//!
//! ```text
//! UF2 Bootloader v3.0
//! Model: Raspberry Pi RP2
//! Board-ID: RPI-RP2
//! ```
//!
//! and for Adafruit's SAMD51 bootloader `Board-ID: SAMD51J19A-Metro-v0` or
//! `SAMD51J19A-Feather-M4-v0`. Copying a UF2 file onto the drive flashes
//! it; the bootloader resets the board into the new firmware when the last
//! block has arrived.
//!
//! Where drives are looked for ([`candidate_dirs`]): the directories in
//! `OSAP_UF2_MOUNTS` if it is set (a path list, `:`-separated on Unix,
//! `;` on Windows), instead of the system's; otherwise on Linux every mount
//! point in `/proc/self/mounts` and the children of `/media/$USER` and
//! `/run/media/$USER`, on macOS the children of `/Volumes`, on Windows the
//! drive letters `D:` to `Z:`.

use std::ffi::OsString;
use std::io::{self, Read, Write};
use std::path::{Path, PathBuf};

use crate::uf2::{RP2040_FAMILY_ID, SAMD51_FAMILY_ID};

/// The environment variable that replaces the system's mount points with
/// a list of directories (tests use it for a fake drive; a user for a
/// drive mounted somewhere unusual).
pub const MOUNTS_ENV: &str = "OSAP_UF2_MOUNTS";
/// The file that marks a UF2 bootloader drive.
pub const INFO_FILE: &str = "INFO_UF2.TXT";
/// The name the UF2 is written under on the drive (any `.uf2` name works).
pub const TARGET_FILE: &str = "firmware.uf2";
/// A real `INFO_UF2.TXT` is under 200 bytes; a larger file is not one.
const INFO_MAX: u64 = 64 * 1024;

/// A mounted UF2 bootloader drive.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BootDrive {
    /// The drive's root directory.
    pub path: PathBuf,
    /// `Board-ID:` of its `INFO_UF2.TXT`, e.g. `RPI-RP2`.
    pub board_id: String,
    /// `Model:` of its `INFO_UF2.TXT`, e.g. `Raspberry Pi RP2` (empty if
    /// the file has no such line).
    pub model: String,
}

impl std::fmt::Display for BootDrive {
    /// `/media/me/RPI-RP2 (RPI-RP2, Raspberry Pi RP2)`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} ({}", self.path.display(), self.board_id)?;
        if !self.model.is_empty() {
            write!(f, ", {}", self.model)?;
        }
        write!(f, ")")
    }
}

/// Whether a drive with this `Board-ID` takes UF2 files of `family`:
/// RP2040 boot ROMs say `RPI-RP2`, Adafruit's SAMD51 bootloaders say
/// `SAMD51J19A-Metro-v0` and the like. Unknown families match nothing.
pub fn family_matches(family: u32, board_id: &str) -> bool {
    match family {
        RP2040_FAMILY_ID => board_id.starts_with("RPI-RP2"),
        SAMD51_FAMILY_ID => board_id.contains("SAMD51"),
        _ => false,
    }
}

/// What a drive of `family` says in its `INFO_UF2.TXT`, for messages.
pub fn expected_board_id(family: u32) -> &'static str {
    match family {
        RP2040_FAMILY_ID => "Board-ID: RPI-RP2",
        SAMD51_FAMILY_ID => "a Board-ID containing SAMD51",
        _ => "a Board-ID of that family (none known)",
    }
}

/// Parses an `INFO_UF2.TXT`: returns `(model, board_id)`. `Board-ID` is
/// required (it is how the family is told); `Model` may be missing.
pub(crate) fn parse_info(text: &str) -> Result<(String, String), String> {
    let mut model = None;
    let mut board = None;
    for line in text.lines() {
        let Some((key, value)) = line.split_once(':') else {
            continue;
        };
        let value = value.trim();
        match key.trim() {
            "Model" if model.is_none() => model = Some(value.to_string()),
            "Board-ID" if board.is_none() => board = Some(value.to_string()),
            _ => {}
        }
    }
    match board {
        Some(b) if !b.is_empty() => Ok((model.unwrap_or_default(), b)),
        _ => Err("no `Board-ID:` line".into()),
    }
}

/// The boot drive rooted at `dir`: `None` if `dir` has no `INFO_UF2.TXT`
/// (an ordinary drive or directory), an error if it has one that cannot be
/// read or has no `Board-ID`.
pub fn read_drive(dir: &Path) -> io::Result<Option<BootDrive>> {
    let info = dir.join(INFO_FILE);
    if !info.is_file() {
        return Ok(None);
    }
    let invalid = |why: String| {
        io::Error::new(
            io::ErrorKind::InvalidData,
            format!("{}: {why}", info.display()),
        )
    };
    let mut raw = Vec::new();
    std::fs::File::open(&info)
        .and_then(|f| f.take(INFO_MAX + 1).read_to_end(&mut raw))
        .map_err(|e| invalid(format!("cannot read it: {e}")))?;
    if raw.len() as u64 > INFO_MAX {
        return Err(invalid(format!(
            "over {INFO_MAX} bytes: not a UF2 bootloader's info file"
        )));
    }
    let (model, board_id) = parse_info(&String::from_utf8_lossy(&raw)).map_err(invalid)?;
    Ok(Some(BootDrive {
        path: dir.to_path_buf(),
        board_id,
        model,
    }))
}

/// The boot drives of `family` among `candidates`, each a directory that
/// may be a drive's root; directories without `INFO_UF2.TXT`, missing or
/// unreadable ones are skipped, and a drive seen under two paths is listed
/// once. Sorted by path.
pub fn find_boot_drives_in(family: u32, candidates: &[PathBuf]) -> io::Result<Vec<BootDrive>> {
    let mut seen = std::collections::BTreeSet::new();
    let mut out = Vec::new();
    for dir in candidates {
        let Some(drive) = read_drive(dir)? else {
            continue;
        };
        if !family_matches(family, &drive.board_id) {
            continue;
        }
        // /proc/self/mounts and /media/$USER list the same mount twice.
        let key = std::fs::canonicalize(dir).unwrap_or_else(|_| dir.clone());
        if seen.insert(key) {
            out.push(drive);
        }
    }
    out.sort_by(|a, b| a.path.cmp(&b.path));
    Ok(out)
}

/// The mounted UF2 boot drives of `family` (a UF2 family id such as
/// [`RP2040_FAMILY_ID`]), searched in [`candidate_dirs`]. An
/// `INFO_UF2.TXT` that cannot be read or has no `Board-ID` line is an
/// error naming the file.
pub fn find_boot_drives(family: u32) -> io::Result<Vec<BootDrive>> {
    find_boot_drives_in(family, &candidate_dirs())
}

/// Where [`find_boot_drives`] looks: [`env_candidates`] if
/// `OSAP_UF2_MOUNTS` is set and not empty, else [`system_candidates`].
pub fn candidate_dirs() -> Vec<PathBuf> {
    match std::env::var_os(MOUNTS_ENV) {
        Some(list) if !list.is_empty() => env_candidates(&list),
        _ => system_candidates(),
    }
}

/// The candidates an `OSAP_UF2_MOUNTS` value names: each listed directory,
/// and, for one that is not itself a drive (no `INFO_UF2.TXT`), its
/// subdirectories, so the variable can name a drive or a folder drives are
/// mounted under.
pub fn env_candidates(list: &std::ffi::OsStr) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for dir in std::env::split_paths(list) {
        if dir.as_os_str().is_empty() {
            continue;
        }
        if !dir.join(INFO_FILE).is_file() {
            out.extend(children(&dir));
        }
        out.push(dir);
    }
    out
}

/// The system's candidate directories on this OS (see the module doc).
pub fn system_candidates() -> Vec<PathBuf> {
    if cfg!(target_os = "linux") {
        linux_candidates()
    } else if cfg!(target_os = "macos") {
        children(Path::new("/Volumes"))
    } else if cfg!(windows) {
        windows_candidates()
    } else {
        Vec::new()
    }
}

/// Linux: every mount point, and the children of the desktop's automount
/// folders (they are mount points too, but a listing costs nothing and
/// covers a /proc that is not mounted).
fn linux_candidates() -> Vec<PathBuf> {
    let mut out = std::fs::read_to_string("/proc/self/mounts")
        .map(|text| parse_mounts(&text))
        .unwrap_or_default();
    if let Some(user) = std::env::var_os("USER").filter(|u| !u.is_empty()) {
        for base in ["/media", "/run/media"] {
            out.extend(children(&Path::new(base).join(&user)));
        }
    }
    out
}

/// Windows: drive letters D: to Z: (A: to C: are floppies and the system).
fn windows_candidates() -> Vec<PathBuf> {
    (b'D'..=b'Z')
        .map(|l| PathBuf::from(format!("{}:\\", l as char)))
        .filter(|p| p.is_dir())
        .collect()
}

/// Subdirectories of `dir` (none if it cannot be read).
fn children(dir: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut out: Vec<PathBuf> = entries
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| p.is_dir())
        .collect();
    out.sort();
    out
}

/// Filesystems no boot drive is on, or that must not be touched: kernel
/// pseudo filesystems, and autofs, where a look would trigger a mount.
const SKIPPED_FS: &[&str] = &[
    "proc",
    "sysfs",
    "devtmpfs",
    "devpts",
    "cgroup",
    "cgroup2",
    "securityfs",
    "debugfs",
    "tracefs",
    "pstore",
    "bpf",
    "mqueue",
    "hugetlbfs",
    "configfs",
    "fusectl",
    "binfmt_misc",
    "efivarfs",
    "autofs",
    "nsfs",
];

/// The mount points in a `/proc/self/mounts` text (`device mountpoint
/// fstype options 0 0` per line, with space, tab, newline and backslash in
/// the mount point written as octal escapes such as `\040`), less those
/// on kernel pseudo filesystems and autofs (no boot drive is on one).
pub fn parse_mounts(text: &str) -> Vec<PathBuf> {
    text.lines()
        .filter_map(|line| {
            let mut fields = line.split_ascii_whitespace();
            let (_dev, mount, fstype) = (fields.next()?, fields.next()?, fields.next()?);
            if SKIPPED_FS.contains(&fstype) {
                return None;
            }
            Some(PathBuf::from(unescape_mount(mount)))
        })
        .collect()
}

/// Undoes the kernel's octal escapes (`\040` is a space); a backslash not
/// followed by three octal digits stays as it is.
pub fn unescape_mount(s: &str) -> OsString {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        let octal = b
            .get(i + 1..i + 4)
            .filter(|d| b[i] == b'\\' && d.iter().all(|c| (b'0'..=b'7').contains(c)));
        match octal {
            Some(d) => {
                let v = u32::from(d[0] - b'0') * 64
                    + u32::from(d[1] - b'0') * 8
                    + u32::from(d[2] - b'0');
                // \400 and up are not bytes; keep such text as it is.
                match u8::try_from(v) {
                    Ok(byte) => {
                        out.push(byte);
                        i += 4;
                    }
                    Err(_) => {
                        out.push(b[i]);
                        i += 1;
                    }
                }
            }
            None => {
                out.push(b[i]);
                i += 1;
            }
        }
    }
    bytes_to_os(out)
}

#[cfg(unix)]
fn bytes_to_os(bytes: Vec<u8>) -> OsString {
    use std::os::unix::ffi::OsStringExt;
    OsString::from_vec(bytes)
}

#[cfg(not(unix))]
fn bytes_to_os(bytes: Vec<u8>) -> OsString {
    String::from_utf8_lossy(&bytes).into_owned().into()
}

/// Copies `uf2` onto `drive` as `firmware.uf2` and flushes it to the
/// device; returns the file's path.
///
/// The bootloader resets the board as soon as the last block lands, so the
/// drive may disappear while the file is still being closed: the final
/// fsync (or a late write) can fail with an I/O error, and the file may be
/// gone afterwards. Once every byte has been handed to the OS, such an
/// error is the board rebooting, not a failed copy, so it counts as
/// success. An error before that (drive gone, read-only, full) is returned.
pub fn write_uf2(drive: &BootDrive, uf2: &[u8]) -> io::Result<PathBuf> {
    let path = drive.path.join(TARGET_FILE);
    let mut file = std::fs::File::create(&path)?;
    let mut written = 0;
    // One block per write: the OS may pass them on as they come, and an
    // error is known to the byte.
    while written < uf2.len() {
        let end = (written + crate::uf2::BLOCK).min(uf2.len());
        match file.write(&uf2[written..end]) {
            Ok(0) => {
                return Err(io::Error::new(
                    io::ErrorKind::WriteZero,
                    format!("{}: the drive took no more bytes", path.display()),
                ))
            }
            Ok(n) => written += n,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    // All bytes are written: from here an error is the board resetting.
    let _ = file.sync_all();
    Ok(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_info_files() {
        let rp = "UF2 Bootloader v3.0\nModel: Raspberry Pi RP2\nBoard-ID: RPI-RP2\n";
        assert_eq!(
            parse_info(rp),
            Ok(("Raspberry Pi RP2".into(), "RPI-RP2".into()))
        );
        // Adafruit's, with CRLF line ends.
        let metro = "UF2 Bootloader v3.14.0 SFHWRO\r\nModel: Metro M4 Express\r\nBoard-ID: SAMD51J19A-Metro-v0\r\n";
        assert_eq!(
            parse_info(metro),
            Ok(("Metro M4 Express".into(), "SAMD51J19A-Metro-v0".into()))
        );
        assert_eq!(
            parse_info("Board-ID: RPI-RP2"),
            Ok((String::new(), "RPI-RP2".into()))
        );
        assert!(parse_info("UF2 Bootloader\nModel: x\n").is_err());
        assert!(parse_info("Board-ID:   \n").is_err());
        assert!(parse_info("").is_err());
    }

    #[test]
    fn families_match_board_ids() {
        assert!(family_matches(RP2040_FAMILY_ID, "RPI-RP2"));
        assert!(!family_matches(RP2040_FAMILY_ID, "SAMD51J19A-Metro-v0"));
        assert!(family_matches(SAMD51_FAMILY_ID, "SAMD51J19A-Metro-v0"));
        assert!(family_matches(SAMD51_FAMILY_ID, "SAMD51J19A-Feather-M4-v0"));
        assert!(!family_matches(SAMD51_FAMILY_ID, "RPI-RP2"));
        // A SAMD21 board's bootloader takes a different family.
        assert!(!family_matches(SAMD51_FAMILY_ID, "SAMD21G18A-Zero-v0"));
        assert!(!family_matches(0x1234, "RPI-RP2"));
    }

    #[test]
    fn parses_proc_mounts() {
        let text = "\
sysfs /sys sysfs rw,nosuid 0 0
proc /proc proc rw 0 0
/dev/sda1 / ext4 rw,relatime 0 0
/dev/sdb1 /media/me/RPI-RP2 vfat rw,nosuid,nodev 0 0
/dev/sdc1 /media/me/My\\040Drive\\040(2) vfat rw 0 0
/dev/sdd1 /mnt/tab\\011and\\134back\\012line exfat rw 0 0
systemd-1 /boot/efi autofs rw 0 0
broken-line
";
        assert_eq!(
            parse_mounts(text),
            [
                PathBuf::from("/"),
                "/media/me/RPI-RP2".into(),
                "/media/me/My Drive (2)".into(),
                "/mnt/tab\tand\\back\nline".into(),
            ]
        );
    }

    #[test]
    fn unescapes_only_octal_bytes() {
        assert_eq!(unescape_mount("a\\040b"), "a b");
        assert_eq!(unescape_mount("\\"), "\\");
        assert_eq!(unescape_mount("a\\04"), "a\\04");
        assert_eq!(unescape_mount("a\\x40"), "a\\x40");
        assert_eq!(unescape_mount("\\777"), "\\777");
        assert_eq!(unescape_mount("\\303\\251t\\303\\251"), "été");
    }
}
