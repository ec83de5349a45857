//! Signatures longer than one packet: a function whose signature does not
//! fit a 64-byte link is still read whole by a scan. Host h – module a over
//! an in-process link with a 64-byte MTU; the reply travels as segments
//! (osap_core::segment) and h's port reassembles it.

use osap_core::route::Route;
use osap_host::link::{ChannelLink, LinkConfig};
use osap_host::som::{attach_function, HostFunction, Manager, Value};
use osap_host::{Host, HostConfig};
use pipes_core::control::{ControlKey, Reply, ReplyBody, Request};
use pipes_core::{ScalarType, Type};
use std::time::Duration;

mod common;
use common::{host, refresh};

const F32: Type = Type::Scalar(ScalarType::F32);
const MTU: u16 = 64;

/// Joins `a` and `b` with an in-process link of `mtu` bytes.
async fn connect_small(a: &Host, b: &Host, mtu: u16) {
    let mut config = LinkConfig::new("memory", "small");
    config.mtu = mtu;
    let (mut la, io_a) = a.make_link(config.clone());
    let (mut lb, io_b) = b.make_link(config);
    ChannelLink::join(&mut la, &mut lb);
    a.attach_link(la).await.unwrap();
    b.attach_link(lb).await.unwrap();
    io_a.set_open(true);
    io_b.set_open(true);
}

const INPUTS: [&str; 6] = [
    "maximum_velocity_mm_per_s",
    "maximum_acceleration_mm_per_s2",
    "maximum_jerk_mm_per_s3",
    "steps_per_millimetre",
    "current_scale_fraction",
    "homing_direction_sign",
];

/// h – a (64-byte MTU); a has `configure_axis`, whose signature takes
/// 190 bytes. a holds at most 2 packets per port, as a microcontroller
/// does, so its reply goes out over several loops.
async fn net() -> (Host, Host) {
    let mut config = HostConfig::named("a");
    config.runtime.port_quota = 2;
    let (h, a) = (host("h"), Host::start(config).unwrap());
    let inputs: Vec<(&str, Type)> = INPUTS.iter().map(|n| (*n, F32)).collect();
    let f = HostFunction::new(
        "configure_axis",
        &inputs,
        &[
            ("accepted", Type::Scalar(ScalarType::Bool)),
            ("limited_velocity", F32),
        ],
        |_| Ok(vec![Value::Bool(true), Value::F32(1.0)]),
    )
    .unwrap()
    .with_docs(&long_docs())
    .unwrap();
    attach_function(&a, f).await.unwrap();
    connect_small(&h, &a, MTU).await;
    (h, a)
}

/// `configure_axis`'s documentation: 1.9 KB, multi-byte characters
/// (`µ`, `°`) cut across segment boundaries.
fn long_docs() -> String {
    let mut docs = String::from("Configures one axis: limits in mm/s, mm/s² and mm/s³.\n\n");
    for i in 0..38 {
        docs.push_str(&format!(
            "Line {i:02}: steps every 25 µs at 40 °C, or else.\n"
        ));
    }
    docs.truncate(docs.trim_end().len());
    assert!(docs.len() > 1800 && docs.len() <= pipes_core::docs::MAX_DOCS);
    docs
}

