//! Every module of the machine file is watched: its `get_status` reports
//! every 50 ms, pushed through a pipe, say it still answers, and one silent
//! for [`LINK_LOST_AFTER`] is lost ([`MachineEvent::LinkLost`]), whether it
//! drives a motor, a tool or only I/O.

use std::collections::BTreeMap;

use osap_host::som::Manager;
use tokio::sync::broadcast;

use super::events::MachineEvent;
use super::monitor::{self, SharedReports};
use super::{source, MachineError, ModuleInfo, LINK_LOST_AFTER, STATUS_PERIOD_US};
use crate::network::modfn::get_status;

/// Pipes every module's `get_status` to its status monitor, every
/// status period; a module without `get_status` cannot be watched and is
/// refused.
pub(super) async fn status_reports(
    manager: &mut Manager,
    modules: &BTreeMap<String, ModuleInfo>,
    reports: &SharedReports,
) -> Result<(), MachineError> {
    for (key, m) in modules {
        if manager.function(&get_status::on(&m.runtime)).is_err() {
            return Err(MachineError::Unsupported(format!(
                "modules.{key}: the module has no get_status, so the machine could not tell if it stopped answering; update its firmware (`osap flash`)"
            )));
        }
        let status_fn = manager
            .define(monitor::status(key, reports.clone())?)
            .await?;
        source::<get_status::Inputs>(
            manager,
            &m.runtime,
            Some(STATUS_PERIOD_US),
            false,
            &status_fn,
        )
        .await?;
    }
    Ok(())
}

/// Reports a module whose status reports stop arriving.
pub(super) async fn watch_modules(
    modules: Vec<String>,
    reports: SharedReports,
    events: broadcast::Sender<MachineEvent>,
) {
    let mut lost: Vec<String> = Vec::new();
    let started = tokio::time::Instant::now();
    loop {
        tokio::time::sleep(LINK_LOST_AFTER / 4).await;
        let now = tokio::time::Instant::now();
        let r = monitor::lock(&reports);
        for key in &modules {
            let last = r.seen.get(key).map_or(started, |s| s.2);
            let silent = now.duration_since(last) > LINK_LOST_AFTER;
            if silent && !lost.contains(key) {
                lost.push(key.clone());
                let _ = events.send(MachineEvent::LinkLost {
                    module: key.clone(),
                });
            } else if !silent {
                lost.retain(|k| k != key);
            }
        }
    }
}
