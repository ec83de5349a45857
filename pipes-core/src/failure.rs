//! A function's failure codes by name, sent with its signature.
//!
//! A refusal (`CallError::Failed(code)`, [`crate::FailureCode`]) is a bare
//! byte whose meaning is the function's own. A function that knows its
//! codes publishes them ([`crate::function::Implementation::failures`]):
//! each [`Failure`] is a code, a short name and a reason. A host asks for
//! them with the signature and names a refusal from what the function
//! itself sent, whatever the device.
//!
//! On the wire (`docs/pipes.md` §5) the table is a section of the
//! signature reply's tail, sent only when the request asks for it:
//!
//! ```text
//! request  [2]                 -> reply [2][0][signature]            (as before)
//! request  [2][parts: u8]      -> reply [2][0][signature] sections
//! section  [tag: u8][len: u16 LE][body: len bytes]
//! tag 1    failures: [count: u8] count × ([code: u8][name: str8][reason: str8])
//! tag 2    summary: UTF-8 text (crate::docs)
//! tag 3    docs: UTF-8 text (crate::docs)
//! ```
//!
//! `parts` is a bit set ([`SignatureParts`]); a function answers the parts
//! it knows and ignores other bits. A host that never asks never sees a
//! tail, so readers from before the tail keep reading every reply; a
//! function from before the tail refuses `[2][parts]` as malformed (status
//! 2), and the host asks again with `[2]`: no names. A reader skips
//! sections of tags it does not know; a known section that does not read
//! whole is an error, never a partial table.

use core::fmt;

use osap_core::codec::{CodecError, Reader, Writer};
use osap_core::segment::Window;

/// Why a failure table could not be written or read. A signature's
/// errors include these ([`FailureError`](crate::signature::FailureError)
/// converts each to its own variant of the same name).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum FailureError {
    /// The bytes end early.
    Truncated,
    /// The output buffer is too small.
    NoSpace,
    /// A name or reason is not valid UTF-8.
    BadUtf8,
    /// A name or reason is longer than 255 bytes.
    NameTooLong,
    /// Bytes were left over after the table.
    TrailingBytes,
    /// More than 255 codes, or more than a section's 65 535 bytes.
    TooManyFailures,
    /// The table names this code twice.
    DuplicateFailure(u8),
    /// The documentation is longer than [`crate::docs::MAX_DOCS`] bytes.
    DocsTooLong,
}

impl fmt::Display for FailureError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FailureError::Truncated => f.write_str("failure table is truncated"),
            FailureError::NoSpace => {
                f.write_str("output buffer is too small for the failure table")
            }
            FailureError::BadUtf8 => f.write_str("a failure name is not valid UTF-8"),
            FailureError::NameTooLong => f.write_str("a failure name is longer than 255 bytes"),
            FailureError::TrailingBytes => f.write_str("bytes left over after the failure table"),
            FailureError::TooManyFailures => {
                f.write_str("the failure table has more than 255 codes or 65 535 bytes")
            }
            FailureError::DuplicateFailure(code) => {
                write!(f, "the failure table names code {code} twice")
            }
            FailureError::DocsTooLong => write!(
                f,
                "the documentation is longer than {} bytes: shorten it",
                crate::docs::MAX_DOCS
            ),
        }
    }
}

impl core::error::Error for FailureError {}

impl From<CodecError> for FailureError {
    fn from(e: CodecError) -> Self {
        match e {
            CodecError::NoSpace => FailureError::NoSpace,
            CodecError::BadUtf8 => FailureError::BadUtf8,
            CodecError::StringTooLong => FailureError::NameTooLong,
            // Truncated, or a codec error a newer osap-core adds: the
            // body could not be read.
            _ => FailureError::Truncated,
        }
    }
}

/// One failure code, by name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Failure {
    /// The code, as `CallError::Failed` carries it.
    pub code: u8,
    /// Its short name (`QueueFull`), at most 255 bytes.
    pub name: &'static str,
    /// What it means and how to fix it, one sentence without a capital or
    /// a full stop, to follow "refused: "; at most 255 bytes.
    pub reason: &'static str,
}

impl fmt::Display for Failure {
    /// `QueueFull (code 8): the module's queue is full (..): ..`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write_failure(f, self.code, self.name, self.reason)
    }
}

/// How every failure prints, static or read from the wire.
fn write_failure(f: &mut fmt::Formatter<'_>, code: u8, name: &str, reason: &str) -> fmt::Result {
    if reason.is_empty() {
        write!(f, "{name} (code {code})")
    } else {
        write!(f, "{name} (code {code}): {reason}")
    }
}

/// The section tag of a failure table.
pub const TAG_FAILURES: u8 = 1;

/// Bytes of a section header: tag and `u16` length.
pub const SECTION_HEADER: usize = 3;

