//! Link hygiene of TCP listeners: link slots come back when connections
//! end (1000 connections in turn, each from its own loopback address, then
//! 100 at once), a peer that floods requests and never reads loses only its
//! own link, and the connection limit refuses clearly.
//!
//! The server runs on a tokio runtime of its own thread, as another
//! process would; raw clients speak framed packets over plain sockets.

use osap_core::framing::{encode_frame, max_frame_len, FrameDecoder};
use osap_core::netresponder::key;
use osap_core::route::Route;
use osap_host::link::stream::{ListenOptions, Listener, MAX_FRAME};
use osap_host::link::{tcp, ChannelLink, LinkConfig};
use osap_host::netrunner::{self, ScanOptions};
use osap_host::{Host, HostConfig};
use std::net::{Ipv4Addr, SocketAddr};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpSocket, TcpStream};

const SERVER: &str = "hygiene-server";
const PATIENCE: Duration = Duration::from_secs(20);

/// A host serving TCP on loopback from a thread and runtime of its own,
/// with `modules` in-process runtimes behind it (for scans).
struct Server {
    addr: SocketAddr,
    listener: Option<Listener>,
    hosts: Vec<Host>,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Server {
    fn start(options: ListenOptions, modules: usize) -> Server {
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
        let thread = std::thread::spawn(move || {
            let rt = tokio::runtime::Builder::new_multi_thread()
                .worker_threads(2)
                .enable_all()
                .build()
                .unwrap();
            rt.block_on(async move {
                let host = Host::start(HostConfig::named(SERVER)).unwrap();
                let mut hosts = vec![host.clone()];
                for i in 0..modules {
                    let m = Host::start(HostConfig {
                        time: osap_core::clock::TimeConfig::default(),
                        ..HostConfig::named(format!("module-{i}"))
                    })
                    .unwrap();
                    let (mut a, io_a) = host.make_link(LinkConfig::new("mem", "m"));
                    let (mut b, io_b) = m.make_link(LinkConfig::new("mem", "host"));
                    ChannelLink::join(&mut a, &mut b);
                    io_a.set_open(true);
                    io_b.set_open(true);
                    host.attach_link(a).await.unwrap();
                    m.attach_link(b).await.unwrap();
                    hosts.push(m);
                }
                let listener = tcp::listen_with(&host, tcp::loopback(0), options)
                    .await
                    .unwrap();
                ready_tx.send((listener, hosts)).unwrap();
                let _ = stopped.await;
            });
        });
        let (listener, hosts) = ready_rx.recv().unwrap();
        Server {
            addr: listener.socket_addr().unwrap(),
            listener: Some(listener),
            hosts,
            stop: Some(stop),
            thread: Some(thread),
        }
    }

    fn listener(&self) -> &Listener {
        self.listener.as_ref().unwrap()
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        drop(self.listener.take());
        self.hosts.clear();
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The bytes a host puts on a link to ask its neighbour's netresponder for
/// its name: captured from a real host, so raw clients send exactly what a
/// runtime would.
async fn name_request() -> Vec<u8> {
    let host = Host::start(HostConfig::named("capture")).unwrap();
    let (index, io) = host
        .add_link(LinkConfig::new("capture", "x"))
        .await
        .unwrap();
    io.set_open(true);
    let port = host.open_port("capture").await.unwrap();
    let route = Route::through_links(&[index]).unwrap();
    let asking = tokio::spawn(async move {
        let _ = port
            .request(&route, 0, &[key::NAME], Duration::from_secs(5))
            .await;
    });
    let packet = loop {
        let p = io.next_tx().await.unwrap();
        if p.last() == Some(&key::NAME) {
            break p;
        }
    };
    asking.abort();
    packet
}

fn framed(packet: &[u8]) -> Vec<u8> {
    let mut out = vec![0u8; max_frame_len(packet.len())];
    let n = encode_frame(packet, &mut out).unwrap();
    out.truncate(n);
    out
}

/// A loopback address of its own for client `i` (127.0.0.0/8 is loopback).
fn client_ip(i: usize) -> Ipv4Addr {
    Ipv4Addr::new(127, 1 + (i / 250) as u8, (i % 250) as u8, 1 + (i % 7) as u8)
}

async fn connect_from(ip: Ipv4Addr, server: SocketAddr) -> std::io::Result<TcpStream> {
    let socket = TcpSocket::new_v4()?;
    socket.bind(SocketAddr::new(ip.into(), 0))?;
    socket.connect(server).await
}

/// Reads frames until one holds the server's name.
async fn await_name(stream: &mut TcpStream) -> Result<(), String> {
    let mut decoder = Box::new(FrameDecoder::<MAX_FRAME>::new());
    let mut buf = vec![0u8; 4096];
    loop {
        let n = stream.read(&mut buf).await.map_err(|e| e.to_string())?;
        if n == 0 {
            return Err("closed before the reply".into());
        }
        let mut input = &buf[..n];
        while let Some(frame) = decoder.decode(&mut input) {
            if let Ok(p) = frame {
                if p.windows(SERVER.len()).any(|w| w == SERVER.as_bytes()) {
                    return Ok(());
                }
            }
        }
    }
}

/// One raw client from `ip`: connect, ask the name, read the reply, close.
/// Returns the server's link indices in use just after.
async fn ask_once(server: SocketAddr, ip: Ipv4Addr, request: &[u8]) -> Result<(), String> {
    let mut s = connect_from(ip, server).await.map_err(|e| e.to_string())?;
    s.write_all(request).await.map_err(|e| e.to_string())?;
    tokio::time::timeout(PATIENCE, await_name(&mut s))
        .await
        .map_err(|_| "no reply".to_string())?
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_thousand_connections_in_turn_then_a_hundred_at_once() {
    let server = Server::start(ListenOptions::default(), 0);
    let request = framed(&name_request().await);
    let mut highest = 0u8;
    let started = Instant::now();
    for i in 0..1000 {
        let ip = client_ip(i);
        let mut s = connect_from(ip, server.addr).await.unwrap();
        s.write_all(&request).await.unwrap();
        tokio::time::timeout(PATIENCE, await_name(&mut s))
            .await
            .unwrap_or_else(|_| panic!("connection {i} from {ip}: no reply"))
            .unwrap_or_else(|e| panic!("connection {i} from {ip}: {e}"));
        for l in server.listener().links() {
            highest = highest.max(l.index);
        }
    }
    // Freed indices are reused: a handful at most were ever in use.
    assert!(highest < 4, "link index {highest} was handed out");
    let stats = server.listener().stats();
    assert_eq!((stats.accepted, stats.refused), (1000, 0), "{stats:?}");

    let in_turn = started.elapsed();
    // 100 at once, past the limit of 16: the rest wait their turn.
    let started = Instant::now();
    let mut all = tokio::task::JoinSet::new();
    for i in 0..100 {
        let request = request.clone();
        let addr = server.addr;
        all.spawn(async move { (i, ask_once(addr, client_ip(1000 + i), &request).await) });
    }
    while let Some(done) = all.join_next().await {
        let (i, result) = done.unwrap();
        result.unwrap_or_else(|e| panic!("concurrent client {i}: {e}"));
    }
    eprintln!(
        "1000 connections in turn: {in_turn:?}; 100 at once: {:?}; highest link index {highest}",
        started.elapsed()
    );
    let stats = server.listener().stats();
    assert_eq!((stats.accepted, stats.refused), (1100, 0), "{stats:?}");
    // Every link is given back.
    let mut rx = server.listener().subscribe();
    tokio::time::timeout(PATIENCE, rx.wait_for(|l| l.is_empty()))
        .await
        .expect("links left after every client closed")
        .unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_connection_limit_refuses_clearly() {
    let options = ListenOptions {
        max_connections: 1,
        queue_timeout: Duration::from_millis(100),
        ..ListenOptions::default()
    };
    let server = Server::start(options, 0);
    let client = Host::start(HostConfig::named("client")).unwrap();
    let first = tcp::connect(&client, &server.addr.to_string())
        .await
        .unwrap();
    let other = Host::start(HostConfig::named("other")).unwrap();
    let err = tcp::connect(&other, &server.addr.to_string())
        .await
        .unwrap_err()
        .to_string();
    assert!(err.contains("connection limit"), "{err}");
    assert_eq!(server.listener().stats().refused, 1);
    // Once the first goes, the next is served.
    first.close().await;
    let mut rx = server.listener().subscribe();
    tokio::time::timeout(PATIENCE, rx.wait_for(|l| l.is_empty()))
        .await
        .unwrap()
        .unwrap();
    tcp::connect(&other, &server.addr.to_string())
        .await
        .unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_idle_connection_is_closed_and_its_slot_freed() {
    let options = ListenOptions {
        idle_timeout: Some(Duration::from_millis(300)),
        ..ListenOptions::default()
    };
    let server = Server::start(options, 0);
    let mut s = connect_from(client_ip(7), server.addr).await.unwrap();
    let mut rx = server.listener().subscribe();
    tokio::time::timeout(PATIENCE, rx.wait_for(|l| l.len() == 1))
        .await
        .unwrap()
        .unwrap();
    // Silent: closed after the idle timeout (the greeting byte, then EOF).
    let mut rest = Vec::new();
    tokio::time::timeout(PATIENCE, s.read_to_end(&mut rest))
        .await
        .expect("an idle connection stayed open")
        .unwrap();
    assert_eq!(rest, [0]);
    tokio::time::timeout(PATIENCE, rx.wait_for(|l| l.is_empty()))
        .await
        .unwrap()
        .unwrap();
}

/// Floods the server from its own address with name requests and never
/// reads, until the server closes the connection (counted in `kicked`) or
/// `stop`.
fn flood(server: SocketAddr, request: Vec<u8>, stop: Arc<AtomicBool>, kicked: Arc<AtomicU64>) {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let burst: Vec<u8> = request
        .iter()
        .copied()
        .cycle()
        .take(request.len() * 500)
        .collect();
    rt.block_on(async move {
        let mut s = connect_from(Ipv4Addr::new(127, 0, 0, 99), server)
            .await
            .unwrap();
        while !stop.load(Ordering::Relaxed) {
            // Bounded, so that `stop` is seen while the socket is full.
            let write = tokio::time::timeout(Duration::from_millis(100), s.write_all(&burst));
            if let Ok(Err(_)) = write.await {
                kicked.fetch_add(1, Ordering::Relaxed);
                return;
            }
        }
    });
}

/// Round-trip times of `count` name requests over `route`; a request with
/// no reply within a second counts as taking that second (and is counted
/// in the second result).
async fn rpcs(port: &osap_host::PortHandle, route: &Route, count: usize) -> (Vec<Duration>, usize) {
    let mut times = Vec::with_capacity(count);
    let mut lost = 0;
    for _ in 0..count {
        let start = Instant::now();
        if let Err(e) = port
            .request(route, 0, &[key::NAME], Duration::from_secs(1))
            .await
        {
            eprintln!("lost after {:?}: {e}", start.elapsed());
            lost += 1;
        }
        times.push(start.elapsed());
    }
    (times, lost)
}

fn p99(mut times: Vec<Duration>) -> Duration {
    times.sort();
    times[(times.len() * 99 / 100).min(times.len() - 1)]
}

/// The server's counters of its link `index`.
async fn server_link(server: &Server, index: u8) -> osap_core::counters::LinkCounters {
    server.hosts[0]
        .with_runtime(move |rt, _| rt.link_counters(usize::from(index)).cloned())
        .await
        .unwrap()
        .unwrap_or_else(|| panic!("the server has no link {index}"))
}

/// One attempt: the client asks the server's name 10 000 times alone, then
/// 10 000 times beside a peer that floods the same requests and never reads
/// their replies. What each loses is asserted: the flooder its replies
/// (they expire or die with its link) and then its link, closed by the
/// server for not reading; the client nothing, alone or beside it (every
/// request answered within its 1 s wait, none of the server's packets
/// bound to it dropped, its link never lost). The p99 times are printed,
/// not bounded: on this shared machine they measure the load.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_peer_that_floods_and_never_reads_loses_only_its_own_link() {
    const RPCS: usize = 10_000;
    let server = Server::start(ListenOptions::default(), 3);
    let request = framed(&name_request().await);
    let client = Host::start(HostConfig::named("client")).unwrap();
    let link = tcp::connect(&client, &server.addr.to_string())
        .await
        .unwrap();
    let route = Route::through_links(&[link.index()]).unwrap();
    let port = client.open_port("rpc").await.unwrap();
    let options = ScanOptions {
        timeout: Duration::from_millis(200),
        ..ScanOptions::default()
    };
    // The client's link on the server: the only one until the flooder's.
    let client_link = {
        let links = server.listener().links();
        assert_eq!(links.len(), 1, "{links:?}");
        links[0].index
    };

    let report = netrunner::scan(&client, &options).await.unwrap();
    assert!(report.failures.is_empty(), "{:?}", report.failures);
    let runtimes = report.map.runtimes.len();
    assert_eq!(runtimes, 5);

    let (quiet, quiet_lost) = rpcs(&port, &route, RPCS).await;
    let quiet = p99(quiet);

    let stop = Arc::new(AtomicBool::new(false));
    let kicked = Arc::new(AtomicU64::new(0));
    let flooder = {
        let (stop, kicked, request) = (stop.clone(), kicked.clone(), request.clone());
        let addr = server.addr;
        std::thread::spawn(move || flood(addr, request, stop, kicked))
    };
    // Wait until the flood is on: the flooder has a link.
    let mut rx = server.listener().subscribe();
    let flooder_link = tokio::time::timeout(
        PATIENCE,
        rx.wait_for(|l| l.iter().any(|l| l.peer == "127.0.0.99")),
    )
    .await
    .unwrap()
    .unwrap()
    .iter()
    .find(|l| l.peer == "127.0.0.99")
    .unwrap()
    .index;
    let started = Instant::now();
    let (loaded, loaded_lost) = rpcs(&port, &route, RPCS).await;
    let loaded = p99(loaded);
    let took = started.elapsed();
    let flooded = server
        .listener()
        .links()
        .iter()
        .any(|l| l.peer == "127.0.0.99");
    // What the server dropped of the packets bound to the client.
    let to_client = server_link(&server, client_link).await;
    // The scan finds every runtime; the only failures are routes to the
    // flooder (not a runtime: it answers nothing).
    let report = netrunner::scan(&client, &options).await.unwrap();
    // The flooder loses its link for not reading (the stall bound), and
    // sees it closed.
    tokio::time::timeout(
        PATIENCE,
        rx.wait_for(|l| !l.iter().any(|l| l.peer == "127.0.0.99")),
    )
    .await
    .expect("the flooder kept its link")
    .unwrap();
    // The flooder stops by itself once a write fails on the closed
    // connection.
    let joined = tokio::time::timeout(
        PATIENCE,
        tokio::task::spawn_blocking(move || flooder.join().unwrap()),
    )
    .await;
    stop.store(true, Ordering::Relaxed);
    joined
        .expect("the flooder never saw its connection closed")
        .unwrap();
    // The flooder's link's tally, now that it is closed (no connection
    // took its index since).
    let to_flooder = server_link(&server, flooder_link).await;
    let counters = server.hosts[0]
        .with_runtime(|rt, _| *rt.counters())
        .await
        .unwrap();
    eprintln!(
        "p99 of {RPCS} name requests: {quiet:?} alone ({quiet_lost} lost), {loaded:?} beside \
         the flooder ({loaded_lost} lost; {took:?} in all; the flooder was {} by the end, and \
         saw its connection closed {} times); the server: to the client {to_client:?}; to the \
         flooder {to_flooder:?}; in all {counters:?}",
        if flooded { "still connected" } else { "closed" },
        kicked.load(Ordering::Relaxed),
    );

    // What the flooder loses: its link, and it saw it closed.
    assert_eq!(
        kicked.load(Ordering::Relaxed),
        1,
        "the flooder's connection was not closed"
    );
    // Its replies: once its socket is full they wait in the server's
    // stack and expire there, or die with its link.
    let f = to_flooder;
    assert!(f.expired + f.closed + f.send_errors > 0, "{f:?}");
    // So fewer replies left for it than requests came in.
    assert!(f.received > 0 && f.sent < f.received, "{f:?}");
    // What the client does not lose: any request, alone or beside the
    // flooder, any packet the server had for it, or its link.
    assert_eq!(
        (quiet_lost, loaded_lost),
        (0, 0),
        "the client lost requests"
    );
    assert_eq!(
        (to_client.expired, to_client.closed, to_client.send_errors),
        (0, 0, 0),
        "the server dropped packets bound to the client: {to_client:?}"
    );
    assert_eq!(link.stats().disconnects, 0, "the client lost its link");
    assert_eq!(report.map.runtimes.len(), runtimes, "{:?}", report.failures);
    for f in &report.failures {
        assert!(
            f.route.len() == 2 && f.route[1] == flooder_link,
            "a scan failure other than the flooder's link: {f:?} (flooder on {flooder_link})"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn closed_client_links_give_their_index_back() {
    let server = Server::start(ListenOptions::default(), 0);
    let client = Host::start(HostConfig::named("client")).unwrap();
    let port = client.open_port("rpc").await.unwrap();
    // More than the host's 32 link slots, one after another.
    for i in 0..40 {
        let link = tcp::connect(&client, &server.addr.to_string())
            .await
            .unwrap_or_else(|e| panic!("connection {i}: {e}"));
        let route = Route::through_links(&[link.index()]).unwrap();
        port.request(&route, 0, &[key::NAME], PATIENCE)
            .await
            .unwrap_or_else(|e| panic!("connection {i}: {e}"));
        link.close().await;
    }
}
