//! Property tests: every kind of value round-trips through the codec; no
//! input makes value, message or conversion code panic; conversions are
//! exact and round-trip where the table allows both directions.

use osap_core::codec::{Reader, Writer};
use pipes_core::convert::{rule, Rule};
use pipes_core::{
    convert, Args, Array, ConvertReason, Converted, Message, MessageKey, ScalarType, Tensor, Type,
    Value,
};
use proptest::prelude::*;

/// A value that owns its data, so strategies can make them.
#[derive(Debug, Clone)]
enum Owned {
    Scalar(ScalarType, Vec<u8>),
    Null,
    Ascii(String),
    Utf8(String),
    Array(ScalarType, Vec<u8>),
    Tensor(ScalarType, Vec<u16>, Vec<u8>),
}

impl Owned {
    fn value(&self) -> Value<'_> {
        match self {
            Owned::Null => Value::Null,
            Owned::Scalar(s, b) => {
                // Decode from the raw bytes: the only way to build any scalar.
                let mut buf = vec![s.key()];
                buf.extend_from_slice(b);
                let v = Value::from_bytes(&buf).unwrap();
                scalar_static(v)
            }
            Owned::Ascii(s) => Value::ascii(s.as_str()),
            Owned::Utf8(s) => Value::utf8(s.as_str()),
            Owned::Array(s, b) => Value::Array(Array::new(*s, b).unwrap()),
            Owned::Tensor(s, d, b) => Value::Tensor(Tensor::new(*s, d, b).unwrap()),
        }
    }
}

