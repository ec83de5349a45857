//! Every machine a session reaches: each bridge's `osap/NAME/info`.

use std::time::Duration;

use zenoh::query::QueryTarget;
use zenoh::Session;

use crate::json::Info;
use crate::keys::ALL_INFO;

/// One machine found: the name its keys use, and its info.
#[derive(Debug, Clone, PartialEq)]
pub struct Found {
    /// The NAME of its keys (`osap/NAME/…`).
    pub key_name: String,
    /// What it says of itself.
    pub info: Info,
}

/// Asks every bridge reachable from `session` for its info, waiting at
/// most `timeout`; sorted by name. A reply that is not a machine's info is
/// skipped with a warning.
pub async fn list(session: &Session, timeout: Duration) -> Result<Vec<Found>, String> {
    let replies = session
        .get(ALL_INFO)
        .target(QueryTarget::All)
        .timeout(timeout)
        .await
        .map_err(|e| format!("zenoh query {ALL_INFO}: {e}"))?;
    let mut found = Vec::new();
    while let Ok(reply) = replies.recv_async().await {
        let Ok(sample) = reply.result() else { continue };
        let key = sample.key_expr().as_str();
        let key_name = key
            .strip_prefix("osap/")
            .and_then(|k| k.strip_suffix("/info"))
            .unwrap_or(key)
            .to_string();
        let text = sample.payload().try_to_string().map(|t| t.into_owned());
        match text
            .ok()
            .and_then(|t| serde_json::from_str::<Info>(&t).ok())
        {
            Some(info) => found.push(Found { key_name, info }),
            None => tracing::warn!("{key}: not a machine's info"),
        }
    }
    found.sort_by(|a, b| a.key_name.cmp(&b.key_name));
    found.dedup_by(|a, b| a.key_name == b.key_name);
    Ok(found)
}
