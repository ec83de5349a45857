//! The netresponder (port 0) answers every query across the network.

use osap_core::clock::TimeConfig;
use osap_core::codec::{Reader, Writer};
use osap_core::netresponder::{key, Level, Status};
use osap_core::route::Route;
use osap_core::transport::Transport;
use osap_tests::{request, Net};

/// A two-node network: a (link 0) -- (link 1) b, b has one test port.
fn pair() -> (Net, usize, usize) {
    let mut net = Net::new();
    let a = net.node("host", 1, 1);
    let b = net.node("module-b", 2, 1);
    net.wire(a, 0, b, 1);
    (net, a, b)
}

/// Sends one request body to b's port 0 and returns the reply's
/// `(status, fields)` after checking the transport and key.
fn ask(net: &mut Net, a: usize, seq: u16, body: &[u8]) -> (Status, Vec<u8>) {
    let before = net.nodes[a].ports[0].received.len();
    let route = Route::through_links(&[0]).unwrap();
    net.port(a, 1).queue(route, 0, 10_000, &request(seq, body));
    net.run_until(10, 20, |n| n.nodes[a].ports[0].received.len() > before)
        .expect("netresponder replied");
    let reply = net.nodes[a].ports[0].received[before].clone();
    assert_eq!(reply.source_port, 0);
    let (t, rest) = Transport::decode(&reply.payload).unwrap();
    assert_eq!(t, Transport::Reply(seq));
    assert_eq!(rest[0], body[0], "reply echoes the key");
    (Status::from_u8(rest[1]).unwrap(), rest[2..].to_vec())
}

#[test]
fn runtime_info_returns_the_previous_scan_id() {
    let (mut net, a, _) = pair();
    let (s, f) = ask(&mut net, a, 1, &[key::RUNTIME_INFO, 7, 0, 0, 0]);
    assert_eq!(s, Status::Ok);
    let mut r = Reader::new(&f);
    assert_eq!(r.u32().unwrap(), 0, "never scanned before");
    assert_eq!(r.array::<3>().unwrap(), [0, 0, 0]);
    assert_eq!(r.u8().unwrap(), 0, "build key");
    assert_eq!(r.u16().unwrap(), 256, "packet size");
    assert_eq!(r.u16().unwrap(), 2, "port 0 and one test port");
    assert_eq!(r.u8().unwrap(), 2, "links");
    assert_eq!(r.u8().unwrap(), 255, "unsynced tier");
    assert_eq!(r.u8().unwrap(), 1, "the request came in on b's link 1");
    assert_eq!(r.u32().unwrap(), 0, "function set: none declared");
    assert!(r.is_empty());
    // The next scan sees the id of the last one: that is how a scanner
    // recognises a runtime it already visited through another path.
    let (_, f) = ask(&mut net, a, 2, &[key::RUNTIME_INFO, 8, 0, 0, 0]);
    assert_eq!(Reader::new(&f).u32().unwrap(), 7);
}

#[test]
fn names_read_and_set() {
    let (mut net, a, b) = pair();
    let (_, f) = ask(&mut net, a, 1, &[key::TYPE_NAME]);
    assert_eq!(Reader::new(&f).str8().unwrap(), "test_node");
    let (_, f) = ask(&mut net, a, 2, &[key::NAME]);
    assert_eq!(Reader::new(&f).str8().unwrap(), "module-b");
    let mut body = vec![key::SET_NAME, 6];
    body.extend_from_slice(b"x-axis");
    let (s, f) = ask(&mut net, a, 3, &body);
    assert_eq!(s, Status::Ok);
    assert_eq!(Reader::new(&f).str8().unwrap(), "x-axis");
    assert_eq!(net.nodes[b].runtime.identity().name.as_str(), "x-axis");
    assert!(net.nodes[b].runtime.take_changes().name);
    assert!(!net.nodes[b].runtime.take_changes().name, "taken once");
    // Too long: refused, name unchanged.
    let mut long = vec![key::SET_NAME, 40];
    long.extend_from_slice(&[b'a'; 40]);
    assert_eq!(ask(&mut net, a, 4, &long).0, Status::InvalidValue);
    // Not UTF-8: malformed.
    assert_eq!(
        ask(&mut net, a, 5, &[key::SET_NAME, 1, 0xff]).0,
        Status::Malformed
    );
    assert_eq!(net.nodes[b].runtime.identity().name.as_str(), "x-axis");
}

