//! Function signatures: a name, named typed inputs and named typed outputs.
//!
//! Firmware declares its signatures statically ([`Signature`], [`Arg`], all
//! `&'static`); the host reads them back from the "get signature" reply with
//! the zero-copy [`SignatureView`]. The wire layout (`docs/pipes.md` §5) is
//!
//! ```text
//! [name: str8][n_in: u8] n_in × ([name: str8][type key: u8])
//!             [n_out: u8] n_out × ([name: str8][type key: u8])
//! ```
//!
//! where `str8` is a `u8` byte length followed by UTF-8. A reply to a
//! request that asks for more (`[2][parts]`) appends sections after it,
//! such as the function's failure table ([`crate::failure`]);
//! [`SignatureView::decode_described`] reads them.

use core::fmt;

use osap_core::codec::{CodecError, Reader, Writer};
use osap_core::segment::Window;

use crate::failure::{decode_tail, FailureError, FailureList, Tail};
use crate::types::Type;
use crate::value::ValueError;

/// The most inputs, and the most outputs, a PIPES function may have here.
///
/// Functions keep one fixed store per input, so this bounds their memory.
pub const MAX_ARGS: usize = 8;

/// One named, typed input or output.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Arg {
    /// The argument's name (at most 255 bytes of UTF-8).
    pub name: &'static str,
    /// Its type.
    pub ty: Type,
}

impl Arg {
    /// An argument named `name` of type `ty`.
    pub const fn new(name: &'static str, ty: Type) -> Arg {
        Arg { name, ty }
    }
}

/// A function's signature, declared statically.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Signature {
    /// The function's name (at most 255 bytes).
    pub name: &'static str,
    /// Its inputs, by index (at most [`MAX_ARGS`]).
    pub inputs: &'static [Arg],
    /// Its outputs, by index (at most [`MAX_ARGS`]).
    pub outputs: &'static [Arg],
}

/// Why a signature could not be written or read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum SignatureError {
    /// The bytes end early.
    Truncated,
    /// The output buffer is too small.
    NoSpace,
    /// A name is not valid UTF-8.
    BadUtf8,
    /// A name is longer than 255 bytes.
    NameTooLong,
    /// More than [`MAX_ARGS`] inputs or outputs.
    TooManyArgs,
    /// An argument's type key names no type.
    BadType {
        /// Whether it is an output (else an input).
        output: bool,
        /// The argument's index.
        index: u8,
        /// Why the key is refused.
        error: ValueError,
    },
    /// Bytes were left over after the signature.
    TrailingBytes,
    /// A failure table has more than 255 codes, or more than a section's
    /// 65 535 bytes ([`crate::failure`]).
    TooManyFailures,
    /// A failure table names this code twice.
    DuplicateFailure(u8),
    /// The documentation is longer than [`crate::docs::MAX_DOCS`] bytes.
    DocsTooLong,
}

impl fmt::Display for SignatureError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SignatureError::Truncated => f.write_str("signature is truncated"),
            SignatureError::NoSpace => f.write_str("output buffer is too small for the signature"),
            SignatureError::BadUtf8 => f.write_str("a name is not valid UTF-8"),
            SignatureError::NameTooLong => f.write_str("a name is longer than 255 bytes"),
            SignatureError::TooManyArgs => write!(f, "more than {MAX_ARGS} inputs or outputs"),
            SignatureError::BadType {
                output,
                index,
                error,
            } => {
                let side = if *output { "output" } else { "input" };
                write!(f, "{side} {index}: {error}")
            }
            SignatureError::TrailingBytes => f.write_str("bytes left over after the signature"),
            SignatureError::TooManyFailures => {
                f.write_str("the failure table has more than 255 codes or 65 535 bytes")
            }
            SignatureError::DuplicateFailure(code) => {
                write!(f, "the failure table names code {code} twice")
            }
            SignatureError::DocsTooLong => FailureError::DocsTooLong.fmt(f),
        }
    }
}

impl core::error::Error for SignatureError {}

impl From<FailureError> for SignatureError {
    fn from(e: FailureError) -> Self {
        match e {
            FailureError::NoSpace => SignatureError::NoSpace,
            FailureError::BadUtf8 => SignatureError::BadUtf8,
            FailureError::NameTooLong => SignatureError::NameTooLong,
            FailureError::TrailingBytes => SignatureError::TrailingBytes,
            FailureError::TooManyFailures => SignatureError::TooManyFailures,
            FailureError::DuplicateFailure(code) => SignatureError::DuplicateFailure(code),
            FailureError::DocsTooLong => SignatureError::DocsTooLong,
            // Truncated, or a failure error a newer pipes-core adds.
            _ => SignatureError::Truncated,
        }
    }
}

