//! What the osap-host integration tests share: a named host, the shipped
//! topology files, and a refresh that must read everything.
#![allow(dead_code)]

use osap_host::som::Manager;
use osap_host::{Host, HostConfig};
use std::path::PathBuf;

/// A host runtime named `name`, with the default configuration.
pub fn host(name: &str) -> Host {
    Host::start(HostConfig::named(name)).unwrap()
}

/// The path of a topology shipped in `osap-host/topologies/`.
pub fn shipped(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("topologies")
        .join(name)
}

/// Refreshes the model and checks that every runtime and function was read.
pub async fn refresh(m: &mut Manager) {
    let report = m.refresh().await.unwrap();
    assert!(
        report.scan_failures.is_empty(),
        "{:?}",
        report.scan_failures
    );
    assert!(
        report.function_failures.is_empty(),
        "{:?}",
        report.function_failures
    );
}
