//! The golden vectors in `docs/protocol.md` are checked here: every vector
//! in the document must be known to this test and must match what the code
//! encodes, and decoding it must give back its meaning. Run with
//! `OSAP_PRINT_VECTORS=1` to print the vectors as the code produces them.

use osap_core::clock::{ClockStatus, SyncState, SyncStats, TimeConfig, TimeReply};
use osap_core::codec::Writer;
use osap_core::framing::{encode_frame, FrameDecoder};
use osap_core::netresponder::key;
use osap_core::packet::{Instruction, Packet};
use osap_core::route::Route;
use osap_core::time::{Instant, SystemInstant};
use osap_core::transport::Transport;
use std::collections::BTreeMap;

mod support {
    pub(crate) mod doc_vectors;
}
use support::doc_vectors::hex;

/// Vectors in `docs/protocol.md`: fenced blocks opened with "```hex name".
fn document_vectors() -> BTreeMap<String, Vec<u8>> {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/protocol.md");
    let doc = std::fs::read_to_string(path).expect("docs/protocol.md");
    support::doc_vectors::document_vectors(&doc, "hex")
}

fn ins(i: Instruction) -> Vec<u8> {
    let mut b = [0u8; 3];
    let n = i.encode(&mut b).unwrap();
    b[..n].to_vec()
}

fn packet(route: &Route, terminal: Instruction, ttl: u16, mtu: u16, payload: &[u8]) -> Vec<u8> {
    let mut b = [0u8; 256];
    let n = route
        .write_packet(&mut b, terminal, ttl, mtu, payload)
        .unwrap();
    b[..n].to_vec()
}

