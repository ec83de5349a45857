//! Real link gateways between hosts: serial over a pseudo-terminal pair,
//! TCP, UDP and Unix sockets, in one process and between two processes;
//! link loss and reconnection; refusal to open the machine to a network;
//! corrupted bytes on a stream.
//!
//! Nothing here sleeps to synchronise: tests wait on link states, listener
//! reports or replies, each under an overall timeout.

#![cfg(unix)]

use osap_core::framing::{encode_frame, max_frame_len};
use osap_core::netresponder::key;
use osap_core::route::Route;
use osap_host::link::stream::{run_stream, LinkHandle, LinkState, Listener};
use osap_host::link::{serial, tcp, udp, unix};
use osap_host::{HostError, LinkConfig, PortHandle};
use std::io::{self, BufRead, BufReader};
use std::net::SocketAddr;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::task::{ready, Context, Poll};
use std::time::Duration;
use tokio::io::unix::AsyncFd;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt, ReadBuf};

mod common;
use common::host;

/// Longest any one wait may take before the test fails.
const PATIENCE: Duration = Duration::from_secs(15);
/// Timeout of a request that is expected to succeed.
const REQUEST: Duration = Duration::from_secs(2);
/// Timeout of a request that is expected to fail.
const SHORT: Duration = Duration::from_millis(200);

/// A fresh path in the temp directory, unique to this process and call.
fn temp_path(tag: &str) -> PathBuf {
    static NEXT: AtomicU32 = AtomicU32::new(0);
    std::env::temp_dir().join(format!(
        "osap-links-{}-{tag}-{}",
        std::process::id(),
        NEXT.fetch_add(1, Ordering::Relaxed)
    ))
}

/// Asks the runtime at the end of link `link` for its name.
async fn name_over(port: &PortHandle, link: u8, timeout: Duration) -> Result<String, HostError> {
    let route = Route::through_links(&[link]).unwrap();
    let reply = port.request(&route, 0, &[key::NAME], timeout).await?;
    // [key][status][str8]
    assert_eq!(&reply.body[..2], &[key::NAME, 0], "{:?}", reply.body);
    Ok(String::from_utf8(reply.body[3..].to_vec()).unwrap())
}

/// Waits until the link's state satisfies `want`.
async fn wait_state(link: &LinkHandle, what: &str, want: impl Fn(&LinkState) -> bool) {
    let mut rx = link.subscribe();
    let waited = tokio::time::timeout(PATIENCE, rx.wait_for(|s| want(s))).await;
    assert!(
        matches!(waited, Ok(Ok(_))),
        "link {} never became {what}; it is {}",
        link.index(),
        link.state()
    );
}

fn is_disconnected(s: &LinkState) -> bool {
    matches!(s, LinkState::Disconnected { .. })
}

// ---------------------------------------------------------------------------
// Pseudo-terminals

/// A PTY pair: the slave is the "serial port" a link opens by path; the
/// master is the other end of the cable.
struct Pty {
    master: OwnedFd,
    /// Held so the master does not read EIO before the link opens the
    /// slave.
    slave: OwnedFd,
    path: String,
}

fn openpty() -> Pty {
    let (mut master, mut slave) = (0, 0);
    // SAFETY: openpty writes two descriptors; the optional arguments are
    // null.
    let r = unsafe {
        libc::openpty(
            &mut master,
            &mut slave,
            std::ptr::null_mut(),
            std::ptr::null(),
            std::ptr::null(),
        )
    };
    assert_eq!(r, 0, "openpty: {}", io::Error::last_os_error());
    // SAFETY: both are fresh descriptors that nothing else owns.
    let (master, slave) = unsafe { (OwnedFd::from_raw_fd(master), OwnedFd::from_raw_fd(slave)) };
    // Raw mode from the start, so nothing written before the link
    // configures the port is echoed or translated.
    // SAFETY: termios is plain data, filled by tcgetattr before use.
    unsafe {
        let mut t: libc::termios = std::mem::zeroed();
        assert_eq!(libc::tcgetattr(slave.as_raw_fd(), &mut t), 0);
        libc::cfmakeraw(&mut t);
        assert_eq!(libc::tcsetattr(slave.as_raw_fd(), libc::TCSANOW, &t), 0);
    }
    let mut name = [0 as libc::c_char; 128];
    // SAFETY: the buffer and its length match.
    let r = unsafe { libc::ttyname_r(slave.as_raw_fd(), name.as_mut_ptr(), name.len()) };
    assert_eq!(r, 0, "ttyname_r");
    // SAFETY: ttyname_r wrote a NUL-terminated string.
    let path = unsafe { std::ffi::CStr::from_ptr(name.as_ptr()) }
        .to_string_lossy()
        .into_owned();
    Pty {
        master,
        slave,
        path,
    }
}

