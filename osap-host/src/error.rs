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
    #[error("{0}")]
    Malformed(Box<MalformedReply>),
    /// A request could not be written (a name longer than a request holds).
    #[error("cannot write the {what} request: {problem}")]
    Request {
        /// What the request carries (`name`, `time configuration`).
        what: &'static str,
        /// Why it does not fit.
        problem: osap_core::codec::CodecError,
    },
    /// A runtime could not be built from its configuration.
    #[error("invalid runtime configuration: {0}")]
    Config(ConfigError),
    /// A route could not be built (more hops than a packet carries).
    #[error("cannot build a route: {0}")]
    Route(osap_core::packet::PacketError),
    /// [`crate::PortHandle::reply`] was given a datagram that is not a
    /// request: only a request has a sequence number to answer.
    #[error("only a request can be answered, and this datagram is not one")]
    NotARequest,
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

/// A reply that did not parse ([`HostError::Malformed`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("malformed {what} from {route}: {problem}")]
pub struct MalformedReply {
    /// Route to the runtime that replied.
    pub route: Route,
    /// What was asked for (`runtime information`, `clock status`, ...).
    pub what: &'static str,
    /// What is wrong with the reply.
    pub problem: ReplyProblem,
}

impl HostError {
    /// A [`HostError::Malformed`] for the reply about `what` from `route`.
    pub fn malformed(route: &Route, what: &'static str, problem: impl Into<ReplyProblem>) -> Self {
        HostError::Malformed(Box::new(MalformedReply {
            route: *route,
            what,
            problem: problem.into(),
        }))
    }
}

/// What is wrong with a reply ([`HostError::Malformed`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum ReplyProblem {
    /// It ends before its key and status bytes.
    #[error("it is too short")]
    TooShort,
    /// It answers a different query than the one sent.
    #[error("it answers query 0x{answered:02x}, not 0x{asked:02x}")]
    WrongQuery {
        /// The query's key.
        asked: u8,
        /// The key the reply carries.
        answered: u8,
    },
    /// It answers for a different link or index than the one asked about.
    #[error("it answers for {answered}, not {asked}")]
    WrongIndex {
        /// The index asked about.
        asked: u16,
        /// The index the reply carries.
        answered: u16,
    },
    /// Its status byte is not one this host knows.
    #[error("unknown status {0}")]
    UnknownStatus(u8),
    /// Its fields do not decode.
    #[error(transparent)]
    Codec(#[from] osap_core::codec::CodecError),
    /// A time configuration that does not decode or is out of range.
    #[error(transparent)]
    TimeConfig(#[from] osap_core::clock::TimeConfigError),
    /// A clock status that does not decode.
    #[error(transparent)]
    ClockStatus(#[from] osap_core::clock::ClockStatusError),
    /// A bus role that does not decode.
    #[error(transparent)]
    BusRole(#[from] osap_core::bus::BadRole),
    /// Its body is not the layout expected (the bytes are kept).
    #[error("unexpected body {0:02x?}")]
    Unexpected(Vec<u8>),
}

/// Why a runtime could not be built ([`HostError::Config`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum ConfigError {
    /// Its type name or name does not fit.
    #[error(transparent)]
    Name(#[from] osap_core::netresponder::NameTooLong),
    /// Its time configuration is out of range.
    #[error(transparent)]
    Time(#[from] osap_core::clock::TimeConfigError),
    /// A function it serves has a signature PIPES cannot carry.
    #[error(transparent)]
    Signature(#[from] pipes_core::signature::SignatureError),
}

impl From<ConfigError> for HostError {
    fn from(e: ConfigError) -> HostError {
        HostError::Config(e)
    }
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
