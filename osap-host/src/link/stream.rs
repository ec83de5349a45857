//! Byte-stream links: the framed stream driver, and what every real link
//! gateway shares (the handle, its state, reconnecting, listening).
//!
//! [`run_stream`] moves packets over any byte stream (a serial port, a TCP
//! or Unix socket, a PTY) as frames of `docs/protocol.md` §5:
//! `COBS(packet ‖ crc16) ‖ 00`. The serial, TCP and Unix modules open
//! streams and hand them to it; a client link that loses its stream keeps
//! retrying in the background and resumes when the peer is back, without
//! restarting the host.
//!
//! A [`LinkHandle`] owns a link's task: it reports the link's [`LinkState`]
//! and stops the task when closed or dropped. A [`Listener`] accepts
//! connections and gives each one a link.

use super::noise::{self, Key};
use super::{LinkConfig, LinkIo, LinkStats};
use crate::error::ReplyProblem;
use crate::runtime::Host;
use crate::{HostError, HOST_MTU};
use osap_core::framing::{encode_frame, max_frame_len, FrameDecoder};
use osap_core::netresponder::key;
use osap_core::route::Route;
use std::fmt;
use std::future::Future;
use std::io;
use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::sync::{watch, Notify};
use tokio::task::{JoinHandle, JoinSet};

/// Longest frame a host link accepts: a [`HOST_MTU`] packet, framed.
pub const MAX_FRAME: usize = max_frame_len(HOST_MTU);

/// Bytes asked of the stream per read.
const READ_CHUNK: usize = 4096;

/// First wait before a reconnect attempt; doubled after each failure.
pub const RECONNECT_MIN: Duration = Duration::from_millis(100);
/// Longest wait between reconnect attempts.
pub const RECONNECT_MAX: Duration = Duration::from_secs(2);
/// How long one connection attempt may take before it counts as failed.
pub const CONNECT_TIMEOUT: Duration = Duration::from_secs(5);

/// How long an accepted connection may stay silent before it is closed,
/// by default.
pub const IDLE_TIMEOUT: Duration = Duration::from_secs(60);
/// How long one frame's write may take before the peer counts as not
/// reading and its connection is closed, by default.
pub const STALL_TIMEOUT: Duration = Duration::from_secs(5);
/// Connections a listener serves at once, by default.
pub const MAX_CONNECTIONS: usize = 16;
/// How long a connection past the limit waits for one to end before it is
/// refused, by default: a burst of short connections is served in turn.
pub const QUEUE_TIMEOUT: Duration = Duration::from_secs(1);
/// Connections past the limit that may wait at once; more are refused at
/// once.
pub const MAX_WAITING: usize = 256;

/// Bounds on one connection of a stream link.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StreamLimits {
    /// Close when nothing arrives for this long (`None`: never).
    pub idle: Option<Duration>,
    /// Close when one frame's write cannot complete within this long: the
    /// peer has stopped reading and the socket no longer drains (`None`:
    /// never).
    pub stall: Option<Duration>,
}

impl StreamLimits {
    /// No bounds: a serial port waits as long as its device does.
    pub const NONE: StreamLimits = StreamLimits {
        idle: None,
        stall: None,
    };
    /// A socket client's: no idle bound (the link reconnects anyway), the
    /// default stall bound.
    pub const CLIENT: StreamLimits = StreamLimits {
        idle: None,
        stall: Some(STALL_TIMEOUT),
    };
}

/// Why [`run_stream`] returned.
#[derive(Debug)]
pub enum StreamEnd {
    /// Nothing arrived within the idle timeout.
    Idle(Duration),
    /// A write could not complete within the stall bound: the peer does
    /// not read.
    Stalled(Duration),
    /// The peer closed the stream (end of file, hang-up).
    Eof,
    /// Reading or writing failed (the device went away, the connection was
    /// reset).
    Error(io::Error),
    /// The link was closed from the host's side.
    Closed,
}

impl fmt::Display for StreamEnd {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            StreamEnd::Eof => f.write_str("the peer closed the connection"),
            StreamEnd::Error(e) => write!(f, "{e}"),
            StreamEnd::Closed => f.write_str("the link was closed by the host"),
            StreamEnd::Idle(t) => write!(f, "nothing arrived for {t:?} (idle timeout)"),
            StreamEnd::Stalled(t) => write!(
                f,
                "the peer stopped reading (a write did not complete within {t:?})"
            ),
        }
    }
}

