//! `uf2-link flash` (the firmwares' cargo runner) end to end, on fake
//! boot drives named by `OSAP_UF2_MOUNTS`: a tiny ELF made here, its UF2
//! written by the library's writer, as the linker would.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use uf2_link::drive::INFO_FILE;
use uf2_link::uf2::{FlashImage, RP2040_FAMILY_ID, SAMD51_FAMILY_ID};

const RP2040_INFO: &str = "UF2 Bootloader v3.0\nModel: Raspberry Pi RP2\nBoard-ID: RPI-RP2\n";
const METRO_INFO: &str =
    "UF2 Bootloader v3.14.0\r\nModel: Metro M4 Express\r\nBoard-ID: SAMD51J19A-Metro-v0\r\n";

/// A minimal 32-bit little-endian ARM executable with one loadable
/// segment of `data` at `addr` (no sections: the runner reads program
/// headers only).
fn tiny_elf(addr: u32, data: &[u8]) -> Vec<u8> {
    let mut e = Vec::new();
    e.extend_from_slice(b"\x7fELF\x01\x01\x01\0\0\0\0\0\0\0\0\0");
    let h16 = |e: &mut Vec<u8>, v: u16| e.extend_from_slice(&v.to_le_bytes());
    let h32 = |e: &mut Vec<u8>, v: u32| e.extend_from_slice(&v.to_le_bytes());
    h16(&mut e, 2); // ET_EXEC
    h16(&mut e, 40); // EM_ARM
    h32(&mut e, 1); // version
    h32(&mut e, addr); // entry
    h32(&mut e, 52); // program headers right after this header
    h32(&mut e, 0); // no section headers
    h32(&mut e, 0x0500_0200); // EABI5, soft float
    h16(&mut e, 52);
    h16(&mut e, 32);
    h16(&mut e, 1);
    h16(&mut e, 40);
    h16(&mut e, 0);
    h16(&mut e, 0);
    // PT_LOAD, file offset 84, vaddr = paddr = addr, R+X.
    for v in [
        1,
        84,
        addr,
        addr,
        data.len() as u32,
        data.len() as u32,
        5,
        4,
    ] {
        h32(&mut e, v);
    }
    e.extend_from_slice(data);
    e
}

/// Firmware of `family` at `addr` as cargo and the linker leave it:
/// `dir/fw` and `dir/fw.uf2`. Returns the ELF's path and the UF2's bytes.
fn firmware(dir: &Path, family: u32, addr: u32) -> (PathBuf, Vec<u8>) {
    let code: Vec<u8> = (0..600u32).map(|i| (i * 7) as u8).collect();
    let elf = dir.join("fw");
    fs::write(&elf, tiny_elf(addr, &code)).unwrap();
    let mut image = FlashImage::new(addr..addr + 0x10_0000);
    image.add(addr, &code).unwrap();
    let uf2 = image.to_uf2(family);
    fs::write(dir.join("fw.uf2"), &uf2).unwrap();
    (elf, uf2)
}

fn boot_drive(root: &Path, name: &str, info: &str) -> PathBuf {
    let dir = root.join(name);
    fs::create_dir_all(&dir).unwrap();
    fs::write(dir.join(INFO_FILE), info).unwrap();
    dir
}

fn runner(chip: &str, elf: &Path, mounts: &[&Path]) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_uf2-link"));
    c.args(["flash", "--family", chip, "--"])
        .arg(elf)
        .env("OSAP_UF2_MOUNTS", std::env::join_paths(mounts).unwrap())
        .env_remove("OSAP_UF2_WAIT")
        .env_remove("CARGO_BIN_NAME");
    c
}

