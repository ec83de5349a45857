//! The golden vectors of the function protocol (`docs/pipes.md` §5, fenced
//! blocks opened with "```hex-fn name"): every one must equal what the code
//! encodes, decode back to its meaning, and every vector here must be in
//! the document and vice versa. `PIPES_PRINT_VECTORS=1` prints them.

use std::collections::BTreeMap;

use osap_core::codec::{Reader, Writer};
use osap_core::route::Route;
use pipes_core::control::{
    encode_described_reply, encode_error, encode_signature_reply, ControlError, ControlKey,
    InputMode, Reply, ReplyBody, Request, ANY_SLOT,
};
use pipes_core::failure::{Failure, SignatureParts};
use pipes_core::pipe::{PipeConfig, PipeStats};
use pipes_core::signature::{Arg, Signature, SignatureView};
use pipes_core::{Args, ArgsWriter, ConvertError, ConvertReason, ScalarType, Type, Value};

const F32: Type = Type::Scalar(ScalarType::F32);
const F64: Type = Type::Scalar(ScalarType::F64);

static ADD: Signature = Signature {
    name: "add",
    inputs: &[Arg::new("a", F32), Arg::new("b", F32)],
    outputs: &[Arg::new("sum", F32)],
};

/// `add`'s failure table: what a reply to `[2][1]` appends.
static ADD_FAILURES: [Failure; 1] = [Failure {
    code: 1,
    name: "Overflow",
    reason: "the sum is not finite: add smaller numbers",
}];

/// `add`'s documentation: what a reply to `[2][06]` carries.
const ADD_DOCS: &str = "Adds a and b.\nRounds to nearest.";

#[path = "../../osap-core/tests/support/doc_vectors.rs"]
mod doc_vectors;
use doc_vectors::hex;

/// Vectors in `docs/pipes.md`: fenced blocks opened with "```hex-fn name".
fn document_vectors() -> BTreeMap<String, Vec<u8>> {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/pipes.md");
    let doc = std::fs::read_to_string(path).expect("docs/pipes.md");
    doc_vectors::document_vectors(&doc, "hex-fn")
}