/// Moves packets between a link and a byte stream until the stream ends.
///
/// Marks the link open, writes a lone `0x00` so that the peer's decoder
/// drops whatever partial frame it held, then at once
/// - reads the stream, splits it into frames, and hands each good packet to
///   the runtime (waiting while the runtime's queue for the link is full, so
///   a busy host pushes back on the sender instead of dropping); frames that
///   fail COBS, the CRC, or are too long are dropped and counted in the
///   link's `frame_errors`;
/// - frames and writes every packet the runtime sends over the link.
///
/// Receive stamps are the host clock when the read that completed the frame
/// returned: when software saw the bytes, which trails the wire by the OS's
/// and (for USB) the bus's latency.
///
/// The stream is never flushed (on a serial port `flush` is `tcdrain`, which
/// blocks the thread until the bytes are out), so give it one that writes
/// straight through: a socket, a serial port or a PTY, not a `BufWriter`.
///
/// Returns why it stopped, with the link marked closed (which drops what
/// was queued to send).
pub async fn run_stream<S>(stream: S, io: &LinkIo) -> StreamEnd
where
    S: AsyncRead + AsyncWrite,
{
    run_stream_with(stream, io, StreamLimits::NONE).await
}

/// [`run_stream`] within `limits`: a connection that stays silent past
/// `limits.idle`, or whose peer stops reading for `limits.stall`, is
/// closed (counted in the link's `idle_closed` or `stalled`).
pub async fn run_stream_with<S>(stream: S, io: &LinkIo, limits: StreamLimits) -> StreamEnd
where
    S: AsyncRead + AsyncWrite,
{
    let (reader, writer) = tokio::io::split(stream);
    io.set_open(true);
    let end = tokio::select! {
        end = read_frames(reader, io, limits.idle) => end,
        end = write_frames(writer, io, limits.stall) => end,
    };
    match end {
        StreamEnd::Idle(_) => io.count_idle(),
        StreamEnd::Stalled(_) => io.count_stalled(),
        _ => {}
    }
    io.set_open(false);
    end
}

/// The receive half of [`run_stream`].
async fn read_frames<R: AsyncRead + Unpin>(
    mut reader: R,
    io: &LinkIo,
    idle: Option<Duration>,
) -> StreamEnd {
    let mut decoder = Box::new(FrameDecoder::<MAX_FRAME>::new());
    let mut buf = vec![0u8; READ_CHUNK];
    loop {
        io.rx_ready().await;
        let read = reader.read(&mut buf);
        let read = match idle {
            Some(t) => match tokio::time::timeout(t, read).await {
                Ok(r) => r,
                Err(_) => return StreamEnd::Idle(t),
            },
            None => read.await,
        };
        let n = match read {
            Ok(0) => return StreamEnd::Eof,
            Ok(n) => n,
            Err(e) => return StreamEnd::Error(e),
        };
        let stamp = io.clock().now();
        let mut input = buf.get(..n).unwrap_or_default();
        while let Some(result) = decoder.decode(&mut input) {
            match result {
                Ok(packet) => {
                    let packet = packet.to_vec();
                    io.rx_ready().await;
                    io.deliver_stamped(packet, stamp);
                }
                Err(e) => {
                    io.count_frame_errors(1);
                    tracing::debug!(link = %io.config().name, error = %e, "dropped a bad frame");
                }
            }
        }
    }
}

/// The transmit half of [`run_stream`].
async fn write_frames<W: AsyncWrite + Unpin>(
    mut writer: W,
    io: &LinkIo,
    stall: Option<Duration>,
) -> StreamEnd {
    // Resynchronise the peer's decoder: end whatever it was assembling.
    if let Err(e) = write_within(&mut writer, &[0], stall).await {
        return e;
    }
    let mut frame = vec![0u8; MAX_FRAME];
    while let Some(packet) = io.next_tx().await {
        let Some(out) = frame.get_mut(..max_frame_len(packet.len())) else {
            tracing::warn!(
                link = %io.config().name,
                len = packet.len(),
                "packet longer than the host MTU, not sent"
            );
            continue;
        };
        let len = match encode_frame(&packet, out) {
            Ok(len) => len,
            Err(e) => {
                tracing::warn!(link = %io.config().name, error = %e, "could not frame a packet");
                continue;
            }
        };
        if let Err(e) = write_within(&mut writer, frame.get(..len).unwrap_or_default(), stall).await
        {
            return e;
        }
    }
    StreamEnd::Closed
}

