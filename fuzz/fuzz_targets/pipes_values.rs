//! Arbitrary bytes as PIPES values and dataflow messages: decoding never
//! panics, whatever decodes re-encodes to exactly the bytes it consumed,
//! and converting any decoded value to any type never panics.
#![no_main]

use libfuzzer_sys::fuzz_target;
use osap_core::codec::{Reader, Writer};
use pipes_core::{convert, Message, Type, Value};

fuzz_target!(|data: &[u8]| {
    let mut r = Reader::new(data);
    if let Ok(v) = Value::decode(&mut r) {
        let consumed = data.len() - r.rest().len();
        let mut buf = [0u8; 4096];
        let mut w = Writer::new(&mut buf);
        if v.encode(&mut w).is_ok() {
            assert_eq!(w.finish(), &data[..consumed]);
        }
        for ty in Type::all() {
            if let Ok(c) = convert(&v, &ty) {
                let mut out = [0u8; 8192];
                let _ = c.encode(&mut Writer::new(&mut out));
            }
        }
    }
    if let Ok(m) = Message::parse(data) {
        for (index, value) in m.args.iter() {
            let _ = (index, value.ty());
        }
    }
});