/// Which parts of its description a "get signature" request asks a
/// function to append: the request's `parts` byte.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SignatureParts(pub u8);

impl SignatureParts {
    /// The signature alone.
    pub const NONE: SignatureParts = SignatureParts(0);
    /// Bit 0: the failure table (section [`TAG_FAILURES`]).
    pub const FAILURES: SignatureParts = SignatureParts(1);
    /// Bit 1: the documentation's summary line (section
    /// [`TAG_SUMMARY`](crate::docs::TAG_SUMMARY)).
    pub const SUMMARY: SignatureParts = SignatureParts(2);
    /// Bit 2: the whole documentation (section
    /// [`TAG_DOCS`](crate::docs::TAG_DOCS)).
    pub const DOCS: SignatureParts = SignatureParts(4);

    /// Whether the failure table is asked for.
    pub const fn failures(self) -> bool {
        self.0 & Self::FAILURES.0 != 0
    }

    /// Whether the summary line is asked for.
    pub const fn summary(self) -> bool {
        self.0 & Self::SUMMARY.0 != 0
    }

    /// Whether the whole documentation is asked for.
    pub const fn docs(self) -> bool {
        self.0 & Self::DOCS.0 != 0
    }

    /// Both sets of parts.
    pub const fn with(self, other: SignatureParts) -> SignatureParts {
        SignatureParts(self.0 | other.0)
    }
}

/// Checks a table before it is published: at most 255 entries, names and
/// reasons of at most 255 bytes, no code twice, and a section that fits its
/// `u16` length.
pub fn check_failures(failures: &[Failure]) -> Result<(), FailureError> {
    if failures.len() > usize::from(u8::MAX) || failures_body_len(failures) > usize::from(u16::MAX)
    {
        return Err(FailureError::TooManyFailures);
    }
    for (i, f) in failures.iter().enumerate() {
        if f.name.len() > 255 || f.reason.len() > 255 {
            return Err(FailureError::NameTooLong);
        }
        if failures[..i].iter().any(|g| g.code == f.code) {
            return Err(FailureError::DuplicateFailure(f.code));
        }
    }
    Ok(())
}

/// Bytes of a failure section's body.
fn failures_body_len(failures: &[Failure]) -> usize {
    1 + failures
        .iter()
        .map(|f| 3 + f.name.len() + f.reason.len())
        .sum::<usize>()
}

/// The documentation as sent: cut to [`MAX_DOCS`](crate::docs::MAX_DOCS)
/// bytes at a character boundary (a checked text is never cut).
fn sent_docs(docs: &str) -> &str {
    let mut end = docs.len().min(crate::docs::MAX_DOCS);
    while !docs.is_char_boundary(end) {
        end -= 1;
    }
    docs.get(..end).unwrap_or("")
}

/// Bytes [`write_tail`] writes for `parts`, with the failure table
/// `failures` and the documentation `docs`.
pub fn tail_len(parts: SignatureParts, failures: &[Failure], docs: &str) -> usize {
    let docs = sent_docs(docs);
    let mut n = 0;
    if parts.failures() {
        n += SECTION_HEADER + failures_body_len(failures);
    }
    if parts.summary() {
        n += SECTION_HEADER + crate::docs::summary_len(docs);
    }
    if parts.docs() {
        n += SECTION_HEADER + docs.len();
    }
    n
}

/// Writes the tail `parts` asks for, piece by piece (see the module docs):
/// the failure table, the summary and the documentation, in this order.
/// The table must pass [`check_failures`] and the text
/// [`check_docs`](crate::docs::check_docs) (a function checks both once,
/// when it is made); past the limits the lengths would not match the
/// bytes, so unchecked ones are cut to them here.
pub fn write_tail(w: &mut Window<'_>, parts: SignatureParts, failures: &[Failure], docs: &str) {
    let docs = sent_docs(docs);
    if parts.failures() {
        write_failures(w, failures);
    }
    if parts.summary() {
        w.put(&[crate::docs::TAG_SUMMARY]);
        w.put(&(crate::docs::summary_len(docs) as u16).to_le_bytes());
        crate::docs::write_summary(w, docs);
    }
    if parts.docs() {
        w.put(&[crate::docs::TAG_DOCS]);
        w.put(&(docs.len() as u16).to_le_bytes());
        w.put(docs.as_bytes());
    }
}

/// Writes the failure section.
fn write_failures(w: &mut Window<'_>, failures: &[Failure]) {
    let failures = failures.get(..255).unwrap_or(failures);
    let len = failures_body_len(failures).min(usize::from(u16::MAX)) as u16;
    w.put(&[TAG_FAILURES]);
    w.put(&len.to_le_bytes());
    w.put(&[failures.len() as u8]);
    let str8 = |w: &mut Window<'_>, s: &str| {
        let b = s.as_bytes().get(..255).unwrap_or(s.as_bytes());
        w.put(&[b.len() as u8]);
        w.put(b);
    };
    for f in failures {
        if w.is_full() {
            return;
        }
        w.put(&[f.code]);
        str8(w, f.name);
        str8(w, f.reason);
    }
}