/// Writes all of `bytes`, failing with [`StreamEnd::Stalled`] if that
/// takes longer than `stall`.
async fn write_within<W: AsyncWrite + Unpin>(
    writer: &mut W,
    bytes: &[u8],
    stall: Option<Duration>,
) -> Result<(), StreamEnd> {
    let write = writer.write_all(bytes);
    let result = match stall {
        Some(t) => tokio::time::timeout(t, write)
            .await
            .map_err(|_| StreamEnd::Stalled(t))?,
        None => write.await,
    };
    result.map_err(StreamEnd::Error)
}

/// Where a link stands, as its [`LinkHandle`] reports it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LinkState {
    /// The link is up: packets flow.
    Connected,
    /// The link is down and its task is trying to bring it back (or, for a
    /// UDP link without a fixed peer, waiting for the first datagram).
    /// Packets routed over it meanwhile are dropped by the runtime.
    Disconnected {
        /// Failed attempts since the link went down.
        attempts: u32,
        /// Why the link went down, or why the last attempt failed.
        reason: String,
    },
    /// The link was closed through its handle and will not come back.
    Closed,
}

impl fmt::Display for LinkState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LinkState::Connected => f.write_str("connected"),
            LinkState::Disconnected { attempts, reason } => {
                write!(f, "disconnected ({reason}; {attempts} attempts since)")
            }
            LinkState::Closed => f.write_str("closed"),
        }
    }
}

/// A link whose I/O runs in its own task (a serial port, a TCP, UDP or Unix
/// socket). Closing or dropping the handle stops the task, marks the link
/// closed and detaches it from the runtime (see
/// [`Host::detach_link`]): its index is free for the next link.
#[derive(Debug)]
pub struct LinkHandle {
    index: u8,
    io: LinkIo,
    local: Option<SocketAddr>,
    state: Arc<watch::Sender<LinkState>>,
    stop: Arc<Notify>,
    task: Option<JoinHandle<()>>,
}

impl LinkHandle {
    /// A client link, connected on `first`: [`run_client`] carries its
    /// frames and calls `reconnect` after a loss.
    pub(crate) fn spawn_client<S, C, F>(
        host: &Host,
        index: u8,
        io: LinkIo,
        local: Option<SocketAddr>,
        first: S,
        reconnect: C,
        limits: StreamLimits,
    ) -> LinkHandle
    where
        S: AsyncRead + AsyncWrite + Send + 'static,
        C: FnMut() -> F + Send + 'static,
        F: Future<Output = Result<S, HostError>> + Send + 'static,
    {
        // Connected already: open now, so that a packet sent as soon as
        // this returns is not dropped before the task has run.
        io.set_open(true);
        LinkHandle::spawn(
            host,
            index,
            io,
            local,
            LinkState::Connected,
            move |io, state| run_client(io, state, first, reconnect, limits),
        )
    }

    /// Starts `body` in a task that stops on [`close`](Self::close) or drop,
    /// and that marks the link closed and detaches it from `host` when it
    /// stops.
    pub(crate) fn spawn<F>(
        host: &Host,
        index: u8,
        io: LinkIo,
        local: Option<SocketAddr>,
        initial: LinkState,
        body: impl FnOnce(LinkIo, Arc<watch::Sender<LinkState>>) -> F,
    ) -> LinkHandle
    where
        F: Future<Output = ()> + Send + 'static,
    {
        let state = Arc::new(watch::Sender::new(initial));
        let stop = Arc::new(Notify::new());
        let body = body(io.clone(), state.clone());
        let task = {
            let (io, state, stop) = (io.clone(), state.clone(), stop.clone());
            let host = host.clone();
            tokio::spawn(async move {
                tokio::select! {
                    _ = stop.notified() => {}
                    _ = body => {}
                }
                // The body has been dropped here, in this task, so nothing
                // can reopen the link after this.
                io.set_open(false);
                // Its index is free for the next link.
                host.release_link(index);
                state.send_replace(LinkState::Closed);
                tracing::info!(link = %io.config().name, "link closed");
            })
        };
        LinkHandle {
            index,
            io,
            local,
            state,
            stop,
            task: Some(task),
        }
    }

    /// The link's index in the host runtime (the `L` in a route).
    pub fn index(&self) -> u8 {
        self.index
    }

    /// The link's configuration (type and instance names, MTU, speed).
    pub fn config(&self) -> &LinkConfig {
        self.io.config()
    }

