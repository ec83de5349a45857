//! TCP links: a framed byte stream (`docs/protocol.md` §5) over a TCP
//! connection, as a client that reconnects or as a listener that accepts.
//!
//! Listeners bind to loopback unless the caller explicitly allows another
//! address, so a machine is never opened to a network by default. Links
//! have type `tcp`; a client's is named by the address it connects to, a
//! listener's by the peer's IP address.
//!
//! TCP only notices a peer that vanished without closing (a cable pulled
//! somewhere in between) when a send fails; a peer that closes or resets
//! the connection is noticed at once.

use super::stream::{check_bind, link_error, Accept, LinkHandle, ListenAddr, Listener};
use super::LinkConfig;
use crate::runtime::Host;
use crate::HostError;
use std::io;
use std::net::SocketAddr;
use tokio::net::{TcpListener, TcpStream};

pub use super::stream::loopback;

/// Connects to `addr` (`host:port`), once.
async fn dial(addr: &str) -> Result<TcpStream, HostError> {
    let stream = TcpStream::connect(addr).await.map_err(|e| {
        let hint = match e.kind() {
            io::ErrorKind::ConnectionRefused => {
                "connection refused: nothing listens there (is the peer running?)".to_string()
            }
            _ => e.to_string(),
        };
        link_error(format!("cannot connect to {addr}"), e.kind(), hint)
    })?;
    // Control traffic is small packets that must go now, not be batched.
    let _ = stream.set_nodelay(true);
    Ok(stream)
}

/// Connects to a listener at `addr` (`host:port`; names are resolved on
/// every attempt) and adds the connection to `host` as a link of type
/// `tcp` named `addr`. If the connection is lost the link is marked closed
/// and the task reconnects, with backoff from 100 ms to 2 s, until the
/// listener is back.
///
/// Fails, without adding a link, if the first connection cannot be made.
pub async fn connect(host: &Host, addr: &str) -> Result<LinkHandle, HostError> {
    let stream = dial(addr).await?;
    let local = stream.local_addr().ok();
    let (index, io) = host.add_link(LinkConfig::new("tcp", addr)).await?;
    let addr = addr.to_string();
    Ok(LinkHandle::spawn_client(
        index,
        io,
        local,
        stream,
        move || {
            let addr = addr.clone();
            async move { dial(&addr).await }
        },
    ))
}

/// Listens for TCP connections at `addr` and gives each a link of `host`
/// (see [`Listener`]). Use [`loopback`]`(port)` for the default; any address
/// that is not loopback is refused unless `allow_remote` is true, because
/// whoever can reach it can drive the machine. Port 0 picks a free port;
/// [`Listener::socket_addr`] tells which.
pub async fn listen(
    host: &Host,
    addr: SocketAddr,
    allow_remote: bool,
) -> Result<Listener, HostError> {
    check_bind(addr, allow_remote)?;
    let listener = TcpListener::bind(addr).await.map_err(|e| {
        let hint = match e.kind() {
            io::ErrorKind::AddrInUse => {
                "the address is in use (another host already listens there?)".to_string()
            }
            _ => e.to_string(),
        };
        link_error(format!("cannot listen on {addr}"), e.kind(), hint)
    })?;
    let bound = listener.local_addr().unwrap_or(addr);
    Ok(Listener::spawn(
        host,
        Tcp(listener),
        ListenAddr::Inet(bound),
        "tcp",
        None,
    ))
}

/// A TCP listener as the generic listener wants it.
struct Tcp(TcpListener);

impl Accept for Tcp {
    type Stream = TcpStream;

    async fn accept(&mut self) -> io::Result<(TcpStream, String)> {
        let (stream, peer) = self.0.accept().await?;
        let _ = stream.set_nodelay(true);
        Ok((stream, peer.ip().to_string()))
    }
}
