//! The stepper proxy checked in under `stepper_proxy/` is exactly what
//! proxygen generates from a scan of a simulated machine
//! (`osap-sim/topologies/single-usb.toml`: one `stepper`, "motor", running
//! the module firmware's logic), byte for byte. The emulator test
//! (`emulator.rs`) compiles this proxy and binds it, unchanged, to the RP2040
//! firmware. `PROXYGEN_BLESS=1 cargo test -p osap-tests --test
//! stepper_proxy_golden` rewrites it (the convention of proxygen's own golden
//! tests).

#[rustfmt::skip]
#[path = "stepper_proxy/mod.rs"]
mod stepper_proxy;

use osap_host::som::Manager;
use osap_host::{Host, HostConfig};
use osap_module::functions::SIGNATURES;
use osap_sim::machine::{self, SimMachine};
use proxygen::GeneratedFile;
use std::path::{Path, PathBuf};
use stepper_proxy::Stepper;

/// Where the checked-in proxy lives: `tests/tests/stepper_proxy/`.
fn proxy_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/stepper_proxy")
}

const REGENERATE: &str =
    "regenerate it with PROXYGEN_BLESS=1 cargo test -p osap-tests --test stepper_proxy_golden";

/// Whether `PROXYGEN_BLESS=1`: rewrite the checked-in files instead of
/// comparing.
fn bless() -> bool {
    std::env::var("PROXYGEN_BLESS").is_ok_and(|v| v == "1")
}

/// The files under `dir`, relative to it.
fn checked_in(dir: &Path) -> Vec<String> {
    let entries =
        std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e} ({REGENERATE})", dir.display()));
    let mut names: Vec<String> = entries
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

/// Compares `files` with the files in `dir` byte for byte (the same files,
/// the same contents), or rewrites `dir` with `PROXYGEN_BLESS=1`.
fn golden(dir: &Path, files: &[GeneratedFile]) {
    if bless() {
        let _ = std::fs::remove_dir_all(dir);
        proxygen::write(dir, files).unwrap();
        println!("rewrote {}", dir.display());
        return;
    }
    let mut generated: Vec<String> = files.iter().map(|f| f.path.display().to_string()).collect();
    generated.sort();
    assert_eq!(
        generated,
        checked_in(dir),
        "files generated vs checked in under {}: {REGENERATE}",
        dir.display()
    );
    for f in files {
        let path = dir.join(&f.path);
        let want = std::fs::read_to_string(&path).unwrap();
        if want != f.contents {
            let line = want
                .lines()
                .zip(f.contents.lines())
                .position(|(a, b)| a != b)
                .unwrap_or_else(|| want.lines().count().min(f.contents.lines().count()));
            panic!(
                "{} is not what proxygen generates from a scan of the simulated machine \
                 (first difference at line {}); {REGENERATE}\n  checked in: {:?}\n  generated:  {:?}",
                path.display(),
                line + 1,
                want.lines().nth(line),
                f.contents.lines().nth(line)
            );
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_checked_in_stepper_proxy_is_generated_from_a_simulated_scan() {
    let host = Host::start(HostConfig::named("h")).unwrap();
    let topology = machine::load(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../osap-sim/topologies/single-usb.toml"),
    )
    .unwrap()
    .with_zero_latency(true);
    let _machine = SimMachine::start(&host, &topology).await.unwrap();
    let mut m = Manager::new(&host).await.unwrap();
    let report = m.refresh().await.unwrap();
    assert!(
        report.scan_failures.is_empty() && report.function_failures.is_empty(),
        "{report:?}"
    );

    let files = proxygen::generate(m.som(), &proxygen::Options::default()).unwrap();
    golden(&proxy_dir(), &files);

    // The proxy has the firmware's function set (osap-module's SIGNATURES),
    // and binds to the module it was generated from.
    let names: Vec<&str> = Stepper::SIGNATURES.iter().map(|s| s.function).collect();
    let firmware: Vec<&str> = SIGNATURES.iter().map(|s| s.name).collect();
    assert_eq!(names, firmware);
    let motor = Stepper::bind(&m, "motor").unwrap();
    assert_eq!(motor.get_steps().await.unwrap().steps, 0);
}