/// Writes the tail `parts` asks for into `w`. On error nothing is written.
pub fn encode_tail(
    w: &mut Writer<'_>,
    parts: SignatureParts,
    failures: &[Failure],
    docs: &str,
) -> Result<(), FailureError> {
    check_failures(failures)?;
    crate::docs::check_docs(docs)?;
    let n = tail_len(parts, failures, docs);
    if n > w.remaining() {
        return Err(FailureError::NoSpace);
    }
    let start = w.len();
    let mut buf = [0u8; 64];
    // Through a small window at a time: the pieces writer is the one
    // encoding, so the two can never differ.
    let mut at = 0;
    while at < n {
        let mut win = Window::new(at, &mut buf);
        write_tail(&mut win, parts, failures, docs);
        let got = win.written();
        if got == 0 || w.bytes(&buf[..got]).is_err() {
            w.truncate(start);
            return Err(FailureError::NoSpace);
        }
        at += got;
    }
    Ok(())
}

/// A signature reply's tail as read: the sections it holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(crate) struct Tail<'a> {
    /// The failure table, if the tail has one.
    pub(crate) failures: Option<FailureList<'a>>,
    /// The summary line, if the tail has one.
    pub(crate) summary: Option<&'a str>,
    /// The whole documentation, if the tail has one.
    pub(crate) docs: Option<&'a str>,
    /// Every byte of the tail, as read.
    pub(crate) bytes: &'a [u8],
}

/// Reads every byte left in `r` as tail sections.
pub(crate) fn decode_tail<'a>(r: &mut Reader<'a>) -> Result<Tail<'a>, FailureError> {
    let bytes = r.rest();
    let mut t = Tail {
        bytes,
        ..Tail::default()
    };
    while !r.is_empty() {
        let tag = r.u8()?;
        let len = r.u16()?;
        let body = r.bytes(usize::from(len))?;
        // A later section of a known tag is skipped like an unknown one.
        match tag {
            TAG_FAILURES if t.failures.is_none() => {
                t.failures = Some(FailureList::decode(body)?);
            }
            crate::docs::TAG_SUMMARY if t.summary.is_none() => {
                t.summary = Some(crate::docs::decode_text(body)?);
            }
            crate::docs::TAG_DOCS if t.docs.is_none() => {
                t.docs = Some(crate::docs::decode_text(body)?);
            }
            _ => {}
        }
    }
    Ok(t)
}

/// A checked failure table read from a signature reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FailureList<'a> {
    count: u8,
    bytes: &'a [u8],
}

impl<'a> FailureList<'a> {
    /// Reads a whole section body.
    fn decode(body: &'a [u8]) -> Result<FailureList<'a>, FailureError> {
        let mut r = Reader::new(body);
        let count = r.u8()?;
        let start = r.rest();
        for _ in 0..count {
            r.u8()?;
            r.str8()?;
            r.str8()?;
        }
        if !r.is_empty() {
            return Err(FailureError::TrailingBytes);
        }
        Ok(FailureList {
            count,
            bytes: start,
        })
    }

    /// The number of codes.
    pub fn len(&self) -> usize {
        usize::from(self.count)
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// The codes in the order sent.
    pub fn iter(&self) -> FailureIter<'a> {
        FailureIter {
            r: Reader::new(self.bytes),
            left: self.count,
        }
    }

    /// What `code` means, if the table names it (the first entry, should
    /// a table name a code twice).
    pub fn get(&self, code: u8) -> Option<FailureView<'a>> {
        self.iter().find(|f| f.code == code)
    }
}

/// One failure code read from a [`FailureList`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FailureView<'a> {
    /// The code.
    pub code: u8,
    /// Its name.
    pub name: &'a str,
    /// What it means and how to fix it.
    pub reason: &'a str,
}

impl fmt::Display for FailureView<'_> {
    /// As [`Failure`] prints.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write_failure(f, self.code, self.name, self.reason)
    }
}

/// Iterates a checked [`FailureList`].
#[derive(Debug, Clone)]
pub struct FailureIter<'a> {
    r: Reader<'a>,
    left: u8,
}

