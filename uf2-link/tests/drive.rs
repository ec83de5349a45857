//! Boot drive detection against fake mounts: directories with (or
//! without) an `INFO_UF2.TXT`, as the bootloaders write it.

use std::ffi::OsString;
use std::fs;
use std::path::{Path, PathBuf};

use uf2_link::drive::{
    env_candidates, find_boot_drives_in, read_drive, write_uf2, BootDrive, INFO_FILE,
};
use uf2_link::uf2::{RP2040_FAMILY_ID, SAMD51_FAMILY_ID};

const RP2040_INFO: &str = "UF2 Bootloader v3.0\nModel: Raspberry Pi RP2\nBoard-ID: RPI-RP2\n";
const METRO_INFO: &str =
    "UF2 Bootloader v3.14.0 SFHWRO\r\nModel: Metro M4 Express\r\nBoard-ID: SAMD51J19A-Metro-v0\r\n";
const FEATHER_INFO: &str =
    "UF2 Bootloader v3.14.0 SFHWRO\r\nModel: Feather M4 Express\r\nBoard-ID: SAMD51J19A-Feather-M4-v0\r\n";

/// A fake drive: `name` under `root`, with `info` as its INFO_UF2.TXT.
fn drive(root: &Path, name: &str, info: Option<&str>) -> PathBuf {
    let dir = root.join(name);
    fs::create_dir_all(&dir).unwrap();
    fs::write(dir.join("INDEX.HTM"), "<html></html>").unwrap();
    if let Some(info) = info {
        fs::write(dir.join(INFO_FILE), info).unwrap();
    }
    dir
}

#[test]
fn finds_an_rp2040_drive() {
    let root = tempfile::tempdir().unwrap();
    let rp = drive(root.path(), "RPI-RP2", Some(RP2040_INFO));
    let stick = drive(root.path(), "USB STICK", None);
    let found = find_boot_drives_in(RP2040_FAMILY_ID, &[stick.clone(), rp.clone()]).unwrap();
    assert_eq!(
        found,
        [BootDrive {
            path: rp.clone(),
            board_id: "RPI-RP2".into(),
            model: "Raspberry Pi RP2".into(),
        }]
    );
    // The other family does not see it.
    assert!(find_boot_drives_in(SAMD51_FAMILY_ID, &[stick, rp])
        .unwrap()
        .is_empty());
}

#[test]
fn finds_a_samd51_drive() {
    let root = tempfile::tempdir().unwrap();
    let metro = drive(root.path(), "METROM4BOOT", Some(METRO_INFO));
    let found = find_boot_drives_in(SAMD51_FAMILY_ID, std::slice::from_ref(&metro)).unwrap();
    assert_eq!(found.len(), 1);
    assert_eq!(found[0].path, metro);
    assert_eq!(found[0].board_id, "SAMD51J19A-Metro-v0");
    assert_eq!(found[0].model, "Metro M4 Express");
    assert!(find_boot_drives_in(RP2040_FAMILY_ID, &[metro])
        .unwrap()
        .is_empty());
}

#[test]
fn a_usb_stick_is_not_a_boot_drive() {
    let root = tempfile::tempdir().unwrap();
    let stick = drive(root.path(), "STICK", None);
    assert_eq!(read_drive(&stick).unwrap(), None);
    // Nor is a missing directory, or a file.
    let file = root.path().join("file");
    fs::write(&file, "x").unwrap();
    let gone = root.path().join("gone");
    for family in [RP2040_FAMILY_ID, SAMD51_FAMILY_ID] {
        assert!(
            find_boot_drives_in(family, &[stick.clone(), file.clone(), gone.clone()])
                .unwrap()
                .is_empty()
        );
    }
}

#[test]
fn lists_two_drives_once_each() {
    let root = tempfile::tempdir().unwrap();
    let metro = drive(root.path(), "METROM4BOOT", Some(METRO_INFO));
    let feather = drive(root.path(), "FEATHERBOOT", Some(FEATHER_INFO));
    // The same drive seen twice (a mount point and a /media child) counts
    // once.
    let again = root.path().join(".").join("METROM4BOOT");
    let found =
        find_boot_drives_in(SAMD51_FAMILY_ID, &[metro.clone(), feather.clone(), again]).unwrap();
    let paths: Vec<&Path> = found.iter().map(|d| d.path.as_path()).collect();
    assert_eq!(paths, [feather.as_path(), metro.as_path()]);
}