impl From<CodecError> for SignatureError {
    fn from(e: CodecError) -> Self {
        match e {
            CodecError::Truncated => SignatureError::Truncated,
            CodecError::NoSpace => SignatureError::NoSpace,
            CodecError::BadUtf8 => SignatureError::BadUtf8,
            CodecError::StringTooLong => SignatureError::NameTooLong,
            // A codec error a newer osap-core adds: the body could not be read.
            _ => SignatureError::Truncated,
        }
    }
}

impl Signature {
    /// Checks the limits: names of at most 255 bytes, at most [`MAX_ARGS`]
    /// inputs and outputs.
    pub fn check(&self) -> Result<(), SignatureError> {
        if self.inputs.len() > MAX_ARGS || self.outputs.len() > MAX_ARGS {
            return Err(SignatureError::TooManyArgs);
        }
        let names = self.inputs.iter().chain(self.outputs).map(|a| a.name);
        if core::iter::once(self.name)
            .chain(names)
            .any(|n| n.len() > usize::from(u8::MAX))
        {
            return Err(SignatureError::NameTooLong);
        }
        Ok(())
    }

    /// How many bytes [`encode`](Signature::encode) writes.
    pub fn encoded_len(&self) -> usize {
        let args = |a: &[Arg]| 1 + a.iter().map(|a| 2 + a.name.len()).sum::<usize>();
        1 + self.name.len() + args(self.inputs) + args(self.outputs)
    }

    /// Writes the signature. On error nothing is written.
    pub fn encode(&self, w: &mut Writer<'_>) -> Result<(), SignatureError> {
        self.check()?;
        if self.encoded_len() > w.remaining() {
            return Err(SignatureError::NoSpace);
        }
        w.str8(self.name)?;
        for list in [self.inputs, self.outputs] {
            // check() bounds the count by MAX_ARGS.
            w.u8(list.len() as u8)?;
            for a in list {
                w.str8(a.name)?;
                w.u8(a.ty.key())?;
            }
        }
        Ok(())
    }

    /// Writes the same bytes as [`encode`](Signature::encode), field by
    /// field, into a window: how a signature longer than one packet is
    /// sent in segments without a buffer for all of it. The signature must
    /// pass [`check`](Signature::check) (a function checks it once, when it
    /// is made); a longer name is cut to 255 bytes here.
    pub fn write_pieces(&self, w: &mut Window<'_>) {
        self.write_pieces_named(self.name, w)
    }

    /// [`encoded_len`](Signature::encoded_len) with `name` in place of the
    /// signature's own (cut to 255 bytes, as written).
    pub fn encoded_len_named(&self, name: &str) -> usize {
        self.encoded_len() - self.name.len().min(255) + name.len().min(255)
    }

    /// [`write_pieces`](Signature::write_pieces) with `name` in place of
    /// the signature's own: a function named at run time.
    pub fn write_pieces_named(&self, name: &str, w: &mut Window<'_>) {
        let str8 = |w: &mut Window<'_>, s: &str| {
            let b = &s.as_bytes()[..s.len().min(255)];
            w.put(&[b.len() as u8]);
            w.put(b);
        };
        str8(w, name);
        for list in [self.inputs, self.outputs] {
            w.put(&[list.len().min(MAX_ARGS) as u8]);
            for a in list.iter().take(MAX_ARGS) {
                if w.is_full() {
                    return;
                }
                str8(w, a.name);
                w.put(&[a.ty.key()]);
            }
        }
    }

    /// Whether `view` describes this same signature.
    pub fn matches(&self, view: &SignatureView<'_>) -> bool {
        let same = |a: &[Arg], b: ArgList<'_>| {
            a.len() == b.len()
                && a.iter()
                    .zip(b.iter())
                    .all(|(x, y)| x.name == y.name && x.ty == y.ty)
        };
        self.name == view.name()
            && same(self.inputs, view.inputs())
            && same(self.outputs, view.outputs())
    }
}

/// One argument read from a [`SignatureView`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ArgView<'a> {
    /// The argument's name.
    pub name: &'a str,
    /// Its type.
    pub ty: Type,
}