    /// The local socket address, for socket links.
    pub fn local_addr(&self) -> Option<SocketAddr> {
        self.local
    }

    /// Where the link stands now.
    pub fn state(&self) -> LinkState {
        self.state.borrow().clone()
    }

    /// A receiver that sees every change of the link's state.
    pub fn subscribe(&self) -> watch::Receiver<LinkState> {
        self.state.subscribe()
    }

    /// The link's packet counts.
    pub fn stats(&self) -> LinkStats {
        self.io.stats()
    }

    /// Waits until the link is connected, up to `timeout`. The error says
    /// why the link is still down.
    pub async fn wait_connected(&self, timeout: Duration) -> Result<(), HostError> {
        let mut rx = self.subscribe();
        let up = |s: &LinkState| !matches!(s, LinkState::Disconnected { .. });
        let waited = tokio::time::timeout(timeout, rx.wait_for(up)).await;
        match self.state() {
            LinkState::Connected => Ok(()),
            state => Err(link_error(
                format!(
                    "link {} ({}) is not connected",
                    self.index,
                    self.config().name
                ),
                if waited.is_err() {
                    io::ErrorKind::TimedOut
                } else {
                    io::ErrorKind::NotConnected
                },
                format!("{state}"),
            )),
        }
    }

    /// Checks that an OSAP runtime answers at the other end of the link by
    /// asking its name, which it returns. A port that is open but is not an
    /// OSAP device (or runs at another baud rate) fails with an error that
    /// says so.
    pub async fn probe(&self, host: &Host, timeout: Duration) -> Result<String, HostError> {
        let what = format!("link {} ({})", self.index, self.config().name);
        if let state @ (LinkState::Disconnected { .. } | LinkState::Closed) = self.state() {
            return Err(link_error(
                format!("{what} is not connected"),
                io::ErrorKind::NotConnected,
                format!("{state}"),
            ));
        }
        let errors_before = self.stats().frame_errors;
        let port = host.open_port("link_probe").await?;
        let route = Route::through_links(&[self.index]).map_err(HostError::Route)?;
        match port.request(&route, 0, &[key::NAME], timeout).await {
            Ok(reply) => match reply.body.as_slice() {
                [k, 0, len, name @ ..] if *k == key::NAME && usize::from(*len) == name.len() => {
                    Ok(String::from_utf8_lossy(name).into_owned())
                }
                other => Err(HostError::malformed(
                    &route,
                    "name",
                    ReplyProblem::Unexpected(other.to_vec()),
                )),
            },
            Err(HostError::Timeout { .. }) => {
                let garbled = self.stats().frame_errors.saturating_sub(errors_before);
                let why = if garbled > 0 {
                    format!(
                        "{garbled} garbled frames arrived instead: the baud rate may be wrong, \
                         or the device is not an OSAP device"
                    )
                } else {
                    "nothing came back: the device is not an OSAP device, or its firmware \
                     is not running"
                        .to_string()
                };
                Err(link_error(
                    format!("no OSAP runtime answered on {what} within {timeout:?}"),
                    io::ErrorKind::TimedOut,
                    why,
                ))
            }
            Err(e) => Err(e),
        }
    }

    /// Stops the link's task and waits until it has stopped (the device or
    /// socket is closed when this returns).
    pub async fn close(mut self) {
        self.stop.notify_one();
        if let Some(task) = self.task.take() {
            let _ = task.await;
        }
    }
}

impl Drop for LinkHandle {
    fn drop(&mut self) {
        self.stop.notify_one();
    }
}

impl LinkState {
    /// Whether the link is up.
    pub fn is_connected(&self) -> bool {
        matches!(self, LinkState::Connected)
    }
}

/// An error with a context and an explanation, as a [`HostError::Io`].
pub(crate) fn link_error(context: String, kind: io::ErrorKind, message: String) -> HostError {
    HostError::Io {
        context,
        source: io::Error::new(kind, message),
    }
}