#[test]
fn a_malformed_info_file_is_an_error_naming_it() {
    let root = tempfile::tempdir().unwrap();
    let bad = drive(
        root.path(),
        "ODD",
        Some("UF2 Bootloader\nModel: something\n"),
    );
    let e = find_boot_drives_in(RP2040_FAMILY_ID, &[bad]).unwrap_err();
    assert_eq!(e.kind(), std::io::ErrorKind::InvalidData);
    assert!(
        e.to_string()
            .contains("ODD/INFO_UF2.TXT: no `Board-ID:` line"),
        "{e}"
    );
    // Binary junk is an error too, never a panic.
    let junk = drive(root.path(), "JUNK", None);
    fs::write(junk.join(INFO_FILE), [0xFF, 0xFE, 0, 1, 2]).unwrap();
    assert!(read_drive(&junk).is_err());
    let huge = drive(root.path(), "HUGE", None);
    fs::write(huge.join(INFO_FILE), vec![b'a'; 100_000]).unwrap();
    assert!(read_drive(&huge).unwrap_err().to_string().contains("over"));
}

#[test]
fn env_lists_drives_or_their_parents() {
    let root = tempfile::tempdir().unwrap();
    let media = root.path().join("media");
    let rp = drive(&media, "RPI-RP2", Some(RP2040_INFO));
    let stick = drive(&media, "STICK", None);
    let direct = drive(root.path(), "elsewhere", Some(METRO_INFO));
    let list: OsString = std::env::join_paths([&media, &direct]).unwrap();
    let candidates = env_candidates(&list);
    // The folder's children, the folder, and the drive named directly.
    assert!(candidates.contains(&rp));
    assert!(candidates.contains(&stick));
    assert!(candidates.contains(&direct));
    assert_eq!(
        find_boot_drives_in(RP2040_FAMILY_ID, &candidates).unwrap()[0].path,
        rp
    );
    assert_eq!(
        find_boot_drives_in(SAMD51_FAMILY_ID, &candidates).unwrap()[0].path,
        direct
    );
    // A drive named directly is not searched below.
    drive(&direct, "inner", Some(RP2040_INFO));
    assert!(!env_candidates(direct.as_os_str()).contains(&direct.join("inner")));
}

#[test]
fn writes_the_uf2_onto_the_drive() {
    let root = tempfile::tempdir().unwrap();
    let dir = drive(root.path(), "RPI-RP2", Some(RP2040_INFO));
    let d = read_drive(&dir).unwrap().unwrap();
    let bytes: Vec<u8> = (0..3 * 512).map(|i| i as u8).collect();
    let path = write_uf2(&d, &bytes).unwrap();
    assert_eq!(path, dir.join("firmware.uf2"));
    assert_eq!(fs::read(&path).unwrap(), bytes);
    // A drive that went away before the copy started is an error.
    let gone = BootDrive {
        path: root.path().join("gone"),
        ..d
    };
    assert!(write_uf2(&gone, &bytes).is_err());
}

/// The bootloader resets the board as the last block lands, so the final
/// flush may fail: stood in for by /dev/null (whose fsync fails with
/// EINVAL) behind the drive's firmware.uf2. A write that fails before the
/// end (/dev/full: no space) is still an error.
#[cfg(target_os = "linux")]
#[test]
fn a_failed_flush_after_the_last_byte_is_success() {
    let root = tempfile::tempdir().unwrap();
    let resets = drive(root.path(), "RESETS", Some(RP2040_INFO));
    std::os::unix::fs::symlink("/dev/null", resets.join("firmware.uf2")).unwrap();
    let d = read_drive(&resets).unwrap().unwrap();
    assert_eq!(
        write_uf2(&d, &[0u8; 1024]).unwrap(),
        resets.join("firmware.uf2")
    );

    let full = drive(root.path(), "FULL", Some(RP2040_INFO));
    std::os::unix::fs::symlink("/dev/full", full.join("firmware.uf2")).unwrap();
    let d = read_drive(&full).unwrap().unwrap();
    let e = write_uf2(&d, &[0u8; 1024]).unwrap_err();
    assert_eq!(e.raw_os_error(), Some(28), "{e}");
}
