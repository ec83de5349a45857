//! `uf2-link`: the linker of the firmware crates (firmware-rp2040,
//! firmware-samd51).
//!
//! Cargo has no post-build step, so each firmware's `.cargo/config.toml`
//! names a two-line `link.sh` of its own as the linker, as flip-link does;
//! that script runs this wrapper (through `uf2-link/link.sh`, which builds
//! it on demand) with the chip's UF2 settings ahead of rustc's arguments:
//!
//! ```text
//! uf2-link --family samd51 --flash 0x4000..0x7e000 -- <rustc's linker args>
//! ```
//!
//! It
//! 1. runs the real linker, `rust-lld -flavor gnu`, with rustc's arguments;
//! 2. writes the linked ELF's loadable segments as `<elf>.uf2` next to it,
//!    tagged with the chip's UF2 family id, for drag-and-drop flashing onto
//!    the board's boot drive; every segment must lie in the `--flash`
//!    window (the program's part of flash), so a bootloader or a data area
//!    outside it is never overwritten;
//! 3. prints the firmware's flash and RAM use on stderr, which rustc shows
//!    as a `linker stderr` warning because the firmware's rustflags turn on
//!    the `linker-messages` lint.
//!
//! It is also each firmware's cargo runner (its `flash.sh`, named as
//! `runner` in `.cargo/config.toml`), so `cargo run --release` flashes a
//! board in its UF2 bootloader:
//!
//! ```text
//! uf2-link flash --family rp2040|samd51 -- <ELF>
//! ```
//!
//! copies `<elf>.uf2` onto the one mounted boot drive of that family
//! (see `uf2_link::runner`); with no drive it says how to get one and exits
//! with status 1.

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};

use uf2_link::{report, runner, uf2, uf2_path};

fn main() -> ExitCode {
    let args: Vec<OsString> = std::env::args_os().skip(1).collect();
    if args.first().is_some_and(|a| a == "flash") {
        return match runner::run(&args[1..]) {
            Ok(flashed) => {
                println!(
                    "uf2-link: {}",
                    flashed.to_string().replace('\n', "\nuf2-link: ")
                );
                ExitCode::SUCCESS
            }
            Err(e) => {
                eprintln!("uf2-link: {e}");
                ExitCode::FAILURE
            }
        };
    }
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("uf2-link: {e}");
            ExitCode::FAILURE
        }
    }
}

/// The chip settings that come before `--`.
#[derive(Debug, PartialEq, Eq)]
struct Chip {
    /// UF2 family id.
    family: u32,
    /// Program flash window.
    flash: uf2::Window,
}

/// Splits `--family X --flash START..END --` off the front of `args`. The
/// family is a number or a chip name (`rp2040`, `samd51`).
fn chip_args(args: &[OsString]) -> Result<(Chip, &[OsString]), String> {
    let mut family = None;
    let mut flash = None;
    let mut i = 0;
    loop {
        let Some(flag) = args.get(i).and_then(|a| a.to_str()) else {
            return Err(
                "expected `--family X --flash START..END --` before the linker arguments".into(),
            );
        };
        if flag == "--" {
            i += 1;
            break;
        }
        let value = args
            .get(i + 1)
            .and_then(|a| a.to_str())
            .ok_or_else(|| format!("{flag} needs a value"))?;
        match flag {
            "--family" => {
                family = Some(match value {
                    "rp2040" => uf2::RP2040_FAMILY_ID,
                    "samd51" => uf2::SAMD51_FAMILY_ID,
                    id => number(id)?,
                })
            }
            "--flash" => {
                let (a, b) = value
                    .split_once("..")
                    .ok_or_else(|| format!("--flash {value}: expected START..END"))?;
                flash = Some(number(a)?..number(b)?);
            }
            _ => return Err(format!("unknown option {flag}")),
        }
        i += 2;
    }
    match (family, flash) {
        (Some(family), Some(flash)) if flash.start < flash.end => {
            Ok((Chip { family, flash }, &args[i..]))
        }
        (Some(_), Some(flash)) => Err(format!("empty --flash window {flash:#x?}")),
        _ => Err("both --family and --flash are needed".into()),
    }
}

/// A number in hex (`0x` prefix) or decimal.
fn number(s: &str) -> Result<u32, String> {
    let r = match s.strip_prefix("0x").or_else(|| s.strip_prefix("0X")) {
        Some(hex) => u32::from_str_radix(&hex.replace('_', ""), 16),
        None => s.replace('_', "").parse(),
    };
    r.map_err(|e| format!("{s}: {e}"))
}

fn run(args: &[OsString]) -> Result<(), Box<dyn std::error::Error>> {
    let (chip, args) = chip_args(args)?;
    // rustc may or may not lead with the flavor; we always pass our own.
    let args = match args {
        [flag, flavor, rest @ ..] if flag == "-flavor" => {
            let _ = flavor;
            rest
        }
        _ => args,
    };
    let status = Command::new(lld())
        .arg("-flavor")
        .arg("gnu")
        .args(args)
        .status()
        .map_err(|e| format!("cannot run rust-lld: {e}"))?;
    if !status.success() {
        return Err(format!("rust-lld failed ({status})").into());
    }
    let Some(elf) = output_path(args) else {
        return Err("no -o <output> among the linker arguments".into());
    };
    let data = std::fs::read(&elf)?;

    let mut image = uf2::FlashImage::new(chip.flash.clone());
    for (addr, bytes) in report::load_segments(&data)? {
        image.add(addr, &bytes)?;
    }
    let uf2_path = uf2_path(&elf, std::env::var_os("CARGO_BIN_NAME"));
    std::fs::write(&uf2_path, image.to_uf2(chip.family))?;

    let usage = report::usage(&data, &chip.flash)?;
    eprintln!(
        "{}: {}; {} ({} blocks)",
        file_name(&elf),
        usage.render(),
        uf2_path.display(),
        image.page_count()
    );
    Ok(())
}