/// The PTY master as an async byte stream.
struct PtyMaster(AsyncFd<OwnedFd>);

impl PtyMaster {
    fn new(fd: OwnedFd) -> PtyMaster {
        // SAFETY: fcntl on a descriptor we own.
        unsafe {
            let flags = libc::fcntl(fd.as_raw_fd(), libc::F_GETFL);
            libc::fcntl(fd.as_raw_fd(), libc::F_SETFL, flags | libc::O_NONBLOCK);
        }
        // SAFETY: the OwnedFd is open and owned by the AsyncFd until it
        // is dropped, and always returns the same descriptor.
        let fd = unsafe { AsyncFd::register(fd) };
        PtyMaster(fd.map_err(io::Error::from).unwrap())
    }
}

fn check(n: isize) -> io::Result<usize> {
    usize::try_from(n).map_err(|_| io::Error::last_os_error())
}

impl AsyncRead for PtyMaster {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        loop {
            let mut guard = ready!(self.0.poll_read_ready(cx))?;
            let unfilled = buf.initialize_unfilled();
            let result = guard.try_io(|fd| {
                // SAFETY: reads into the unfilled part of the buffer.
                check(unsafe {
                    libc::read(fd.as_raw_fd(), unfilled.as_mut_ptr().cast(), unfilled.len())
                })
            });
            match result {
                Ok(Ok(n)) => {
                    buf.advance(n);
                    return Poll::Ready(Ok(()));
                }
                Ok(Err(e)) => return Poll::Ready(Err(e)),
                Err(_would_block) => continue,
            }
        }
    }
}

impl AsyncWrite for PtyMaster {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        data: &[u8],
    ) -> Poll<io::Result<usize>> {
        loop {
            let mut guard = ready!(self.0.poll_write_ready(cx))?;
            // SAFETY: writes from a valid slice.
            let result = guard.try_io(|fd| {
                check(unsafe { libc::write(fd.as_raw_fd(), data.as_ptr().cast(), data.len()) })
            });
            match result {
                Ok(r) => return Poll::Ready(r),
                Err(_would_block) => continue,
            }
        }
    }

    fn poll_flush(self: Pin<&mut Self>, _: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }

    fn poll_shutdown(self: Pin<&mut Self>, _: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }
}

// ---------------------------------------------------------------------------
// Serial

#[tokio::test]
async fn serial_link_over_a_pty_reaches_the_peer() {
    let a = host("a");
    let b = host("b");
    let pty = openpty();
    let link = serial::spawn_serial(&a, &pty.path, 115_200).await.unwrap();
    let config = link.config();
    assert_eq!(config.type_name, "uart");
    assert_eq!(config.name, pty.path);
    assert_eq!(
        (config.bits_per_second, config.bits_per_byte),
        (115_200, 10)
    );
    assert!(link.state().is_connected());

    // Host B runs the other end of the "cable".
    let (_, io_b) = b.add_link(LinkConfig::new("uart", "pty")).await.unwrap();
    let master = PtyMaster::new(pty.master);
    tokio::spawn(async move { run_stream(master, &io_b).await });

    let port = a.open_port("test").await.unwrap();
    assert_eq!(name_over(&port, link.index(), REQUEST).await.unwrap(), "b");
    assert_eq!(link.probe(&a, REQUEST).await.unwrap(), "b");
    assert_eq!(link.stats().frame_errors, 0);
    link.close().await;
    drop(pty.slave);
}