impl<'a> Iterator for FailureIter<'a> {
    type Item = FailureView<'a>;
    fn next(&mut self) -> Option<FailureView<'a>> {
        if self.left == 0 {
            return None;
        }
        self.left -= 1;
        // Checked when decoded: a failed read only ends the iteration.
        let item = (|| {
            Some(FailureView {
                code: self.r.u8().ok()?,
                name: self.r.str8().ok()?,
                reason: self.r.str8().ok()?,
            })
        })();
        if item.is_none() {
            self.left = 0;
        }
        item
    }
    fn size_hint(&self) -> (usize, Option<usize>) {
        (usize::from(self.left), Some(usize::from(self.left)))
    }
}

impl ExactSizeIterator for FailureIter<'_> {}

#[cfg(test)]
mod tests {
    use super::*;

    static TABLE: [Failure; 2] = [
        Failure {
            code: 3,
            name: "Gap",
            reason: "points missing: send them all",
        },
        Failure {
            code: 8,
            name: "Full",
            reason: "",
        },
    ];

    fn tail(parts: SignatureParts, failures: &[Failure]) -> std::vec::Vec<u8> {
        let mut buf = [0u8; 256];
        let mut w = Writer::new(&mut buf);
        encode_tail(&mut w, parts, failures, "").unwrap();
        let n = w.len();
        assert_eq!(n, tail_len(parts, failures, ""));
        buf[..n].to_vec()
    }

    #[test]
    fn a_table_reads_back_and_prints_like_the_static_one() {
        let bytes = tail(SignatureParts::FAILURES, &TABLE);
        assert_eq!(&bytes[..4], &[TAG_FAILURES, 43, 0, 2]);
        let t = decode_tail(&mut Reader::new(&bytes)).unwrap();
        let list = t.failures.unwrap();
        assert_eq!(list.len(), 2);
        let gap = list.get(3).unwrap();
        assert_eq!(
            std::format!("{gap}"),
            "Gap (code 3): points missing: send them all"
        );
        assert_eq!(std::format!("{gap}"), std::format!("{}", TABLE[0]));
        assert_eq!(std::format!("{}", list.get(8).unwrap()), "Full (code 8)");
        assert_eq!(list.get(4), None);
        assert_eq!(t.bytes, &bytes[..]);
    }

    #[test]
    fn no_parts_no_tail_and_an_empty_table_is_a_table() {
        assert!(tail(SignatureParts::NONE, &TABLE).is_empty());
        let bytes = tail(SignatureParts::FAILURES, &[]);
        assert_eq!(bytes, [TAG_FAILURES, 1, 0, 0]);
        let t = decode_tail(&mut Reader::new(&bytes)).unwrap();
        assert!(t.failures.unwrap().is_empty());
        let t = decode_tail(&mut Reader::new(&[])).unwrap();
        assert_eq!(t.failures, None);
    }

    #[test]
    fn unknown_sections_are_skipped_and_bad_ones_refused() {
        let mut bytes = std::vec![9, 2, 0, 0xAA, 0xBB];
        bytes.extend(tail(SignatureParts::FAILURES, &TABLE));
        let t = decode_tail(&mut Reader::new(&bytes)).unwrap();
        assert_eq!(t.failures.unwrap().len(), 2);
        // A known section with a byte too many, or one too few.
        assert_eq!(
            decode_tail(&mut Reader::new(&[1, 2, 0, 0, 0])),
            Err(FailureError::TrailingBytes)
        );
        assert_eq!(
            decode_tail(&mut Reader::new(&[1, 1, 0, 1])),
            Err(FailureError::Truncated)
        );
        assert_eq!(
            decode_tail(&mut Reader::new(&[1, 0])),
            Err(FailureError::Truncated)
        );
        assert_eq!(
            decode_tail(&mut Reader::new(&[1, 4, 0, 1, 3, 1, b'a'])),
            Err(FailureError::Truncated)
        );
        assert_eq!(
            decode_tail(&mut Reader::new(&[1, 5, 0, 1, 3, 1, 0xFF, 0])),
            Err(FailureError::BadUtf8)
        );
    }

    #[test]
    fn tables_beyond_the_limits_are_refused() {
        static TWICE: [Failure; 2] = [
            Failure {
                code: 1,
                name: "A",
                reason: "",
            },
            Failure {
                code: 1,
                name: "B",
                reason: "",
            },
        ];
        assert_eq!(
            check_failures(&TWICE),
            Err(FailureError::DuplicateFailure(1))
        );
        let long = "x".repeat(256).leak();
        let one = [Failure {
            code: 1,
            name: long,
            reason: "",
        }];
        assert_eq!(check_failures(&one), Err(FailureError::NameTooLong));
        assert_eq!(check_failures(&TABLE), Ok(()));
        let mut small = [0u8; 8];
        let mut w = Writer::new(&mut small);
        assert_eq!(
            encode_tail(&mut w, SignatureParts::FAILURES, &TABLE, ""),
            Err(FailureError::NoSpace)
        );
        assert_eq!(w.len(), 0);
    }
}
