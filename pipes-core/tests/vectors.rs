//! The golden vectors and the conversion table in `docs/pipes.md` are checked
//! here. Every vector in the document must be known to this test: either it
//! matches what the code encodes from its meaning (and decodes back to that
//! meaning), or it is a `reject.*` vector that decoding must refuse with the
//! stated error. Run with `PIPES_PRINT_VECTORS=1` to print the vectors and the
//! table as the code produces them.

use std::collections::BTreeMap;

use osap_core::codec::Writer;
use pipes_core::convert::{rule, Rule};
use pipes_core::{
    convert, Array, ConvertReason, Message, MessageError, MessageKey, ScalarType, Tensor, Type,
    Value, ValueError,
};

#[path = "../../osap-core/tests/support/doc_vectors.rs"]
mod doc_vectors;
use doc_vectors::hex;

/// Vectors in `docs/pipes.md`: fenced blocks opened with "```hex name".
fn document_vectors() -> BTreeMap<String, Vec<u8>> {
    doc_vectors::document_vectors(&doc(), "hex")
}

fn doc() -> String {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/pipes.md");
    std::fs::read_to_string(path).expect("docs/pipes.md")
}

fn value(v: Value<'_>) -> Vec<u8> {
    let mut b = vec![0u8; 256];
    let mut w = Writer::new(&mut b);
    v.encode(&mut w).unwrap();
    let n = w.len();
    b.truncate(n);
    b
}

fn le<T: Copy, const N: usize>(xs: &[T], f: impl Fn(T) -> [u8; N]) -> Vec<u8> {
    xs.iter().flat_map(|x| f(*x)).collect()
}

