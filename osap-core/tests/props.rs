//! Property tests: instruction codec, routes and their reversal, the packet
//! stack against a simple model, and the runtime under arbitrary input.

use osap_core::link::queue::QueueLink;
use osap_core::packet::{Instruction, Packet};
use osap_core::port::{Delivery, Port, PortInfo, PortTx};
use osap_core::route::{Route, MAX_ROUTE_LEN};
use osap_core::stack::{ClaimError, Owner, PacketStack, PushError};
use osap_core::time::Instant;
use osap_core::Runtime;
use proptest::prelude::*;

fn instruction() -> impl Strategy<Value = Instruction> {
    prop_oneof![
        (0u8..64).prop_map(Instruction::SystemMsg),
        (0u8..64).prop_map(Instruction::LinkForward),
        (0u8..64, any::<u8>()).prop_map(|(bus, drop)| Instruction::BusForward { bus, drop }),
        (0u16..2048, 0u16..2048).prop_map(|(src, dst)| Instruction::PortHandle { src, dst }),
    ]
}

fn hop() -> impl Strategy<Value = Instruction> {
    prop_oneof![
        4 => (0u8..64).prop_map(Instruction::LinkForward),
        1 => (0u8..64, any::<u8>()).prop_map(|(bus, drop)| Instruction::BusForward { bus, drop }),
    ]
}

fn route() -> impl Strategy<Value = Route> {
    prop::collection::vec(hop(), 0..16).prop_filter_map("fits", |hops| {
        let mut r = Route::local();
        for h in hops {
            r.push(h).ok()?;
        }
        Some(r)
    })
}

proptest! {
    #[test]
    fn instruction_round_trip(i in instruction()) {
        let mut b = [0u8; 3];
        let n = i.encode(&mut b).unwrap();
        prop_assert_eq!(n, i.encoded_len());
        prop_assert_eq!(Instruction::len_from_first_byte(b[0]), n);
        prop_assert_eq!(Instruction::decode(&b[..n]), Ok(i));
    }

    #[test]
    fn any_bytes_decode_without_panic(bytes in prop::collection::vec(any::<u8>(), 0..8)) {
        if let Ok(i) = Instruction::decode(&bytes) {
            let mut b = [0u8; 3];
            let n = i.encode(&mut b).unwrap();
            prop_assert_eq!(&b[..n], &bytes[..n]);
        }
        let _ = Route::from_bytes(&bytes);
        let _ = Packet::new_checked(&bytes[..]).map(|p| (p.instruction(), p.after_instruction(), p.walked()));
    }

    #[test]
    fn route_bytes_round_trip_and_reversal(r in route()) {
        prop_assert_eq!(Route::from_bytes(r.as_bytes()), Ok(r));
        prop_assert_eq!(r.reversed().reversed(), r);
        let fwd: Vec<_> = r.hops().collect();
        let mut back: Vec<_> = r.reversed().hops().collect();
        back.reverse();
        prop_assert_eq!(fwd, back);
        prop_assert_eq!(r.reversed().len(), r.len());
    }

    /// Walk a packet hop by hop through runtimes that each received it on
    /// some link: the reversed walked route lists those links back to front.
    #[test]
    fn walking_then_reversing_leads_back(
        out_links in prop::collection::vec(0u8..64, 1..MAX_ROUTE_LEN),
        arrival_links in prop::collection::vec(0u8..64, MAX_ROUTE_LEN),
        payload in prop::collection::vec(any::<u8>(), 0..32),
    ) {
        let route = Route::through_links(&out_links).unwrap();
        let mut buf = [0u8; 128];
        let n = route
            .write_packet(&mut buf, Instruction::PortHandle { src: 9, dst: 4 }, 1000, 128, &payload)
            .unwrap();
        let mut pkt = Packet::new_checked(&mut buf[..n]).unwrap();
        for &arrived_on in &arrival_links[..out_links.len()] {
            pkt.ingest(Instruction::LinkForward(arrived_on)).unwrap();
        }
        let view = Packet::new_checked(pkt.into_inner() as &[u8]).unwrap();
        prop_assert_eq!(view.instruction(), Ok(Instruction::PortHandle { src: 9, dst: 4 }));
        prop_assert_eq!(view.after_instruction(), Ok(&payload[..]));
        let back = Route::from_bytes(view.walked()).unwrap().reversed();
        let expected: Vec<_> = arrival_links[..out_links.len()]
            .iter()
            .rev()
            .map(|&l| Instruction::LinkForward(l))
            .collect();
        prop_assert_eq!(back.hops().collect::<Vec<_>>(), expected);
    }
}

#[derive(Debug, Clone)]
enum Op {
    Push { owner: Owner, deadline: u64 },
    Release { pos: usize },
}

fn op() -> impl Strategy<Value = Op> {
    let owner = prop_oneof![
        (0u16..5).prop_map(Owner::Port),
        (0u8..3).prop_map(Owner::Link),
        Just(Owner::System),
    ];
    prop_oneof![
        3 => (owner, 0u64..20).prop_map(|(owner, deadline)| Op::Push { owner, deadline }),
        2 => (0usize..10).prop_map(|pos| Op::Release { pos }),
    ]
}