fn text(o: &Output) -> (String, String) {
    (
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

#[test]
fn flashes_the_one_rp2040_drive() {
    let build = tempfile::tempdir().unwrap();
    let mounts = tempfile::tempdir().unwrap();
    let (elf, uf2) = firmware(build.path(), RP2040_FAMILY_ID, 0x1000_0000);
    let rp = boot_drive(mounts.path(), "RPI-RP2", RP2040_INFO);
    // A USB stick and a SAMD51 board's drive beside it are left alone.
    fs::create_dir(mounts.path().join("STICK")).unwrap();
    let metro = boot_drive(mounts.path(), "METROM4BOOT", METRO_INFO);

    let out = runner("rp2040", &elf, &[mounts.path()]).output().unwrap();
    let (stdout, stderr) = text(&out);
    assert!(out.status.success(), "{stdout}\n{stderr}");
    assert_eq!(fs::read(rp.join("firmware.uf2")).unwrap(), uf2);
    assert!(!metro.join("firmware.uf2").exists());
    assert!(!mounts.path().join("STICK/firmware.uf2").exists());
    assert!(
        stdout.contains(&format!(
            "flashed {} (RP2040 (0xe48bff56), 3 blocks at 0x10000000..0x10000300) to {} (RPI-RP2, Raspberry Pi RP2)",
            build.path().join("fw.uf2").display(),
            rp.display()
        )),
        "{stdout}"
    );
    assert!(
        stdout.contains("the board reboots into the new firmware"),
        "{stdout}"
    );
}

#[test]
fn flashes_a_samd51_drive_named_directly() {
    let build = tempfile::tempdir().unwrap();
    let mounts = tempfile::tempdir().unwrap();
    let (elf, uf2) = firmware(build.path(), SAMD51_FAMILY_ID, 0x4000);
    let metro = boot_drive(mounts.path(), "METROM4BOOT", METRO_INFO);
    let out = runner("samd51", &elf, &[&metro]).output().unwrap();
    assert!(out.status.success(), "{:?}", text(&out));
    assert_eq!(fs::read(metro.join("firmware.uf2")).unwrap(), uf2);
}

#[test]
fn no_drive_says_how_to_get_one_and_fails() {
    let build = tempfile::tempdir().unwrap();
    let mounts = tempfile::tempdir().unwrap();
    let (elf, _) = firmware(build.path(), RP2040_FAMILY_ID, 0x1000_0000);
    // Only a drive of the other family.
    boot_drive(mounts.path(), "METROM4BOOT", METRO_INFO);
    let out = runner("rp2040", &elf, &[mounts.path()]).output().unwrap();
    let (stdout, stderr) = text(&out);
    assert_eq!(out.status.code(), Some(1), "{stdout}\n{stderr}");
    for needle in [
        "no RP2040 boot drive found",
        "Board-ID: RPI-RP2",
        &build.path().join("fw.uf2").display().to_string(),
        "hold BOOTSEL while plugging",
        "osap flash",
        "cargo flash-probe",
        "OSAP_UF2_MOUNTS=<its directory>",
        "OSAP_UF2_WAIT",
    ] {
        assert!(stderr.contains(needle), "{needle:?} not in:\n{stderr}");
    }

    let (elf, _) = firmware(build.path(), SAMD51_FAMILY_ID, 0x4000);
    let empty = tempfile::tempdir().unwrap();
    let out = runner("samd51", &elf, &[empty.path()]).output().unwrap();
    let (_, stderr) = text(&out);
    assert_eq!(out.status.code(), Some(1));
    assert!(stderr.contains("no SAMD51 boot drive found"), "{stderr}");
    assert!(stderr.contains("double-tap the reset button"), "{stderr}");
}

#[test]
fn two_drives_are_listed_not_guessed() {
    let build = tempfile::tempdir().unwrap();
    let mounts = tempfile::tempdir().unwrap();
    let (elf, _) = firmware(build.path(), RP2040_FAMILY_ID, 0x1000_0000);
    let a = boot_drive(mounts.path(), "RPI-RP2", RP2040_INFO);
    let b = boot_drive(mounts.path(), "RPI-RP2 1", RP2040_INFO);
    let out = runner("rp2040", &elf, &[mounts.path()]).output().unwrap();
    let (_, stderr) = text(&out);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        stderr.contains("2 RP2040 boot drives are mounted"),
        "{stderr}"
    );
    assert!(stderr.contains(&a.display().to_string()));
    assert!(stderr.contains(&b.display().to_string()));
    assert!(stderr.contains("Leave only one board connected"));
    assert!(!a.join("firmware.uf2").exists() && !b.join("firmware.uf2").exists());
}

#[test]
fn waits_for_a_drive_to_appear() {
    let build = tempfile::tempdir().unwrap();
    let mounts = tempfile::tempdir().unwrap();
    let (elf, uf2) = firmware(build.path(), RP2040_FAMILY_ID, 0x1000_0000);
    let child = runner("rp2040", &elf, &[mounts.path()])
        .env("OSAP_UF2_WAIT", "20")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(600));
    // Written under another name and renamed, as a mount appears whole.
    let staging = boot_drive(build.path(), "staging", RP2040_INFO);
    fs::rename(&staging, mounts.path().join("RPI-RP2")).unwrap();
    let out = child.wait_with_output().unwrap();
    let (stdout, stderr) = text(&out);
    assert!(out.status.success(), "{stdout}\n{stderr}");
    assert!(stderr.contains("waiting up to 20.0 s"), "{stderr}");
    assert_eq!(
        fs::read(mounts.path().join("RPI-RP2/firmware.uf2")).unwrap(),
        uf2
    );

    // A wait that runs out ends like no drive at all.
    let out = runner("rp2040", &elf, &[mounts.path().join("nothing").as_path()])
        .env("OSAP_UF2_WAIT", "0.3")
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(text(&out).1.contains("no RP2040 boot drive found"));
    let out = runner("rp2040", &elf, &[mounts.path()])
        .env("OSAP_UF2_WAIT", "soon")
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(text(&out)
        .1
        .contains("OSAP_UF2_WAIT=soon: expected a number of seconds"));
}