/// Runs a client link: `first` now, then, whenever the stream ends,
/// `connect` again with backoff ([`RECONNECT_MIN`] doubling to
/// [`RECONNECT_MAX`]) until it succeeds. State changes go to `state` and to
/// `tracing`.
pub(crate) async fn run_client<S, C, F>(
    io: LinkIo,
    state: Arc<watch::Sender<LinkState>>,
    first: S,
    mut connect: C,
    limits: StreamLimits,
) where
    S: AsyncRead + AsyncWrite + Send,
    C: FnMut() -> F + Send,
    F: Future<Output = Result<S, HostError>> + Send,
{
    let what = format!("{} link {}", io.config().type_name, io.config().name);
    let mut next = Some(first);
    loop {
        if let Some(stream) = next.take() {
            // Open before saying so, so that whoever waits for `Connected`
            // can route over the link at once.
            io.set_open(true);
            state.send_replace(LinkState::Connected);
            tracing::info!("{what}: connected");
            let end = run_stream_with(stream, &io, limits).await;
            tracing::warn!("{what}: lost ({end}); reconnecting");
            state.send_replace(LinkState::Disconnected {
                attempts: 0,
                reason: end.to_string(),
            });
        }
        let mut delay = RECONNECT_MIN;
        let mut attempts = 0u32;
        while next.is_none() {
            tokio::time::sleep(delay).await;
            let result = match tokio::time::timeout(CONNECT_TIMEOUT, connect()).await {
                Ok(result) => result,
                Err(_) => Err(link_error(
                    "connecting".into(),
                    io::ErrorKind::TimedOut,
                    format!("no answer within {CONNECT_TIMEOUT:?}"),
                )),
            };
            match result {
                Ok(stream) => {
                    tracing::info!("{what}: back after {} failed attempts", attempts);
                    next = Some(stream);
                }
                Err(e) => {
                    attempts = attempts.saturating_add(1);
                    tracing::debug!("{what}: reconnect attempt {attempts} failed: {e}");
                    state.send_replace(LinkState::Disconnected {
                        attempts,
                        reason: e.to_string(),
                    });
                    delay = (delay * 2).min(RECONNECT_MAX);
                }
            }
        }
    }
}

/// `127.0.0.1:port`: the address listeners use unless told otherwise, so a
/// machine is never opened to the network by default.
pub fn loopback(port: u16) -> SocketAddr {
    SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), port)
}

/// Refuses to bind `addr` if it is reachable from other machines, unless
/// `allow_remote` says the user asked for that and `keyed` says that
/// connections must prove they hold the link key.
pub(crate) fn check_bind(
    addr: SocketAddr,
    allow_remote: bool,
    keyed: bool,
) -> Result<(), HostError> {
    if addr.ip().is_loopback() {
        return Ok(());
    }
    if !allow_remote {
        return Err(link_error(
            format!("refusing to listen on {addr}"),
            io::ErrorKind::PermissionDenied,
            "that address is reachable from other machines, and anyone who can reach it could \
             drive this machine; listen on 127.0.0.1 (the default), or pass allow_remote \
             (--allow-remote) with a key (--key FILE) if you really mean to open it to the \
             network"
                .into(),
        ));
    }
    if !keyed {
        return Err(link_error(
            format!("refusing to listen on {addr} without a key"),
            io::ErrorKind::PermissionDenied,
            "a link reachable from other machines must authenticate its peers: make a key \
             with `osap keygen FILE`, copy it to the clients, and pass --key FILE on both ends"
                .into(),
        ));
    }
    Ok(())
}

/// Where a [`Listener`] listens.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ListenAddr {
    /// A TCP address.
    Inet(SocketAddr),
    /// A Unix socket path.
    Unix(PathBuf),
}

impl fmt::Display for ListenAddr {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ListenAddr::Inet(a) => write!(f, "{a}"),
            ListenAddr::Unix(p) => write!(f, "{}", p.display()),
        }
    }
}

/// A link a [`Listener`] made for an accepted connection.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AcceptedLink {
    /// The link's index in the host runtime.
    pub index: u8,
    /// Who it was made for: the peer's IP address for TCP, the socket path
    /// for Unix sockets (Unix peers have no address).
    pub peer: String,
    /// Whether a connection is using it now (always, while listed: a link
    /// is detached, and leaves the list, when its connection ends).
    pub connected: bool,
}

