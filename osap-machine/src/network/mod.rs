//! How a machine is reached, below the `Machine` itself: the links
//! to its modules, the machine's entry point (where the machine file's
//! routes start), and finding each module of `[modules]` on the network
//! and checking it is a kind of module the machine knows.
//!
//! Needs only the machine file model and osap-host, so a script (and
//! the `halt` module) can reach the modules without starting a machine.

mod find;
mod kinds;
pub mod modfn;

use std::time::Duration;

use osap_host::link::stream::LinkHandle;
use osap_host::{Host, HostError};

pub use find::{find_modules, module_routes, FindError, ModuleInfo};
pub use kinds::{function_set_id_of, kind_of, Mismatch, ModuleKind, KNOWN_KINDS};

/// How to reach a machine's modules.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Link {
    /// A serial port (USB CDC or a UART adapter) at a baud rate.
    Serial {
        /// The port's path, e.g. `/dev/ttyACM0`.
        path: String,
        /// Baud rate (USB CDC ignores it).
        baud: u32,
    },
    /// A TCP link to a network (for example `osap serve`).
    Tcp(String),
    /// A TCP link to a network that requires a key (`osap serve --key`):
    /// the Noise handshake proves this end holds it (docs/security.md).
    TcpKeyed {
        /// `host:port`.
        addr: String,
        /// The key the server was given.
        key: osap_host::link::noise::Key,
    },
}

/// Whether every link is TCP: the machine is served by another process
/// (`osap serve`), whose host is its clock root and its entry point.
pub fn served(links: &[Link]) -> bool {
    !links.is_empty()
        && links
            .iter()
            .all(|l| matches!(l, Link::Tcp(_) | Link::TcpKeyed { .. }))
}

/// Where a machine file's routes start: the machine's entry point, the
/// runtime whose own links lead to the modules.
///
/// A route counts link indices from there, so the same machine file
/// works whether this host holds the modules' links itself or reaches a
/// process that serves them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Entry {
    /// This host: the modules hang off its own links (USB, serial, a
    /// simulation in this process).
    #[default]
    Host,
    /// The runtime at the far end of this host's link `link`: a machine
    /// another process serves (`osap serve`, over TCP), whose own links
    /// lead to the modules.
    Beyond(u8),
}

impl Entry {
    /// The entry point of a machine reached over `handles` (opened from
    /// `links`, in order): beyond the first link when the machine is
    /// [`served`], this host otherwise.
    pub fn of(links: &[Link], handles: &[LinkHandle]) -> Entry {
        match handles.first() {
            Some(h) if served(links) => Entry::Beyond(h.index()),
            _ => Entry::Host,
        }
    }

    /// `route` (link indices from the entry point, as a machine file
    /// gives it) as link indices from this host.
    pub fn from_host(self, route: &[u8]) -> Vec<u8> {
        match self {
            Entry::Host => route.to_vec(),
            Entry::Beyond(link) => std::iter::once(link).chain(route.iter().copied()).collect(),
        }
    }
}

/// How long a serial link may take to answer its first probe.
const SERIAL_PROBE: Duration = Duration::from_millis(500);

/// Opens `links` on `host`, in order: each serial port (probed: something
/// must answer on it), each TCP address (with its key when given). The
/// handles keep the links open.
pub async fn open_links(host: &Host, links: &[Link]) -> Result<Vec<LinkHandle>, HostError> {
    let mut handles = Vec::new();
    for link in links {
        let l = match link {
            Link::Serial { path, baud } => {
                let l = osap_host::link::serial::spawn_serial(host, path, *baud).await?;
                l.probe(host, SERIAL_PROBE).await?;
                l
            }
            Link::Tcp(addr) => osap_host::link::tcp::connect(host, addr).await?,
            Link::TcpKeyed { addr, key } => {
                osap_host::link::tcp::connect_with_key(host, addr, key).await?
            }
        };
        handles.push(l);
    }
    Ok(handles)
}

/// The machine file's route of a module (`[modules] KEY = { route = [..] }`)
/// as link indices; a hop past 255 (refused by the file's validation) reads
/// as 255, which no runtime has.
pub(crate) fn file_route(route: &[u16]) -> Vec<u8> {
    route
        .iter()
        .map(|&h| u8::try_from(h).unwrap_or(u8::MAX))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_served_machine_starts_its_routes_beyond_the_link() {
        assert_eq!(Entry::Host.from_host(&[0, 3]), vec![0, 3]);
        assert_eq!(Entry::Beyond(2).from_host(&[0, 3]), vec![2, 0, 3]);
        assert!(served(&[Link::Tcp("a:1".into()), Link::Tcp("b:1".into())]));
        assert!(!served(&[
            Link::Tcp("a:1".into()),
            Link::Serial {
                path: "/dev/ttyACM0".into(),
                baud: 115_200
            }
        ]));
        assert!(!served(&[]));
        assert_eq!(Entry::of(&[], &[]), Entry::Host);
    }
}