#[test]
fn refuses_a_wrong_stale_or_broken_uf2() {
    let build = tempfile::tempdir().unwrap();
    let mounts = tempfile::tempdir().unwrap();
    let rp = boot_drive(mounts.path(), "RPI-RP2", RP2040_INFO);
    boot_drive(mounts.path(), "METROM4BOOT", METRO_INFO);
    let run = |chip: &str, elf: &Path| {
        let out = runner(chip, elf, &[mounts.path()]).output().unwrap();
        assert_eq!(out.status.code(), Some(1));
        text(&out).1
    };
    let (elf, mut uf2) = firmware(build.path(), RP2040_FAMILY_ID, 0x1000_0000);

    // The wrong board's runner.
    let e = run("samd51", &elf);
    assert!(
        e.contains("is for RP2040 (0xe48bff56), but this runner flashes SAMD51"),
        "{e}"
    );
    // A UF2 from an older build of the ELF.
    uf2[40] ^= 1;
    fs::write(build.path().join("fw.uf2"), &uf2).unwrap();
    let e = run("rp2040", &elf);
    assert!(e.contains("a stale UF2?"), "{e}");
    assert!(e.contains("cargo build --release"), "{e}");
    // A broken one (cut short).
    fs::write(build.path().join("fw.uf2"), &uf2[..700]).unwrap();
    let e = run("rp2040", &elf);
    assert!(
        e.contains("is not a usable UF2 file: the file is 700 bytes"),
        "{e}"
    );
    // None at all.
    fs::remove_file(build.path().join("fw.uf2")).unwrap();
    let e = run("rp2040", &elf);
    assert!(e.contains("cannot read"), "{e}");
    assert!(e.contains("fw.uf2"), "{e}");
    // Nothing was copied.
    assert!(!rp.join("firmware.uf2").exists());
    // Arguments the firmware cannot take.
    let out = runner("rp2040", &elf, &[mounts.path()])
        .arg("--verbose")
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(text(&out)
        .1
        .contains("the firmware takes no arguments, got --verbose"));
}
