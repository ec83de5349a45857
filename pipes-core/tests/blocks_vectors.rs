//! The golden vectors of the block manager (`docs/pipes.md` §7, fenced
//! blocks opened with "```hex-blocks name"): every one must equal what the
//! code encodes and decode back to the same bytes, and every vector here
//! must be in the document and vice versa. `PIPES_PRINT_VECTORS=1` prints
//! them.

use std::collections::BTreeMap;

use osap_core::codec::{Reader, Writer};
use pipes_core::manager::{
    parse_reply, write_block_entry, write_class_entry, BlockEntry, ClassEntry, ClassPart,
    ManagerError, ManagerRequest, BAD_ARGUMENT, END,
};
use pipes_core::signature::{Arg, Signature};
use pipes_core::{Args, ArgsWriter, FailureCode, ScalarType, Type, Value};

#[path = "../../osap-core/tests/support/doc_vectors.rs"]
mod doc_vectors;
use doc_vectors::hex;

const F32: Type = Type::Scalar(ScalarType::F32);

/// A `scale` class: `scale(gain: f32, offset: f32)`.
static SCALE_NEW: Signature = Signature {
    name: "scale",
    inputs: &[Arg::new("gain", F32), Arg::new("offset", F32)],
    outputs: &[],
};

fn document_vectors() -> BTreeMap<String, Vec<u8>> {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/pipes.md");
    let doc = std::fs::read_to_string(path).expect("docs/pipes.md");
    doc_vectors::document_vectors(&doc, "hex-blocks")
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

/// `[key][0]` then `body`.
fn ok(key: u8, body: impl FnOnce(&mut Writer<'_>)) -> Vec<u8> {
    enc(|w| {
        w.u8(key).unwrap();
        w.u8(0).unwrap();
        body(w);
    })
}

fn refused(key: u8, e: ManagerError) -> Vec<u8> {
    enc(|w| {
        w.u8(key).unwrap();
        e.encode(w).unwrap();
    })
}

fn code_vectors() -> BTreeMap<String, Vec<u8>> {
    let mut v = BTreeMap::new();
    let mut put = |k: &str, b: Vec<u8>| assert!(v.insert(k.to_string(), b).is_none());
    let req = |r: ManagerRequest<'_>| enc(|w| r.encode(w).unwrap());
    let half = args(&[(0, Value::F32(0.5)), (1, Value::F32(-1.0))]);
    let half_args = Args::decode(&mut Reader::new(&half)).unwrap();

    put(
        "blocks.request.list_classes",
        req(ManagerRequest::ListClasses { from: 0 }),
    );
    put(
        "blocks.reply.list_classes",
        ok(1, |w| {
            w.u8(END).unwrap();
            w.u8(2).unwrap();
            for (class, name, used) in [(0, "comparator", 1), (1, "scale", 0)] {
                let e = ClassEntry {
                    class,
                    name,
                    capacity: 2,
                    used,
                };
                write_class_entry(w, &e).unwrap();
            }
        }),
    );
    put(
        "blocks.request.get_class",
        req(ManagerRequest::GetClass {
            class: 1,
            part: ClassPart::Constructor,
        }),
    );
    put(
        "blocks.reply.get_class",
        ok(2, |w| {
            w.u8(1).unwrap();
            w.u8(0).unwrap();
            SCALE_NEW.encode(w).unwrap();
        }),
    );
    put(
        "blocks.request.new",
        req(ManagerRequest::NewBlock {
            class: 1,
            name: "half",
            args: half_args,
        }),
    );
    put(
        "blocks.reply.new",
        ok(3, |w| {
            w.u8(2).unwrap();
            w.u16(7).unwrap();
        }),
    );
    put(
        "blocks.request.list_blocks",
        req(ManagerRequest::ListBlocks { from: 0 }),
    );
    put(
        "blocks.reply.list_blocks",
        ok(5, |w| {
            w.u8(END).unwrap();
            w.u8(1).unwrap();
            let e = BlockEntry {
                slot: 2,
                class: 1,
                offset: 7,
                name: "half",
            };
            write_block_entry(w, &e).unwrap();
        }),
    );
    put(
        "blocks.request.get_block",
        req(ManagerRequest::GetBlock { slot: 2 }),
    );
    put(
        "blocks.reply.get_block",
        ok(6, |w| {
            w.u8(2).unwrap();
            w.u8(1).unwrap();
            w.u8(1).unwrap();
            w.u16(7).unwrap();
            w.str8("half").unwrap();
            w.bytes(&half).unwrap();
        }),
    );
    put(
        "blocks.request.delete",
        req(ManagerRequest::DeleteBlock { name: "half" }),
    );
    put("blocks.reply.delete", ok(4, |w| w.u8(2).unwrap()));
    put(
        "blocks.reply.error.pool_full",
        refused(3, ManagerError::PoolFull(1)),
    );
    put(
        "blocks.reply.error.bad_argument",
        refused(3, ManagerError::Failed(FailureCode::Other(BAD_ARGUMENT))),
    );
    put(
        "blocks.reply.error.name_taken",
        refused(3, ManagerError::NameTaken),
    );
    put(
        "blocks.reply.error.no_such_block",
        refused(4, ManagerError::NoSuchBlock),
    );
    v
}

#[test]
fn document_matches_code() {
    let code = code_vectors();
    if std::env::var_os("PIPES_PRINT_VECTORS").is_some() {
        for (k, b) in &code {
            println!("```hex-blocks {k}\n{}\n```\n", hex(b));
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
    for (k, b) in &document_vectors() {
        if k.starts_with("blocks.request.") {
            let r = ManagerRequest::parse(b).unwrap();
            let again = enc(|w| r.encode(w).unwrap());
            assert_eq!(again, *b, "{k}");
        } else {
            let (key, result) = parse_reply(b).unwrap();
            assert_eq!(key, b[0]);
            assert_eq!(k.contains(".error."), result.is_err(), "{k}");
        }
    }
}