#[tokio::test]
async fn serial_link_reopens_when_the_device_comes_back() {
    let a = host("a");
    let b = host("b");
    // The link opens a stable path, as /dev/serial/by-id/... would be; the
    // device behind it goes away and comes back.
    let path = temp_path("tty");
    let pty = openpty();
    std::os::unix::fs::symlink(&pty.path, &path).unwrap();
    let path_str = path.to_str().unwrap();
    let link = serial::spawn_serial(&a, path_str, 115_200).await.unwrap();
    let (_, io_b) = b.add_link(LinkConfig::new("uart", "pty")).await.unwrap();
    let master = PtyMaster::new(pty.master);
    let peer = {
        let io_b = io_b.clone();
        tokio::spawn(async move { run_stream(master, &io_b).await })
    };
    let port = a.open_port("test").await.unwrap();
    assert_eq!(name_over(&port, link.index(), REQUEST).await.unwrap(), "b");

    // Unplug: the device node goes, the other end hangs up.
    std::fs::remove_file(&path).unwrap();
    peer.abort();
    let _ = peer.await;
    drop(pty.slave);
    wait_state(&link, "disconnected", is_disconnected).await;
    assert!(name_over(&port, link.index(), SHORT).await.is_err());
    let LinkState::Disconnected { reason, .. } = link.state() else {
        unreachable!()
    };
    assert!(!reason.is_empty());

    // Plug back in: a new device node at the same path.
    let pty2 = openpty();
    std::os::unix::fs::symlink(&pty2.path, &path).unwrap();
    let master = PtyMaster::new(pty2.master);
    tokio::spawn(async move { run_stream(master, &io_b).await });
    wait_state(&link, "connected", LinkState::is_connected).await;
    assert_eq!(name_over(&port, link.index(), REQUEST).await.unwrap(), "b");
    assert!(link.stats().disconnects >= 1);

    link.close().await;
    let _ = std::fs::remove_file(&path);
    drop(pty2.slave);
}

#[tokio::test]
async fn probe_names_a_port_that_is_not_an_osap_device() {
    let a = host("a");

    // A device that answers everything with text, not frames.
    let chatty = openpty();
    let link = serial::spawn_serial(&a, &chatty.path, 9600).await.unwrap();
    let mut master = PtyMaster::new(chatty.master);
    tokio::spawn(async move {
        let mut buf = [0u8; 256];
        while matches!(master.read(&mut buf).await, Ok(n) if n > 0) {
            if master
                .write_all(b"ERROR: unknown command\r\n\0")
                .await
                .is_err()
            {
                break;
            }
        }
    });
    let err = link.probe(&a, SHORT).await.unwrap_err().to_string();
    assert!(err.contains("no OSAP runtime answered"), "{err}");
    assert!(err.contains("garbled frames"), "{err}");
    assert!(err.contains("not an OSAP device"), "{err}");
    link.close().await;

    // A device that says nothing at all.
    let silent = openpty();
    let link = serial::spawn_serial(&a, &silent.path, 9600).await.unwrap();
    let err = link.probe(&a, SHORT).await.unwrap_err().to_string();
    assert!(err.contains("nothing came back"), "{err}");
    assert!(err.contains("not an OSAP device"), "{err}");
    link.close().await;
    drop((chatty.slave, silent));
}

#[tokio::test]
async fn serial_open_errors_say_what_is_wrong() {
    let a = host("a");
    let missing = "/dev/ttyOSAP-no-such-device";
    let err = serial::spawn_serial(&a, missing, 115_200)
        .await
        .unwrap_err()
        .to_string();
    assert!(err.contains("cannot open serial port"), "{err}");
    assert!(err.contains("does not exist"), "{err}");

    let file = temp_path("not-a-tty");
    std::fs::write(&file, b"hello").unwrap();
    let err = serial::spawn_serial(&a, file.to_str().unwrap(), 115_200)
        .await
        .unwrap_err()
        .to_string();
    assert!(err.contains("not a serial port"), "{err}");
    std::fs::remove_file(&file).unwrap();
}

#[test]
fn discovery_reports_no_devices_clearly() {
    let found = serial::available_ports().unwrap();
    assert!(found.iter().all(serial::SerialCandidate::is_osap));
    if found.is_empty() {
        let err = serial::find_port().unwrap_err().to_string();
        assert!(err.contains("no osap-rs devices found"), "{err}");
        assert!(err.contains("--port"), "{err}");
    }
}

// ---------------------------------------------------------------------------
// Streams

