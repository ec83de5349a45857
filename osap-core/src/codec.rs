//! Bounds-checked little-endian readers and writers over byte slices.
//!
//! Every message body in osap-core is a fixed sequence of little-endian fields
//! and short strings. These two cursors make each field access a checked
//! operation that returns an error instead of panicking, so a truncated or
//! malicious body can never index out of range.

use core::fmt;

/// The body being read or written was too short, or a string was not UTF-8.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum CodecError {
    /// A read ran past the end of the input.
    Truncated,
    /// A write ran past the end of the output buffer.
    NoSpace,
    /// A string field did not hold valid UTF-8.
    BadUtf8,
    /// A string was longer than its length prefix (or the receiver) allows.
    StringTooLong,
}

impl fmt::Display for CodecError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            CodecError::Truncated => "message body is truncated",
            CodecError::NoSpace => "output buffer is too small",
            CodecError::BadUtf8 => "string is not valid UTF-8",
            CodecError::StringTooLong => "string is too long",
        })
    }
}

impl core::error::Error for CodecError {}

/// Reads fields from the front of a byte slice.
#[derive(Debug, Clone)]
pub struct Reader<'a> {
    buf: &'a [u8],
}

impl<'a> Reader<'a> {
    /// A reader over `buf`.
    pub const fn new(buf: &'a [u8]) -> Self {
        Reader { buf }
    }

    /// The bytes not yet read.
    pub fn rest(&self) -> &'a [u8] {
        self.buf
    }

    /// Whether every byte has been read.
    pub fn is_empty(&self) -> bool {
        self.buf.is_empty()
    }

    /// Takes the next `n` bytes.
    pub fn bytes(&mut self, n: usize) -> Result<&'a [u8], CodecError> {
        if n > self.buf.len() {
            return Err(CodecError::Truncated);
        }
        let (head, tail) = self.buf.split_at(n);
        self.buf = tail;
        Ok(head)
    }

    /// Takes the next `N` bytes as an array.
    pub fn array<const N: usize>(&mut self) -> Result<[u8; N], CodecError> {
        let mut out = [0u8; N];
        out.copy_from_slice(self.bytes(N)?);
        Ok(out)
    }

    /// Reads a `u8`.
    pub fn u8(&mut self) -> Result<u8, CodecError> {
        Ok(self.array::<1>()?[0])
    }

    /// Reads a little-endian `u16`.
    pub fn u16(&mut self) -> Result<u16, CodecError> {
        Ok(u16::from_le_bytes(self.array()?))
    }

    /// Reads a little-endian `u32`.
    pub fn u32(&mut self) -> Result<u32, CodecError> {
        Ok(u32::from_le_bytes(self.array()?))
    }

    /// Reads a little-endian `u64`.
    pub fn u64(&mut self) -> Result<u64, CodecError> {
        Ok(u64::from_le_bytes(self.array()?))
    }

    /// Reads a little-endian `i64`.
    pub fn i64(&mut self) -> Result<i64, CodecError> {
        Ok(i64::from_le_bytes(self.array()?))
    }

    /// Reads a little-endian IEEE 754 `f32`.
    pub fn f32(&mut self) -> Result<f32, CodecError> {
        Ok(f32::from_le_bytes(self.array()?))
    }

    /// Reads a short string: a `u8` length, then that many UTF-8 bytes.
    pub fn str8(&mut self) -> Result<&'a str, CodecError> {
        let len = self.u8()? as usize;
        core::str::from_utf8(self.bytes(len)?).map_err(|_| CodecError::BadUtf8)
    }
}

/// Writes fields into a byte slice, front to back.
#[derive(Debug)]
pub struct Writer<'a> {
    buf: &'a mut [u8],
    len: usize,
}

impl<'a> Writer<'a> {
    /// A writer that fills `buf` from its start.
    pub fn new(buf: &'a mut [u8]) -> Self {
        Writer { buf, len: 0 }
    }

    /// How many bytes have been written.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether nothing has been written yet.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// How many bytes can still be written.
    pub fn remaining(&self) -> usize {
        self.buf.len() - self.len
    }

