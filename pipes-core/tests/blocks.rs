//! The block manager over the wire: classes listed, blocks made, used,
//! refused and deleted, on runtime B of the two-runtime harness.

mod common;

use common::{args, err, ok, returned, to_b, Net, TestFn};
use osap_core::codec::{Reader, Writer};
use osap_core::port::Port;
use osap_core::transport::Transport;
use pipes_core::control::{ControlError, ReplyBody, Request};
use pipes_core::function::{CallError, Implementation, Outputs};
use pipes_core::manager::{
    parse_reply, BlockClass, BlockFactory, BlockName, Blocks, ClassPart, ManagerError,
    ManagerReply, ManagerRequest, BLOCK_PORT_TYPE, END, FREE_PORT_TYPE, MANAGER_PORT_TYPE,
};
use pipes_core::signature::{Arg, Signature};
use pipes_core::{Args, FailureCode, ScalarType, Type, Value};
use proptest::prelude::*;

const F32: Type = Type::Scalar(ScalarType::F32);
const U32: Type = Type::Scalar(ScalarType::U32);

static GAIN_NEW: Signature = Signature {
    name: "gain",
    inputs: &[Arg::new("k", F32)],
    outputs: &[],
};
static GAIN: Signature = Signature {
    name: "gain",
    inputs: &[Arg::new("x", F32)],
    outputs: &[Arg::new("y", F32)],
};
static COUNT_NEW: Signature = Signature {
    name: "count",
    inputs: &[],
    outputs: &[],
};
static COUNT: Signature = Signature {
    name: "count",
    inputs: &[],
    outputs: &[Arg::new("n", U32)],
};

static CLASSES: [BlockClass; 2] = [
    BlockClass {
        constructor: &GAIN_NEW,
        block: &GAIN,
        capacity: 1,
        input_mode: pipes_core::control::InputMode::OnAnyFresh,
        output_mode: pipes_core::control::OutputMode::Always,
    },
    BlockClass {
        constructor: &COUNT_NEW,
        block: &COUNT,
        capacity: 1,
        input_mode: pipes_core::control::InputMode::OnAnyFresh,
        output_mode: pipes_core::control::OutputMode::OnChange,
    },
];

/// A gain refuses a k that is not finite, with code 1.
struct Block {
    name: BlockName,
    k: Option<f32>,
    n: u32,
}

impl Implementation for Block {
    fn signature(&self) -> &'static Signature {
        if self.k.is_some() {
            &GAIN
        } else {
            &COUNT
        }
    }
    fn name(&self) -> &str {
        self.name.as_str()
    }
    fn call(&mut self, inputs: &[Value<'_>], outputs: &mut Outputs<'_>) -> Result<(), CallError> {
        match (self.k, inputs) {
            (Some(k), [Value::F32(x)]) => outputs.set(0, &Value::F32(k * x)),
            (None, []) => {
                self.n += 1;
                outputs.set(0, &Value::U32(self.n))
            }
            _ => Err(CallError::Failed(FailureCode::Other(2))),
        }
    }
}

struct Factory;

impl BlockFactory for Factory {
    type Block = Block;
    fn classes(&self) -> &'static [BlockClass] {
        &CLASSES
    }
    fn make(
        &mut self,
        class: usize,
        _slot: u8,
        name: BlockName,
        inputs: &[Value<'_>],
    ) -> Result<Block, CallError> {
        match (class, inputs) {
            (0, [Value::F32(k)]) if k.is_finite() => Ok(Block {
                name,
                k: Some(*k),
                n: 0,
            }),
            (0, _) => Err(CallError::Failed(FailureCode::Other(1))),
            _ => Ok(Block {
                name,
                k: None,
                n: 0,
            }),
        }
    }
}

// The harness's runtimes have 8 port indices: the pool takes 1 to 7.
type Pool = Blocks<Factory, 2, 2, 2, 64>;

/// B holds the pool at port 1 (its manager) and slots from port 2 on.
fn net() -> Net {
    let pool: Box<dyn TestFn> = Box::new(Pool::new(Factory).unwrap());
    Net::new(vec![], vec![pool])
}

const MANAGER: u16 = 1;

