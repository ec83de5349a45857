//! Errors of the host runtime.

use osap_core::port::SendError;
use osap_core::route::Route;
use std::time::Duration;

/// What can go wrong talking to the network from a host.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum HostError {
    /// The host's runtime task has stopped.
    #[error("the host runtime has stopped")]
    Stopped,
    /// The runtime refused the packet.
    #[error("could not send: {0}")]
    Send(SendError),
    /// No reply came in time.
    #[error("no reply within {timeout:?} from port {port} over route {route}")]
    Timeout {
        /// How long was waited.
        timeout: Duration,
        /// The route the request went over.
        route: String,
        /// The destination port.
        port: u16,
    },
    /// Every port index is in use.
    #[error("no free port index (the host has {0})")]
    NoFreePort(usize),
    /// Every link index is in use.
    #[error("no free link index (the host has {0})")]
    NoFreeLink(usize),
    /// A netresponder refused a query.
    #[error("the runtime at {route} refused the query: {status:?}")]
    Remote {
        /// Route to the runtime.
        route: String,
        /// Its answer.
        status: osap_core::netresponder::Status,
    },
    /// A reply did not parse.
    #[error("malformed reply: {0}")]
    Malformed(String),
    /// A runtime's clock did not settle on its time source in time.
    #[error("{0}")]
    NotSynchronised(Box<NotSynchronised>),
    /// An I/O error from a link.
    #[error("{context}: {source}")]
    Io {
        /// What was being done.
        context: String,
        /// The error.
        #[source]
        source: std::io::Error,
    },
}

/// What [`HostError::NotSynchronised`] reports.
#[derive(Debug, thiserror::Error)]
#[error("the clock at {route} did not settle within {waited:?}; last status: {last:?}")]
pub struct NotSynchronised {
    /// Route to the runtime.
    pub route: Route,
    /// How long was waited.
    pub waited: Duration,
    /// Its last clock status.
    pub last: osap_core::clock::ClockStatus,
}

/// Why a saved file ([`crate::map::NetworkMap::from_json`],
/// [`crate::som::Som::from_json`]) could not be read.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum JsonError {
    /// The text is not JSON of the file's layout.
    #[error(transparent)]
    Json(#[from] serde_json::Error),
    /// The file's layout version is not the one this build reads.
    #[error("{what} version {found} is not supported (this build reads {supported})")]
    Version {
        /// What the file holds (`network map`, `system object model`).
        what: &'static str,
        /// The file's version.
        found: u32,
        /// The version this build reads.
        supported: u32,
    },
}