/// Bytes that are not valid frames: a bad CRC, bad COBS, too short, and
/// one far longer than any packet.
fn garbage() -> Vec<u8> {
    let mut bad_crc = vec![0u8; max_frame_len(4)];
    let n = encode_frame(&[1, 2, 3, 4], &mut bad_crc).unwrap();
    bad_crc.truncate(n);
    bad_crc[2] ^= 0x40;
    let mut g = bad_crc;
    g.extend_from_slice(&[0x05, 0xaa, 0x00]);
    g.extend_from_slice(&[0x02, 0xaa, 0x00]);
    g.extend(std::iter::repeat_n(0x55, 3000));
    g.push(0);
    g
}

#[tokio::test]
async fn corrupted_bytes_on_a_stream_are_counted_not_delivered() {
    let a = host("a");
    let b = host("b");
    let (ia, io_a) = a.add_link(LinkConfig::new("uart", "a")).await.unwrap();
    let (_, io_b) = b.add_link(LinkConfig::new("uart", "b")).await.unwrap();
    let (a_end, mut a_wire) = tokio::io::duplex(8192);
    let (b_end, mut b_wire) = tokio::io::duplex(8192);
    let stats_b = io_b.clone();
    tokio::spawn(async move { run_stream(a_end, &io_a).await });
    tokio::spawn(async move { run_stream(b_end, &io_b).await });

    // Noise on the line to B ahead of everything A sends.
    b_wire.write_all(&garbage()).await.unwrap();
    tokio::spawn(async move { tokio::io::copy_bidirectional(&mut a_wire, &mut b_wire).await });

    let port = a.open_port("test").await.unwrap();
    assert_eq!(name_over(&port, ia, REQUEST).await.unwrap(), "b");
    let stats = stats_b.stats();
    assert_eq!(stats.frame_errors, 4, "{stats:?}");
    assert!(stats.received >= 1, "{stats:?}");
    assert_eq!(port.stray_replies(), 0);
}

// ---------------------------------------------------------------------------
// Sockets

#[tokio::test]
async fn tcp_links_between_two_hosts() {
    let a = host("a");
    let b = host("b");
    let listener = tcp::listen(&b, tcp::loopback(0), false).await.unwrap();
    let addr = listener.socket_addr().unwrap();
    assert!(addr.ip().is_loopback());
    let link = tcp::connect(&a, &addr.to_string()).await.unwrap();
    assert_eq!(link.config().type_name, "tcp");
    assert_eq!(link.config().name, addr.to_string());

    let port_a = a.open_port("test").await.unwrap();
    assert_eq!(
        name_over(&port_a, link.index(), REQUEST).await.unwrap(),
        "b"
    );

    // And back the other way, over the link B's listener made.
    let ib = listener.wait_connected(PATIENCE).await.unwrap();
    let accepted = listener.links();
    assert_eq!(accepted.len(), 1);
    assert_eq!(accepted[0].peer, "127.0.0.1");
    let port_b = b.open_port("test").await.unwrap();
    assert_eq!(name_over(&port_b, ib, REQUEST).await.unwrap(), "a");
}

#[tokio::test]
async fn udp_links_between_two_hosts() {
    let a = host("a");
    let b = host("b");
    // B learns its peer from the first datagram; A is told B's address.
    let link_b = udp::bind(&b, udp::loopback(0), None, false).await.unwrap();
    assert!(is_disconnected(&link_b.state()));
    let addr_b = link_b.local_addr().unwrap();
    let link_a = udp::bind(&a, udp::loopback(0), Some(addr_b), false)
        .await
        .unwrap();
    assert_eq!(link_a.config().type_name, "udp");
    assert_eq!(link_a.config().name, addr_b.to_string());

    let port_a = a.open_port("test").await.unwrap();
    assert_eq!(
        name_over(&port_a, link_a.index(), REQUEST).await.unwrap(),
        "b"
    );
    wait_state(&link_b, "connected", LinkState::is_connected).await;
    let port_b = b.open_port("test").await.unwrap();
    assert_eq!(
        name_over(&port_b, link_b.index(), REQUEST).await.unwrap(),
        "a"
    );
}

#[tokio::test]
async fn unix_links_between_two_hosts() {
    let a = host("a");
    let b = host("b");
    let path = temp_path("sock");
    let listener = unix::listen(&b, &path).await.unwrap();
    let link = unix::connect(&a, &path).await.unwrap();
    assert_eq!(link.config().type_name, "unix");

    let port_a = a.open_port("test").await.unwrap();
    assert_eq!(
        name_over(&port_a, link.index(), REQUEST).await.unwrap(),
        "b"
    );
    let ib = listener.wait_connected(PATIENCE).await.unwrap();
    let port_b = b.open_port("test").await.unwrap();
    assert_eq!(name_over(&port_b, ib, REQUEST).await.unwrap(), "a");

    // The socket file goes with the listener; a second listener on a live
    // socket is refused.
    let err = unix::listen(&b, &path).await.unwrap_err().to_string();
    assert!(err.contains("another listener"), "{err}");
    drop(listener);
    assert!(!path.exists());
}

