//! `osap flash` against simulated modules with simulated UF2 bootloaders
//! (`[module.bootloader]`): the drive is a temporary directory, and
//! `OSAP_UF2_MOUNTS` points `osap flash` at it, as it would at a real
//! board's mounted drive.
//!
//! - A served machine (`osap serve`, its own process): the module enters
//!   its bootloader, the UF2 lands on its drive, the module comes back with
//!   the same function set, `--name` renames it, and a following
//!   `osap scan` shows the new name.
//! - In-process (`--sim`): the module directly at the other end of the link
//!   is picked by itself; an ELF is flashed through the `.uf2` next to it;
//!   a UF2 of another family is refused before anything is sent to the
//!   module; no drive appearing times out with a message that says what
//!   to do.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use uf2_link::uf2::{self, RP2040_FAMILY_ID, SAMD51_FAMILY_ID};

/// A fresh directory for one test.
fn scratch(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("osap-flash-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A UF2 of `family`: 4 blocks of filler at the start of flash.
fn image(family: u32) -> Vec<u8> {
    let payload = [0xC3u8; uf2::PAYLOAD];
    (0..4u32)
        .flat_map(|i| uf2::block(0x1000_0000 + i * 256, &payload, i, 4, family))
        .collect()
}

/// A topology of one RP2040 module on USB whose drive is `drive`.
fn topology(dir: &Path, drive: &Path) -> PathBuf {
    let path = dir.join("machine.toml");
    std::fs::write(
        &path,
        format!(
            "name = \"flash-test\"\n\n[[module]]\nname = \"motor\"\ntype = \"stepper\"\n\
             [module.bootloader]\ndrive = {:?}\nchip = \"rp2040\"\nreboot_ms = 100\n\n\
             [[link]]\na = \"host\"\nb = \"motor\"\nkind = \"usb\"\n",
            drive.to_string_lossy()
        ),
    )
    .unwrap();
    path
}

fn osap(args: &[&str], mounts: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_osap"))
        .args(args)
        .env("OSAP_UF2_MOUNTS", mounts)
        .output()
        .expect("osap runs")
}

fn text(o: &Output) -> (String, String) {
    (
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

fn no_debug(stderr: &str) {
    for leak in ["Remote {", "Io {", "Os {", "kind:", "Custom {"] {
        assert!(!stderr.contains(leak), "Debug output leaked: {stderr}");
    }
}

#[test]
fn a_served_module_is_flashed_comes_back_and_is_renamed() {
    let dir = scratch("served");
    let drive = dir.join("drive");
    let topo = topology(&dir, &drive);
    let fw = dir.join("fw.uf2");
    std::fs::write(&fw, image(RP2040_FAMILY_ID)).unwrap();
    let (_server, addr) = common::serve(&topo);

    let fw_arg = fw.to_string_lossy().into_owned();
    let o = osap(
        &[
            "flash",
            &fw_arg,
            "--tcp",
            &addr,
            "--module",
            "motor",
            "--name",
            "x-axis",
            "--timeout",
            "10",
        ],
        &drive,
    );
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "{stdout}\n{stderr}");
    let id = format!("{:#010x}", osap_module::FUNCTION_SET_ID);
    for want in [
        "firmware: ",
        "RP2040 (0xe48bff56), 4 blocks",
        "motor: rebooting into its bootloader",
        "boot drive: ",
        "RPI-RP2",
        "wrote ",
        &format!("function set {id} -> {id}"),
        "renamed motor to x-axis",
        "x-axis: flashed; its function set matches this osap's",
    ] {
        assert!(
            stdout.contains(want),
            "{want:?} missing:\n{stdout}\n{stderr}"
        );
    }
    assert!(stdout.contains("after: stepper "), "{stdout}");
    // The drive unmounted: nothing left on it.
    assert!(!drive.join("INFO_UF2.TXT").exists());
    assert!(!drive.join("firmware.uf2").exists());

    // The rename is the served module's: a following scan shows it.
    let o = Command::new(env!("CARGO_BIN_EXE_osap"))
        .args(["scan", "--tcp", &addr])
        .output()
        .unwrap();
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "{stdout}\n{stderr}");
    assert!(stdout.contains("x-axis"), "{stdout}");
    assert!(!stdout.contains("motor"), "{stdout}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_module_on_the_link_is_flashed_from_an_elf_and_its_uf2() {
    let dir = scratch("elf");
    let drive = dir.join("drive");
    let topo = topology(&dir, &drive);
    // An ELF (only its magic matters here) and the UF2 the linker wrote
    // next to it.
    let elf = dir.join("firmware-rp2040");
    std::fs::write(&elf, b"\x7fELF\x01\x01\x01\0not really").unwrap();
    std::fs::write(dir.join("firmware-rp2040.uf2"), image(RP2040_FAMILY_ID)).unwrap();
    let o = osap(
        &[
            "flash",
            &elf.to_string_lossy(),
            "--sim",
            &topo.to_string_lossy(),
            "--timeout",
            "10",
        ],
        &drive,
    );
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "{stdout}\n{stderr}");
    assert!(stdout.contains("firmware-rp2040.uf2 (RP2040"), "{stdout}");
    assert!(
        stdout.contains("module: motor (simulated rp2040 board)"),
        "{stdout}"
    );
    assert!(
        stdout.contains("motor: flashed; its function set matches"),
        "{stdout}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_uf2_of_another_family_is_refused_before_the_module_is_asked() {
    let dir = scratch("family");
    let drive = dir.join("drive");
    let topo = topology(&dir, &drive);
    let fw = dir.join("samd51.uf2");
    std::fs::write(&fw, image(SAMD51_FAMILY_ID)).unwrap();
    let o = osap(
        &[
            "flash",
            &fw.to_string_lossy(),
            "--sim",
            &topo.to_string_lossy(),
        ],
        &drive,
    );
    let (stdout, stderr) = text(&o);
    assert_eq!(o.status.code(), Some(1), "{stdout}\n{stderr}");
    assert!(
        stderr.contains("motor is RP2040 (0xe48bff56) (simulated rp2040 board)"),
        "{stderr}"
    );
    assert!(
        stderr.contains("is SAMD51 (0x55114460) firmware"),
        "{stderr}"
    );
    assert!(
        stderr.contains("refused before anything was sent to the module"),
        "{stderr}"
    );
    assert!(!stdout.contains("rebooting"), "{stdout}");
    // The module was never asked: its bootloader never showed its drive.
    assert!(!drive.join("INFO_UF2.TXT").exists());
    no_debug(&stderr);

    // Not a UF2 at all: refused before connecting.
    let junk = dir.join("junk.uf2");
    std::fs::write(&junk, b"hello").unwrap();
    let o = osap(
        &[
            "flash",
            &junk.to_string_lossy(),
            "--sim",
            &topo.to_string_lossy(),
        ],
        &drive,
    );
    let (_, stderr) = text(&o);
    assert_eq!(o.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("is not a valid UF2 file"), "{stderr}");
    no_debug(&stderr);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn no_drive_appearing_times_out_and_says_what_to_do() {
    let dir = scratch("nodrive");
    let drive = dir.join("drive");
    let topo = topology(&dir, &drive);
    let fw = dir.join("fw.uf2");
    std::fs::write(&fw, image(RP2040_FAMILY_ID)).unwrap();
    // osap flash looks somewhere else than where the drive appears.
    let elsewhere = dir.join("elsewhere");
    std::fs::create_dir_all(&elsewhere).unwrap();
    let o = osap(
        &[
            "flash",
            &fw.to_string_lossy(),
            "--sim",
            &topo.to_string_lossy(),
            // Long enough that the module's reboot (100 ms after it
            // answers) has happened when the command gives up, even with
            // the other tests' simulations loading the machine.
            "--timeout",
            "3",
        ],
        &elsewhere,
    );
    let (stdout, stderr) = text(&o);
    assert_eq!(o.status.code(), Some(1), "{stdout}\n{stderr}");
    assert!(
        stdout.contains("motor: rebooting into its bootloader"),
        "{stdout}"
    );
    for want in [
        "no UF2 boot drive of RP2040 (0xe48bff56) (Board-ID: RPI-RP2) appeared within 3 s",
        "OSAP_UF2_MOUNTS=",
        "BOOTSEL",
        "double-tap reset",
        "--timeout",
    ] {
        assert!(stderr.contains(want), "{want:?} missing: {stderr}");
    }
    no_debug(&stderr);
    // The module did reboot into its bootloader: its drive is there.
    assert!(drive.join("INFO_UF2.TXT").exists());
    let _ = std::fs::remove_dir_all(&dir);
}
