//! Puts memory.x where the linker finds it, relinks when it changes, and
//! passes the linker scripts (cortex-m-rt's link.x, embassy-rp's link-rp.x
//! for the boot2 section). Link arguments live here rather than in
//! `.cargo/config.toml` rustflags so that a `RUSTFLAGS` from the
//! environment, which replaces those, cannot drop them.

use std::env;
use std::fs;
use std::path::PathBuf;

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    fs::write(out.join("memory.x"), include_bytes!("memory.x")).expect("write memory.x");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rustc-link-arg-bins=--nmagic");
    println!("cargo:rustc-link-arg-bins=-Tlink.x");
    println!("cargo:rustc-link-arg-bins=-Tlink-rp.x");
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=build.rs");
}
