//! Keyed TCP links (Noise NNpsk0): a good key works end to end; a wrong
//! key, a plain client, a replayed, truncated or oversized handshake get a
//! closed socket and not one byte; key files are checked.

use osap_core::framing::{encode_frame, max_frame_len};
use osap_core::netresponder::key;
use osap_core::route::Route;
use osap_host::link::noise::Key;
use osap_host::link::stream::{ListenOptions, Listener};
use osap_host::link::tcp;
use osap_host::netrunner::{self, ScanOptions};
use osap_host::{Host, HostConfig};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

const PATIENCE: Duration = Duration::from_secs(10);
/// The protocol, pinned here so that a change of it is a change of tests.
const PATTERN: &str = "Noise_NNpsk0_25519_ChaChaPoly_BLAKE2s";
const PROLOGUE: &[u8] = b"osap-rs link v1";
const SECRET: [u8; 32] = [7; 32];

async fn keyed_server(name: &str) -> (Host, Listener, SocketAddr) {
    let host = Host::start(HostConfig::named(name)).unwrap();
    let options = ListenOptions {
        key: Some(Key::from_bytes(SECRET)),
        handshake_timeout: Duration::from_millis(500),
        ..ListenOptions::default()
    };
    let listener = tcp::listen_with(&host, tcp::loopback(0), options)
        .await
        .unwrap();
    let addr = listener.socket_addr().unwrap();
    (host, listener, addr)
}

/// Everything the server sends until it closes the connection.
async fn read_until_closed(s: &mut TcpStream) -> Vec<u8> {
    let mut got = Vec::new();
    let _ = tokio::time::timeout(PATIENCE, s.read_to_end(&mut got))
        .await
        .expect("the server kept the connection open");
    got
}

fn initiator(secret: &[u8; 32]) -> snow::HandshakeState {
    snow::Builder::new(PATTERN.parse().unwrap())
        .prologue(PROLOGUE)
        .unwrap()
        .psk(0, secret)
        .unwrap()
        .build_initiator()
        .unwrap()
}

fn prefixed(msg: &[u8]) -> Vec<u8> {
    let mut out = (msg.len() as u16).to_be_bytes().to_vec();
    out.extend_from_slice(msg);
    out
}

async fn read_prefixed(s: &mut TcpStream) -> Vec<u8> {
    let mut len = [0u8; 2];
    s.read_exact(&mut len).await.unwrap();
    let mut msg = vec![0u8; usize::from(u16::from_be_bytes(len))];
    s.read_exact(&mut msg).await.unwrap();
    msg
}