#[tokio::test]
async fn documentation_longer_than_many_packets_is_read_whole() {
    let (h, _a) = net().await;
    let mut m = Manager::new(&h).await.unwrap();
    refresh(&mut m).await;
    let f = &m.som().runtimes[1].functions[0];
    assert_eq!(
        f.summary,
        "Configures one axis: limits in mm/s, mm/s² and mm/s³."
    );
    let fref = osap_host::som::FnRef::new("a", "configure_axis");
    let d = m.describe(&fref).await.unwrap();
    assert_eq!(d.docs, long_docs());
    assert_eq!(d.summary, f.summary);
    assert!(d.failures.as_ref().unwrap().is_empty());
    // The same through a handle.
    let d2 = m.function(&fref).unwrap().describe().await.unwrap();
    assert_eq!(d2, d);

    // Over the wire: a reply of 30-odd segments, read whole, byte for byte.
    let port = h.open_port("script").await.unwrap();
    let route = Route::through_links(&[0]).unwrap().with_mtu(MTU);
    let mut b = vec![0u8; 4];
    let mut w = osap_core::codec::Writer::new(&mut b);
    Request::Describe(pipes_core::failure::SignatureParts::DOCS)
        .encode(&mut w)
        .unwrap();
    let n = w.len();
    b.truncate(n);
    let reply = port
        .request(&route, 1, &b, Duration::from_millis(2000))
        .await
        .unwrap();
    let Ok(ReplyBody::Signature(sig)) = Reply::parse(&reply.body).unwrap().result else {
        panic!("not a signature reply")
    };
    assert_eq!(sig.docs(), Some(long_docs().as_str()));
    assert_eq!(sig.summary(), None, "not asked for");
    let st = port.segment_stats();
    assert_eq!(st.delivered, 1);
    assert!(st.segments >= 30, "{st:?}");
    assert_eq!((st.lost, st.malformed, st.duplicates), (0, 0, 0));
}

#[tokio::test]
async fn a_signature_longer_than_a_packet_is_read_by_a_scan() {
    let (h, _a) = net().await;
    let mut m = Manager::new(&h).await.unwrap();
    refresh(&mut m).await;
    let som = m.som();
    let a = &som.runtimes[1];
    assert_eq!(a.record.route_mtu, MTU);
    assert_eq!(a.functions.len(), 1);
    let f = &a.functions[0];
    assert_eq!(f.name, "configure_axis");
    let names: Vec<_> = f.inputs.iter().map(|i| i.name.as_str()).collect();
    assert_eq!(names, INPUTS);
    assert!(f.inputs.iter().all(|i| i.type_name == "f32"));
    let outs: Vec<_> = f.outputs.iter().map(|o| o.name.as_str()).collect();
    assert_eq!(outs, ["accepted", "limited_velocity"]);
}

#[tokio::test]
async fn long_replies_arrive_in_segments_and_short_ones_in_one_packet() {
    let (h, _a) = net().await;
    let port = h.open_port("script").await.unwrap();
    let route = Route::through_links(&[0]).unwrap().with_mtu(MTU);
    let function_port = 1;
    let ask = |req: Request<'static>| {
        let mut b = vec![0u8; 16];
        let mut w = osap_core::codec::Writer::new(&mut b);
        req.encode(&mut w).unwrap();
        let n = w.len();
        b.truncate(n);
        b
    };

    let reply = port
        .request(
            &route,
            function_port,
            &ask(Request::GetSignature),
            Duration::from_millis(500),
        )
        .await
        .unwrap();
    assert!(reply.body.len() > usize::from(MTU), "{}", reply.body.len());
    let parsed = Reply::parse(&reply.body).unwrap();
    assert_eq!(parsed.key, ControlKey::GetSignature.to_u8());
    let Ok(ReplyBody::Signature(sig)) = parsed.result else {
        panic!("{parsed:?}")
    };
    assert_eq!(sig.name(), "configure_axis");
    assert_eq!(sig.inputs().len(), 6);
    let st = port.segment_stats();
    assert_eq!(st.delivered, 1);
    assert!(st.segments >= 4, "{st:?}");
    assert_eq!((st.lost, st.malformed, st.duplicates), (0, 0, 0));

    // A short reply stays one packet.
    let reply = port
        .request(
            &route,
            function_port,
            &ask(Request::GetInputMode),
            Duration::from_millis(500),
        )
        .await
        .unwrap();
    assert_eq!(reply.body[..2], [ControlKey::GetInputMode.to_u8(), 0]);
    assert_eq!(port.segment_stats(), st);
}
