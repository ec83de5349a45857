//! Puts `ram.x` (everything in SRAM, as time-critical RP2040 code usually
//! runs) on the linker's search path.
fn main() {
    let out = std::path::PathBuf::from(std::env::var_os("OUT_DIR").unwrap());
    std::fs::copy("ram.x", out.join("ram.x")).unwrap();
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=ram.x");
}