/// How a [`Listener`] treats the connections it accepts.
#[derive(Debug, Clone)]
pub struct ListenOptions {
    /// Allow an address other than loopback; it then needs `key` too.
    pub allow_remote: bool,
    /// The key every connection must prove it holds, in a Noise handshake,
    /// before it gets a link; `None`: plain frames (loopback only).
    pub key: Option<Key>,
    /// Connections served at once ([`MAX_CONNECTIONS`] by default). One
    /// more waits up to `queue_timeout` for a connection to end, and is
    /// then closed unread, and logged; past [`MAX_WAITING`] waiting, at
    /// once.
    pub max_connections: usize,
    /// How long a connection past the limit waits ([`QUEUE_TIMEOUT`] by
    /// default).
    pub queue_timeout: Duration,
    /// Close a connection that sends nothing for this long
    /// ([`IDLE_TIMEOUT`] by default; `None`: never).
    pub idle_timeout: Option<Duration>,
    /// Close a connection whose peer stops reading for this long
    /// ([`STALL_TIMEOUT`] by default; `None`: never).
    pub stall_timeout: Option<Duration>,
    /// How long a keyed connection's handshake may take.
    pub handshake_timeout: Duration,
    /// Drop packets for a connection once its send queue has been full
    /// this long, so that they do not hold packet slots other peers need
    /// (`None`, the default: they wait, and expire at their deadlines).
    /// A busy client legitimately stops reading for a while: 25 ms and
    /// even 500 ms lost a served machine's acknowledgements (and so its
    /// points) to a client planning motion, so this is for peers that are
    /// expected to keep up.
    pub drop_after: Option<Duration>,
}

impl Default for ListenOptions {
    fn default() -> Self {
        ListenOptions {
            allow_remote: false,
            key: None,
            max_connections: MAX_CONNECTIONS,
            queue_timeout: QUEUE_TIMEOUT,
            idle_timeout: Some(IDLE_TIMEOUT),
            stall_timeout: Some(STALL_TIMEOUT),
            handshake_timeout: noise::HANDSHAKE_TIMEOUT,
            drop_after: None,
        }
    }
}

/// What a [`Listener`] has done with the connections it was offered.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ListenerStats {
    /// Connections accepted (given a link, or a handshake first).
    pub accepted: u64,
    /// Connections closed unread because `max_connections` were open (and
    /// none ended within `queue_timeout`).
    pub refused: u64,
    /// Keyed connections closed because their handshake failed (wrong
    /// key, replay, garbage, timeout).
    pub handshake_failed: u64,
}

#[derive(Debug, Default)]
struct Counters {
    accepted: AtomicU64,
    refused: AtomicU64,
    handshake_failed: AtomicU64,
}

/// Accepts connections for a [`Listener`].
pub(crate) trait Accept: Send + 'static {
    /// The connections it yields.
    type Stream: AsyncRead + AsyncWrite + Send + Unpin + 'static;
    /// Waits for the next connection; returns it and the peer's name.
    fn accept(&mut self) -> impl Future<Output = io::Result<(Self::Stream, String)>> + Send;
}

/// Accepts connections on a socket and gives each one a link of its own
/// for as long as it lasts; when it ends, the link is detached and its
/// index is free again (a peer that comes back gets its old index if it is
/// still free, so routes through it stay valid). At most
/// `max_connections` are served at once; connections that stay silent or
/// stop reading are closed (see [`ListenOptions`]). Closing or dropping
/// the listener stops accepting and closes every connection it accepted;
/// while it lives, it keeps the host running.
#[derive(Debug)]
pub struct Listener {
    addr: ListenAddr,
    links: watch::Receiver<Vec<AcceptedLink>>,
    counters: Arc<Counters>,
    stop: Arc<Notify>,
    task: Option<JoinHandle<()>>,
    /// A Unix socket file to remove when the listener goes.
    unlink: Option<PathBuf>,
}

impl Listener {
    /// Starts accepting on `acceptor` in a task.
    pub(crate) fn spawn<A: Accept>(
        host: &Host,
        acceptor: A,
        addr: ListenAddr,
        type_name: &'static str,
        unlink: Option<PathBuf>,
        options: ListenOptions,
    ) -> Listener {
        let (links_tx, links) = watch::channel(Vec::new());
        let stop = Arc::new(Notify::new());
        let counters = Arc::new(Counters::default());
        let task = tokio::spawn(accept_loop(
            Shared {
                host: host.clone(),
                addr: addr.clone(),
                type_name,
                options,
                links: links_tx,
                table: std::sync::Mutex::new(Vec::new()),
                counters: counters.clone(),
            },
            acceptor,
            stop.clone(),
        ));
        Listener {
            addr,
            links,
            counters,
            stop,
            task: Some(task),
            unlink,
        }
    }

    /// Where it listens.
    pub fn local_addr(&self) -> &ListenAddr {
        &self.addr
    }

