//! Dataflow messages: some of a function's outputs delivered to some of
//! another function's inputs (WIRE.md §6).
//!
//! ```text
//! [message key: u8][count: u8] then count × ([destination input index: u8][value])
//! ```
//!
//! Each argument costs two bytes of overhead (its index and its type key) and
//! the receiver needs no stored state to decode it. The part after the key is
//! an [`Args`] list, which later messages of the function protocol (RPC calls
//! and returns) reuse.
//!
//! Message keys are the project's: see [`MessageKey`]. A message is checked
//! whole when it is parsed (every value valid, no index twice, no bytes left
//! over), so iterating it afterwards cannot fail.

use core::fmt;

use osap_core::codec::{CodecError, Reader, Writer};

use crate::value::{Value, ValueError};

/// The first byte of a PIPES message.
///
/// Only the dataflow message is defined so far; keys 2..=255 are reserved for
/// the function protocol (signatures, RPC call and return, pipe get/set/wipe)
/// and 0 is never used, so a zeroed buffer is not a message.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum MessageKey {
    /// Values for some inputs of a function, sent down a pipe.
    PipeDatagram = 1,
}

impl MessageKey {
    /// The key with wire value `b`, if defined.
    pub const fn from_u8(b: u8) -> Option<MessageKey> {
        match b {
            1 => Some(MessageKey::PipeDatagram),
            _ => None,
        }
    }

    /// The wire value.
    pub const fn to_u8(self) -> u8 {
        self as u8
    }
}

/// Why a message could not be read or written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum MessageError {
    /// The message ended early (including inside a value).
    Truncated,
    /// The output buffer is too small.
    NoSpace,
    /// The message key is not defined.
    UnknownKey(u8),
    /// Two arguments name the same input index.
    DuplicateIndex(u8),
    /// More than 255 arguments (the count is one byte).
    TooManyArgs,
    /// Bytes were left over after the last argument.
    TrailingBytes,
    /// The value for input `index` is malformed (or, when writing, cannot be
    /// encoded).
    BadValue {
        /// The destination input index of the argument.
        index: u8,
        /// What is wrong with its value.
        error: ValueError,
    },
}

impl fmt::Display for MessageError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            MessageError::Truncated => f.write_str("message is truncated"),
            MessageError::NoSpace => f.write_str("output buffer is too small for the message"),
            MessageError::UnknownKey(k) => write!(f, "message key {k:#04x} is not defined"),
            MessageError::DuplicateIndex(i) => write!(f, "input index {i} appears twice"),
            MessageError::TooManyArgs => f.write_str("more than 255 arguments"),
            MessageError::TrailingBytes => f.write_str("bytes left over after the message"),
            MessageError::BadValue { index, error } => {
                write!(f, "value for input {index}: {error}")
            }
        }
    }
}

impl core::error::Error for MessageError {}

/// A set of input indices (0..=255).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
struct IndexSet([u32; 8]);

impl IndexSet {
    /// Adds `i`; false if it was already there.
    fn insert(&mut self, i: u8) -> bool {
        let (word, bit) = ((i >> 5) as usize, 1u32 << (i & 31));
        let fresh = self.0[word] & bit == 0;
        self.0[word] |= bit;
        fresh
    }
}

/// Reads one `[index][value]`, mapping errors to message errors.
fn read_arg<'a>(r: &mut Reader<'a>) -> Result<(u8, Value<'a>), MessageError> {
    let index = r.u8().map_err(|_| MessageError::Truncated)?;
    match Value::decode(r) {
        Ok(v) => Ok((index, v)),
        Err(ValueError::Truncated) => Err(MessageError::Truncated),
        Err(error) => Err(MessageError::BadValue { index, error }),
    }
}

/// A checked argument list: `[count: u8]` then count × `[index][value]`,
/// no index twice.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Args<'a> {
    count: u8,
    /// The argument bytes after the count, all valid.
    bytes: &'a [u8],
}

impl<'a> Args<'a> {
    /// Reads and checks an argument list from `r`, leaving `r` after its last
    /// argument. On error `r` is left where it was.
    pub fn decode(r: &mut Reader<'a>) -> Result<Args<'a>, MessageError> {
        let mut t = r.clone();
        let count = t.u8().map_err(|_| MessageError::Truncated)?;
        let start = t.rest();
        let mut seen = IndexSet::default();
        for _ in 0..count {
            let (index, _) = read_arg(&mut t)?;
            if !seen.insert(index) {
                return Err(MessageError::DuplicateIndex(index));
            }
        }
        let used = start.len() - t.rest().len();
        *r = t;
        Ok(Args {
            count,
            bytes: start.get(..used).unwrap_or(&[]),
        })
    }

    /// The number of arguments.
    pub fn len(&self) -> usize {
        self.count as usize
    }

    /// Writes the list as it was read: `[count]` then the arguments.
    pub fn encode(&self, w: &mut Writer<'_>) -> Result<(), CodecError> {
        if w.remaining() < 1 + self.bytes.len() {
            return Err(CodecError::NoSpace);
        }
        w.u8(self.count)?;
        w.bytes(self.bytes)
    }

    /// Whether there are no arguments.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// The arguments as `(destination input index, value)`, in message order.
    pub fn iter(&self) -> ArgIter<'a> {
        ArgIter {
            r: Reader::new(self.bytes),
            left: self.count,
        }
    }

