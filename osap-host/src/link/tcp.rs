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
//!
//! A listener with a key ([`listen_with`], [`ListenOptions::key`]) serves
//! only clients that prove they hold it in a Noise handshake
//! ([`connect_with_key`], see [`noise`]); a listener on a non-loopback
//! address must have one. Listeners bound how many connections they serve,
//! and close connections that stay silent or stop reading (see
//! [`ListenOptions`] and `docs/security.md`).

use super::noise::{self, Key, NoiseStream};
use super::stream::{
    check_bind, link_error, Accept, LinkHandle, ListenAddr, ListenOptions, Listener, StreamLimits,
};
use super::LinkConfig;
use crate::runtime::Host;
use crate::HostError;
use std::io;
use std::net::SocketAddr;
use std::time::Duration;
use tokio::io::AsyncWriteExt;
use tokio::net::{TcpListener, TcpStream};

pub use super::stream::loopback;

/// How long a plain client waits for the listener's first byte (it sends
/// one as soon as it serves the connection, which at its connection limit
/// may take its queue timeout) before going on without it.
const GREETING_TIMEOUT: Duration = Duration::from_secs(5);

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

/// Send buffer of an accepted socket, bytes (the kernel doubles it).
const SEND_BUFFER: usize = 32 * 1024;

/// [`dial`], then waits for the listener's first byte: a listener that
/// closes the connection before it says a word refused it.
async fn dial_plain(addr: &str) -> Result<TcpStream, HostError> {
    let mut stream = dial(addr).await?;
    // Two delimiters: empty frames to a plain listener, and to a keyed one
    // a zero-length handshake message, which it refuses at once (instead
    // of both ends waiting for the other to speak first).
    stream
        .write_all(&[0, 0])
        .await
        .map_err(|e| link_error(format!("cannot connect to {addr}"), e.kind(), e.to_string()))?;
    let mut first = [0u8; 1];
    match tokio::time::timeout(GREETING_TIMEOUT, stream.peek(&mut first)).await {
        Ok(Ok(0)) | Ok(Err(_)) => Err(link_error(
            format!("cannot connect to {addr}"),
            io::ErrorKind::ConnectionRefused,
            "the server closed the connection at once: it may be at its connection limit \
             (osap serve --max-connections), or it may require a key (--key FILE)"
                .into(),
        )),
        // A byte, or a slow listener: go on (the stream sorts out the rest).
        Ok(Ok(_)) | Err(_) => Ok(stream),
    }
}

/// [`dial`], then the Noise handshake with `key`.
async fn dial_keyed(addr: &str, key: &Key) -> Result<NoiseStream, HostError> {
    let stream = dial(addr).await?;
    noise::initiate(stream, key, noise::HANDSHAKE_TIMEOUT)
        .await
        .map_err(|e| link_error(format!("cannot connect to {addr}"), e.kind(), e.to_string()))
}

/// Connects to a listener at `addr` (`host:port`; names are resolved on
/// every attempt) and adds the connection to `host` as a link of type
/// `tcp` named `addr`. If the connection is lost the link is marked closed
/// and the task reconnects, with backoff from 100 ms to 2 s, until the
/// listener is back.
///
/// Fails, without adding a link, if the first connection cannot be made,
/// or if the listener closes it at once (at its connection limit, or it
/// wants a key: see [`connect_with_key`]).
pub async fn connect(host: &Host, addr: &str) -> Result<LinkHandle, HostError> {
    let stream = dial_plain(addr).await?;
    let local = stream.local_addr().ok();
    let (index, io) = host.add_link(LinkConfig::new("tcp", addr)).await?;
    let addr = addr.to_string();
    Ok(LinkHandle::spawn_client(
        host,
        index,
        io,
        local,
        stream,
        move || {
            let addr = addr.clone();
            async move { dial_plain(&addr).await }
        },
        StreamLimits::CLIENT,
    ))
}

/// [`connect`] to a listener that requires a key: every connection starts
/// with a Noise handshake proving that both ends hold `key`, and carries
/// its frames encrypted. Fails if the first handshake does (wrong key,
/// a listener without a key, or one at its connection limit).
pub async fn connect_with_key(host: &Host, addr: &str, key: &Key) -> Result<LinkHandle, HostError> {
    let stream = dial_keyed(addr, key).await?;
    let (index, io) = host.add_link(LinkConfig::new("tcp", addr)).await?;
    let (addr, key) = (addr.to_string(), key.clone());
    Ok(LinkHandle::spawn_client(
        host,
        index,
        io,
        None,
        stream,
        move || {
            let (addr, key) = (addr.clone(), key.clone());
            async move { dial_keyed(&addr, &key).await }
        },
        StreamLimits::CLIENT,
    ))
}

/// Listens for TCP connections at `addr` and gives each a link of `host`
/// (see [`Listener`]), with the default limits. Use [`loopback`]`(port)`
/// for the default; any address that is not loopback is refused unless
/// `allow_remote` is true, and then [`listen_with`] a key is needed,
/// because whoever can reach it can drive the machine. Port 0 picks a
/// free port; [`Listener::socket_addr`] tells which.
pub async fn listen(
    host: &Host,
    addr: SocketAddr,
    allow_remote: bool,
) -> Result<Listener, HostError> {
    let options = ListenOptions {
        allow_remote,
        ..ListenOptions::default()
    };
    listen_with(host, addr, options).await
}

/// [`listen`] with every option: a key that connections must prove they
/// hold, the connection limit, idle and stall timeouts.
pub async fn listen_with(
    host: &Host,
    addr: SocketAddr,
    options: ListenOptions,
) -> Result<Listener, HostError> {
    check_bind(addr, options.allow_remote, options.key.is_some())?;
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
        options,
    ))
}

/// A TCP listener as the generic listener wants it.
struct Tcp(TcpListener);

impl Accept for Tcp {
    type Stream = TcpStream;

    async fn accept(&mut self) -> io::Result<(TcpStream, String)> {
        let (stream, peer) = self.0.accept().await?;
        let _ = stream.set_nodelay(true);
        // Without a bound the kernel grows the send buffer to megabytes, and
        // a peer that floods requests without reading gets that many
        // replies' worth of service before its link backs up and stops
        // being read. A window this size still fills any LAN.
        let _ = socket2::SockRef::from(&stream).set_send_buffer_size(SEND_BUFFER);
        Ok((stream, peer.ip().to_string()))
    }
}