    /// The TCP address it listens on (with the port the OS chose, if it was
    /// asked for port 0); `None` for a Unix socket.
    pub fn socket_addr(&self) -> Option<SocketAddr> {
        match &self.addr {
            ListenAddr::Inet(a) => Some(*a),
            ListenAddr::Unix(_) => None,
        }
    }

    /// The links of the connections it serves now.
    pub fn links(&self) -> Vec<AcceptedLink> {
        self.links.borrow().clone()
    }

    /// A receiver that sees every change of [`links`](Self::links).
    pub fn subscribe(&self) -> watch::Receiver<Vec<AcceptedLink>> {
        self.links.clone()
    }

    /// What it has done with the connections offered so far.
    pub fn stats(&self) -> ListenerStats {
        ListenerStats {
            accepted: self.counters.accepted.load(Ordering::Relaxed),
            refused: self.counters.refused.load(Ordering::Relaxed),
            handshake_failed: self.counters.handshake_failed.load(Ordering::Relaxed),
        }
    }

    /// Waits up to `timeout` until some accepted connection is up; returns
    /// its link index.
    pub async fn wait_connected(&self, timeout: Duration) -> Result<u8, HostError> {
        let mut rx = self.subscribe();
        let found = tokio::time::timeout(timeout, rx.wait_for(|l| l.iter().any(|l| l.connected)))
            .await
            .ok()
            .and_then(Result::ok)
            .and_then(|l| l.iter().find(|l| l.connected).map(|l| l.index));
        found.ok_or_else(|| {
            link_error(
                format!("listening on {}", self.addr),
                io::ErrorKind::TimedOut,
                format!("no connection within {timeout:?}"),
            )
        })
    }

    /// Stops accepting, closes every accepted connection, and waits until
    /// that is done.
    pub async fn close(mut self) {
        self.stop.notify_one();
        if let Some(task) = self.task.take() {
            let _ = task.await;
        }
    }
}

impl Drop for Listener {
    fn drop(&mut self) {
        self.stop.notify_one();
        if let Some(path) = self.unlink.take() {
            let _ = std::fs::remove_file(path);
        }
    }
}

/// A connection's stream once it is authenticated (or needs not be).
trait Duplex: AsyncRead + AsyncWrite + Send + Unpin {}
impl<T: AsyncRead + AsyncWrite + Send + Unpin> Duplex for T {}

/// What a listener's task and its connections' tasks share.
struct Shared {
    host: Host,
    addr: ListenAddr,
    type_name: &'static str,
    options: ListenOptions,
    links: watch::Sender<Vec<AcceptedLink>>,
    /// The published links, each with its connection's number.
    table: std::sync::Mutex<Vec<(u64, AcceptedLink)>>,
    counters: Arc<Counters>,
}

impl Shared {
    fn edit(&self, f: impl FnOnce(&mut Vec<(u64, AcceptedLink)>)) {
        let mut table = self.table.lock().unwrap_or_else(|e| e.into_inner());
        f(&mut table);
        self.links
            .send_replace(table.iter().map(|(_, l)| l.clone()).collect());
    }
}

/// The listener task: accepts, refuses past the limit, runs each
/// connection in a task of its own, and on stop closes them all.
async fn accept_loop<A: Accept>(shared: Shared, mut acceptor: A, stop: Arc<Notify>) {
    let shared = Arc::new(shared);
    let (type_name, addr) = (shared.type_name, shared.addr.clone());
    let max = shared.options.max_connections;
    let slots = Arc::new(tokio::sync::Semaphore::new(max));
    let mut connections: JoinSet<()> = JoinSet::new();
    let mut number = 0u64;
    tracing::info!("{type_name}: listening on {addr}");
    loop {
        tokio::select! {
            _ = stop.notified() => break,
            Some(_) = connections.join_next() => {}
            accepted = acceptor.accept() => {
                let (stream, peer) = match accepted {
                    Ok(a) => a,
                    Err(e) => {
                        // Out of file descriptors and the like: pause, go on.
                        tracing::warn!("{type_name}: accepting on {addr} failed: {e}");
                        tokio::time::sleep(RECONNECT_MIN).await;
                        continue;
                    }
                };
                if connections.len() >= max.saturating_add(MAX_WAITING) {
                    refuse(&shared, &peer);
                    // Closed unread: the peer sees the connection end at once.
                    drop(stream);
                    continue;
                }
                number += 1;
                let (shared, slots) = (shared.clone(), slots.clone());
                connections.spawn(async move {
                    let wait = shared.options.queue_timeout;
                    let Ok(Ok(slot)) = tokio::time::timeout(wait, slots.acquire_owned()).await
                    else {
                        refuse(&shared, &peer);
                        return;
                    };
                    shared.counters.accepted.fetch_add(1, Ordering::Relaxed);
                    serve_connection(shared, stream, peer, number).await;
                    drop(slot);
                });
            }
        }
    }
    // Waits for every connection task to be gone (each detaches its link
    // as it goes), so none can reopen its link after this.
    connections.shutdown().await;
    shared.edit(Vec::clear);
    tracing::info!("{type_name}: stopped listening on {addr}");
}

