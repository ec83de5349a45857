//! What the osap-host integration tests share: a named host and a refresh
//! that must read everything.
#![allow(dead_code)]

use osap_host::som::Manager;
use osap_host::{Host, HostConfig};

/// A host runtime named `name`, with the default configuration.
pub(crate) fn host(name: &str) -> Host {
    Host::start(HostConfig::named(name)).unwrap()
}

/// Refreshes the model and checks that every runtime and function was read.
pub(crate) async fn refresh(m: &mut Manager) {
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