fn message(args: &[(u8, Value<'_>)]) -> Vec<u8> {
    let mut b = vec![0u8; 256];
    let mut w = Writer::new(&mut b);
    Message::encode(&mut w, MessageKey::PipeDatagram, args).unwrap();
    let n = w.len();
    b.truncate(n);
    b
}

/// Every accepted vector as (bytes the code encodes, its meaning as a value
/// or message is checked separately in `document_vectors_decode`).
fn code_vectors() -> BTreeMap<String, Vec<u8>> {
    let f32s = le(&[1.0f32, 2.0, 3.0], f32::to_le_bytes);
    let i16s = le(&[1i16, 2, 3, -1, -2, -3], i16::to_le_bytes);
    let one_f32 = 0.5f32.to_le_bytes();
    let mut v = BTreeMap::new();
    let mut put = |k: &str, b: Vec<u8>| {
        assert!(v.insert(k.to_string(), b).is_none(), "{k} twice");
    };
    put("value.null", value(Value::Null));
    put("value.bool.true", value(Value::Bool(true)));
    put("value.i8.-5", value(Value::I8(-5)));
    put("value.i32.-2", value(Value::I32(-2)));
    put("value.i128.-1", value(Value::I128(-1)));
    put("value.u16.1000", value(Value::U16(1000)));
    put("value.u64.1000000", value(Value::U64(1_000_000)));
    put("value.f16.1.0", value(Value::F16(0x3c00)));
    put("value.f32.1.5", value(Value::F32(1.5)));
    put("value.f64.-0.25", value(Value::F64(-0.25)));
    put("value.ascii.hi", value(Value::ascii("hi")));
    put("value.utf8.é", value(Value::utf8("é")));
    put("value.utf8.empty", value(Value::utf8("")));
    put(
        "value.arry_f32.1.2.3",
        value(Value::Array(Array::new(ScalarType::F32, &f32s).unwrap())),
    );
    put(
        "value.arry_bool.true.false",
        value(Value::Array(Array::new(ScalarType::Bool, &[1, 0]).unwrap())),
    );
    put(
        "value.arry_u8.empty",
        value(Value::Array(Array::new(ScalarType::U8, &[]).unwrap())),
    );
    put(
        "value.tnsr_i16.2x3",
        value(Value::Tensor(
            Tensor::new(ScalarType::I16, &[2, 3], &i16s).unwrap(),
        )),
    );
    put(
        "value.tnsr_f32.rank0",
        value(Value::Tensor(
            Tensor::new(ScalarType::F32, &[], &one_f32).unwrap(),
        )),
    );
    put(
        "message.pipe_datagram.maxl_point",
        message(&[(0, Value::U64(1_000_000)), (1, Value::F32(2.5))]),
    );
    put("message.pipe_datagram.empty", message(&[]));
    put(
        "message.pipe_datagram.mixed",
        message(&[(3, Value::utf8("ok")), (0, Value::Bool(true))]),
    );
    // What a receiver holds after converting arry_i16 [1, -1] for an arry_f32 input.
    let src = le(&[1i16, -1], i16::to_le_bytes);
    let a = Value::Array(Array::new(ScalarType::I16, &src).unwrap());
    let c = convert(&a, &Type::Array(ScalarType::F32)).unwrap();
    let mut b = vec![0u8; 64];
    let mut w = Writer::new(&mut b);
    c.encode(&mut w).unwrap();
    let n = w.len();
    b.truncate(n);
    put("convert.arry_i16.1.-1.to_arry_f32", b);
    v
}

#[derive(Debug, PartialEq)]
enum Rejected {
    Value(ValueError),
    Message(MessageError),
}

/// Vectors the code must refuse, and how.
fn reject_vectors() -> BTreeMap<&'static str, Rejected> {
    use Rejected::*;
    BTreeMap::from([
        ("reject.value.bool.2", Value(ValueError::BadBool(2))),
        (
            "reject.value.unknown_key",
            Value(ValueError::ReservedType(3)),
        ),
        ("reject.value.f128", Value(ValueError::ReservedType(36))),
        (
            "reject.value.arry_utf8",
            Value(ValueError::UnknownType(0x71)),
        ),
        ("reject.value.ascii.non_ascii", Value(ValueError::NotAscii)),
        ("reject.value.utf8.invalid", Value(ValueError::BadUtf8)),
        (
            "reject.value.utf8.length_past_end",
            Value(ValueError::Truncated),
        ),
        (
            "reject.value.arry_f32.count_past_end",
            Value(ValueError::Truncated),
        ),
        (
            "reject.value.arry_bool.element_3",
            Value(ValueError::BadBool(3)),
        ),
        (
            "reject.value.tnsr_u8.dims_past_end",
            Value(ValueError::Truncated),
        ),
        (
            "reject.message.duplicate_index",
            Message(MessageError::DuplicateIndex(0)),
        ),
        (
            "reject.message.count_too_high",
            Message(MessageError::Truncated),
        ),
        (
            "reject.message.trailing_bytes",
            Message(MessageError::TrailingBytes),
        ),
        (
            "reject.message.unknown_key",
            Message(MessageError::UnknownKey(0)),
        ),
    ])
}

/// The scalar and string conversion table as `docs/pipes.md` shows it.
fn conversion_table() -> String {
    let types: Vec<Type> = std::iter::once(Type::Null)
        .chain(ScalarType::ALL.into_iter().map(Type::Scalar))
        .chain([Type::Ascii, Type::Utf8])
        .collect();
    let mut s = String::from("| from \\ to |");
    for t in &types {
        s.push_str(&format!(" {t} |"));
    }
    s.push_str("\n|---|");
    for _ in &types {
        s.push_str("---|");
    }
    s.push('\n');
    for from in &types {
        s.push_str(&format!("| **{from}** |"));
        for to in &types {
            s.push_str(match rule(from, to) {
                Rule::Identity => " = |",
                Rule::Always => " ✓ |",
                Rule::IfExact => " ? |",
                Rule::Never(ConvertReason::Lossy) => " L |",
                Rule::Never(_) => " · |",
            });
        }
        s.push('\n');
    }
    s
}

#[test]
fn document_vectors_match_the_code() {
    let code = code_vectors();
    let reject = reject_vectors();
    if std::env::var_os("PIPES_PRINT_VECTORS").is_some() {
        for (k, b) in &code {
            println!("```hex {k}\n{}\n```", hex(b));
        }
        println!("{}", conversion_table());
    }
    let doc = document_vectors();
    for (name, bytes) in &doc {
        if let Some(expected) = code.get(name) {
            assert_eq!(hex(bytes), hex(expected), "vector {name}");
        } else {
            assert!(
                reject.contains_key(name.as_str()),
                "docs/pipes.md has vector {name} that no test checks"
            );
        }
    }
    for name in code.keys() {
        assert!(
            doc.contains_key(name),
            "vector {name} is missing from docs/pipes.md"
        );
    }
    for name in reject.keys() {
        assert!(
            doc.contains_key(*name),
            "vector {name} is missing from docs/pipes.md"
        );
    }
}

#[test]
fn document_vectors_decode_to_their_meaning() {
    let doc = document_vectors();
    let get = |k: &str| doc.get(k).unwrap_or_else(|| panic!("missing {k}")).clone();

    // Every value vector decodes and re-encodes to the same bytes.
    for (name, bytes) in doc.iter().filter(|(k, _)| k.starts_with("value.")) {
        let v = Value::from_bytes(bytes).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(&value(v), bytes, "{name}");
    }
    assert_eq!(Value::from_bytes(&get("value.i8.-5")), Ok(Value::I8(-5)));
    assert_eq!(
        Value::from_bytes(&get("value.utf8.é")),
        Ok(Value::utf8("é"))
    );
    let a = get("value.arry_f32.1.2.3");
    let v = Value::from_bytes(&a).unwrap();
    let arr = v.as_array().unwrap();
    assert!(arr.typed::<f32>().unwrap().eq([1.0, 2.0, 3.0]));
    let t = get("value.tnsr_i16.2x3");
    let v = Value::from_bytes(&t).unwrap();
    let t = v.as_tensor().unwrap();
    assert!(t.dims().iter().eq([2, 3]));
    assert_eq!(t.get(&[1, 2]), Some(Value::I16(-3)));
    let r0 = get("value.tnsr_f32.rank0");
    let v = Value::from_bytes(&r0).unwrap();
    assert_eq!(v.as_tensor().unwrap().get(&[]), Some(Value::F32(0.5)));

    let m = get("message.pipe_datagram.maxl_point");
    assert_eq!(m.len(), 18, "WIRE.md: a MAXL control point is 18 bytes");
    let m = Message::parse(&m).unwrap();
    assert_eq!(m.key, MessageKey::PipeDatagram);
    assert!(m
        .args
        .iter()
        .eq([(0, Value::U64(1_000_000)), (1, Value::F32(2.5))]));
    let m = get("message.pipe_datagram.mixed");
    let m = Message::parse(&m).unwrap();
    assert_eq!(m.args.get(3), Some(Value::utf8("ok")));
    assert_eq!(m.args.get(0), Some(Value::Bool(true)));
    assert!(Message::parse(&get("message.pipe_datagram.empty"))
        .unwrap()
        .args
        .is_empty());

    let c = get("convert.arry_i16.1.-1.to_arry_f32");
    let v = Value::from_bytes(&c).unwrap();
    assert!(v
        .as_array()
        .unwrap()
        .typed::<f32>()
        .unwrap()
        .eq([1.0, -1.0]));

    for (name, expected) in reject_vectors() {
        let bytes = get(name);
        let got = if name.starts_with("reject.value.") {
            Rejected::Value(Value::from_bytes(&bytes).unwrap_err())
        } else {
            Rejected::Message(Message::parse(&bytes).unwrap_err())
        };
        assert_eq!(got, expected, "{name}");
    }
}

#[test]
fn document_conversion_table_matches_the_code() {
    let table = conversion_table();
    assert!(
        doc().contains(&table),
        "the conversion table in docs/pipes.md differs from convert::rule; it should read:\n{table}"
    );
}