fn body(f: impl FnOnce(&mut Writer<'_>)) -> Vec<u8> {
    let mut b = [0u8; 256];
    let mut w = Writer::new(&mut b);
    f(&mut w);
    let n = w.len();
    b[..n].to_vec()
}

fn transport(t: Transport, rest: &[u8]) -> Vec<u8> {
    let mut b = vec![0u8; t.encoded_len()];
    t.encode(&mut b).unwrap();
    b.extend_from_slice(rest);
    b
}

/// Every vector, as the code produces it from its meaning.
fn code_vectors() -> BTreeMap<String, Vec<u8>> {
    let mut v = BTreeMap::new();
    let mut put = |k: &str, b: Vec<u8>| {
        v.insert(k.to_string(), b);
    };
    put("instruction.system_msg.1", ins(Instruction::SystemMsg(1)));
    put(
        "instruction.link_forward.5",
        ins(Instruction::LinkForward(5)),
    );
    put(
        "instruction.bus_forward.3.broadcast",
        ins(Instruction::BusForward { bus: 3, drop: 255 }),
    );
    put(
        "instruction.port_handle.1.2",
        ins(Instruction::PortHandle { src: 1, dst: 2 }),
    );
    put(
        "instruction.port_handle.2047.5",
        ins(Instruction::PortHandle { src: 2047, dst: 5 }),
    );
    put("transport.raw", transport(Transport::Raw, &[]));
    put(
        "transport.request.0x1234",
        transport(Transport::Request(0x1234), &[]),
    );
    put(
        "transport.reply.0x1234",
        transport(Transport::Reply(0x1234), &[]),
    );

    let local = packet(
        &Route::local(),
        Instruction::PortHandle { src: 1, dst: 2 },
        1000,
        256,
        &[0x00, 0x2a],
    );
    put("packet.local", local.clone());
    put("frame.packet.local", {
        let mut f = [0u8; 64];
        let n = encode_frame(&local, &mut f).unwrap();
        f[..n].to_vec()
    });

    // Port 3 asks the neighbour on link 1 for its type name (request 0x0102).
    let ask = packet(
        &Route::through_links(&[1]).unwrap(),
        Instruction::PortHandle { src: 3, dst: 0 },
        10_000,
        128,
        &transport(Transport::Request(0x0102), &[key::TYPE_NAME]),
    );
    put("packet.type_name_request", ask.clone());
    // The neighbour took it in on its link 2.
    let mut arrived = ask.clone();
    Packet::new_checked(&mut arrived[..])
        .unwrap()
        .ingest(Instruction::LinkForward(2))
        .unwrap();
    put("packet.type_name_request.after_ingest", arrived);
    // Its reply goes back over its link 2 to port 3.
    let mut name_body = vec![key::TYPE_NAME, 0];
    name_body.extend(body(|w| w.str8("stepper").unwrap()));
    put(
        "packet.type_name_reply",
        packet(
            &Route::through_links(&[2]).unwrap(),
            Instruction::PortHandle { src: 0, dst: 3 },
            20_000,
            128,
            &transport(Transport::Reply(0x0102), &name_body),
        ),
    );

    // Two hops out: link 1 here, link 4 at the next runtime.
    put(
        "packet.two_hops",
        packet(
            &Route::through_links(&[1, 4]).unwrap(),
            Instruction::PortHandle { src: 1, dst: 2 },
            5_000,
            64,
            &[0x00, 0xaa],
        ),
    );

    put(
        "packet.time_request",
        packet(
            &Route::through_links(&[0]).unwrap(),
            Instruction::SystemMsg(0),
            20_000,
            256,
            &body(|w| w.u64(1_000_000).unwrap()),
        ),
    );
    put(
        "body.time_reply",
        body(|w| {
            TimeReply {
                request_time: Instant::from_micros(1_000_000),
                responder_time: SystemInstant::from_micros(1_000_250),
                responder_tier: 1,
            }
            .encode(w)
            .unwrap()
        }),
    );

    put(
        "netresponder.runtime_info.request",
        body(|w| {
            w.u8(key::RUNTIME_INFO).unwrap();
            w.u32(0x0000_0010).unwrap();
        }),
    );
    put(
        "netresponder.runtime_info.reply",
        body(|w| {
            w.u8(key::RUNTIME_INFO).unwrap();
            w.u8(0).unwrap();
            w.u32(0x0000_000f).unwrap(); // previous scan id
            w.bytes(&[0, 1, 2]).unwrap(); // version 0.1.2
            w.u8(1).unwrap(); // build: osap-rs embedded
            w.u16(256).unwrap(); // packet size
            w.u16(5).unwrap(); // ports
            w.u8(2).unwrap(); // links
            w.u8(255).unwrap(); // tier
            w.u8(1).unwrap(); // arrived on link 1
            w.u32(0x96fb_3630).unwrap(); // function-set id
        }),
    );
    put(
        "netresponder.link_info.reply",
        body(|w| {
            w.u8(key::LINK_INFO).unwrap();
            w.u8(0).unwrap();
            w.u8(1).unwrap(); // index
            w.u8(1).unwrap(); // open, a neighbour heard
            w.u16(128).unwrap(); // mtu
            w.str8("uart").unwrap();
            w.str8("").unwrap();
        }),
    );
    put(
        "netresponder.port_info.reply",
        body(|w| {
            w.u8(key::PORT_INFO).unwrap();
            w.u8(0).unwrap();
            w.u16(0).unwrap();
            w.str8("netresponder").unwrap();
            w.str8("").unwrap();
        }),
    );
    put(
        "netresponder.set_name.request",
        body(|w| {
            w.u8(key::SET_NAME).unwrap();
            w.str8("x-axis").unwrap();
        }),
    );
    put("netresponder.error.no_such_index", vec![key::PORT_INFO, 3]);
    put(
        "netresponder.time_config.default",
        body(|w| TimeConfig::default().encode(w).unwrap()),
    );
    put(
        "netresponder.time_status.example",
        body(|w| {
            ClockStatus {
                tier: 2,
                state: SyncState::Synced,
                offset_ns: -1_500,
                rate_ppb: 42_000,
                following: 1,
                last_rtt_us: 310,
                min_rtt_us: 298,
                stats: SyncStats {
                    samples: 1200,
                    accepted: 1150,
                    rejected_rtt: 40,
                    rejected_residual: 9,
                    bogus: 1,
                    jumps: 1,
                    untrusted: 3,
                    deferred_steps: 0,
                },
                settled: true,
                motion_active: false,
            }
            .encode(w)
            .unwrap()
        }),
    );
    v.extend(segment_vectors());
    v
}

#[test]
fn document_vectors_match_the_code() {
    let code = code_vectors();
    if std::env::var_os("OSAP_PRINT_VECTORS").is_some() {
        for (k, b) in &code {
            println!("```hex {k}\n{}\n```", hex(b));
        }
    }
    let doc = document_vectors();
    for (name, bytes) in &doc {
        let expected = code
            .get(name)
            .unwrap_or_else(|| panic!("docs/protocol.md has vector {name} that no test checks"));
        assert_eq!(hex(bytes), hex(expected), "vector {name}");
    }
    for name in code.keys() {
        assert!(
            doc.contains_key(name),
            "vector {name} is missing from docs/protocol.md"
        );
    }
}

#[test]
fn document_vectors_decode_to_their_meaning() {
    let doc = document_vectors();
    let get = |k: &str| doc.get(k).unwrap_or_else(|| panic!("missing {k}")).clone();

    assert_eq!(
        Instruction::decode(&get("instruction.port_handle.2047.5")),
        Ok(Instruction::PortHandle { src: 2047, dst: 5 })
    );
    assert_eq!(
        Instruction::decode(&get("instruction.bus_forward.3.broadcast")),
        Ok(Instruction::BusForward { bus: 3, drop: 255 })
    );

    let local = get("packet.local");
    let p = Packet::new_checked(&local[..]).unwrap();
    assert_eq!((p.ptr(), p.ttl(), p.mtu()), (5, 1000, 256));
    assert_eq!(
        p.instruction(),
        Ok(Instruction::PortHandle { src: 1, dst: 2 })
    );
    assert_eq!(p.after_instruction(), Ok(&[0x00, 0x2a][..]));

    let mut dec = FrameDecoder::<64>::new();
    let frame = get("frame.packet.local");
    let mut input = &frame[..];
    assert_eq!(dec.decode(&mut input), Some(Ok(&local[..])));

    let arrived = get("packet.type_name_request.after_ingest");
    let p = Packet::new_checked(&arrived[..]).unwrap();
    assert_eq!(p.ptr(), 6);
    assert_eq!(p.walked(), &[0x42]);
    assert_eq!(
        p.instruction(),
        Ok(Instruction::PortHandle { src: 3, dst: 0 })
    );
    let (t, rest) = Transport::decode(p.after_instruction().unwrap()).unwrap();
    assert_eq!(
        (t, rest),
        (Transport::Request(0x0102), &[key::TYPE_NAME][..])
    );

    let two = get("packet.two_hops");
    let p = Packet::new_checked(&two[..]).unwrap();
    assert_eq!(Route::from_bytes(&two[5..7]), Route::through_links(&[1, 4]));
    assert_eq!(p.instruction(), Ok(Instruction::LinkForward(1)));

    let reply = TimeReply::decode(&get("body.time_reply")).unwrap();
    assert_eq!(
        reply.responder_time.as_micros() - reply.request_time.as_micros(),
        250
    );
    assert_eq!(
        TimeConfig::decode(&get("netresponder.time_config.default")),
        Ok(TimeConfig::default())
    );
}

/// The `add` signature reply (pipes.md §5) to request 0x1234, 22 bytes,
/// as a sender whose packets take 16 payload bytes cuts it (§3).
fn segmented_reply() -> (Vec<u8>, osap_core::segment::Plan) {
    let sig = [
        0x03, b'a', b'd', b'd', 0x02, 0x01, b'a', 0x22, 0x01, b'b', 0x22, 0x01, 0x03, b's', b'u',
        b'm', 0x22,
    ];
    let mut body = vec![0x02, 0x00];
    body.extend(sig);
    let whole = transport(Transport::Reply(0x1234), &body);
    let plan = osap_core::segment::Plan::new(whole.len(), 16).unwrap();
    (whole, plan)
}

fn segment_vectors() -> BTreeMap<String, Vec<u8>> {
    use osap_core::segment::{SegmentHeader, HEADER_LEN};
    let (whole, plan) = segmented_reply();
    (0..plan.count)
        .map(|i| {
            let mut s = vec![0u8; HEADER_LEN];
            SegmentHeader {
                id: 7,
                index: i,
                count: plan.count,
                len: plan.len,
            }
            .encode(&mut s)
            .unwrap();
            let at = plan.offset(i);
            s.extend_from_slice(&whole[at..at + plan.body_len(i)]);
            (format!("segment.reply.{i}_of_{}", plan.count), s)
        })
        .collect()
}

#[test]
fn segment_vectors_reassemble_to_the_reply() {
    use osap_core::segment::Reassembler;
    let doc = document_vectors();
    let (whole, _) = segmented_reply();
    let mut r: Reassembler<1, 64> = Reassembler::new();
    let route = Route::through_links(&[2]).unwrap();
    let mut out = None;
    // Out of order, one duplicate.
    for k in [
        "segment.reply.2_of_3",
        "segment.reply.0_of_3",
        "segment.reply.0_of_3",
        "segment.reply.1_of_3",
    ] {
        let seg = doc.get(k).unwrap_or_else(|| panic!("missing {k}"));
        if let Some(d) = r.on_segment(Instant::ZERO, &route, 1, seg).unwrap() {
            out = Some(d.to_vec());
        }
    }
    assert_eq!(out.as_deref(), Some(&whole[..]));
    let (t, body) = Transport::decode(&whole).unwrap();
    assert_eq!(
        (t, &body[..2]),
        (Transport::Reply(0x1234), &[0x02, 0x00][..])
    );
    assert_eq!(r.stats().duplicates, 1);
}