/// A checked list of arguments inside a [`SignatureView`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ArgList<'a> {
    count: u8,
    bytes: &'a [u8],
}

impl<'a> ArgList<'a> {
    fn decode(r: &mut Reader<'a>, output: bool) -> Result<ArgList<'a>, SignatureError> {
        let count = r.u8()?;
        if usize::from(count) > MAX_ARGS {
            return Err(SignatureError::TooManyArgs);
        }
        let start = r.rest();
        for index in 0..count {
            r.str8()?;
            let key = r.u8()?;
            Type::from_key(key).map_err(|error| SignatureError::BadType {
                output,
                index,
                error,
            })?;
        }
        let used = start.len() - r.rest().len();
        Ok(ArgList {
            count,
            bytes: start.get(..used).unwrap_or(&[]),
        })
    }

    /// The number of arguments.
    pub fn len(&self) -> usize {
        usize::from(self.count)
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// The arguments in index order.
    pub fn iter(&self) -> ArgViewIter<'a> {
        ArgViewIter {
            r: Reader::new(self.bytes),
            left: self.count,
        }
    }

    /// The argument at `index`.
    pub fn get(&self, index: usize) -> Option<ArgView<'a>> {
        self.iter().nth(index)
    }
}

/// Iterates a checked [`ArgList`].
#[derive(Debug, Clone)]
pub struct ArgViewIter<'a> {
    r: Reader<'a>,
    left: u8,
}

impl<'a> Iterator for ArgViewIter<'a> {
    type Item = ArgView<'a>;
    fn next(&mut self) -> Option<ArgView<'a>> {
        if self.left == 0 {
            return None;
        }
        self.left -= 1;
        // Checked when decoded: these reads cannot fail, and if they did the
        // iteration would simply end.
        let item = (|| {
            let name = self.r.str8().ok()?;
            let ty = Type::from_key(self.r.u8().ok()?).ok()?;
            Some(ArgView { name, ty })
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

impl ExactSizeIterator for ArgViewIter<'_> {}

/// A signature read in place from its wire form (the host side).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SignatureView<'a> {
    name: &'a str,
    inputs: ArgList<'a>,
    outputs: ArgList<'a>,
    bytes: &'a [u8],
    tail: Tail<'a>,
}

impl<'a> SignatureView<'a> {
    /// Reads and checks a signature from `r`, leaving `r` after it. On error
    /// `r` is left where it was.
    pub fn decode(r: &mut Reader<'a>) -> Result<SignatureView<'a>, SignatureError> {
        let mut t = r.clone();
        let start = t.rest();
        let name = t.str8()?;
        let inputs = ArgList::decode(&mut t, false)?;
        let outputs = ArgList::decode(&mut t, true)?;
        let used = start.len() - t.rest().len();
        *r = t;
        Ok(SignatureView {
            name,
            inputs,
            outputs,
            bytes: start.get(..used).unwrap_or(&[]),
            tail: Tail::default(),
        })
    }

    /// Reads a signature and every section after it to the end of `r` (a
    /// reply to `[2][parts]`; see [`crate::failure`]). A signature with
    /// no tail (the old layout) reads as one without a failure table. On
    /// error `r` is left where it was.
    pub fn decode_described(r: &mut Reader<'a>) -> Result<SignatureView<'a>, SignatureError> {
        let mut t = r.clone();
        let mut v = SignatureView::decode(&mut t)?;
        v.tail = decode_tail(&mut t)?;
        *r = t;
        Ok(v)
    }

    /// Reads a signature that must fill `bytes` exactly.
    pub fn parse(bytes: &'a [u8]) -> Result<SignatureView<'a>, SignatureError> {
        let mut r = Reader::new(bytes);
        let v = SignatureView::decode(&mut r)?;
        if !r.is_empty() {
            return Err(SignatureError::TrailingBytes);
        }
        Ok(v)
    }

    /// The function's name.
    pub fn name(&self) -> &'a str {
        self.name
    }

    /// Its inputs.
    pub fn inputs(&self) -> ArgList<'a> {
        self.inputs
    }

    /// Its outputs.
    pub fn outputs(&self) -> ArgList<'a> {
        self.outputs
    }

    /// The signature's bytes, as read (without the tail).
    pub fn as_bytes(&self) -> &'a [u8] {
        self.bytes
    }

    /// The function's failure table, if the reply had one: `None` for a
    /// reply in the old layout, or to a request that did not ask for it.
    pub fn failures(&self) -> Option<FailureList<'a>> {
        self.tail.failures
    }