/// rust-lld: rustc puts its sysroot's tool directory on the linker's PATH;
/// if that ever changes, ask rustc where the sysroot is.
fn lld() -> PathBuf {
    let on_path = std::env::var_os("PATH")
        .into_iter()
        .flat_map(|p| std::env::split_paths(&p).collect::<Vec<_>>())
        .map(|d| d.join("rust-lld"))
        .find(|p| p.is_file());
    if let Some(p) = on_path {
        return p;
    }
    let sysroot = Command::new(std::env::var_os("RUSTC").unwrap_or_else(|| "rustc".into()))
        .args(["--print", "sysroot"])
        .output()
        .ok()
        .and_then(|o| String::from_utf8(o.stdout).ok())
        .map(|s| PathBuf::from(s.trim()));
    let host = Command::new("rustc")
        .arg("-vV")
        .output()
        .ok()
        .and_then(|o| String::from_utf8(o.stdout).ok())
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("host: ").map(str::to_string))
        });
    match (sysroot, host) {
        (Some(root), Some(host)) => root.join("lib/rustlib").join(host).join("bin/rust-lld"),
        _ => PathBuf::from("rust-lld"),
    }
}

/// The value of `-o` (as `-o path` or `-opath`).
fn output_path(args: &[OsString]) -> Option<PathBuf> {
    let mut it = args.iter();
    while let Some(a) = it.next() {
        if a == "-o" {
            return it.next().map(PathBuf::from);
        }
        if let Some(p) = a.to_str().and_then(|s| s.strip_prefix("-o")) {
            if !p.is_empty() && !p.starts_with('-') {
                return Some(PathBuf::from(p));
            }
        }
    }
    None
}

fn file_name(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::{chip_args, output_path, Chip};
    use std::ffi::OsString;
    use std::path::PathBuf;
    use uf2_link::uf2_path;

    fn args(a: &[&str]) -> Vec<OsString> {
        a.iter().map(OsString::from).collect()
    }

    #[test]
    fn finds_output() {
        assert_eq!(
            output_path(&args(&["x.o", "-o", "/t/fw", "--gc-sections"])),
            Some(PathBuf::from("/t/fw"))
        );
        assert_eq!(
            output_path(&args(&["-o/t/fw"])),
            Some(PathBuf::from("/t/fw"))
        );
        assert_eq!(output_path(&args(&["-Tlink.x"])), None);
    }

    #[test]
    fn chip_settings_come_first() {
        let a = args(&[
            "--family",
            "0x55114460",
            "--flash",
            "0x4000..0x7e000",
            "--",
            "-flavor",
            "gnu",
            "-o",
            "fw",
        ]);
        let (chip, rest) = chip_args(&a).unwrap();
        assert_eq!(
            chip,
            Chip {
                family: 0x5511_4460,
                flash: 0x4000..0x7_E000
            }
        );
        assert_eq!(rest, &a[5..]);
        let rp = args(&[
            "--flash",
            "0x1000_0000..0x1100_0000",
            "--family",
            "0xe48bff56",
            "--",
        ]);
        let (chip, rest) = chip_args(&rp).unwrap();
        assert_eq!(chip.family, 0xe48b_ff56);
        let named = args(&["--family", "samd51", "--flash", "0x4000..0x7e000", "--"]);
        assert_eq!(chip_args(&named).unwrap().0.family, 0x5511_4460);
        let named = args(&["--family", "rp2040", "--flash", "1..2", "--"]);
        assert_eq!(chip_args(&named).unwrap().0.family, 0xe48b_ff56);
        assert_eq!(chip.flash, 0x1000_0000..0x1100_0000);
        assert!(rest.is_empty());
        // rustc's arguments alone, a missing value, a bad window.
        assert!(chip_args(&args(&["-flavor", "gnu", "-o", "fw"])).is_err());
        assert!(chip_args(&args(&["--family"])).is_err());
        assert!(chip_args(&args(&["--family", "1", "--"])).is_err());
        assert!(chip_args(&args(&["--family", "1", "--flash", "8..4", "--"])).is_err());
        assert!(chip_args(&args(&["--family", "1", "--flash", "16", "--"])).is_err());
    }

    #[test]
    fn uf2_lands_next_to_cargos_copy() {
        assert_eq!(
            uf2_path(
                "/t/release/deps/firmware_rp2040-0123abcd".as_ref(),
                Some("firmware-rp2040".into())
            ),
            PathBuf::from("/t/release/firmware-rp2040.uf2")
        );
        assert_eq!(
            uf2_path("/t/out/fw.elf".as_ref(), Some("fw".into())),
            PathBuf::from("/t/out/fw.elf.uf2")
        );
        assert_eq!(
            uf2_path("/t/release/deps/fw-1".as_ref(), None),
            PathBuf::from("/t/release/deps/fw-1.uf2")
        );
    }
}