async fn wait_failures(listener: &Listener, n: u64) {
    let deadline = tokio::time::Instant::now() + PATIENCE;
    while listener.stats().handshake_failed < n {
        assert!(
            tokio::time::Instant::now() < deadline,
            "{:?}",
            listener.stats()
        );
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
}

#[tokio::test]
async fn a_good_key_works_end_to_end() {
    let (_server, listener, addr) = keyed_server("keyed-server").await;
    let client = Host::start(HostConfig::named("client")).unwrap();
    let link = tcp::connect_with_key(&client, &addr.to_string(), &Key::from_bytes(SECRET))
        .await
        .unwrap();
    let port = client.open_port("test").await.unwrap();
    let route = Route::through_links(&[link.index()]).unwrap();
    let reply = port
        .request(&route, 0, &[key::NAME], PATIENCE)
        .await
        .unwrap();
    assert!(reply.body.ends_with(b"keyed-server"), "{:?}", reply.body);
    let options = ScanOptions {
        timeout: Duration::from_millis(500),
        ..ScanOptions::default()
    };
    let report = netrunner::scan(&client, &options).await.unwrap();
    assert!(report.failures.is_empty(), "{:?}", report.failures);
    assert_eq!(report.map.runtimes.len(), 2);
    assert_eq!(listener.links().len(), 1);
    assert_eq!(listener.stats().handshake_failed, 0);
}

#[tokio::test]
async fn a_wrong_key_gets_a_closed_socket_and_nothing_else() {
    let (_server, listener, addr) = keyed_server("keyed-server").await;
    // Through the API: a clear error.
    let client = Host::start(HostConfig::named("client")).unwrap();
    let err = tcp::connect_with_key(&client, &addr.to_string(), &Key::from_bytes([8; 32]))
        .await
        .unwrap_err()
        .to_string();
    assert!(err.contains("key may be wrong"), "{err}");
    // On the wire: not one byte back.
    let mut s = TcpStream::connect(addr).await.unwrap();
    let mut hs = initiator(&[8; 32]);
    let mut msg = [0u8; 256];
    let n = hs.write_message(&[], &mut msg).unwrap();
    s.write_all(&prefixed(&msg[..n])).await.unwrap();
    assert_eq!(read_until_closed(&mut s).await, b"");
    // A plain client too.
    let err = tcp::connect(&client, &addr.to_string())
        .await
        .unwrap_err()
        .to_string();
    assert!(err.contains("key"), "{err}");
    wait_failures(&listener, 3).await;
    assert!(listener.links().is_empty());
}

#[tokio::test]
async fn a_replayed_handshake_gains_nothing() {
    let (_server, listener, addr) = keyed_server("keyed-server").await;
    // A real session, recorded: the first message and the confirmation.
    let mut s = TcpStream::connect(addr).await.unwrap();
    let mut hs = initiator(&SECRET);
    let mut buf = vec![0u8; 65_535];
    let n = hs.write_message(&[], &mut buf).unwrap();
    let first = prefixed(&buf[..n]);
    s.write_all(&first).await.unwrap();
    let answer = read_prefixed(&mut s).await;
    hs.read_message(&answer, &mut buf).unwrap();
    let mut transport = hs.into_transport_mode().unwrap();
    let n = transport.write_message(&[], &mut buf).unwrap();
    let confirmation = prefixed(&buf[..n]);
    s.write_all(&confirmation).await.unwrap();
    let mut rx = listener.subscribe();
    tokio::time::timeout(PATIENCE, rx.wait_for(|l| l.len() == 1))
        .await
        .unwrap()
        .unwrap();
    drop(s);
    tokio::time::timeout(PATIENCE, rx.wait_for(|l| l.is_empty()))
        .await
        .unwrap()
        .unwrap();

    // Replayed on a new connection: the server answers the first message
    // (it cannot tell a replay from a new session) but the recorded
    // confirmation does not verify against the new session's keys, so the
    // connection closes with no link made and no frame sent.
    let mut s = TcpStream::connect(addr).await.unwrap();
    s.write_all(&first).await.unwrap();
    let fresh = read_prefixed(&mut s).await;
    assert_ne!(fresh, answer, "a new session must use new ephemeral keys");
    s.write_all(&confirmation).await.unwrap();
    assert_eq!(read_until_closed(&mut s).await, b"");
    wait_failures(&listener, 1).await;
    assert!(listener.links().is_empty());
}

#[tokio::test]
async fn truncated_and_oversized_handshakes_are_closed_silently() {
    let (_server, listener, addr) = keyed_server("keyed-server").await;
    let mut hs = initiator(&SECRET);
    let mut msg = [0u8; 256];
    let n = hs.write_message(&[], &mut msg).unwrap();
    let whole = prefixed(&msg[..n]);

    // Cut short, then the writer closes: closed at once.
    let mut s = TcpStream::connect(addr).await.unwrap();
    s.write_all(&whole[..10]).await.unwrap();
    s.shutdown().await.unwrap();
    assert_eq!(read_until_closed(&mut s).await, b"");
    // Cut short and left hanging: closed at the handshake timeout.
    let mut s = TcpStream::connect(addr).await.unwrap();
    s.write_all(&whole[..10]).await.unwrap();
    assert_eq!(read_until_closed(&mut s).await, b"");
    // A length far past any handshake message: closed without reading it.
    let mut s = TcpStream::connect(addr).await.unwrap();
    s.write_all(&[0xff, 0xff]).await.unwrap();
    s.write_all(&[0u8; 1000]).await.unwrap();
    assert_eq!(read_until_closed(&mut s).await, b"");
    wait_failures(&listener, 3).await;
    assert!(listener.links().is_empty());
}

#[tokio::test]
async fn oversized_or_forged_frames_after_the_handshake() {
    let (_server, listener, addr) = keyed_server("keyed-server").await;
    let mut s = TcpStream::connect(addr).await.unwrap();
    let mut hs = initiator(&SECRET);
    let mut buf = vec![0u8; 65_535];
    let n = hs.write_message(&[], &mut buf).unwrap();
    s.write_all(&prefixed(&buf[..n])).await.unwrap();
    let answer = read_prefixed(&mut s).await;
    hs.read_message(&answer, &mut buf).unwrap();
    let mut transport = hs.into_transport_mode().unwrap();
    let n = transport.write_message(&[], &mut buf).unwrap();
    s.write_all(&prefixed(&buf[..n])).await.unwrap();
    let index = {
        let mut rx = listener.subscribe();
        let l = tokio::time::timeout(PATIENCE, rx.wait_for(|l| l.len() == 1))
            .await
            .unwrap()
            .unwrap();
        l[0].index
    };
    // A largest message whose plaintext is one frame far longer than a
    // packet: dropped and counted, the link stays.
    let mut plain = vec![1u8; 65_535 - 16];
    *plain.last_mut().unwrap() = 0;
    let n = transport.write_message(&plain, &mut buf).unwrap();
    assert_eq!(n, 65_535);
    s.write_all(&prefixed(&buf[..n])).await.unwrap();
    // Then a name request, framed as a runtime frames it: answered.
    let request = name_request().await;
    let mut frame = vec![0u8; max_frame_len(request.len())];
    let len = encode_frame(&request, &mut frame).unwrap();
    let n = transport.write_message(&frame[..len], &mut buf).unwrap();
    s.write_all(&prefixed(&buf[..n])).await.unwrap();
    let mut plain = Vec::new();
    let mut out = vec![0u8; 65_535];
    tokio::time::timeout(PATIENCE, async {
        while !plain.windows(12).any(|w| w == b"keyed-server") {
            let reply = read_prefixed(&mut s).await;
            let m = transport.read_message(&reply, &mut out).unwrap();
            plain.extend_from_slice(&out[..m]);
        }
    })
    .await
    .expect("no reply after an oversized frame");
    assert_eq!(listener.links()[0].index, index);
    // A forged message (not encrypted with the session's key): closed.
    s.write_all(&prefixed(&[0x55; 64])).await.unwrap();
    let _ = read_until_closed(&mut s).await;
    let mut rx = listener.subscribe();
    tokio::time::timeout(PATIENCE, rx.wait_for(|l| l.is_empty()))
        .await
        .unwrap()
        .unwrap();
}

/// The bytes a host puts on a link to ask its neighbour's name, captured
/// from a real host.
async fn name_request() -> Vec<u8> {
    let host = Host::start(HostConfig::named("capture")).unwrap();
    let (index, io) = host
        .add_link(osap_host::LinkConfig::new("capture", "x"))
        .await
        .unwrap();
    io.set_open(true);
    let port = host.open_port("capture").await.unwrap();
    let route = Route::through_links(&[index]).unwrap();
    let asking = tokio::spawn(async move {
        let _ = port.request(&route, 0, &[key::NAME], PATIENCE).await;
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

fn temp_path(tag: &str) -> PathBuf {
    std::env::temp_dir().join(format!("osap-key-{}-{tag}", std::process::id()))
}

#[test]
fn key_files_are_made_private_and_checked() {
    use std::os::unix::fs::PermissionsExt;
    let path = temp_path("file");
    let _ = std::fs::remove_file(&path);
    let key = Key::write_new(&path).unwrap();
    let mode = std::fs::metadata(&path).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode, 0o600);
    assert_eq!(Key::load(&path).unwrap(), key);
    // Not overwritten.
    let err = Key::write_new(&path).unwrap_err().to_string();
    assert!(err.contains("exists"), "{err}");
    // Readable by others: refused, naming the fix.
    std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o644)).unwrap();
    let err = Key::load(&path).unwrap_err().to_string();
    assert!(err.contains("chmod 600"), "{err}");
    std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o600)).unwrap();
    std::fs::write(&path, "not a key\n").unwrap();
    assert!(Key::load(&path).is_err());
    std::fs::remove_file(&path).unwrap();
}

#[tokio::test]
async fn remote_listeners_need_a_key() {
    let host = Host::start(HostConfig::named("b")).unwrap();
    let any: SocketAddr = "0.0.0.0:0".parse().unwrap();
    let options = ListenOptions {
        allow_remote: true,
        ..ListenOptions::default()
    };
    let err = tcp::listen_with(&host, any, options.clone())
        .await
        .unwrap_err()
        .to_string();
    assert!(err.contains("osap keygen"), "{err}");
    let keyed = ListenOptions {
        key: Some(Key::from_bytes(SECRET)),
        ..options
    };
    tcp::listen_with(&host, any, keyed).await.unwrap();
}
