//! `uf2-link flash --family rp2040|samd51 -- <ELF>`: cargo's runner for
//! the firmware crates, so `cargo run --release` flashes a board.
//!
//! Each firmware's `.cargo/config.toml` names its `flash.sh` as the runner;
//! cargo runs it with the freshly linked ELF. This
//! 1. reads `<elf>.uf2`, which the linker wrote beside it ([`crate::uf2_path`]),
//!    checks it ([`crate::uf2::inspect`]), that its family is the board's,
//!    and that it holds exactly the ELF's loadable bytes (so a stale UF2 is
//!    never flashed);
//! 2. looks for the family's boot drives ([`crate::drive::find_boot_drives`]),
//!    waiting up to `OSAP_UF2_WAIT` seconds for one to appear;
//! 3. with exactly one, copies the UF2 onto it; with none or several, says
//!    what to do and fails.

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use crate::drive::{self, BootDrive};
use crate::uf2::{self, Uf2Info};

/// Seconds to wait for a boot drive to appear before giving up (default:
/// look once).
pub const WAIT_ENV: &str = "OSAP_UF2_WAIT";
/// How often a wait looks for a drive.
pub const POLL: Duration = Duration::from_millis(250);

/// What `flash` was asked to do.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FlashArgs {
    /// The board's UF2 family id.
    pub family: u32,
    /// The ELF cargo built (its UF2 is beside it).
    pub elf: PathBuf,
}

/// Parses the arguments after `flash`: `--family rp2040|samd51 -- <ELF>`.
pub(crate) fn parse_args(args: &[OsString]) -> Result<FlashArgs, String> {
    const USAGE: &str = "usage: uf2-link flash --family rp2040|samd51 -- <ELF>";
    let mut family = None;
    let mut i = 0;
    loop {
        let Some(flag) = args.get(i).and_then(|a| a.to_str()) else {
            return Err(USAGE.into());
        };
        match flag {
            "--" => {
                i += 1;
                break;
            }
            "--family" => {
                let name = args.get(i + 1).and_then(|a| a.to_str()).unwrap_or("");
                family = Some(uf2::family_by_name(name).ok_or_else(|| {
                    format!("--family {name:?}: expected rp2040 or samd51; {USAGE}")
                })?);
                i += 2;
            }
            _ => return Err(format!("unknown option {flag}; {USAGE}")),
        }
    }
    let family = family.ok_or_else(|| format!("--family is needed; {USAGE}"))?;
    match &args[i..] {
        [elf] => Ok(FlashArgs {
            family,
            elf: PathBuf::from(elf),
        }),
        [] => Err(format!("no ELF to flash; {USAGE}")),
        [_, extra @ ..] => Err(format!(
            "the firmware takes no arguments, got {}: drop what follows `--` in `cargo run`",
            extra
                .iter()
                .map(|a| a.to_string_lossy())
                .collect::<Vec<_>>()
                .join(" ")
        )),
    }
}

/// Why flashing did not happen. The `Display` text is the whole message,
/// with the fix.
#[derive(Debug)]
#[non_exhaustive]
pub enum FlashError {
    /// Bad arguments, a missing, malformed, stale or wrong-family UF2, a
    /// bad `OSAP_UF2_WAIT`, an unreadable `INFO_UF2.TXT` or a failed copy.
    Failed(String),
    /// No boot drive of the family is mounted.
    NoDrive(String),
    /// More than one is.
    SeveralDrives(String),
}

impl std::fmt::Display for FlashError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FlashError::Failed(m) | FlashError::NoDrive(m) | FlashError::SeveralDrives(m) => {
                f.write_str(m)
            }
        }
    }
}

impl std::error::Error for FlashError {}

/// What was flashed where.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Flashed {
    /// The UF2 file copied.
    pub uf2: PathBuf,
    /// What it holds.
    pub info: Uf2Info,
    /// The drive it went to.
    pub drive: BootDrive,
    /// The file written on the drive.
    pub written: PathBuf,
}

impl std::fmt::Display for Flashed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "flashed {} ({}) to {}, as {}",
            self.uf2.display(),
            self.info,
            self.drive,
            self.written.display()
        )?;
        write!(
            f,
            "the board reboots into the new firmware (its boot drive goes away)"
        )
    }
}

