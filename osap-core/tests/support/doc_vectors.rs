//! Reading the golden vectors of a protocol document: fenced blocks opened
//! with "```<tag> <name>", holding hex bytes and `#` comments. Shared by the
//! vector tests of osap-core and pipes-core (included by path).

#![allow(dead_code)]

use std::collections::BTreeMap;

/// Bytes as space-separated lower-case hex.
pub(crate) fn hex(bytes: &[u8]) -> String {
    bytes
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect::<Vec<_>>()
        .join(" ")
}

/// Space-separated hex back to bytes; panics on anything else.
pub(crate) fn unhex(s: &str) -> Vec<u8> {
    s.split_whitespace()
        .map(|t| u8::from_str_radix(t, 16).unwrap_or_else(|_| panic!("bad hex {t:?}")))
        .collect()
}

/// Every block of `doc` fenced with "```<tag> <name>", by name. A name
/// that appears twice fails the test.
pub(crate) fn document_vectors(doc: &str, tag: &str) -> BTreeMap<String, Vec<u8>> {
    let opener = format!("```{tag} ");
    let mut out = BTreeMap::new();
    let mut lines = doc.lines();
    while let Some(line) = lines.next() {
        let Some(name) = line.strip_prefix(opener.as_str()) else {
            continue;
        };
        let mut text = String::new();
        for l in lines.by_ref() {
            if l.starts_with("```") {
                break;
            }
            text.push_str(l.split('#').next().unwrap_or(""));
            text.push(' ');
        }
        let prev = out.insert(name.trim().to_string(), unhex(&text));
        assert!(prev.is_none(), "vector {name} appears twice");
    }
    out
}
