//! Puts memory.x where the linker finds it, relinks when it changes, and
//! passes the linker script (cortex-m-rt's link.x) and `--nmagic`.
//! Link arguments live here rather than in `.cargo/config.toml` rustflags
//! so that a `RUSTFLAGS` from the environment, which replaces those,
//! cannot drop them.
//!
//! `--nmagic`: without it rust-lld puts the ELF headers in a loadable
//! segment at 0x0, inside the bootloader, because FLASH does not start on
//! a 64 KiB boundary; flashers and UF2 writers would then try to write
//! there.

use std::env;
use std::fs;
use std::path::PathBuf;

fn main() {
    let metro = env::var_os("CARGO_FEATURE_METRO_M4").is_some();
    let feather = env::var_os("CARGO_FEATURE_FEATHER_M4").is_some();
    if metro == feather {
        // src/main.rs stops the build with a clear message too; this
        // only keeps the link step from running first.
        println!("cargo:warning=choose exactly one board feature: metro-m4 or feather-m4");
    }
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    fs::write(out.join("memory.x"), include_bytes!("memory.x")).expect("write memory.x");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rustc-link-arg-bins=--nmagic");
    println!("cargo:rustc-link-arg-bins=-Tlink.x");
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=build.rs");
}