/// `uf2-link flash`: the arguments after `flash`. Reads `OSAP_UF2_WAIT`,
/// `OSAP_UF2_MOUNTS` and `CARGO_BIN_NAME` from the environment.
pub fn run(args: &[OsString]) -> Result<Flashed, FlashError> {
    let failed = FlashError::Failed;
    let args = parse_args(args).map_err(failed)?;
    let wait = wait_from_env(std::env::var_os(WAIT_ENV)).map_err(failed)?;
    let uf2_path = crate::uf2_path(&args.elf, std::env::var_os("CARGO_BIN_NAME"));
    let (bytes, info) = load_uf2(&args.elf, &uf2_path, args.family).map_err(failed)?;
    let drive = wait_for_drive(args.family, wait, &uf2_path, &info)?;
    let written = drive::write_uf2(&drive, &bytes).map_err(|e| {
        failed(format!(
            "copying {} to {} failed: {e} (is the drive still mounted and writable?)",
            uf2_path.display(),
            drive.path.display()
        ))
    })?;
    Ok(Flashed {
        uf2: uf2_path,
        info,
        drive,
        written,
    })
}

/// `OSAP_UF2_WAIT`'s value as a duration (none when unset or empty).
pub(crate) fn wait_from_env(value: Option<OsString>) -> Result<Option<Duration>, String> {
    let Some(value) = value.filter(|v| !v.is_empty()) else {
        return Ok(None);
    };
    value
        .to_str()
        .and_then(|s| s.trim().parse::<f64>().ok())
        .and_then(|s| Duration::try_from_secs_f64(s).ok())
        .map(Some)
        .ok_or_else(|| {
            format!(
                "{WAIT_ENV}={}: expected a number of seconds, e.g. {WAIT_ENV}=10",
                value.to_string_lossy()
            )
        })
}

/// Reads and checks the UF2 beside `elf`: well formed, of `family`, and
/// made from `elf` (the bytes the ELF loads, nothing else).
pub(crate) fn load_uf2(
    elf: &Path,
    uf2_path: &Path,
    family: u32,
) -> Result<(Vec<u8>, Uf2Info), String> {
    let rebuild = "rebuild it with `cargo build --release` in the firmware crate";
    let bytes = std::fs::read(uf2_path).map_err(|e| {
        format!(
            "cannot read {} ({e}): the firmware's linker (uf2-link) writes it beside the ELF; {rebuild}",
            uf2_path.display()
        )
    })?;
    let info = uf2::inspect(&bytes).map_err(|e| {
        format!(
            "{} is not a usable UF2 file: {e}; {rebuild}",
            uf2_path.display()
        )
    })?;
    if info.family_id != family {
        return Err(format!(
            "{} is for {}, but this runner flashes {} boards: build the right firmware crate",
            uf2_path.display(),
            uf2::family_label(info.family_id),
            uf2::family_label(family)
        ));
    }
    let elf_bytes =
        std::fs::read(elf).map_err(|e| format!("cannot read the ELF {}: {e}", elf.display()))?;
    let from_elf = image_of(&elf_bytes, family)
        .map_err(|e| format!("cannot read the ELF {}: {e}", elf.display()))?;
    if from_elf != bytes {
        return Err(format!(
            "{} does not hold what {} loads (a stale UF2?); {rebuild}",
            uf2_path.display(),
            elf.display()
        ));
    }
    Ok((bytes, info))
}

/// The UF2 the linker writes for an ELF (its loadable segments, in 256-byte
/// pages). The window was checked at link time; here any address goes.
fn image_of(elf: &[u8], family: u32) -> Result<Vec<u8>, Box<dyn std::error::Error>> {
    let mut image = uf2::FlashImage::new(0..u32::MAX);
    for (addr, bytes) in crate::report::load_segments(elf)? {
        image.add(addr, &bytes)?;
    }
    Ok(image.to_uf2(family))
}

/// The one boot drive of `family`, polling every 250 ms for up to `wait`.
fn wait_for_drive(
    family: u32,
    wait: Option<Duration>,
    uf2_path: &Path,
    info: &Uf2Info,
) -> Result<BootDrive, FlashError> {
    let deadline = wait.map(|w| Instant::now() + w);
    let mut told = false;
    loop {
        let mut drives = drive::find_boot_drives(family).map_err(|e| {
            FlashError::Failed(format!(
                "{e} (a boot drive's INFO_UF2.TXT; set {} to the drive to flash)",
                drive::MOUNTS_ENV
            ))
        })?;
        match drives.len() {
            1 => return Ok(drives.remove(0)),
            0 => {}
            _ => return Err(FlashError::SeveralDrives(several_message(family, &drives))),
        }
        match (deadline, wait) {
            (Some(deadline), Some(wait)) if Instant::now() < deadline => {
                if !told {
                    eprintln!(
                        "uf2-link: waiting up to {:.1} s for a {} boot drive…",
                        wait.as_secs_f64(),
                        uf2::family_name(family).unwrap_or("UF2")
                    );
                    told = true;
                }
                std::thread::sleep(POLL.min(deadline - Instant::now()));
            }
            _ => {
                return Err(FlashError::NoDrive(no_drive_message(
                    family, uf2_path, info,
                )))
            }
        }
    }
}

