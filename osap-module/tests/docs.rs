//! Every module function explains itself: its documentation (the `///`
//! lines of its entry in `module_function_table!`) is what it publishes
//! with its signature, and it changes neither the signature bytes nor the
//! function-set id.

use osap_core::codec::Writer;
use osap_module::functions::{function_set_id, FnId, ALL, DOCS, SIGNATURES};
use osap_module::FUNCTION_SET_ID;
use pipes_core::control::{encode_described_reply, encode_signature_reply, Reply, ReplyBody};
use pipes_core::docs::MAX_DOCS;
use pipes_core::failure::SignatureParts;

#[test]
fn every_function_is_documented_within_the_limit() {
    assert_eq!(DOCS.len(), ALL.len());
    for &id in &ALL {
        let name = SIGNATURES[id as usize].name;
        let docs = id.docs();
        assert!(!docs.is_empty(), "{name} has no docs");
        assert!(docs.len() <= MAX_DOCS, "{name}: {} bytes", docs.len());
        // Read as rustdoc shows it: no indentation left from the table.
        assert!(!docs.starts_with(' '), "{name}: {docs:?}");
        assert!(!docs.contains("\n "), "{name}: {docs:?}");
        let summary = pipes_core::docs::summary(docs);
        assert!(summary.ends_with('.'), "{name}: summary {summary:?}");
    }
    // What the docs cost in flash (the texts; the table of pointers adds
    // 8 bytes a function): a budget, so a text that grows by much is
    // noticed.
    let total: usize = DOCS.iter().map(|d| d.len()).sum();
    println!("module docs: {total} bytes in {} texts", DOCS.len());
    assert!(total < 8 * 1024, "{total} bytes of docs");
    assert!(FnId::add_point
        .docs()
        .starts_with("Queues a control point: the axis is at `position` (user units) at\n"));
    assert_eq!(
        pipes_core::docs::summary(FnId::set_microsteps.docs()),
        "Sets the driver's microstep mode (1, 2, 4, .. 256, as the board's\ndriver offers), \
         while no stream is queued."
    );
}

#[test]
fn docs_travel_with_the_signature_and_leave_it_and_the_id_unchanged() {
    let id = FnId::set_interval;
    let sig = SIGNATURES[id as usize];
    let mut plain = vec![0u8; 4096];
    let mut w = Writer::new(&mut plain);
    encode_signature_reply(&mut w, sig).unwrap();
    let n = w.len();
    plain.truncate(n);

    let parts = SignatureParts::SUMMARY.with(SignatureParts::DOCS);
    let mut described = vec![0u8; 4096];
    let mut w = Writer::new(&mut described);
    encode_described_reply(&mut w, sig, parts, id.failures(), id.docs()).unwrap();
    let n = w.len();
    described.truncate(n);

    assert!(described.starts_with(&plain), "the signature bytes stay");
    let Ok(ReplyBody::Signature(s)) = Reply::parse(&described).unwrap().result else {
        panic!("not a signature reply")
    };
    assert_eq!(s.as_bytes(), &plain[2..]);
    assert_eq!(s.docs(), Some(id.docs()));
    assert_eq!(
        s.summary(),
        Some("Sets the control-point interval, µs (a power of two, 256 to 16 384), while no stream is queued.")
    );
    assert_eq!(s.failures(), None, "not asked for");
    // The id hashes the signatures alone.
    assert_eq!(FUNCTION_SET_ID, function_set_id(&SIGNATURES));
}