/// Counts and logs a connection refused at the limit.
fn refuse(shared: &Shared, peer: &str) {
    shared.counters.refused.fetch_add(1, Ordering::Relaxed);
    tracing::warn!(
        "{}: refused a connection from {peer} on {}: {} connections are open, the limit \
         (max_connections, osap serve --max-connections)",
        shared.type_name,
        shared.addr,
        shared.options.max_connections
    );
}

/// Serves one accepted connection: authenticates it if the listener has a
/// key, gives it a link, runs it, and frees the link when it ends (also
/// when the task is aborted).
async fn serve_connection<S>(shared: Arc<Shared>, stream: S, peer: String, number: u64)
where
    S: AsyncRead + AsyncWrite + Send + Unpin + 'static,
{
    let (type_name, addr) = (shared.type_name, &shared.addr);
    // A peer without the key never gets a link, nor a byte.
    let stream: Box<dyn Duplex> = match &shared.options.key {
        Some(key) => match noise::accept(stream, key, shared.options.handshake_timeout).await {
            Ok(s) => Box::new(s),
            Err(e) => {
                shared
                    .counters
                    .handshake_failed
                    .fetch_add(1, Ordering::Relaxed);
                tracing::warn!(
                    "{type_name}: closed a connection from {peer} on {addr}: no valid \
                     handshake ({e})"
                );
                return;
            }
        },
        None => Box::new(stream),
    };
    let (index, io) = match shared
        .host
        .add_link(LinkConfig::new(type_name, &peer))
        .await
    {
        Ok(link) => link,
        Err(e) => {
            tracing::warn!("{type_name}: refused a connection from {peer} on {addr}: {e}");
            return;
        }
    };
    // A peer that stops reading is not read: it cannot keep the runtime
    // busy, and the stall bound closes it if it never reads again.
    io.set_pause_reads_when_full(true);
    io.set_drop_when_full_for(shared.options.drop_after);
    let _release = Release {
        shared: shared.clone(),
        io: io.clone(),
        index,
        number,
    };
    shared.edit(|t| {
        t.push((
            number,
            AcceptedLink {
                index,
                peer: peer.clone(),
                connected: true,
            },
        ))
    });
    tracing::info!("{type_name} link {index} from {peer}: connected on {addr}");
    let limits = StreamLimits {
        idle: shared.options.idle_timeout,
        stall: shared.options.stall_timeout,
    };
    let end = run_stream_with(stream, &io, limits).await;
    tracing::info!("{type_name} link {index} from {peer}: disconnected ({end})");
}

/// Frees a connection's link when its task ends, however it ends.
struct Release {
    shared: Arc<Shared>,
    io: LinkIo,
    index: u8,
    number: u64,
}

impl Drop for Release {
    fn drop(&mut self) {
        self.io.set_open(false);
        self.shared.host.release_link(self.index);
        let number = self.number;
        self.shared.edit(|t| t.retain(|(n, _)| *n != number));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_loopback_binds_by_default() {
        assert!(check_bind(loopback(7000), false, false).is_ok());
        assert!(check_bind("[::1]:7000".parse().unwrap(), false, false).is_ok());
        assert!(check_bind("127.0.0.2:1".parse().unwrap(), false, false).is_ok());
        let err = check_bind("0.0.0.0:7000".parse().unwrap(), false, true).unwrap_err();
        let text = err.to_string();
        assert!(
            text.contains("refusing to listen on 0.0.0.0:7000"),
            "{text}"
        );
        assert!(text.contains("allow_remote"), "{text}");
        let err = check_bind("0.0.0.0:7000".parse().unwrap(), true, false).unwrap_err();
        assert!(err.to_string().contains("osap keygen"), "{err}");
        assert!(check_bind("0.0.0.0:7000".parse().unwrap(), true, true).is_ok());
    }
}