    /// The function's summary line (the first sentence of its docs), if
    /// the reply had one: `None` for a reply that did not carry it (not
    /// asked for, or a function from before the docs); `Some("")` for a
    /// function without docs ([`crate::docs`]).
    pub fn summary(&self) -> Option<&'a str> {
        self.tail.summary
    }

    /// The function's whole documentation, if the reply had it (as
    /// [`summary`](Self::summary)).
    pub fn docs(&self) -> Option<&'a str> {
        self.tail.docs
    }

    /// The tail's bytes, as read (empty in the old layout).
    pub fn tail_bytes(&self) -> &'a [u8] {
        self.tail.bytes
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::types::ScalarType;

    static ADD: Signature = Signature {
        name: "add",
        inputs: &[
            Arg::new("a", Type::Scalar(ScalarType::F32)),
            Arg::new("b", Type::Scalar(ScalarType::F32)),
        ],
        outputs: &[Arg::new("sum", Type::Scalar(ScalarType::F32))],
    };

    #[test]
    fn pieces_in_any_window_are_the_encoding() {
        let mut full = [0u8; 64];
        let mut w = Writer::new(&mut full);
        ADD.encode(&mut w).unwrap();
        let n = w.len();
        for start in 0..=n {
            for size in 0..=n - start + 2 {
                let mut out = [0xAAu8; 64];
                let mut win = Window::new(start, &mut out[..size]);
                ADD.write_pieces(&mut win);
                let got = win.written();
                assert_eq!(got, size.min(n - start), "{start} {size}");
                assert_eq!(out[..got], full[start..start + got]);
            }
        }
    }

    #[test]
    fn round_trip() {
        let mut buf = [0u8; 64];
        let mut w = Writer::new(&mut buf);
        ADD.encode(&mut w).unwrap();
        let n = w.len();
        assert_eq!(n, ADD.encoded_len());
        assert_eq!(
            &buf[..n],
            &[3, b'a', b'd', b'd', 2, 1, b'a', 34, 1, b'b', 34, 1, 3, b's', b'u', b'm', 34]
        );
        let v = SignatureView::parse(&buf[..n]).unwrap();
        assert_eq!(v.name(), "add");
        assert_eq!(v.inputs().len(), 2);
        assert_eq!(v.inputs().iter().len(), 2);
        assert_eq!(
            v.outputs().get(0),
            Some(ArgView {
                name: "sum",
                ty: Type::Scalar(ScalarType::F32)
            })
        );
        assert!(ADD.matches(&v));
        assert_eq!(v.as_bytes(), &buf[..n]);
    }

    #[test]
    fn errors_leave_nothing() {
        let mut buf = [0u8; 10];
        let mut w = Writer::new(&mut buf);
        assert_eq!(ADD.encode(&mut w), Err(SignatureError::NoSpace));
        assert_eq!(w.len(), 0);
        static MANY: Signature = Signature {
            name: "x",
            inputs: &[Arg::new("", Type::Null); 9],
            outputs: &[],
        };
        assert_eq!(MANY.check(), Err(SignatureError::TooManyArgs));
    }

    #[test]
    fn decode_errors() {
        assert_eq!(SignatureView::parse(&[]), Err(SignatureError::Truncated));
        assert_eq!(
            SignatureView::parse(&[1, b'f', 0]),
            Err(SignatureError::Truncated)
        );
        assert_eq!(
            SignatureView::parse(&[1, b'f', 9]),
            Err(SignatureError::TooManyArgs)
        );
        assert_eq!(
            SignatureView::parse(&[1, b'f', 0, 1, 0, 3]),
            Err(SignatureError::BadType {
                output: true,
                index: 0,
                error: ValueError::ReservedType(3)
            })
        );
        assert_eq!(
            SignatureView::parse(&[1, 0xff, 0, 0]),
            Err(SignatureError::BadUtf8)
        );
        assert_eq!(
            SignatureView::parse(&[0, 0, 0, 0]),
            Err(SignatureError::TrailingBytes)
        );
        let mut r = Reader::new(&[1, b'f', 1]);
        assert!(SignatureView::decode(&mut r).is_err());
        assert_eq!(r.rest().len(), 3);
    }
}