/// How to put a board of `family` into its bootloader.
pub fn bootloader_hint(family: u32) -> &'static str {
    match family {
        uf2::RP2040_FAMILY_ID => {
            "hold BOOTSEL while plugging the board into USB, or run `osap flash` to send a running module there"
        }
        uf2::SAMD51_FAMILY_ID => {
            "double-tap the reset button, or run `osap flash` to send a running module there"
        }
        _ => "see the board's documentation",
    }
}

/// The message when no boot drive of `family` is mounted.
pub fn no_drive_message(family: u32, uf2_path: &Path, info: &Uf2Info) -> String {
    let chip = uf2::family_name(family).unwrap_or("UF2");
    let mut m = format!(
        "no {chip} boot drive found (a mounted drive whose INFO_UF2.TXT has {}).\n",
        drive::expected_board_id(family)
    );
    m += &format!("The firmware is built: {} ({info}).\n", uf2_path.display());
    m += "To flash it:\n";
    m += &format!(
        "  - put the board in its bootloader ({}), then run `cargo run --release` again (or copy the UF2 onto the drive);\n",
        bootloader_hint(family)
    );
    m += "  - or, with an SWD debug probe, run `cargo flash-probe` (probe-rs);\n";
    m += &format!(
        "  - if the boot drive is mounted somewhere unusual, set {}=<its directory>; {}=10 waits up to 10 s for it to appear.",
        drive::MOUNTS_ENV,
        WAIT_ENV
    );
    if let Some(list) = std::env::var_os(drive::MOUNTS_ENV).filter(|l| !l.is_empty()) {
        m += &format!(
            "\n{} is set: only {} was searched.",
            drive::MOUNTS_ENV,
            list.to_string_lossy()
        );
    }
    m
}

/// The message when several boot drives of `family` are mounted.
pub fn several_message(family: u32, drives: &[BootDrive]) -> String {
    let mut m = format!(
        "{} {} boot drives are mounted; not guessing which board to flash:\n",
        drives.len(),
        uf2::family_name(family).unwrap_or("UF2")
    );
    for d in drives {
        m += &format!("  - {d}\n");
    }
    m += &format!(
        "Leave only one board connected in its bootloader, or set {}=<the drive's directory>.",
        drive::MOUNTS_ENV
    );
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(a: &[&str]) -> Vec<OsString> {
        a.iter().map(OsString::from).collect()
    }

    #[test]
    fn parses_runner_arguments() {
        assert_eq!(
            parse_args(&args(&["--family", "rp2040", "--", "/t/fw"])),
            Ok(FlashArgs {
                family: uf2::RP2040_FAMILY_ID,
                elf: "/t/fw".into()
            })
        );
        assert_eq!(
            parse_args(&args(&["--family", "samd51", "--", "fw"]))
                .unwrap()
                .family,
            uf2::SAMD51_FAMILY_ID
        );
        assert!(parse_args(&args(&["--family", "esp32", "--", "fw"]))
            .unwrap_err()
            .contains("rp2040 or samd51"));
        assert!(parse_args(&args(&["--family", "rp2040", "--"]))
            .unwrap_err()
            .contains("no ELF"));
        assert!(parse_args(&args(&["--family", "rp2040", "--", "fw", "x"]))
            .unwrap_err()
            .contains("takes no arguments, got x"));
        assert!(parse_args(&args(&["--", "fw"]))
            .unwrap_err()
            .contains("--family is needed"));
        assert!(parse_args(&args(&["fw"])).is_err());
        assert!(parse_args(&args(&["--family"])).is_err());
    }

    #[test]
    fn wait_seconds() {
        assert_eq!(wait_from_env(None), Ok(None));
        assert_eq!(wait_from_env(Some("".into())), Ok(None));
        assert_eq!(
            wait_from_env(Some("2.5".into())),
            Ok(Some(Duration::from_millis(2500)))
        );
        assert!(wait_from_env(Some("-1".into())).is_err());
        assert!(wait_from_env(Some("soon".into()))
            .unwrap_err()
            .contains("OSAP_UF2_WAIT=soon"));
    }
}