fn enc(f: impl FnOnce(&mut Writer<'_>)) -> Vec<u8> {
    let mut b = vec![0u8; 256];
    let mut w = Writer::new(&mut b);
    f(&mut w);
    let n = w.len();
    b.truncate(n);
    b
}

fn args(vals: &[(u8, Value<'_>)]) -> Vec<u8> {
    enc(|w| {
        let mut a = ArgsWriter::new(w).unwrap();
        for (i, v) in vals {
            a.push(*i, v).unwrap();
        }
        a.finish().unwrap();
    })
}

fn code_vectors() -> BTreeMap<String, Vec<u8>> {
    let mut v = BTreeMap::new();
    let mut put = |k: &str, b: Vec<u8>| assert!(v.insert(k.to_string(), b).is_none());
    let call_args = args(&[(0, Value::F32(1.0)), (1, Value::F32(2.0))]);
    let call = Args::decode(&mut Reader::new(&call_args)).unwrap();
    let ret_args = args(&[(0, Value::F32(3.0))]);
    let ret = Args::decode(&mut Reader::new(&ret_args)).unwrap();
    let pipe = PipeConfig::new(Route::through_links(&[1]).unwrap().with_mtu(128), 2, 10_000)
        .with(0, 1)
        .unwrap();
    put("fn.signature.add", enc(|w| ADD.encode(w).unwrap()));
    put(
        "fn.request.get_signature",
        enc(|w| Request::GetSignature.encode(w).unwrap()),
    );
    put(
        "fn.reply.get_signature.add",
        enc(|w| encode_signature_reply(w, &ADD).unwrap()),
    );
    put(
        "fn.request.get_signature.failures",
        enc(|w| {
            Request::Describe(SignatureParts::FAILURES)
                .encode(w)
                .unwrap()
        }),
    );
    put(
        "fn.reply.get_signature.add.failures",
        enc(|w| {
            encode_described_reply(w, &ADD, SignatureParts::FAILURES, &ADD_FAILURES, "").unwrap()
        }),
    );
    let docs = SignatureParts::SUMMARY.with(SignatureParts::DOCS);
    put(
        "fn.request.get_signature.docs",
        enc(|w| Request::Describe(docs).encode(w).unwrap()),
    );
    put(
        "fn.reply.get_signature.add.docs",
        enc(|w| encode_described_reply(w, &ADD, docs, &[], ADD_DOCS).unwrap()),
    );
    put(
        "fn.reply.get_signature.add.no_docs",
        enc(|w| encode_described_reply(w, &ADD, docs, &[], "").unwrap()),
    );
    put(
        "fn.request.call.add",
        enc(|w| Request::Call(call).encode(w).unwrap()),
    );
    put(
        "fn.reply.call.add",
        enc(|w| {
            Reply {
                key: ControlKey::Call.to_u8(),
                result: Ok(ReplyBody::Returned(ret)),
            }
            .encode(w)
            .unwrap()
        }),
    );
    put(
        "fn.request.set_pipe",
        enc(|w| {
            Request::SetPipe {
                slot: ANY_SLOT,
                pipe,
            }
            .encode(w)
            .unwrap()
        }),
    );
    put(
        "fn.reply.set_pipe",
        enc(|w| {
            Reply {
                key: ControlKey::SetPipe.to_u8(),
                result: Ok(ReplyBody::PipeSet(0)),
            }
            .encode(w)
            .unwrap()
        }),
    );
    put(
        "fn.reply.get_pipe_count",
        enc(|w| {
            Reply {
                key: ControlKey::GetPipeCount.to_u8(),
                result: Ok(ReplyBody::PipeCount { slots: 2, used: 1 }),
            }
            .encode(w)
            .unwrap()
        }),
    );
    put(
        "fn.request.set_input_mode.on_timer_1ms",
        enc(|w| {
            Request::SetInputMode(InputMode::OnTimer(1000))
                .encode(w)
                .unwrap()
        }),
    );
    put(
        "fn.reply.error.wrong_arg_count",
        enc(|w| {
            encode_error(
                w,
                3,
                &ControlError::WrongArgCount {
                    expected: 2,
                    got: 1,
                },
            )
            .unwrap()
        }),
    );
    let lossy = ConvertError {
        from: F64,
        to: F32,
        reason: ConvertReason::Lossy,
        element: None,
    };
    put(
        "fn.reply.error.convert_lossy",
        enc(|w| {
            encode_error(
                w,
                3,
                &ControlError::Convert {
                    index: 1,
                    error: lossy,
                },
            )
            .unwrap()
        }),
    );
    put(
        "fn.reply.error.pipe_table_full",
        enc(|w| encode_error(w, 6, &ControlError::PipeTableFull).unwrap()),
    );
    put(
        "fn.pipe_error.no_such_input",
        enc(|w| {
            encode_error(
                w,
                ControlKey::PipeError.to_u8(),
                &ControlError::NoSuchInput(5),
            )
            .unwrap()
        }),
    );
    put(
        "fn.request.get_pipe_stats",
        enc(|w| Request::GetPipeStats(0).encode(w).unwrap()),
    );
    put(
        "fn.reply.get_pipe_stats",
        enc(|w| {
            Reply {
                key: ControlKey::GetPipeStats.to_u8(),
                result: Ok(ReplyBody::PipeStats {
                    slot: 0,
                    stats: PipeStats {
                        sent: 3,
                        overflows: 2,
                        send_errors: 0,
                        remote_errors: 1,
                        acked: 2,
                        retries: 1,
                        failures: 0,
                        last_remote_error: Some(ControlError::NoSuchInput(5)),
                    },
                }),
            }
            .encode(w)
            .unwrap()
        }),
    );
    put(
        "fn.reply.error.no_such_pipe",
        enc(|w| {
            encode_error(
                w,
                ControlKey::GetPipeStats.to_u8(),
                &ControlError::NoSuchPipe(1),
            )
            .unwrap()
        }),
    );
    v
}

#[test]
fn document_matches_code() {
    let code = code_vectors();
    if std::env::var_os("PIPES_PRINT_VECTORS").is_some() {
        for (k, b) in &code {
            println!("```hex-fn {k}\n{}\n```\n", hex(b));
        }
    }
    let doc = document_vectors();
    for (k, b) in &code {
        let d = doc
            .get(k)
            .unwrap_or_else(|| panic!("{k} missing from docs/pipes.md"));
        assert_eq!(hex(d), hex(b), "{k}");
    }
    for k in doc.keys() {
        assert!(
            code.contains_key(k),
            "{k} in docs/pipes.md is unknown to the test"
        );
    }
}

#[test]
fn document_vectors_decode() {
    let doc = document_vectors();
    for (k, b) in &doc {
        if k == "fn.signature.add" {
            assert!(ADD.matches(&SignatureView::parse(b).unwrap()));
        } else if k.starts_with("fn.request.") {
            let r = Request::parse(b).unwrap();
            let mut again = vec![0u8; 256];
            let mut w = Writer::new(&mut again);
            r.encode(&mut w).unwrap();
            let n = w.len();
            assert_eq!(&again[..n], &b[..], "{k}");
        } else {
            let r = Reply::parse(b).unwrap();
            assert_eq!(
                k.contains(".error.") || k.contains("pipe_error"),
                r.result.is_err(),
                "{k}"
            );
            let mut again = vec![0u8; 256];
            let mut w = Writer::new(&mut again);
            r.encode(&mut w).unwrap();
            let n = w.len();
            assert_eq!(&again[..n], &b[..], "{k}");
        }
    }
}

#[test]
fn the_docs_vectors_read_as_their_text() {
    let doc = document_vectors();
    let read = |k: &str| -> (Option<String>, Option<String>) {
        let b = &doc[k];
        let Ok(ReplyBody::Signature(s)) = Reply::parse(b).unwrap().result else {
            panic!("{k}: not a signature reply")
        };
        assert!(ADD.matches(&s), "{k}");
        assert_eq!(s.failures(), None, "{k}");
        (s.summary().map(str::to_owned), s.docs().map(str::to_owned))
    };
    assert_eq!(
        read("fn.reply.get_signature.add.docs"),
        (Some("Adds a and b.".into()), Some(ADD_DOCS.into()))
    );
    assert_eq!(
        read("fn.reply.get_signature.add.no_docs"),
        (Some(String::new()), Some(String::new()))
    );
    let old = &doc["fn.reply.get_signature.add"];
    let Ok(ReplyBody::Signature(s)) = Reply::parse(old).unwrap().result else {
        panic!("not a signature reply")
    };
    assert_eq!((s.summary(), s.docs()), (None, None));
}