proptest! {
    /// The stack always lists packets by serving key (a packet's deadline,
    /// or its owner's newest queued packet's key if later), first come
    /// first served among equal keys, so one owner's packets stay in the
    /// order they came; it never lets an owner past its quota, never loses
    /// a slot, and finds the earliest deadline wherever it is.
    #[test]
    fn stack_matches_model(ops in prop::collection::vec(op(), 1..200)) {
        const N: usize = 8;
        let mut stack: PacketStack<N, 8, 4, 2> = PacketStack::new();
        // Model: (key, insertion number, owner, deadline), kept sorted by
        // key.
        let mut model: Vec<(u64, usize, Owner, u64)> = Vec::new();
        let quota = |o: Owner| match o {
            Owner::Port(_) => 2,
            Owner::Link(_) => 4,
            Owner::System => 4,
        };
        for (serial, op) in ops.into_iter().enumerate() {
            match op {
                Op::Push { owner, deadline } => {
                    let held = model.iter().filter(|m| m.2 == owner).count();
                    let expect = match owner {
                        Owner::Port(p) if p >= 4 => Err(ClaimError::UnknownOwner),
                        Owner::Link(l) if l >= 2 => Err(ClaimError::UnknownOwner),
                        _ if held >= quota(owner) => Err(ClaimError::QuotaExceeded),
                        _ if model.len() >= N => Err(ClaimError::StackFull),
                        _ => Ok(()),
                    };
                    let got = stack.push_with(owner, Instant::ZERO, |buf| {
                        buf[..8].copy_from_slice(&(serial as u64).to_le_bytes());
                        Ok::<_, ()>((8, Instant::from_micros(deadline)))
                    });
                    match (expect, got) {
                        (Ok(()), Ok(_)) => {
                            let key = model
                                .iter()
                                .filter(|m| m.2 == owner)
                                .map(|m| m.0)
                                .fold(deadline, u64::max);
                            let at = model.partition_point(|m| m.0 <= key);
                            model.insert(at, (key, serial, owner, deadline));
                        }
                        (Err(e), Err(PushError::Claim(g))) => prop_assert_eq!(e, g),
                        (e, g) => prop_assert!(false, "expected {:?}, got {:?}", e, g),
                    }
                }
                Op::Release { pos } => {
                    let got = stack.release_at(pos);
                    if pos < model.len() {
                        let m = model.remove(pos);
                        prop_assert_eq!(got.map(|g| (g.deadline.as_micros(), g.owner)), Some((m.3, m.2)));
                    } else {
                        prop_assert!(got.is_none());
                    }
                }
            }
            prop_assert_eq!(stack.len(), model.len());
            prop_assert_eq!(stack.len() + stack.free_slots(), N);
            for (pos, m) in model.iter().enumerate() {
                let slot = stack.at(pos).unwrap();
                prop_assert_eq!(stack.meta(slot).deadline.as_micros(), m.3);
                prop_assert_eq!(stack.packet(slot), &(m.1 as u64).to_le_bytes()[..]);
            }
            // Each owner's packets in the order they came.
            for o in model.iter().map(|m| m.2) {
                let serials: Vec<usize> =
                    model.iter().filter(|m| m.2 == o).map(|m| m.1).collect();
                prop_assert!(serials.windows(2).all(|w| w[0] < w[1]));
            }
            prop_assert_eq!(
                stack.earliest_deadline().map(|d| d.as_micros()),
                model.iter().map(|m| m.3).min()
            );
        }
    }
}

struct Sink(usize);

impl Port for Sink {
    fn info(&self, _: u16) -> PortInfo<'_> {
        PortInfo {
            type_name: "sink",
            name: "",
        }
    }
    fn on_packet(&mut self, _: Delivery<'_>, _: &mut PortTx<'_>) {
        self.0 += 1;
    }
}

fn netresponder_request() -> impl Strategy<Value = Vec<u8>> {
    (prop::collection::vec(any::<u8>(), 0..40), 0u8..16).prop_map(|(mut body, key)| {
        let route = Route::through_links(&[0]).unwrap();
        body.insert(0, key);
        let mut payload = vec![1, 0, 0];
        payload.extend(body);
        let mut buf = [0u8; 128];
        let n = route
            .write_packet(
                &mut buf,
                Instruction::PortHandle { src: 1, dst: 0 },
                1000,
                128,
                &payload,
            )
            .unwrap();
        buf[..n].to_vec()
    })
}

proptest! {
    /// Whatever arrives on a link, the runtime takes it in, never panics,
    /// and empties its stack once every deadline has passed.
    #[test]
    fn runtime_survives_arbitrary_packets(
        packets in prop::collection::vec(
            prop_oneof![
                prop::collection::vec(any::<u8>(), 0..80),
                netresponder_request(),
            ],
            0..24,
        ),
    ) {
        let mut rt: Runtime<8, 128, 4, 2> = Runtime::new("fuzz", "rt").unwrap();
        let mut links = [QueueLink::<32, 128>::new(), QueueLink::<32, 128>::new()];
        let mut ports = [Sink(0)];
        for p in &packets {
            prop_assert!(links[0].inject(p));
        }
        let mut now = 0;
        for _ in 0..40 {
            rt.poll(Instant::from_micros(now), &mut ports, &mut links);
            while links[0].take_sent().is_some() {}
            while links[1].take_sent().is_some() {}
            now += 5_000;
        }
        rt.poll(Instant::from_micros(now + 70_000), &mut ports, &mut links);
        prop_assert_eq!(rt.stack().len(), 0);
        prop_assert_eq!(rt.counters().received as usize, packets.len());
    }
}
