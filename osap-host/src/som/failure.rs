//! Remote refusals by name, from the function's own table.
//!
//! A function's failure code (`ControlError::CallFailed(code)`) is a bare
//! byte whose meaning is the function's own. A function that knows its
//! codes publishes them with its signature (`pipes_core::failure`). When a
//! function first refuses with a failure code, its handle asks it for its
//! signature with the table (`[2][1]`), keeps the table until the next
//! refresh, and the refusal prints by the name the function itself gave
//! (`QueueFull (code 8): ..`). A scan reads signatures alone: a module's
//! tables are about 25 KiB, which a slow bus (an RS-485 line shared by
//! eight drops) would take tens of seconds to carry at every scan.
//!
//! The host knows no device's codes: a function that publishes no table
//! (one from before the tables, or one that names none of its codes) gets
//! its codes printed as numbers, never a wrong name.

use pipes_core::failure::FailureView;
use std::fmt;
use std::sync::Arc;

/// One failure code by name, as the function published it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Failure {
    /// The code, as `CallError::Failed` carries it.
    pub code: u8,
    /// Its short name (`QueueFull`).
    pub name: String,
    /// What it means and how to fix it (may be empty).
    pub reason: String,
}

impl fmt::Display for Failure {
    /// `QueueFull (code 8): the module's queue is full (..): ..`, as the
    /// device's own table prints.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        FailureView {
            code: self.code,
            name: &self.name,
            reason: &self.reason,
        }
        .fmt(f)
    }
}

impl From<FailureView<'_>> for Failure {
    fn from(f: FailureView<'_>) -> Self {
        Failure {
            code: f.code,
            name: f.name.to_owned(),
            reason: f.reason.to_owned(),
        }
    }
}

impl From<pipes_core::failure::Failure> for Failure {
    /// A table compiled into this process (a device's crate, in a test).
    fn from(f: pipes_core::failure::Failure) -> Self {
        Failure {
            code: f.code,
            name: f.name.to_owned(),
            reason: f.reason.to_owned(),
        }
    }
}

/// A function's published failure table, as read with its signature.
pub type FailureTable = Arc<[Failure]>;

/// What failure `code` means in `table`, if the table names it.
pub fn lookup(table: &[Failure], code: u8) -> Option<Failure> {
    table.iter().find(|f| f.code == code).cloned()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::som::{FnRef, SomError};
    use osap_core::codec::Writer;
    use pipes_core::control::{
        encode_described_reply, encode_signature_reply, ControlError, Reply, ReplyBody,
    };
    use pipes_core::failure::SignatureParts;
    use pipes_core::signature::Signature;

    static ADD_POINT: Signature = Signature {
        name: "add_point",
        inputs: &[],
        outputs: &[],
    };

    static TABLE: [pipes_core::failure::Failure; 2] = [
        pipes_core::failure::Failure {
            code: 3,
            name: "Gap",
            reason: "two or more points missing before this one: send every interval's point",
        },
        pipes_core::failure::Failure {
            code: 8,
            name: "QueueFull",
            reason: "the module's queue is full (stream too far ahead): send points closer \
                     to their time",
        },
    ];

    /// The table a scan reads from a reply's bytes.
    fn scanned(reply: &[u8]) -> Option<FailureTable> {
        let Ok(ReplyBody::Signature(s)) = Reply::parse(reply).unwrap().result else {
            panic!("not a signature reply")
        };
        s.failures()
            .map(|t| t.iter().map(Failure::from).collect::<Vec<_>>().into())
    }

    fn reply(described: bool) -> Vec<u8> {
        let mut buf = vec![0u8; 1024];
        let mut w = Writer::new(&mut buf);
        if described {
            encode_described_reply(&mut w, &ADD_POINT, SignatureParts::FAILURES, &TABLE, "")
        } else {
            encode_signature_reply(&mut w, &ADD_POINT)
        }
        .unwrap();
        let n = w.len();
        buf.truncate(n);
        buf
    }

    #[test]
    fn a_scanned_signature_names_its_refusals() {
        let table = scanned(&reply(true)).expect("a table");
        assert_eq!(lookup(&table, 8).unwrap().name, "QueueFull");
        assert_eq!(
            lookup(&table, 3).unwrap().to_string(),
            "Gap (code 3): two or more points missing before this one: send every \
             interval's point"
        );
        // Printed exactly as the device's own table prints.
        assert_eq!(lookup(&table, 8).unwrap().to_string(), TABLE[1].to_string());
        assert_eq!(lookup(&table, 42), None);
        // The old layout: no table, no names.
        assert_eq!(scanned(&reply(false)), None);
    }

    #[test]
    fn a_remote_refusal_prints_by_name_only_when_known() {
        let remote = |failure| SomError::Remote {
            function: FnRef::new("a", "add_point"),
            request: "call",
            error: ControlError::CallFailed(pipes_core::FailureCode::Other(8)),
            failure,
        };
        let table = scanned(&reply(true)).unwrap();
        let named = remote(lookup(&table, 8).map(Box::new)).to_string();
        assert!(
            named.ends_with(
                "call refused: QueueFull (code 8): the module's queue is full \
                 (stream too far ahead): send points closer to their time"
            ),
            "{named}"
        );
        let bare = remote(None).to_string();
        assert!(
            bare.ends_with("call refused: the function failed with code 8"),
            "{bare}"
        );
        let no_reason = Failure {
            code: 7,
            name: "Jammed".into(),
            reason: String::new(),
        };
        assert_eq!(no_reason.to_string(), "Jammed (code 7)");
    }
}
