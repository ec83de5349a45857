//! A function's documentation, sent with its signature.
//!
//! A function's `///` doc comment is its text
//! ([`crate::function::Implementation::docs`]): the macros fill it from
//! the doc attributes, as rustdoc shows them, its lines joined by `\n`.
//! It lives in flash (`&'static str`) and is never copied: the reply reads
//! it in place, a window at a time.
//!
//! On the wire (`docs/pipes.md` §5) it is two sections of the signature
//! reply's tail ([`crate::failure`]), each sent only when the request's
//! `parts` asks for it:
//!
//! ```text
//! bit 1  tag 2  summary: UTF-8, the first sentence of the text (its line breaks sent as spaces)
//! bit 2  tag 3  docs:    UTF-8, the whole text
//! ```
//!
//! A function without docs answers empty sections. The text is at most
//! [`MAX_DOCS`] bytes: a function whose text is longer is refused when it
//! is made (and the macros refuse it at compile time), so that the reply
//! fits a host's reassembly buffer with the signature and the failure table.

use osap_core::segment::Window;

use crate::failure::FailureError;

/// The section tag of a function's summary line.
pub const TAG_SUMMARY: u8 = 2;
/// The section tag of a function's whole documentation.
pub const TAG_DOCS: u8 = 3;
/// The longest documentation a function may publish, bytes of UTF-8.
pub const MAX_DOCS: usize = 2048;

/// Checks a text before it is published: at most [`MAX_DOCS`] bytes.
pub fn check_docs(docs: &str) -> Result<(), FailureError> {
    if docs.len() > MAX_DOCS {
        return Err(FailureError::DocsTooLong);
    }
    Ok(())
}

/// The summary of `docs`, as a slice of it: the first sentence of its first
/// paragraph (up to the first `.` that ends a word holding no other `.`, so
/// `e.g.` and `..` do not end it), or the whole first paragraph if no
/// sentence ends in it. Its line breaks are sent as spaces
/// ([`summary_len`], [`write_summary`]).
pub fn summary(docs: &str) -> &str {
    let docs = docs.trim_start();
    let para = docs.split("\n\n").next().unwrap_or(docs);
    let b = para.as_bytes();
    let mut word_start = 0;
    for (i, &c) in b.iter().enumerate() {
        if c == b' ' || c == b'\n' {
            word_start = i + 1;
            continue;
        }
        let ends = b.get(i + 1).is_none_or(|n| *n == b' ' || *n == b'\n');
        // `i` and `word_start` are ASCII positions: char boundaries.
        let word = para.get(word_start..i).unwrap_or("");
        if c == b'.' && ends && !word.is_empty() && !word.contains('.') {
            return para.get(..=i).unwrap_or(para);
        }
    }
    para.trim_end()
}

/// Bytes of [`summary`]`(docs)` as sent (line breaks become spaces: the
/// same length).
pub fn summary_len(docs: &str) -> usize {
    summary(docs).len()
}

/// Writes [`summary`]`(docs)` with its line breaks as spaces.
pub fn write_summary(w: &mut Window<'_>, docs: &str) {
    let mut lines = summary(docs).split('\n');
    if let Some(first) = lines.next() {
        w.put(first.as_bytes());
    }
    for line in lines {
        w.put(b" ");
        w.put(line.as_bytes());
    }
}

/// Reads a text section's body.
pub(crate) fn decode_text(body: &[u8]) -> Result<&str, FailureError> {
    core::str::from_utf8(body).map_err(|_| FailureError::BadUtf8)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_summary_is_the_first_sentence() {
        assert_eq!(
            summary("Queues a point: at `time`.\nThen it runs."),
            "Queues a point: at `time`."
        );
        // Across a line break, not past the paragraph.
        assert_eq!(
            summary("Sets the microstep mode (1, 2, 4, ..\n256, e.g. 16).\nMore."),
            "Sets the microstep mode (1, 2, 4, ..\n256, e.g. 16)."
        );
        assert_eq!(
            summary("No full stop\nat all\n\nSecond."),
            "No full stop\nat all"
        );
        assert_eq!(summary("\n  Leading space.  "), "Leading space.");
        assert_eq!(summary("Ends at the end."), "Ends at the end.");
        assert_eq!(summary("A 1.5 mm step. B."), "A 1.5 mm step.");
        assert_eq!(summary(""), "");
        assert_eq!(summary("."), ".");
    }

    #[test]
    fn the_summary_is_sent_on_one_line() {
        let docs = "Two\nlines. And more.";
        let mut buf = [0u8; 32];
        let mut w = Window::new(0, &mut buf);
        write_summary(&mut w, docs);
        let n = w.written();
        assert_eq!(&buf[..n], b"Two lines.");
        assert_eq!(n, summary_len(docs));
    }

    #[test]
    fn texts_beyond_the_limit_are_refused() {
        use crate::function::{CallError, Implementation, Outputs, PipesFunction};
        use crate::signature::{Signature, SignatureError};
        use crate::value::Value;

        let long = "x".repeat(MAX_DOCS + 1);
        assert_eq!(check_docs(&long), Err(FailureError::DocsTooLong));
        assert_eq!(check_docs(&long[..MAX_DOCS]), Ok(()));
        assert_eq!(decode_text(&[0xFF]), Err(FailureError::BadUtf8));

        static SIG: Signature = Signature {
            name: "chatty",
            inputs: &[],
            outputs: &[],
        };
        struct Chatty(&'static str);
        impl Implementation for Chatty {
            fn signature(&self) -> &'static Signature {
                &SIG
            }
            fn call(&mut self, _: &[Value<'_>], _: &mut Outputs<'_>) -> Result<(), CallError> {
                Ok(())
            }
            fn docs(&self) -> &'static str {
                self.0
            }
        }
        let long: &'static str = long.leak();
        let f = PipesFunction::<_, 0, 1, 8>::new(Chatty(long));
        assert_eq!(f.err(), Some(SignatureError::DocsTooLong));
        assert_eq!(
            std::format!("{}", SignatureError::DocsTooLong),
            "the documentation is longer than 2048 bytes: shorten it"
        );
        assert!(PipesFunction::<_, 0, 1, 8>::new(Chatty(&long[..MAX_DOCS])).is_ok());
    }
}
