//! `uf2_link`: the UF2 side of flashing the firmware crates
//! (firmware-rp2040, firmware-samd51), shared by the `uf2-link` tool and
//! `osap flash`.
//!
//! - [`uf2`]: writing an image as a UF2 file, and [`uf2::inspect`],
//!   checking one and reporting what it writes where;
//! - [`drive`]: finding a mounted UF2 bootloader drive of a chip family
//!   and copying a UF2 file onto it;
//! - [`runner`]: `uf2-link flash`, cargo's runner for the firmwares (what
//!   `cargo run --release` does);
//! - [`report`]: an ELF's loadable segments and its flash and RAM use.
//!
//! The `uf2-link` binary (src/main.rs) is the firmwares' linker wrapper and
//! runner; see its doc.

pub mod drive;
pub mod report;
pub mod runner;
pub mod uf2;

use std::ffi::OsString;
use std::path::{Path, PathBuf};

/// Where the UF2 of a linked ELF is: next to the ELF, `<elf>.uf2`. Cargo
/// links a binary as `<profile>/deps/<crate>-<hash>` and then copies it to
/// `<profile>/<bin name>`, so for a link inside `deps/` the UF2 is written
/// next to that final copy instead (cargo tells rustc, and so the linker,
/// the bin name in `CARGO_BIN_NAME`). The linker writes there and the
/// runner reads from there.
pub fn uf2_path(elf: &Path, bin_name: Option<OsString>) -> PathBuf {
    let parent = elf.parent().unwrap_or(Path::new("."));
    match (bin_name, parent.file_name()) {
        (Some(bin), Some(dir)) if dir == "deps" => {
            let mut name = bin;
            name.push(".uf2");
            parent.parent().unwrap_or(Path::new(".")).join(name)
        }
        _ => {
            let mut p = elf.as_os_str().to_owned();
            p.push(".uf2");
            PathBuf::from(p)
        }
    }
}