    /// Appends raw bytes.
    pub fn bytes(&mut self, data: &[u8]) -> Result<(), CodecError> {
        let end = self
            .len
            .checked_add(data.len())
            .ok_or(CodecError::NoSpace)?;
        let dst = self.buf.get_mut(self.len..end).ok_or(CodecError::NoSpace)?;
        dst.copy_from_slice(data);
        self.len = end;
        Ok(())
    }

    /// Appends a `u8`.
    pub fn u8(&mut self, v: u8) -> Result<(), CodecError> {
        self.bytes(&[v])
    }

    /// Appends a little-endian `u16`.
    pub fn u16(&mut self, v: u16) -> Result<(), CodecError> {
        self.bytes(&v.to_le_bytes())
    }

    /// Appends a little-endian `u32`.
    pub fn u32(&mut self, v: u32) -> Result<(), CodecError> {
        self.bytes(&v.to_le_bytes())
    }

    /// Appends a little-endian `u64`.
    pub fn u64(&mut self, v: u64) -> Result<(), CodecError> {
        self.bytes(&v.to_le_bytes())
    }

    /// Appends a little-endian `i64`.
    pub fn i64(&mut self, v: i64) -> Result<(), CodecError> {
        self.bytes(&v.to_le_bytes())
    }

    /// Appends a little-endian IEEE 754 `f32`.
    pub fn f32(&mut self, v: f32) -> Result<(), CodecError> {
        self.bytes(&v.to_le_bytes())
    }

    /// Appends a short string: a `u8` length, then the UTF-8 bytes.
    pub fn str8(&mut self, s: &str) -> Result<(), CodecError> {
        let len = u8::try_from(s.len()).map_err(|_| CodecError::StringTooLong)?;
        // Check the whole field first so a failed write leaves no partial string.
        if self.remaining() < 1 + s.len() {
            return Err(CodecError::NoSpace);
        }
        self.u8(len)?;
        self.bytes(s.as_bytes())
    }

    /// Overwrites an already written byte (for counts known only at the end).
    pub fn patch_u8(&mut self, at: usize, v: u8) -> Result<(), CodecError> {
        if at >= self.len {
            return Err(CodecError::NoSpace);
        }
        self.buf[at] = v;
        Ok(())
    }

    /// Forgets everything written after the first `len` bytes.
    pub fn truncate(&mut self, len: usize) {
        self.len = self.len.min(len);
    }

    /// Consumes the writer, returning the written prefix of the buffer.
    pub fn finish(self) -> &'a mut [u8] {
        let len = self.len;
        &mut self.buf[..len]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_fields() {
        let mut buf = [0u8; 32];
        let mut w = Writer::new(&mut buf);
        w.u8(7).unwrap();
        w.u16(0x1234).unwrap();
        w.u32(0xdead_beef).unwrap();
        w.str8("abc").unwrap();
        let n = w.len();
        let mut r = Reader::new(&buf[..n]);
        assert_eq!(r.u8(), Ok(7));
        assert_eq!(r.u16(), Ok(0x1234));
        assert_eq!(r.u32(), Ok(0xdead_beef));
        assert_eq!(r.str8(), Ok("abc"));
        assert!(r.is_empty());
        assert_eq!(r.u8(), Err(CodecError::Truncated));
    }

    #[test]
    fn writer_refuses_overflow() {
        let mut buf = [0u8; 3];
        let mut w = Writer::new(&mut buf);
        assert_eq!(w.u32(1), Err(CodecError::NoSpace));
        assert_eq!(w.len(), 0);
        w.u16(1).unwrap();
        assert_eq!(w.str8("a"), Err(CodecError::NoSpace));
    }

    #[test]
    fn reader_rejects_bad_strings() {
        assert_eq!(Reader::new(&[3, b'a']).str8(), Err(CodecError::Truncated));
        assert_eq!(Reader::new(&[1, 0xff]).str8(), Err(CodecError::BadUtf8));
    }
}
