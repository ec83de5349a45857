//! The function set's identity: what every firmware embeds so a check of
//! the built images proves they present the same functions.

use osap_core::codec::Writer;
use osap_module::functions::{function_set_id, FunctionSetHasher, SIGNATURES};
use osap_module::FUNCTION_SET_ID;
use pipes_core::signature::{Arg, Signature};
use pipes_core::types::{ScalarType, Type};

/// FNV-1a over `bytes`, written independently of the crate's const fn.
fn fnv1a(bytes: &[u8]) -> u32 {
    bytes.iter().fold(0x811C_9DC5u32, |h, &b| {
        (h ^ u32::from(b)).wrapping_mul(0x0100_0193)
    })
}

/// The id from the signatures' wire encoding, as a scan receives it.
fn from_wire(signatures: &[&Signature]) -> u32 {
    let mut bytes = vec![signatures.len() as u8];
    for sig in signatures {
        let mut buf = [0u8; 512];
        let mut w = Writer::new(&mut buf);
        sig.encode(&mut w).expect("signature encodes");
        let n = w.len();
        bytes.extend_from_slice(&buf[..n]);
    }
    fnv1a(&bytes)
}

#[test]
fn id_is_the_hash_of_what_a_scan_reads() {
    assert_eq!(FUNCTION_SET_ID, from_wire(&SIGNATURES));
    assert_eq!(FUNCTION_SET_ID, function_set_id(&SIGNATURES));
    // The same id from borrowed names and keys, as a host computes it.
    let mut h = FunctionSetHasher::new(SIGNATURES.len());
    for sig in SIGNATURES {
        let pairs = |args: &'static [Arg]| args.iter().map(|a| (a.name, a.ty.key()));
        h.function(
            &String::from(sig.name),
            pairs(sig.inputs),
            pairs(sig.outputs),
        );
    }
    assert_eq!(h.finish(), FUNCTION_SET_ID);
}

#[test]
fn any_change_to_a_signature_changes_the_id() {
    static X: [Arg; 1] = [Arg::new("x", Type::Scalar(ScalarType::F32))];
    static X_U32: [Arg; 1] = [Arg::new("x", Type::Scalar(ScalarType::U32))];
    static Y: [Arg; 1] = [Arg::new("y", Type::Scalar(ScalarType::F32))];
    let base = Signature {
        name: "f",
        inputs: &X,
        outputs: &[],
    };
    let variants = [
        Signature { name: "g", ..base },
        Signature { inputs: &Y, ..base },
        Signature {
            inputs: &X_U32,
            ..base
        },
        Signature {
            inputs: &[],
            outputs: &X,
            ..base
        },
        Signature {
            inputs: &[],
            ..base
        },
    ];
    let id = function_set_id(&[&base]);
    assert_eq!(id, from_wire(&[&base]));
    for v in &variants {
        assert_ne!(function_set_id(&[v]), id, "{v:?}");
        assert_eq!(function_set_id(&[v]), from_wire(&[v]));
    }

    // The module's own set: rename one function, retype one argument,
    // swap two functions, drop one.
    let mut renamed: Vec<Signature> = SIGNATURES.iter().map(|s| **s).collect();
    renamed[3].name = "get_status2";
    let refs: Vec<&Signature> = renamed.iter().collect();
    assert_ne!(function_set_id(&refs), FUNCTION_SET_ID);

    let mut retyped: Vec<Signature> = SIGNATURES.iter().map(|s| **s).collect();
    let pos = retyped.iter().position(|s| !s.inputs.is_empty()).unwrap();
    let mut args: Vec<Arg> = retyped[pos].inputs.to_vec();
    args[0].ty = Type::Scalar(ScalarType::I8);
    retyped[pos].inputs = Box::leak(args.into_boxed_slice());
    let refs: Vec<&Signature> = retyped.iter().collect();
    assert_ne!(function_set_id(&refs), FUNCTION_SET_ID);

    let mut swapped: Vec<&Signature> = SIGNATURES.to_vec();
    swapped.swap(0, 1);
    assert_ne!(function_set_id(&swapped), FUNCTION_SET_ID);
    assert_ne!(function_set_id(&SIGNATURES[1..]), FUNCTION_SET_ID);
}
