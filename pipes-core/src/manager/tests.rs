use super::*;
use osap_core::codec::Reader;

#[test]
fn names_are_identifiers_of_at_most_24_bytes() {
    for ok in ["a", "probe", "Z_1", "_x", "abcdefghijklmnopqrstuvwx"] {
        assert_eq!(BlockName::new(ok).unwrap().as_str(), ok);
    }
    for bad in ["", "1a", "a b", "a-b", "é", "abcdefghijklmnopqrstuvwxy"] {
        assert_eq!(BlockName::new(bad), Err(ManagerError::BadName), "{bad:?}");
    }
}

#[test]
fn every_error_round_trips() {
    let errors = [
        ManagerError::UnknownKey(9),
        ManagerError::Malformed,
        ManagerError::WrongArgCount {
            expected: 3,
            got: 1,
        },
        ManagerError::NoSuchInput(4),
        ManagerError::Failed(crate::FailureCode::Other(BAD_ARGUMENT)),
        ManagerError::NoSuchClass(7),
        ManagerError::PoolFull(2),
        ManagerError::NameTaken,
        ManagerError::BadName,
        ManagerError::NoSuchBlock,
        ManagerError::Internal,
    ];
    for e in errors {
        let mut b = [0u8; 16];
        let mut w = Writer::new(&mut b);
        e.encode(&mut w).unwrap();
        let n = w.len();
        let mut r = Reader::new(&b[1..n]);
        assert_eq!(b[0], e.status());
        assert_eq!(ManagerError::decode_body(b[0], &mut r).unwrap(), e);
        assert!(r.is_empty());
        assert!(!std::format!("{e}").is_empty());
    }
}

#[test]
fn a_page_stops_where_its_entries_stop_fitting() {
    let names = ["a_rather_long_name_num_1", "a_rather_long_name_num_2", "x"];
    let entries = names.iter().enumerate().map(|(i, n)| BlockEntry {
        slot: i as u8,
        class: 0,
        offset: 1 + 3 * i as u16,
        name: n,
    });
    let mut b = [0u8; 96];
    let mut w = Writer::new(&mut b);
    write_page(&mut w, entries, write_block_entry).unwrap();
    let n = w.len();
    let page = Page::decode(&mut Reader::new(&b[..n]), |r| {
        r.u8()?;
        r.u8()?;
        r.u16()?;
        r.str8()?;
        Ok(())
    })
    .unwrap();
    assert_eq!(page.len(), 1);
    assert_eq!(page.next, 1);
    assert!(n - 2 <= PAGE);
}