fn ask(net: &mut Net, req: ManagerRequest<'_>) -> Vec<u8> {
    let seq = net.next_seq();
    let mut buf = [0u8; 200];
    Transport::Request(seq).encode(&mut buf).unwrap();
    let mut w = Writer::new(&mut buf[3..]);
    req.encode(&mut w).unwrap();
    let n = 3 + w.len();
    let before = net.host().received.len();
    net.host().queue(to_b(), MANAGER, 10_000, &buf[..n]);
    for _ in 0..20 {
        net.step();
        // Skip what a block's pipe sent the host meanwhile.
        let reply = net.host().received[before..].iter().find_map(|p| {
            match Transport::decode(&p.payload) {
                Ok((Transport::Reply(s), body)) if s == seq => Some(body.to_vec()),
                _ => None,
            }
        });
        if let Some(body) = reply {
            return body;
        }
    }
    panic!("no reply to {req:?}");
}

fn new_block(
    net: &mut Net,
    class: u8,
    name: &str,
    vals: &[(u8, Value<'_>)],
) -> Result<(u8, u16), ManagerError> {
    let a = args(vals);
    let args = Args::decode(&mut Reader::new(&a)).unwrap();
    let reply = ask(net, ManagerRequest::NewBlock { class, name, args });
    match parse_reply(&reply).unwrap() {
        (3, Ok(ManagerReply::Created { slot, offset })) => Ok((slot, offset)),
        (3, Err(e)) => Err(e),
        other => panic!("{other:?}"),
    }
}

fn pool(net: &mut Net) -> &mut Pool {
    net.on_b::<Pool>(0)
}

#[test]
fn classes_are_listed_with_their_signatures() {
    let mut net = net();
    let reply = ask(&mut net, ManagerRequest::ListClasses { from: 0 });
    let (_, Ok(ManagerReply::Classes(page))) = parse_reply(&reply).unwrap() else {
        panic!()
    };
    assert_eq!(page.next, END);
    let names: Vec<_> = page
        .classes()
        .map(|c| (c.class, c.name, c.capacity, c.used))
        .collect();
    assert_eq!(names, [(0, "gain", 1, 0), (1, "count", 1, 0)]);
    let reply = ask(
        &mut net,
        ManagerRequest::GetClass {
            class: 0,
            part: ClassPart::Constructor,
        },
    );
    let (
        _,
        Ok(ManagerReply::Class {
            signature, part, ..
        }),
    ) = parse_reply(&reply).unwrap()
    else {
        panic!()
    };
    assert_eq!(part, ClassPart::Constructor);
    assert!(GAIN_NEW.matches(&signature));
    let reply = ask(
        &mut net,
        ManagerRequest::GetClass {
            class: 0,
            part: ClassPart::Block,
        },
    );
    let (_, Ok(ManagerReply::Class { signature, .. })) = parse_reply(&reply).unwrap() else {
        panic!()
    };
    assert!(GAIN.matches(&signature));
    let reply = ask(
        &mut net,
        ManagerRequest::GetClass {
            class: 2,
            part: ClassPart::Block,
        },
    );
    assert_eq!(
        parse_reply(&reply).unwrap().1,
        Err(ManagerError::NoSuchClass(2))
    );
}

#[test]
fn a_block_is_made_used_like_a_function_and_deleted() {
    let mut net = net();
    // Free slots reserve their ports from the start.
    assert_eq!(pool(&mut net).port_count(), 1 + 2 * 3);
    assert_eq!(pool(&mut net).info(0).type_name, MANAGER_PORT_TYPE);
    assert_eq!(pool(&mut net).info(1).type_name, FREE_PORT_TYPE);

    let (slot, offset) = new_block(&mut net, 0, "double", &[(0, Value::F32(2.0))]).unwrap();
    assert_eq!((slot, offset), (0, 1));
    let p = pool(&mut net);
    let info = p.info(offset);
    assert_eq!((info.type_name, info.name), (BLOCK_PORT_TYPE, "double"));
    // A function like any other, at the manager's port + offset, answering
    // to its own name.
    let port = MANAGER + offset;
    let body = net.ask(to_b(), port, &Request::GetSignature);
    let ReplyBody::Signature(s) = ok(&body) else {
        panic!()
    };
    assert_eq!(s.name(), "double");
    assert_eq!(s.inputs().get(0).unwrap().name, "x");
    let body = net.call(to_b(), port, &[(0, Value::F32(1.5))]);
    assert_eq!(returned(&body), [Value::F32(3.0)]);

    // The pool of gains is full; the count class has its own slot.
    assert_eq!(
        new_block(&mut net, 0, "triple", &[(0, Value::I8(3))]),
        Err(ManagerError::PoolFull(0))
    );
    assert_eq!(new_block(&mut net, 1, "ticks", &[]), Ok((1, 4)));
    let body = net.call(to_b(), MANAGER + 4, &[]);
    assert_eq!(returned(&body), [Value::U32(1)]);

    // Listed, by slot.
    let reply = ask(&mut net, ManagerRequest::ListBlocks { from: 0 });
    let (_, Ok(ManagerReply::Blocks(page))) = parse_reply(&reply).unwrap() else {
        panic!()
    };
    let listed: Vec<_> = page
        .blocks()
        .map(|b| (b.slot, b.class, b.offset, b.name))
        .collect();
    assert_eq!(listed, [(0, 0, 1, "double"), (1, 1, 4, "ticks")]);
    assert_eq!(page.next, END);
    // One at a time, with the arguments it was made with (converted).
    let reply = ask(&mut net, ManagerRequest::GetBlock { slot: 0 });
    let (
        _,
        Ok(ManagerReply::Block {
            slot: 0,
            block: Some((entry, args)),
        }),
    ) = parse_reply(&reply).unwrap()
    else {
        panic!()
    };
    assert_eq!((entry.name, entry.class, entry.offset), ("double", 0, 1));
    assert_eq!(args.iter().collect::<Vec<_>>(), [(0, Value::F32(2.0))]);

    // Deleted: its ports are free again and it answers nothing.
    let reply = ask(&mut net, ManagerRequest::DeleteBlock { name: "double" });
    assert_eq!(
        parse_reply(&reply).unwrap().1,
        Ok(ManagerReply::Deleted { slot: 0 })
    );
    assert_eq!(pool(&mut net).info(offset).type_name, FREE_PORT_TYPE);
    assert!(pool(&mut net).block("double").is_none());
    let reply = ask(&mut net, ManagerRequest::DeleteBlock { name: "double" });
    assert_eq!(
        parse_reply(&reply).unwrap().1,
        Err(ManagerError::NoSuchBlock)
    );
    // Its slot takes a new gain.
    assert_eq!(
        new_block(&mut net, 0, "quad", &[(0, Value::F32(4.0))]),
        Ok((0, 1))
    );
    assert_eq!(pool(&mut net).stats().created, 3);
    assert_eq!(pool(&mut net).stats().deleted, 1);
}

#[test]
fn bad_requests_are_refused_and_change_nothing() {
    let mut net = net();
    new_block(&mut net, 1, "g", &[]).unwrap();
    type Case<'a> = (u8, &'a str, Vec<(u8, Value<'a>)>, ManagerError);
    let cases: [Case<'_>; 8] = [
        (0, "g", vec![(0, Value::F32(1.0))], ManagerError::NameTaken),
        (
            0,
            "9lives",
            vec![(0, Value::F32(1.0))],
            ManagerError::BadName,
        ),
        (
            0,
            "has space",
            vec![(0, Value::F32(1.0))],
            ManagerError::BadName,
        ),
        (
            0,
            "a_name_that_is_too_long_x",
            vec![(0, Value::F32(1.0))],
            ManagerError::BadName,
        ),
        (
            0,
            "h",
            vec![],
            ManagerError::WrongArgCount {
                expected: 1,
                got: 0,
            },
        ),
        (
            0,
            "h",
            vec![(0, Value::F32(f32::NAN))],
            ManagerError::Failed(FailureCode::Other(1)),
        ),
        (5, "h", vec![], ManagerError::NoSuchClass(5)),
        (1, "h", vec![], ManagerError::PoolFull(1)),
    ];
    for (class, name, vals, want) in cases {
        assert_eq!(new_block(&mut net, class, name, &vals), Err(want), "{name}");
    }
    // A lossy conversion is refused as a call's would be.
    let e = new_block(&mut net, 0, "h", &[(0, Value::F64(0.1))]).unwrap_err();
    assert!(matches!(e, ManagerError::Convert { index: 0, .. }), "{e:?}");
    assert_eq!(
        new_block(&mut net, 0, "h", &[(3, Value::F32(1.0))]),
        Err(ManagerError::NoSuchInput(3))
    );
    assert_eq!(pool(&mut net).slots().iter().flatten().count(), 1);
    assert_eq!(pool(&mut net).stats().refused, 10);
    // An unknown key, and a request with bytes left over.
    let seq = net.next_seq();
    let mut buf = [0u8; 8];
    Transport::Request(seq).encode(&mut buf).unwrap();
    buf[3] = 9;
    net.host().queue(to_b(), MANAGER, 10_000, &buf[..4]);
    net.steps(5);
    let p = net.host().received.last().unwrap().payload.clone();
    let (_, body) = Transport::decode(&p).unwrap();
    assert_eq!(
        parse_reply(body).unwrap(),
        (9, Err(ManagerError::UnknownKey(9)))
    );
}

#[test]
fn a_deleted_block_takes_its_pipes_with_it() {
    use pipes_core::pipe::PipeConfig;
    let mut net = net();
    let (_, offset) = new_block(&mut net, 1, "ticks", &[]).unwrap();
    assert_eq!(offset, 4);
    // A pipe from the block back to the host port (A port 1; from B, link 0 leads to A).
    let pipe = PipeConfig::new(to_b(), 1, 10_000).with(0, 0).unwrap();
    let body = net.ask(
        to_b(),
        MANAGER + offset,
        &Request::SetPipe { slot: 0xff, pipe },
    );
    assert!(matches!(ok(&body), ReplyBody::PipeSet(0)));
    // Runs on a timer, sending each new count.
    let body = net.ask(
        to_b(),
        MANAGER + offset,
        &Request::SetInputMode(pipes_core::control::InputMode::OnTimer(1000)),
    );
    ok(&body);
    let before = net.host().received.len();
    net.steps(50);
    let sent = net.host().received.len() - before;
    assert!((3..=6).contains(&sent), "{sent} datagrams in 5 ms at 1 kHz");
    ask(&mut net, ManagerRequest::DeleteBlock { name: "ticks" });
    let before = net.host().received.len();
    net.steps(50);
    assert_eq!(
        net.host().received.len(),
        before,
        "a deleted block sends nothing"
    );
    // A request to its old port is dropped, and counted.
    let malformed = pool(&mut net).stats().malformed;
    let seq = net.next_seq();
    let mut buf = [0u8; 8];
    Transport::Request(seq).encode(&mut buf).unwrap();
    buf[3] = 2;
    net.host()
        .queue(to_b(), MANAGER + offset, 10_000, &buf[..4]);
    net.steps(5);
    assert_eq!(pool(&mut net).stats().malformed, malformed + 1);
    assert_eq!(net.host().received.len(), before);
    let _ = err;
    let _: Option<ControlError> = None;
}

#[test]
fn long_lists_come_in_pages() {
    let mut net = net();
    let names = ["a_rather_long_name_no_01", "a_rather_long_name_no_02"];
    new_block(&mut net, 0, names[0], &[(0, Value::F32(1.0))]).unwrap();
    new_block(&mut net, 1, names[1], &[]).unwrap();
    let mut from = 0;
    let mut seen = Vec::new();
    let mut pages = 0;
    while from != END {
        let reply = ask(&mut net, ManagerRequest::ListBlocks { from });
        let (_, Ok(ManagerReply::Blocks(page))) = parse_reply(&reply).unwrap() else {
            panic!()
        };
        assert!(
            reply.len() <= 48 - 3,
            "a page fits any route: {} bytes",
            reply.len()
        );
        seen.extend(page.blocks().map(|b| b.name.to_string()));
        from = page.next;
        pages += 1;
    }
    assert_eq!(seen, names);
    assert!(pages >= 2);
}

proptest! {
    /// Any bytes to the manager are answered or dropped, never a panic, and
    /// any reply bytes parse or are refused.
    #[test]
    fn arbitrary_requests_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..64)) {
        let _ = ManagerRequest::parse(&bytes);
        let _ = parse_reply(&bytes);
        let mut pool = Pool::new(Factory).unwrap();
        if let Ok(ManagerRequest::NewBlock { class, name, args }) = ManagerRequest::parse(&bytes) {
            let _ = pool.create(class, name, &args);
        }
    }
}