#[test]
fn link_and_port_info() {
    let (mut net, a, _) = pair();
    let (s, f) = ask(&mut net, a, 1, &[key::LINK_INFO, 1]);
    assert_eq!(s, Status::Ok);
    let mut r = Reader::new(&f);
    assert_eq!(r.u8().unwrap(), 1);
    assert_eq!(r.u8().unwrap(), 1, "open");
    assert_eq!(r.u16().unwrap(), 256, "mtu");
    assert_eq!(r.str8().unwrap(), "queue");
    assert_eq!(r.str8().unwrap(), "");
    assert_eq!(
        ask(&mut net, a, 2, &[key::LINK_INFO, 2]).0,
        Status::NoSuchIndex
    );
    let (_, f) = ask(&mut net, a, 3, &[key::PORT_INFO, 0, 0]);
    let mut r = Reader::new(&f);
    assert_eq!(r.u16().unwrap(), 0);
    assert_eq!(r.str8().unwrap(), "netresponder");
    let (_, f) = ask(&mut net, a, 4, &[key::PORT_INFO, 1, 0]);
    let mut r = Reader::new(&f);
    assert_eq!(r.u16().unwrap(), 1);
    assert_eq!(r.str8().unwrap(), "test");
    assert_eq!(
        ask(&mut net, a, 5, &[key::PORT_INFO, 2, 0]).0,
        Status::NoSuchIndex
    );
}

#[test]
fn debug_messages_and_verbosity() {
    let (mut net, a, b) = pair();
    let rt = &mut net.nodes[b].runtime;
    rt.log(Level::Info, format_args!("boot {}", 1));
    rt.log(Level::Debug, format_args!("hidden at info verbosity"));
    rt.log(
        Level::Warn,
        format_args!(
            "{}",
            "a line far longer than any log line may be, so it is cut"
        ),
    );
    let (s, f) = ask(&mut net, a, 1, &[key::DEBUG_MESSAGES, 0, 0, 0, 0]);
    assert_eq!(s, Status::Ok);
    let mut r = Reader::new(&f);
    assert_eq!(r.u32().unwrap(), 2, "next sequence number");
    assert_eq!(r.u8().unwrap(), 2, "two lines");
    assert_eq!((r.u32().unwrap(), r.u8().unwrap()), (0, Level::Info as u8));
    assert_eq!(r.str8().unwrap(), "boot 1");
    assert_eq!((r.u32().unwrap(), r.u8().unwrap()), (1, Level::Warn as u8));
    assert_eq!(
        r.str8().unwrap().len(),
        osap_core::netresponder::LOG_LINE_MAX
    );
    // Only newer lines when asked from a sequence number.
    let (_, f) = ask(&mut net, a, 2, &[key::DEBUG_MESSAGES, 1, 0, 0, 0]);
    assert_eq!(f[4], 1);
    // Debug verbosity keeps debug lines.
    assert_eq!(ask(&mut net, a, 3, &[key::SET_VERBOSITY, 3]).0, Status::Ok);
    assert_eq!(
        ask(&mut net, a, 4, &[key::SET_VERBOSITY, 9]).0,
        Status::InvalidValue
    );
    let rt = &mut net.nodes[b].runtime;
    rt.log(Level::Debug, format_args!("now kept"));
    assert_eq!(
        rt.netresponder().log_lines().last().unwrap().text.as_str(),
        "now kept"
    );
}