    /// The value for input `index`, if the message carries one.
    pub fn get(&self, index: u8) -> Option<Value<'a>> {
        self.iter().find(|(i, _)| *i == index).map(|(_, v)| v)
    }
}

/// Iterates a checked argument list. Zero-copy: values borrow the message.
#[derive(Debug, Clone)]
pub struct ArgIter<'a> {
    r: Reader<'a>,
    left: u8,
}

impl<'a> Iterator for ArgIter<'a> {
    type Item = (u8, Value<'a>);
    fn next(&mut self) -> Option<(u8, Value<'a>)> {
        if self.left == 0 {
            return None;
        }
        self.left -= 1;
        // The list was checked when it was parsed; an error cannot happen,
        // but if it did the iteration simply ends.
        match read_arg(&mut self.r) {
            Ok(a) => Some(a),
            Err(_) => {
                self.left = 0;
                None
            }
        }
    }
    fn size_hint(&self) -> (usize, Option<usize>) {
        (self.left as usize, Some(self.left as usize))
    }
}

impl ExactSizeIterator for ArgIter<'_> {}

/// A checked PIPES dataflow message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Message<'a> {
    /// The message key.
    pub key: MessageKey,
    /// The arguments.
    pub args: Args<'a>,
}

impl<'a> Message<'a> {
    /// Parses and checks a whole message: a defined key, then an argument
    /// list that ends the input.
    pub fn parse(bytes: &'a [u8]) -> Result<Message<'a>, MessageError> {
        let mut r = Reader::new(bytes);
        let k = r.u8().map_err(|_| MessageError::Truncated)?;
        let key = MessageKey::from_u8(k).ok_or(MessageError::UnknownKey(k))?;
        let args = Args::decode(&mut r)?;
        if !r.is_empty() {
            return Err(MessageError::TrailingBytes);
        }
        Ok(Message { key, args })
    }

    /// Writes a whole message. On error nothing is written.
    pub fn encode(
        w: &mut Writer<'_>,
        key: MessageKey,
        args: &[(u8, Value<'_>)],
    ) -> Result<(), MessageError> {
        let start = w.len();
        let r = (|| {
            let mut m = ArgsWriter::message(w, key)?;
            for (i, v) in args {
                m.push(*i, v)?;
            }
            m.finish()
        })();
        if r.is_err() {
            w.truncate(start);
        }
        r
    }
}

/// Writes an argument list (optionally after a message key) argument by
/// argument, patching the count in at the end.
#[derive(Debug)]
pub struct ArgsWriter<'w, 'b> {
    w: &'w mut Writer<'b>,
    count_at: usize,
    count: u8,
    seen: IndexSet,
}

impl<'w, 'b> ArgsWriter<'w, 'b> {
    /// Starts an argument list in `w` (writes a placeholder count).
    pub fn new(w: &'w mut Writer<'b>) -> Result<Self, MessageError> {
        let count_at = w.len();
        w.u8(0).map_err(|_| MessageError::NoSpace)?;
        Ok(ArgsWriter {
            w,
            count_at,
            count: 0,
            seen: IndexSet::default(),
        })
    }

    /// Starts a message: writes `key`, then starts its argument list.
    pub fn message(w: &'w mut Writer<'b>, key: MessageKey) -> Result<Self, MessageError> {
        if w.remaining() < 2 {
            return Err(MessageError::NoSpace);
        }
        w.u8(key.to_u8()).map_err(|_| MessageError::NoSpace)?;
        ArgsWriter::new(w)
    }

    /// Appends the value for input `index`. On error nothing is appended and
    /// the list stays valid.
    pub fn push(&mut self, index: u8, value: &Value<'_>) -> Result<(), MessageError> {
        if self.count == u8::MAX {
            return Err(MessageError::TooManyArgs);
        }
        let bad = |error| MessageError::BadValue { index, error };
        let len = value.encoded_len().map_err(bad)?;
        if 1 + len > self.w.remaining() {
            return Err(MessageError::NoSpace);
        }
        if !self.seen.insert(index) {
            return Err(MessageError::DuplicateIndex(index));
        }
        self.w.u8(index).map_err(|_| MessageError::NoSpace)?;
        value.encode(self.w).map_err(bad)?;
        self.count += 1;
        Ok(())
    }

    /// How many arguments have been written.
    pub fn len(&self) -> usize {
        self.count as usize
    }

    /// Whether no arguments have been written.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// Writes the count into its place.
    pub fn finish(self) -> Result<(), MessageError> {
        self.w
            .patch_u8(self.count_at, self.count)
            .map_err(|_| MessageError::NoSpace)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn maxl_control_point_is_18_bytes() {
        let mut buf = [0u8; 64];
        let mut w = Writer::new(&mut buf);
        Message::encode(
            &mut w,
            MessageKey::PipeDatagram,
            &[(0, Value::U64(1_000_000)), (1, Value::F32(2.5))],
        )
        .unwrap();
        assert_eq!(w.len(), 18);
        let n = w.len();
        let m = Message::parse(&buf[..n]).unwrap();
        assert_eq!(m.key, MessageKey::PipeDatagram);
        assert_eq!(m.args.len(), 2);
        assert_eq!(m.args.get(1), Some(Value::F32(2.5)));
        assert_eq!(m.args.get(2), None);
        let all: [(u8, Value<'_>); 2] = {
            let mut it = m.args.iter();
            [it.next().unwrap(), it.next().unwrap()]
        };
        assert_eq!(all, [(0, Value::U64(1_000_000)), (1, Value::F32(2.5))]);
    }

    #[test]
    fn parse_errors() {
        assert_eq!(Message::parse(&[]), Err(MessageError::Truncated));
        assert_eq!(Message::parse(&[9, 0]), Err(MessageError::UnknownKey(9)));
        assert_eq!(Message::parse(&[1]), Err(MessageError::Truncated));
        assert_eq!(Message::parse(&[1, 1]), Err(MessageError::Truncated));
        assert_eq!(Message::parse(&[1, 1, 0]), Err(MessageError::Truncated));
        assert_eq!(Message::parse(&[1, 1, 0, 24]), Err(MessageError::Truncated));
        assert_eq!(
            Message::parse(&[1, 2, 4, 0, 4, 0]),
            Err(MessageError::DuplicateIndex(4))
        );
        assert_eq!(
            Message::parse(&[1, 1, 7, 1, 2]),
            Err(MessageError::BadValue {
                index: 7,
                error: ValueError::BadBool(2)
            })
        );
        assert_eq!(Message::parse(&[1, 0, 0]), Err(MessageError::TrailingBytes));
        assert_eq!(Message::parse(&[1, 0]).map(|m| m.args.len()), Ok(0));
    }

    #[test]
    fn writer_errors_leave_nothing_behind() {
        let mut buf = [0u8; 8];
        let mut w = Writer::new(&mut buf);
        let r = Message::encode(
            &mut w,
            MessageKey::PipeDatagram,
            &[(0, Value::U8(1)), (0, Value::U8(2))],
        );
        assert_eq!(r, Err(MessageError::DuplicateIndex(0)));
        assert_eq!(w.len(), 0);
        let r = Message::encode(&mut w, MessageKey::PipeDatagram, &[(0, Value::U64(1))]);
        assert_eq!(r, Err(MessageError::NoSpace));
        assert_eq!(w.len(), 0);

        let mut m = ArgsWriter::message(&mut w, MessageKey::PipeDatagram).unwrap();
        m.push(3, &Value::U8(9)).unwrap();
        assert_eq!(m.push(4, &Value::U64(1)), Err(MessageError::NoSpace));
        assert_eq!(
            m.push(4, &Value::ascii("é")),
            Err(MessageError::BadValue {
                index: 4,
                error: ValueError::NotAscii
            })
        );
        m.finish().unwrap();
        let n = w.len();
        assert_eq!(&buf[..n], &[1, 1, 3, 24, 9]);
    }

    #[test]
    fn at_most_255_args() {
        let mut buf = [0u8; 1024];
        let mut w = Writer::new(&mut buf);
        let mut m = ArgsWriter::new(&mut w).unwrap();
        for i in 0..=254u8 {
            m.push(i, &Value::Null).unwrap();
        }
        assert_eq!(m.push(255, &Value::Null), Err(MessageError::TooManyArgs));
        m.finish().unwrap();
        let n = w.len();
        let a = Args::decode(&mut Reader::new(&buf[..n])).unwrap();
        assert_eq!(a.len(), 255);
        assert!(a.iter().map(|(i, _)| i).eq(0..=254));
    }
}