/// Rebuilds a scalar so it no longer borrows the temporary buffer.
fn scalar_static(v: Value<'_>) -> Value<'static> {
    match v {
        Value::Null => Value::Null,
        Value::Bool(x) => Value::Bool(x),
        Value::I8(x) => Value::I8(x),
        Value::I16(x) => Value::I16(x),
        Value::I32(x) => Value::I32(x),
        Value::I64(x) => Value::I64(x),
        Value::I128(x) => Value::I128(x),
        Value::U8(x) => Value::U8(x),
        Value::U16(x) => Value::U16(x),
        Value::U32(x) => Value::U32(x),
        Value::U64(x) => Value::U64(x),
        Value::U128(x) => Value::U128(x),
        Value::F16(x) => Value::F16(x),
        Value::F32(x) => Value::F32(x),
        Value::F64(x) => Value::F64(x),
        other => panic!("not a scalar: {other:?}"),
    }
}

fn scalar_type() -> impl Strategy<Value = ScalarType> {
    proptest::sample::select(ScalarType::ALL.to_vec())
}

fn any_type() -> impl Strategy<Value = Type> {
    proptest::sample::select(Type::all().collect::<Vec<_>>())
}

/// `n` elements of `s` as bytes; bools as 0/1, and often small integers so
/// conversions sometimes succeed.
fn elements(s: ScalarType, n: usize) -> impl Strategy<Value = Vec<u8>> {
    let w = s.width();
    proptest::collection::vec(
        (any::<bool>(), proptest::collection::vec(any::<u8>(), w)),
        n,
    )
    .prop_map(move |els| {
        let mut out = Vec::new();
        for (small, mut b) in els {
            if s == ScalarType::Bool {
                b[0] &= 1;
            } else if small && s.is_integer() {
                let sign = if b[0] & 1 == 1 && s.is_signed() {
                    0xff
                } else {
                    0
                };
                for x in &mut b[1..] {
                    *x = sign;
                }
                if sign == 0xff {
                    b[0] |= 0x80;
                } else if s.is_signed() {
                    b[0] &= 0x7f;
                }
            }
            out.extend(b);
        }
        out
    })
}

fn owned() -> impl Strategy<Value = Owned> {
    prop_oneof![
        Just(Owned::Null),
        scalar_type().prop_flat_map(|s| elements(s, 1).prop_map(move |b| Owned::Scalar(s, b))),
        "[ -~]{0,20}".prop_map(Owned::Ascii),
        ".{0,12}".prop_map(Owned::Utf8),
        (scalar_type(), 0usize..12)
            .prop_flat_map(|(s, n)| elements(s, n).prop_map(move |b| Owned::Array(s, b))),
        (scalar_type(), proptest::collection::vec(0u16..4, 0..4)).prop_flat_map(|(s, dims)| {
            let n = dims.iter().map(|d| *d as usize).product();
            elements(s, n).prop_map(move |b| Owned::Tensor(s, dims.clone(), b))
        }),
    ]
}

fn encode(v: &Value<'_>) -> Vec<u8> {
    let mut b = vec![0u8; 4096];
    let mut w = Writer::new(&mut b);
    v.encode(&mut w).unwrap();
    let n = w.len();
    b.truncate(n);
    b
}

fn encode_converted(c: &Converted<'_>) -> Vec<u8> {
    let mut b = vec![0u8; 8192];
    let mut w = Writer::new(&mut b);
    c.encode(&mut w).unwrap();
    let n = w.len();
    assert_eq!(n, c.encoded_len().unwrap());
    b.truncate(n);
    b
}

/// Same value, where NaN equals NaN (payloads aside).
fn same(a: &Value<'_>, b: &Value<'_>) -> bool {
    match (a, b) {
        (Value::F32(x), Value::F32(y)) => x.to_bits() == y.to_bits() || (x.is_nan() && y.is_nan()),
        (Value::F64(x), Value::F64(y)) => x.to_bits() == y.to_bits() || (x.is_nan() && y.is_nan()),
        (Value::F16(x), Value::F16(y)) => x == y || (x & 0x7fff > 0x7c00 && y & 0x7fff > 0x7c00),
        (Value::Array(x), Value::Array(y)) => {
            x.elem() == y.elem()
                && x.len() == y.len()
                && x.iter().zip(y.iter()).all(|(p, q)| same(&p, &q))
        }
        (Value::Tensor(x), Value::Tensor(y)) => {
            x.elem() == y.elem()
                && x.dims() == y.dims()
                && x.elements()
                    .iter()
                    .zip(y.elements().iter())
                    .all(|(p, q)| same(&p, &q))
        }
        _ => a == b,
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn values_round_trip(o in owned()) {
        let v = o.value();
        let bytes = encode(&v);
        prop_assert_eq!(bytes.len(), v.encoded_len().unwrap());
        let back = Value::from_bytes(&bytes).unwrap();
        prop_assert_eq!(back.ty(), v.ty());
        prop_assert_eq!(&encode(&back), &bytes);
        prop_assert!(same(&back, &v));
    }

    /// An owned value (alloc) encodes to the same bytes as the borrowed value
    /// it was made from, compares equal to it, and decodes back equal.
    #[cfg(feature = "alloc")]
    #[test]
    fn owned_values_encode_as_borrowed(o in owned()) {
        let v = o.value();
        let bytes = encode(&v);
        let owned = v.to_owned_value();
        prop_assert!(same(&owned, &v));
        prop_assert_eq!(&encode(&owned), &bytes);
        prop_assert_eq!(owned.encoded_len(), v.encoded_len());
        let back = Value::from_bytes(&bytes).unwrap();
        let back_owned = back.clone().into_owned();
        prop_assert!(same(&back_owned, &back));
        prop_assert_eq!(&encode(&back_owned), &bytes);
    }

    #[test]
    fn decoding_arbitrary_bytes_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..64)) {
        let mut r = Reader::new(&bytes);
        if let Ok(v) = Value::decode(&mut r) {
            // What decoded re-encodes to exactly the bytes it consumed.
            let used = bytes.len() - r.rest().len();
            prop_assert_eq!(encode(&v), &bytes[..used]);
        } else {
            prop_assert_eq!(r.rest().len(), bytes.len());
        }
    }

    #[test]
    fn decoding_arbitrary_typed_prefix_never_panics(
        key in any::<u8>(),
        bytes in proptest::collection::vec(any::<u8>(), 0..48),
    ) {
        let mut input = vec![key];
        input.extend(bytes);
        let _ = Value::from_bytes(&input);
        let _ = Message::parse(&input);
    }

    #[test]
    fn parsing_arbitrary_messages_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..64)) {
        if let Ok(m) = Message::parse(&bytes) {
            let args: Vec<_> = m.args.iter().collect();
            prop_assert_eq!(args.len(), m.args.len());
            let mut out = vec![0u8; 256];
            let mut w = Writer::new(&mut out);
            Message::encode(&mut w, m.key, &args).unwrap();
            let n = w.len();
            prop_assert_eq!(&out[..n], &bytes[..]);
        }
    }

    #[test]
    fn messages_round_trip(
        args in proptest::collection::btree_map(any::<u8>(), owned(), 0..8),
        order in any::<bool>(),
    ) {
        let mut args: Vec<(u8, Value<'_>)> = args.iter().map(|(i, o)| (*i, o.value())).collect();
        if order {
            args.reverse();
        }
        let mut out = vec![0u8; 8192];
        let mut w = Writer::new(&mut out);
        Message::encode(&mut w, MessageKey::PipeDatagram, &args).unwrap();
        let n = w.len();
        let expected: usize = 2 + args.iter().map(|(_, v)| 1 + v.encoded_len().unwrap()).sum::<usize>();
        prop_assert_eq!(n, expected);
        let m = Message::parse(&out[..n]).unwrap();
        prop_assert_eq!(m.args.len(), args.len());
        for ((i, v), (j, u)) in m.args.iter().zip(args.iter()) {
            prop_assert_eq!(i, *j);
            prop_assert!(same(&v, u));
            prop_assert!(same(&m.args.get(i).unwrap(), u));
        }
        // An argument list also parses on its own from a reader.
        let mut r = Reader::new(&out[1..n]);
        let a = Args::decode(&mut r).unwrap();
        prop_assert!(r.is_empty());
        prop_assert_eq!(a.len(), args.len());
    }

    #[test]
    fn conversions_never_panic_and_follow_the_rule(o in owned(), to in any_type()) {
        let v = o.value();
        let from = v.ty();
        match convert(&v, &to) {
            Ok(c) => {
                prop_assert_eq!(c.ty(), to);
                prop_assert!(!matches!(rule(&from, &to), Rule::Never(_)));
                // The converted value encodes to a valid value of the new type.
                let bytes = encode_converted(&c);
                let decoded = Value::from_bytes(&bytes).unwrap();
                prop_assert_eq!(decoded.ty(), to);
                // Where the table allows the way back, it gives the value back.
                if !matches!(rule(&to, &from), Rule::Never(_)) {
                    let back = convert(&decoded, &from).unwrap();
                    let back_bytes = encode_converted(&back);
                    let back_value = Value::from_bytes(&back_bytes).unwrap();
                    prop_assert!(same(&back_value, &v), "{:?} -> {:?} -> {:?}", v, decoded, back_value);
                }
            }
            Err(e) => {
                prop_assert_eq!(e.from, from);
                prop_assert_eq!(e.to, to);
                prop_assert!(!matches!(rule(&from, &to), Rule::Identity | Rule::Always));
                if let Rule::Never(r) = rule(&from, &to) {
                    prop_assert_eq!(e.reason, r);
                }
                prop_assert!(!e.to_string().is_empty());
            }
        }
    }

    #[test]
    fn integer_to_f64_is_lossy_exactly_when_inexact(x in any::<i64>(), shift in 0u32..64) {
        let x = x >> shift;
        let exact = (x as f64) as i128 == x as i128;
        match convert(&Value::I64(x), &Type::Scalar(ScalarType::F64)) {
            Ok(Converted::Value(Value::F64(f))) => {
                prop_assert!(exact);
                prop_assert_eq!(f as i128, x as i128);
            }
            Err(e) => {
                prop_assert!(!exact);
                prop_assert_eq!(e.reason, ConvertReason::Lossy);
            }
            Ok(other) => prop_assert!(false, "unexpected {:?}", other),
        }
    }

    #[test]
    fn integer_narrowing_is_range_checked(x in any::<i64>(), shift in 0u32..64) {
        let x = x >> shift;
        let v = Value::I64(x);
        let r = convert(&v, &Type::Scalar(ScalarType::I16));
        match i16::try_from(x) {
            Ok(y) => prop_assert_eq!(r, Ok(Converted::Value(Value::I16(y)))),
            Err(_) => prop_assert_eq!(r.unwrap_err().reason, ConvertReason::OutOfRange),
        }
    }

    #[test]
    fn f32_to_f64_and_back_is_exact(bits in any::<u32>()) {
        let v = Value::F32(f32::from_bits(bits));
        let Converted::Value(w) = convert(&v, &Type::Scalar(ScalarType::F64)).unwrap() else {
            panic!()
        };
        let Converted::Value(back) = convert(&w, &Type::Scalar(ScalarType::F32)).unwrap() else {
            panic!()
        };
        prop_assert!(same(&back, &v));
    }
}
