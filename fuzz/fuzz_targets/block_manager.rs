//! Arbitrary bytes as block-manager requests and replies: parsing never
//! panics, and a request that parses re-encodes to exactly its bytes.
#![no_main]

use libfuzzer_sys::fuzz_target;
use osap_core::codec::Writer;
use pipes_core::manager::{parse_reply, ManagerRequest};

fuzz_target!(|data: &[u8]| {
    if let Ok(r) = ManagerRequest::parse(data) {
        let mut buf = [0u8; 512];
        let mut w = Writer::new(&mut buf);
        if r.encode(&mut w).is_ok() {
            assert_eq!(w.finish(), data);
        }
    }
    if let Ok((_, Ok(reply))) = parse_reply(data) {
        let _ = format!("{reply:?}");
    }
});