#[test]
fn time_config_read_write_and_validation() {
    let (mut net, a, b) = pair();
    let (s, f) = ask(&mut net, a, 1, &[key::GET_TIME_CONFIG]);
    assert_eq!(s, Status::Ok);
    let quiet = TimeConfig {
        enabled: false,
        ..TimeConfig::default()
    };
    assert_eq!(TimeConfig::decode(&f).unwrap(), quiet);
    let wanted = TimeConfig {
        root: true,
        interval_us: 20_000,
        kp: 0.8,
        ..quiet
    };
    let mut buf = [0u8; 64];
    let mut w = Writer::new(&mut buf);
    w.u8(key::SET_TIME_CONFIG).unwrap();
    wanted.encode(&mut w).unwrap();
    let n = w.len();
    let (s, f) = ask(&mut net, a, 2, &buf[..n]);
    assert_eq!(s, Status::Ok);
    assert_eq!(TimeConfig::decode(&f).unwrap(), wanted);
    assert_eq!(*net.nodes[b].runtime.clock().config(), wanted);
    assert!(net.nodes[b].runtime.take_changes().time_config);
    // An interval of 0 is refused and changes nothing.
    buf[3..7].copy_from_slice(&0u32.to_le_bytes());
    assert_eq!(ask(&mut net, a, 3, &buf[..n]).0, Status::InvalidValue);
    assert_eq!(ask(&mut net, a, 4, &buf[..n - 1]).0, Status::Malformed);
    assert_eq!(*net.nodes[b].runtime.clock().config(), wanted);
}

#[test]
fn counters_and_bad_requests() {
    let (mut net, a, b) = pair();
    assert_eq!(ask(&mut net, a, 1, &[0x7f]).0, Status::UnknownKey);
    assert_eq!(
        ask(&mut net, a, 2, &[key::TYPE_NAME, 0]).0,
        Status::Malformed
    );
    assert_eq!(
        ask(&mut net, a, 3, &[key::RUNTIME_INFO, 1]).0,
        Status::Malformed
    );
    let (s, f) = ask(&mut net, a, 4, &[key::COUNTERS]);
    assert_eq!(s, Status::Ok);
    assert_eq!(f.len(), 15 * 4);
    let mut r = Reader::new(&f);
    let received = r.u32().unwrap();
    assert_eq!(received, 4, "four requests received from the link");
    // A raw datagram to port 0 is not a request: dropped and counted.
    let route = Route::through_links(&[0]).unwrap();
    net.port(a, 1).queue(route, 0, 10_000, &[0, key::NAME]);
    net.run_until(10, 10, |_| false);
    assert_eq!(net.nodes[b].runtime.counters().netresponder_errors, 1);
}

#[test]
fn clock_status_and_hot_start_rate() {
    use osap_core::clock::{SyncState, CLOCK_STATUS_LEN};
    let (mut net, a, b) = pair();
    let (s, f) = ask(&mut net, a, 1, &[key::TIME_STATUS]);
    assert_eq!(s, Status::Ok);
    assert_eq!(f.len(), CLOCK_STATUS_LEN);
    assert_eq!(f[0], 255, "no root anywhere: unsynced");
    assert_eq!(f[1], SyncState::Unsynced as u8);
    // Hot start: write a learned rate; it reads back (clamped to the config).
    let mut body = vec![key::SET_CLOCK_RATE];
    body.extend_from_slice(&(-37_000i32).to_le_bytes());
    let (s, f) = ask(&mut net, a, 2, &body);
    assert_eq!(s, Status::Ok);
    let applied = i32::from_le_bytes(f[..4].try_into().unwrap());
    assert!((applied + 37_000).abs() < 10, "applied {applied}");
    assert!((net.nodes[b].runtime.clock().rate_ppb() + 37_000).abs() < 10);
    let mut body = vec![key::SET_CLOCK_RATE];
    body.extend_from_slice(&i32::MAX.to_le_bytes());
    let (_, f) = ask(&mut net, a, 3, &body);
    let applied = i32::from_le_bytes(f[..4].try_into().unwrap());
    assert!(
        (applied - 500_000).abs() < 100,
        "clamped to 500 ppm, got {applied}"
    );
    assert_eq!(
        ask(&mut net, a, 4, &[key::SET_CLOCK_RATE, 1]).0,
        Status::Malformed
    );
}
