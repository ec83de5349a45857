//! Failure tables and docs on the wire (`pipes_core::failure`,
//! `pipes_core::docs`): a reply in the old layout reads with no table, a
//! described one reads back whole, and no cut, extension or corruption of
//! the tail panics or yields a partial table or text.

use osap_core::codec::Writer;
use pipes_core::control::{encode_described_reply, ControlKey, Reply, ReplyBody};
use pipes_core::failure::{Failure, SignatureParts};
use pipes_core::signature::{Arg, Signature};
use pipes_core::{ScalarType, Type};
use proptest::prelude::*;

static MOVE: Signature = Signature {
    name: "move_to",
    inputs: &[Arg::new("x", Type::Scalar(ScalarType::F32))],
    outputs: &[],
};

static TABLE: [Failure; 3] = [
    Failure {
        code: 3,
        name: "Gap",
        reason: "points missing: send every point",
    },
    Failure {
        code: 8,
        name: "QueueFull",
        reason: "the queue is full: send points closer to their time",
    },
    Failure {
        code: 100,
        name: "NotInstalled",
        reason: "",
    },
];

/// `move_to`'s documentation, with multi-byte characters to cut through.
const DOCS: &str = "Moves to `x`, mm.\nAt 20 °C, within 5 µm.";

fn reply(parts: SignatureParts) -> Vec<u8> {
    let mut buf = vec![0u8; 512];
    let mut w = Writer::new(&mut buf);
    encode_described_reply(&mut w, &MOVE, parts, &TABLE, DOCS).unwrap();
    let n = w.len();
    buf.truncate(n);
    buf
}

fn signature(bytes: &[u8]) -> Option<pipes_core::signature::SignatureView<'_>> {
    match Reply::parse(bytes).ok()?.result {
        Ok(ReplyBody::Signature(s)) => Some(s),
        _ => None,
    }
}

#[test]
fn the_old_layout_reads_with_no_table() {
    let old = reply(SignatureParts::NONE);
    let s = signature(&old).unwrap();
    assert!(MOVE.matches(&s));
    assert_eq!(s.failures(), None);
    assert!(s.tail_bytes().is_empty());
}

#[test]
fn a_described_reply_carries_the_names() {
    let new = reply(SignatureParts::FAILURES);
    assert_eq!(new[0], ControlKey::GetSignature.to_u8());
    // The old layout is a prefix: the tail is appended, nothing moves.
    assert!(new.starts_with(&reply(SignatureParts::NONE)));
    let s = signature(&new).unwrap();
    assert!(MOVE.matches(&s));
    let table = s.failures().unwrap();
    assert_eq!(table.len(), TABLE.len());
    for (got, want) in table.iter().zip(&TABLE) {
        assert_eq!(
            (got.code, got.name, got.reason),
            (want.code, want.name, want.reason)
        );
        assert_eq!(got.to_string(), want.to_string());
    }
    assert_eq!(
        table.get(3).unwrap().to_string(),
        "Gap (code 3): points missing: send every point"
    );
    assert_eq!(
        table.get(100).unwrap().to_string(),
        "NotInstalled (code 100)"
    );
    assert_eq!(table.get(4), None);
}

proptest! {
    #[test]
    fn every_cut_of_the_tail_is_the_old_layout_or_an_error(cut in 0usize..200) {
        let new = reply(SignatureParts::FAILURES);
        let base = reply(SignatureParts::NONE).len();
        let cut = cut.min(new.len());
        match signature(&new[..cut]) {
            Some(s) => {
                // Only the whole reply or exactly the old layout read.
                prop_assert!(cut == base || cut == new.len(), "cut {cut} read");
                prop_assert_eq!(s.failures().is_some(), cut == new.len());
            }
            None => prop_assert!(cut != base && cut != new.len()),
        }
    }

    #[test]
    fn every_cut_of_the_docs_is_a_shorter_reply_or_an_error(cut in 0usize..300) {
        let all = SignatureParts::FAILURES
            .with(SignatureParts::SUMMARY)
            .with(SignatureParts::DOCS);
        let new = reply(all);
        let cut = cut.min(new.len());
        // Where a whole section ends: the only cuts that read.
        let ends = [
            reply(SignatureParts::NONE).len(),
            reply(SignatureParts::FAILURES).len(),
            reply(SignatureParts::FAILURES.with(SignatureParts::SUMMARY)).len(),
            new.len(),
        ];
        match signature(&new[..cut]) {
            Some(s) => {
                prop_assert!(ends.contains(&cut), "cut {cut} read");
                prop_assert_eq!(s.summary().is_some(), cut >= ends[2]);
                prop_assert_eq!(s.docs().is_some(), cut == ends[3]);
                if let Some(summary) = s.summary() {
                    prop_assert_eq!(summary, "Moves to `x`, mm.");
                }
                if let Some(docs) = s.docs() {
                    prop_assert_eq!(docs, DOCS);
                }
            }
            None => prop_assert!(!ends.contains(&cut)),
        }
    }

    #[test]
    fn any_tail_reads_whole_or_not_at_all(tail in proptest::collection::vec(any::<u8>(), 0..300)) {
        let mut bytes = reply(SignatureParts::NONE);
        bytes.extend_from_slice(&tail);
        if let Some(s) = signature(&bytes) {
            if let Some(table) = s.failures() {
                prop_assert_eq!(table.iter().count(), table.len());
                for f in table.iter() {
                    prop_assert_eq!(table.get(f.code).map(|g| g.code), Some(f.code));
                }
            }
        }
    }

    #[test]
    fn corrupting_one_byte_never_panics(at in 0usize..300, byte in any::<u8>()) {
        let mut bytes = reply(
            SignatureParts::FAILURES
                .with(SignatureParts::SUMMARY)
                .with(SignatureParts::DOCS),
        );
        let at = at % bytes.len();
        bytes[at] = byte;
        if let Some(s) = signature(&bytes) {
            if let Some(table) = s.failures() {
                prop_assert_eq!(table.iter().count(), table.len());
            }
        }
    }
}