#[tokio::test]
async fn tcp_client_reconnects_when_the_server_comes_back() {
    let a = host("a");
    let b = host("b");
    let listener = tcp::listen(&b, tcp::loopback(0), false).await.unwrap();
    let addr = listener.socket_addr().unwrap();
    let link = tcp::connect(&a, &addr.to_string()).await.unwrap();
    let port = a.open_port("test").await.unwrap();
    assert_eq!(name_over(&port, link.index(), REQUEST).await.unwrap(), "b");

    // The server goes away: the link is reported down, and requests over
    // it fail, but the host runs on.
    listener.close().await;
    wait_state(&link, "disconnected", is_disconnected).await;
    let err = name_over(&port, link.index(), SHORT).await.unwrap_err();
    assert!(matches!(err, HostError::Timeout { .. }), "{err}");

    // Back on the same address: the same link works again.
    let listener = tcp::listen(&b, addr, false).await.unwrap();
    wait_state(&link, "connected", LinkState::is_connected).await;
    assert_eq!(name_over(&port, link.index(), REQUEST).await.unwrap(), "b");
    assert_eq!(link.stats().disconnects, 1);
    drop(listener);
}

#[tokio::test]
async fn a_returning_peer_gets_its_old_link_back() {
    let a = host("a");
    let b = host("b");
    let listener = tcp::listen(&b, tcp::loopback(0), false).await.unwrap();
    let addr = listener.socket_addr().unwrap().to_string();

    let first = tcp::connect(&a, &addr).await.unwrap();
    let ib = listener.wait_connected(PATIENCE).await.unwrap();
    first.close().await;
    wait_listener(&listener, |l| l.iter().all(|l| !l.connected)).await;

    let second = tcp::connect(&a, &addr).await.unwrap();
    assert_eq!(listener.wait_connected(PATIENCE).await.unwrap(), ib);
    assert_eq!(listener.links().len(), 1);
    let port_b = b.open_port("test").await.unwrap();
    assert_eq!(name_over(&port_b, ib, REQUEST).await.unwrap(), "a");
    drop(second);
}

async fn wait_listener(
    listener: &Listener,
    want: impl Fn(&Vec<osap_host::link::stream::AcceptedLink>) -> bool,
) {
    let mut rx = listener.subscribe();
    let waited = tokio::time::timeout(PATIENCE, rx.wait_for(|l| want(l))).await;
    assert!(
        matches!(waited, Ok(Ok(_))),
        "listener: {:?}",
        listener.links()
    );
}

#[tokio::test]
async fn listeners_refuse_non_loopback_addresses_by_default() {
    let b = host("b");
    let any: SocketAddr = "0.0.0.0:0".parse().unwrap();
    let err = tcp::listen(&b, any, false).await.unwrap_err().to_string();
    assert!(err.contains("refusing to listen on 0.0.0.0:0"), "{err}");
    assert!(err.contains("allow_remote"), "{err}");
    let err = udp::bind(&b, any, None, false)
        .await
        .unwrap_err()
        .to_string();
    assert!(err.contains("refusing"), "{err}");
    let v6: SocketAddr = "[::]:0".parse().unwrap();
    assert!(tcp::listen(&b, v6, false).await.is_err());
}

// ---------------------------------------------------------------------------
// Two processes

/// Set in the environment of a child process to make it the peer:
/// `TCP_ADDR UNIX_PATH`.
const PEER_ENV: &str = "OSAP_LINKS_TEST_PEER";
/// The line the peer prints once it listens.
const PEER_READY: &str = "OSAP_PEER_READY";

/// The peer process: a host named "peer" listening on TCP and on a Unix
/// socket, until its standard input closes. Only runs as a child of
/// `links_to_a_peer_process`, which starts this test binary again with this
/// test selected and the environment set.
#[test]
#[ignore = "the peer process of links_to_a_peer_process"]
fn link_peer_process() {
    let Ok(spec) = std::env::var(PEER_ENV) else {
        return;
    };
    let (tcp_addr, unix_path) = spec.split_once(' ').unwrap();
    let tcp_addr: SocketAddr = tcp_addr.parse().unwrap();
    let unix_path = PathBuf::from(unix_path);
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let host = host("peer");
        let tcp = tcp::listen(&host, tcp_addr, false).await.unwrap();
        let _unix = unix::listen(&host, &unix_path).await.unwrap();
        // UDP: locks onto whoever sends first.
        let udp = udp::bind(&host, udp::loopback(0), None, false)
            .await
            .unwrap();
        println!(
            "{PEER_READY} {} {}",
            tcp.socket_addr().unwrap(),
            udp.local_addr().unwrap()
        );
        // Lives as long as the parent holds its end of stdin.
        let _ = tokio::task::spawn_blocking(|| {
            let mut sink = Vec::new();
            let _ = io::copy(&mut io::stdin(), &mut sink);
        })
        .await;
    });
}

/// A running peer process; killed when dropped.
struct Peer {
    child: Child,
    tcp: SocketAddr,
    udp: SocketAddr,
}

impl Peer {
    async fn spawn(tcp: SocketAddr, unix: &Path) -> Peer {
        let mut child = Command::new(std::env::current_exe().unwrap())
            .args([
                "link_peer_process",
                "--exact",
                "--ignored",
                "--nocapture",
                "--test-threads=1",
            ])
            .env(PEER_ENV, format!("{tcp} {}", unix.display()))
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .unwrap();
        let stdout = child.stdout.take().unwrap();
        let ready = tokio::task::spawn_blocking(move || {
            BufReader::new(stdout)
                .lines()
                .map_while(Result::ok)
                .find_map(|line| {
                    let at = line.find(PEER_READY)?;
                    let mut addrs = line[at + PEER_READY.len()..].split_whitespace();
                    let tcp = addrs.next()?.parse::<SocketAddr>().ok()?;
                    let udp = addrs.next()?.parse::<SocketAddr>().ok()?;
                    Some((tcp, udp))
                })
        });
        let (tcp, udp) = tokio::time::timeout(PATIENCE, ready)
            .await
            .expect("the peer process did not start")
            .unwrap()
            .expect("the peer process exited before listening");
        Peer { child, tcp, udp }
    }
}

impl Drop for Peer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

#[tokio::test]
async fn links_to_a_peer_process() {
    let a = host("a");
    let unix_path = temp_path("peer-sock");
    let peer = Peer::spawn(tcp::loopback(0), &unix_path).await;
    let tcp_addr = peer.tcp;
    let over_tcp = tcp::connect(&a, &tcp_addr.to_string()).await.unwrap();
    let over_unix = unix::connect(&a, &unix_path).await.unwrap();
    let port = a.open_port("test").await.unwrap();
    assert_eq!(
        name_over(&port, over_tcp.index(), REQUEST).await.unwrap(),
        "peer"
    );
    assert_eq!(
        name_over(&port, over_unix.index(), REQUEST).await.unwrap(),
        "peer"
    );
    let over_udp = udp::bind(&a, udp::loopback(0), Some(peer.udp), false)
        .await
        .unwrap();
    assert_eq!(
        name_over(&port, over_udp.index(), REQUEST).await.unwrap(),
        "peer"
    );
    drop(over_udp);

    // The peer dies: both stream links go down; this host keeps running.
    drop(peer);
    wait_state(&over_tcp, "disconnected", is_disconnected).await;
    wait_state(&over_unix, "disconnected", is_disconnected).await;
    assert!(name_over(&port, over_tcp.index(), SHORT).await.is_err());

    // A new peer process on the same addresses (its Unix listener replaces
    // the socket file the dead one left): both links come back.
    let peer = Peer::spawn(tcp_addr, &unix_path).await;
    wait_state(&over_tcp, "connected", LinkState::is_connected).await;
    wait_state(&over_unix, "connected", LinkState::is_connected).await;
    assert_eq!(
        name_over(&port, over_tcp.index(), REQUEST).await.unwrap(),
        "peer"
    );
    assert_eq!(
        name_over(&port, over_unix.index(), REQUEST).await.unwrap(),
        "peer"
    );
    drop(peer);
    let _ = std::fs::remove_file(&unix_path);
}
