//! PIPES values and their codec (WIRE.md §6).
//!
//! A value on the wire is `[type key: u8][value]`:
//!
//! - null: nothing; bool: one byte, 0 or 1 (anything else is an error);
//! - integers and floats: their little-endian bytes (f16 is IEEE binary16,
//!   kept as its raw bits in [`Value::F16`]);
//! - ascii and utf8: a `u16` byte length, then the bytes; ascii must be all
//!   ASCII and utf8 valid UTF-8;
//! - arrays: a `u16` element count, then the bare little-endian elements;
//! - tensors: a `u8` rank, rank × `u16` dims, then the bare elements,
//!   row-major; the element count is the product of the dims (1 for rank 0).
//!
//! Decoding borrows strings and element bytes from the input, so nothing is
//! copied or allocated. Every length is checked against the input before it
//! is used; no input can make decoding panic.
//!
//! With the `alloc` feature a [`Value`] can also own its data: a
//! `Value<'static>` built from `String`s and `Vec`s (or made with
//! [`Value::into_owned`]) is what host code keeps. Owned or borrowed, a value
//! encodes to the same bytes and compares equal to the other form.

use core::fmt;
use core::ops::Deref;

#[cfg(feature = "alloc")]
use alloc::{borrow::ToOwned, string::String, vec::Vec};

use osap_core::codec::{CodecError, Reader, Writer};

use crate::types::{ScalarType, Type};

/// Why a value could not be decoded or encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum ValueError {
    /// The input ended inside a value (or a length runs past the input).
    Truncated,
    /// The output buffer is too small for the value.
    NoSpace,
    /// The type key names no type.
    UnknownType(u8),
    /// The type key is reserved (`unknown`, `f128`, or arrays/tensors of them).
    ReservedType(u8),
    /// A bool (or bool element) was neither 0 nor 1.
    BadBool(u8),
    /// An `ascii` string held a byte above 0x7f.
    NotAscii,
    /// A `utf8` string was not valid UTF-8.
    BadUtf8,
    /// A string is longer than its `u16` length prefix can say.
    StringTooLong,
    /// An array has more than 65535 elements, a tensor more than 255 dims, or
    /// a tensor's element count or byte size overflows.
    TooLarge,
    /// An array's or tensor's element bytes do not match its element type and
    /// shape (a partial element, or a dims product that does not match).
    ShapeMismatch,
    /// Bytes were left over after a value that should have ended the input.
    TrailingBytes,
}

impl fmt::Display for ValueError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ValueError::Truncated => f.write_str("value is truncated"),
            ValueError::NoSpace => f.write_str("output buffer is too small for the value"),
            ValueError::UnknownType(k) => write!(f, "type key {k:#04x} names no type"),
            ValueError::ReservedType(k) => write!(f, "type key {k:#04x} is reserved"),
            ValueError::BadBool(b) => write!(f, "bool byte {b:#04x} is neither 0 nor 1"),
            ValueError::NotAscii => f.write_str("ascii string holds a non-ASCII byte"),
            ValueError::BadUtf8 => f.write_str("utf8 string is not valid UTF-8"),
            ValueError::StringTooLong => f.write_str("string is longer than 65535 bytes"),
            ValueError::TooLarge => f.write_str("array or tensor is too large"),
            ValueError::ShapeMismatch => {
                f.write_str("element bytes do not match the element type and shape")
            }
            ValueError::TrailingBytes => f.write_str("bytes left over after the value"),
        }
    }
}

impl core::error::Error for ValueError {}

impl From<CodecError> for ValueError {
    fn from(e: CodecError) -> Self {
        match e {
            CodecError::Truncated => ValueError::Truncated,
            CodecError::NoSpace => ValueError::NoSpace,
            CodecError::BadUtf8 => ValueError::BadUtf8,
            CodecError::StringTooLong => ValueError::StringTooLong,
            // A codec error a newer osap-core adds: the body could not be read.
            _ => ValueError::Truncated,
        }
    }
}

/// A PIPES value. Its strings and element bytes are borrowed (decoding
/// copies nothing) or, with the `alloc` feature, owned: `Value<'static>` is
/// the value host code keeps.
///
/// Floats compare by IEEE rules (`NaN != NaN`); compare encodings to test
/// bit-exact equality.
#[derive(Debug, Clone, PartialEq)]
pub enum Value<'a> {
    /// No value.
    Null,
    /// A boolean.
    Bool(bool),
    /// A signed 8-bit integer.
    I8(i8),
    /// A signed 16-bit integer.
    I16(i16),
    /// A signed 32-bit integer.
    I32(i32),
    /// A signed 64-bit integer.
    I64(i64),
    /// A signed 128-bit integer.
    I128(i128),
    /// An unsigned 8-bit integer.
    U8(u8),
    /// An unsigned 16-bit integer.
    U16(u16),
    /// An unsigned 32-bit integer.
    U32(u32),
    /// An unsigned 64-bit integer.
    U64(u64),
    /// An unsigned 128-bit integer.
    U128(u128),
    /// An IEEE binary16 float, as its raw bits (see [`crate::f16`](mod@crate::f16)).
    F16(u16),
    /// An IEEE binary32 float.
    F32(f32),
    /// An IEEE binary64 float.
    F64(f64),
    /// An ASCII string. Encoding fails with [`ValueError::NotAscii`] if it is not.
    Ascii(Text<'a>),
    /// A UTF-8 string.
    Utf8(Text<'a>),
    /// An array of scalars.
    Array(Array<'a>),
    /// A tensor of scalars.
    Tensor(Tensor<'a>),
}

impl<'a> Value<'a> {
    /// An ascii value borrowing (or, given a `String`, owning) `s`.
    /// Encoding fails with [`ValueError::NotAscii`] if it is not ASCII.
    pub fn ascii(s: impl Into<Text<'a>>) -> Value<'a> {
        Value::Ascii(s.into())
    }

    /// A utf8 value borrowing (or, given a `String`, owning) `s`.
    pub fn utf8(s: impl Into<Text<'a>>) -> Value<'a> {
        Value::Utf8(s.into())
    }

    /// The value's type.
    pub fn ty(&self) -> Type {
        match self {
            Value::Null => Type::Null,
            Value::Ascii(_) => Type::Ascii,
            Value::Utf8(_) => Type::Utf8,
            Value::Array(a) => Type::Array(a.elem()),
            Value::Tensor(t) => Type::Tensor(t.elem()),
            Value::Bool(_) => Type::Scalar(ScalarType::Bool),
            Value::I8(_) => Type::Scalar(ScalarType::I8),
            Value::I16(_) => Type::Scalar(ScalarType::I16),
            Value::I32(_) => Type::Scalar(ScalarType::I32),
            Value::I64(_) => Type::Scalar(ScalarType::I64),
            Value::I128(_) => Type::Scalar(ScalarType::I128),
            Value::U8(_) => Type::Scalar(ScalarType::U8),
            Value::U16(_) => Type::Scalar(ScalarType::U16),
            Value::U32(_) => Type::Scalar(ScalarType::U32),
            Value::U64(_) => Type::Scalar(ScalarType::U64),
            Value::U128(_) => Type::Scalar(ScalarType::U128),
            Value::F16(_) => Type::Scalar(ScalarType::F16),
            Value::F32(_) => Type::Scalar(ScalarType::F32),
            Value::F64(_) => Type::Scalar(ScalarType::F64),
        }
    }

    /// The array, if this is one.
    pub fn as_array(&self) -> Option<&Array<'a>> {
        match self {
            Value::Array(a) => Some(a),
            _ => None,
        }
    }

    /// The tensor, if this is one.
    pub fn as_tensor(&self) -> Option<&Tensor<'a>> {
        match self {
            Value::Tensor(t) => Some(t),
            _ => None,
        }
    }

    /// The string, if this is an ascii or utf8 value.
    pub fn as_str(&self) -> Option<&str> {
        match self {
            Value::Ascii(s) | Value::Utf8(s) => Some(s),
            _ => None,
        }
    }

    /// The same value borrowing this one's data (nothing is copied): what
    /// [`convert`](crate::convert()) and other views take from a value that
    /// may own its data.
    pub fn reborrow(&self) -> Value<'_> {
        match self {
            Value::Null => Value::Null,
            Value::Bool(x) => Value::Bool(*x),
            Value::I8(x) => Value::I8(*x),
            Value::I16(x) => Value::I16(*x),
            Value::I32(x) => Value::I32(*x),
            Value::I64(x) => Value::I64(*x),
            Value::I128(x) => Value::I128(*x),
            Value::U8(x) => Value::U8(*x),
            Value::U16(x) => Value::U16(*x),
            Value::U32(x) => Value::U32(*x),
            Value::U64(x) => Value::U64(*x),
            Value::U128(x) => Value::U128(*x),
            Value::F16(x) => Value::F16(*x),
            Value::F32(x) => Value::F32(*x),
            Value::F64(x) => Value::F64(*x),
            Value::Ascii(s) => Value::Ascii(Text::new(s)),
            Value::Utf8(s) => Value::Utf8(Text::new(s)),
            Value::Array(a) => Value::Array(a.reborrow()),
            Value::Tensor(t) => Value::Tensor(t.reborrow()),
        }
    }

    /// The number, as an f64, for every integer and float that an f64 holds
    /// exactly (and bools as 0 or 1); `None` otherwise.
    pub fn as_f64(&self) -> Option<f64> {
        match crate::convert(self, &Type::Scalar(ScalarType::F64)).ok()? {
            crate::Converted::Value(Value::F64(x)) => Some(x),
            _ => None,
        }
    }

    /// The same value owning its data (strings, element bytes and dims are
    /// copied if borrowed); it compares equal and encodes identically.
    #[cfg(feature = "alloc")]
    pub fn into_owned(self) -> Value<'static> {
        match self {
            Value::Null => Value::Null,
            Value::Bool(x) => Value::Bool(x),
            Value::I8(x) => Value::I8(x),
            Value::I16(x) => Value::I16(x),
            Value::I32(x) => Value::I32(x),
            Value::I64(x) => Value::I64(x),
            Value::I128(x) => Value::I128(x),
            Value::U8(x) => Value::U8(x),
            Value::U16(x) => Value::U16(x),
            Value::U32(x) => Value::U32(x),
            Value::U64(x) => Value::U64(x),
            Value::U128(x) => Value::U128(x),
            Value::F16(x) => Value::F16(x),
            Value::F32(x) => Value::F32(x),
            Value::F64(x) => Value::F64(x),
            Value::Ascii(s) => Value::Ascii(s.into_owned()),
            Value::Utf8(s) => Value::Utf8(s.into_owned()),
            Value::Array(a) => Value::Array(a.into_owned()),
            Value::Tensor(t) => Value::Tensor(t.into_owned()),
        }
    }

    /// A copy of the value that owns its data (see
    /// [`into_owned`](Value::into_owned)).
    #[cfg(feature = "alloc")]
    pub fn to_owned_value(&self) -> Value<'static> {
        self.reborrow().into_owned()
    }

    /// Reads one `[type key][value]` from `r`. On error `r` is left where it
    /// was, so the caller can report the offset of the bad value.
    pub fn decode(r: &mut Reader<'a>) -> Result<Value<'a>, ValueError> {
        let mut t = r.clone();
        let ty = Type::from_key(t.u8()?)?;
        let v = Value::decode_body(ty, &mut t)?;
        *r = t;
        Ok(v)
    }

    /// Reads a value of a known type whose key has already been read (or is
    /// implied by a signature). On error `r` is left where it was.
    pub fn decode_body(ty: Type, r: &mut Reader<'a>) -> Result<Value<'a>, ValueError> {
        let mut t = r.clone();
        let v = match ty {
            Type::Null => Value::Null,
            Type::Scalar(s) => scalar_from_le(s, t.bytes(s.width())?)?,
            Type::Ascii => {
                let len = t.u16()? as usize;
                let b = t.bytes(len)?;
                if !b.is_ascii() {
                    return Err(ValueError::NotAscii);
                }
                Value::Ascii(Text::new(
                    core::str::from_utf8(b).map_err(|_| ValueError::NotAscii)?,
                ))
            }
            Type::Utf8 => {
                let len = t.u16()? as usize;
                Value::Utf8(Text::new(
                    core::str::from_utf8(t.bytes(len)?).map_err(|_| ValueError::BadUtf8)?,
                ))
            }
            Type::Array(s) => {
                let count = t.u16()? as usize;
                let n = count.checked_mul(s.width()).ok_or(ValueError::TooLarge)?;
                Value::Array(Array::new(s, t.bytes(n)?)?)
            }
            Type::Tensor(s) => {
                let rank = t.u8()? as usize;
                let dims = t.bytes(rank * 2)?;
                let n = Dims(DimsRepr::Wire(dims))
                    .element_count()
                    .and_then(|c| c.checked_mul(s.width()))
                    .ok_or(ValueError::TooLarge)?;
                let elems = Elements::new(s, t.bytes(n)?)?;
                Value::Tensor(Tensor {
                    dims: TensorDims::Wire(Bytes::new(dims)),
                    elem: s,
                    bytes: Bytes::new(elems.bytes),
                })
            }
        };
        *r = t;
        Ok(v)
    }

    /// Decodes a value that must fill `bytes` exactly.
    pub fn from_bytes(bytes: &'a [u8]) -> Result<Value<'a>, ValueError> {
        let mut r = Reader::new(bytes);
        let v = Value::decode(&mut r)?;
        if !r.is_empty() {
            return Err(ValueError::TrailingBytes);
        }
        Ok(v)
    }

    /// How many bytes [`encode`](Value::encode) writes, key included. Errors
    /// as `encode` would for strings that cannot be encoded.
    pub fn encoded_len(&self) -> Result<usize, ValueError> {
        Ok(1 + self.body_len()?)
    }

    /// How many bytes the value takes after its key.
    pub fn body_len(&self) -> Result<usize, ValueError> {
        Ok(match self {
            Value::Null => 0,
            Value::Ascii(s) | Value::Utf8(s) => {
                if matches!(self, Value::Ascii(_)) && !s.is_ascii() {
                    return Err(ValueError::NotAscii);
                }
                if s.len() > u16::MAX as usize {
                    return Err(ValueError::StringTooLong);
                }
                2 + s.len()
            }
            Value::Array(a) => 2 + a.bytes().len(),
            Value::Tensor(t) => 1 + 2 * t.rank() + t.bytes().len(),
            // Every other variant is a scalar.
            v => v.ty().fixed_width().unwrap_or(0),
        })
    }

    /// Writes `[type key][value]`. On error nothing is written.
    pub fn encode(&self, w: &mut Writer<'_>) -> Result<(), ValueError> {
        if self.encoded_len()? > w.remaining() {
            return Err(ValueError::NoSpace);
        }
        w.u8(self.ty().key())?;
        self.encode_body(w)
    }

    /// Writes the value without its key (for types implied by a signature).
    /// On error nothing is written.
    pub fn encode_body(&self, w: &mut Writer<'_>) -> Result<(), ValueError> {
        if self.body_len()? > w.remaining() {
            return Err(ValueError::NoSpace);
        }
        match self {
            Value::Null => Ok(()),
            Value::Bool(b) => Ok(w.u8(*b as u8)?),
            Value::I8(v) => Ok(w.bytes(&v.to_le_bytes())?),
            Value::I16(v) => Ok(w.bytes(&v.to_le_bytes())?),
            Value::I32(v) => Ok(w.bytes(&v.to_le_bytes())?),
            Value::I64(v) => Ok(w.bytes(&v.to_le_bytes())?),
            Value::I128(v) => Ok(w.bytes(&v.to_le_bytes())?),
            Value::U8(v) => Ok(w.bytes(&v.to_le_bytes())?),
            Value::U16(v) | Value::F16(v) => Ok(w.bytes(&v.to_le_bytes())?),
            Value::U32(v) => Ok(w.bytes(&v.to_le_bytes())?),
            Value::U64(v) => Ok(w.bytes(&v.to_le_bytes())?),
            Value::U128(v) => Ok(w.bytes(&v.to_le_bytes())?),
            Value::F32(v) => Ok(w.bytes(&v.to_le_bytes())?),
            Value::F64(v) => Ok(w.bytes(&v.to_le_bytes())?),
            Value::Ascii(s) | Value::Utf8(s) => {
                // body_len checked the length fits a u16.
                w.u16(s.len() as u16)?;
                Ok(w.bytes(s.as_bytes())?)
            }
            Value::Array(a) => {
                w.u16(a.len() as u16)?;
                Ok(w.bytes(a.bytes())?)
            }
            Value::Tensor(t) => {
                w.u8(t.rank() as u8)?;
                for d in t.dims().iter() {
                    w.u16(d)?;
                }
                Ok(w.bytes(t.bytes())?)
            }
        }
    }
}

/// The elements' little-endian bytes, packed.
#[cfg(feature = "alloc")]
fn le_bytes<T: Element>(elements: &[T]) -> Vec<u8> {
    let w = T::TYPE.width();
    let mut bytes = alloc::vec![0u8; elements.len() * w];
    for (chunk, e) in bytes.chunks_exact_mut(w).zip(elements) {
        e.write_le(chunk);
    }
    bytes
}

#[cfg(feature = "alloc")]
impl Value<'static> {
    /// An array of native numbers (or bools) that owns its elements.
    ///
    /// Errors: [`ValueError::TooLarge`] for more than 65535 elements.
    pub fn array<T: Element>(elements: &[T]) -> Result<Value<'static>, ValueError> {
        Ok(Value::Array(Array::from_vec(T::TYPE, le_bytes(elements))?))
    }

    /// A row-major tensor of native numbers (or bools) that owns its dims
    /// and elements.
    ///
    /// Errors as [`Tensor::new`].
    pub fn tensor<T: Element>(dims: &[u16], elements: &[T]) -> Result<Value<'static>, ValueError> {
        Ok(Value::Tensor(Tensor::from_vec(
            T::TYPE,
            dims,
            le_bytes(elements),
        )?))
    }
}

macro_rules! value_from {
    ($($t:ty => $s:ident),* $(,)?) => {$(
        impl From<$t> for Value<'_> {
            fn from(v: $t) -> Self {
                Value::$s(v)
            }
        }
    )*};
}

value_from!(
    bool => Bool, i8 => I8, i16 => I16, i32 => I32, i64 => I64, i128 => I128,
    u8 => U8, u16 => U16, u32 => U32, u64 => U64, u128 => U128,
    f32 => F32, f64 => F64,
);

/// A utf8 value borrowing the string.
impl<'a> From<&'a str> for Value<'a> {
    fn from(s: &'a str) -> Self {
        Value::Utf8(Text::new(s))
    }
}

/// A utf8 value owning the string.
#[cfg(feature = "alloc")]
impl From<String> for Value<'_> {
    fn from(s: String) -> Self {
        Value::Utf8(Text::from(s))
    }
}

/// A short human form: strings quoted, arrays as their type and byte count,
/// tensors as their type and dims, scalars as their variant and number
/// (`U8(5)`).
impl fmt::Display for Value<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Value::Ascii(s) | Value::Utf8(s) => write!(f, "{:?}", s.as_str()),
            Value::Array(a) => write!(f, "arry_{}[{} bytes]", a.elem(), a.bytes().len()),
            Value::Tensor(t) => write!(f, "tnsr_{}{:?}", t.elem(), t.dims()),
            other => write!(f, "{other:?}"),
        }
    }
}

/// Reads one scalar from exactly `width` little-endian bytes.
pub(crate) fn scalar_from_le(s: ScalarType, b: &[u8]) -> Result<Value<'static>, ValueError> {
    fn arr<const N: usize>(b: &[u8]) -> Result<[u8; N], ValueError> {
        b.try_into().map_err(|_| ValueError::Truncated)
    }
    Ok(match s {
        ScalarType::Bool => match arr::<1>(b)?[0] {
            0 => Value::Bool(false),
            1 => Value::Bool(true),
            x => return Err(ValueError::BadBool(x)),
        },
        ScalarType::I8 => Value::I8(i8::from_le_bytes(arr(b)?)),
        ScalarType::I16 => Value::I16(i16::from_le_bytes(arr(b)?)),
        ScalarType::I32 => Value::I32(i32::from_le_bytes(arr(b)?)),
        ScalarType::I64 => Value::I64(i64::from_le_bytes(arr(b)?)),
        ScalarType::I128 => Value::I128(i128::from_le_bytes(arr(b)?)),
        ScalarType::U8 => Value::U8(u8::from_le_bytes(arr(b)?)),
        ScalarType::U16 => Value::U16(u16::from_le_bytes(arr(b)?)),
        ScalarType::U32 => Value::U32(u32::from_le_bytes(arr(b)?)),
        ScalarType::U64 => Value::U64(u64::from_le_bytes(arr(b)?)),
        ScalarType::U128 => Value::U128(u128::from_le_bytes(arr(b)?)),
        ScalarType::F16 => Value::F16(u16::from_le_bytes(arr(b)?)),
        ScalarType::F32 => Value::F32(f32::from_le_bytes(arr(b)?)),
        ScalarType::F64 => Value::F64(f64::from_le_bytes(arr(b)?)),
    })
}

/// A run of bare little-endian elements of one scalar type: the data of an
/// array or a tensor. Always a whole number of elements, and bool elements
/// are always 0 or 1.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Elements<'a> {
    elem: ScalarType,
    bytes: &'a [u8],
}

impl<'a> Elements<'a> {
    /// Elements of type `elem` in `bytes` (bare, little-endian).
    ///
    /// Errors: [`ValueError::ShapeMismatch`] if `bytes` is not a whole number
    /// of elements, [`ValueError::BadBool`] for a bool element not 0 or 1.
    pub fn new(elem: ScalarType, bytes: &'a [u8]) -> Result<Self, ValueError> {
        if !bytes.len().is_multiple_of(elem.width()) {
            return Err(ValueError::ShapeMismatch);
        }
        if elem == ScalarType::Bool {
            if let Some(&b) = bytes.iter().find(|&&b| b > 1) {
                return Err(ValueError::BadBool(b));
            }
        }
        Ok(Elements { elem, bytes })
    }

    /// The element type.
    pub fn elem(&self) -> ScalarType {
        self.elem
    }

    /// The number of elements.
    pub fn len(&self) -> usize {
        self.bytes.len() / self.elem.width()
    }

    /// Whether there are no elements.
    pub fn is_empty(&self) -> bool {
        self.bytes.is_empty()
    }

    /// The raw little-endian element bytes.
    pub fn bytes(&self) -> &'a [u8] {
        self.bytes
    }

    /// Element `i` as a scalar value.
    pub fn get(&self, i: usize) -> Option<Value<'static>> {
        let w = self.elem.width();
        let start = i.checked_mul(w)?;
        let chunk = self.bytes.get(start..start.checked_add(w)?)?;
        scalar_from_le(self.elem, chunk).ok()
    }

    /// The elements as scalar values.
    pub fn iter(&self) -> ElementIter<'a> {
        ElementIter {
            elems: *self,
            next: 0,
        }
    }

    /// The elements as native numbers, if the element type is `T`'s:
    /// `array.elements().typed::<f32>()`.
    pub fn typed<T: Element>(&self) -> Option<TypedIter<'a, T>> {
        (self.elem == T::TYPE).then(|| TypedIter {
            chunks: self.bytes.chunks_exact(T::TYPE.width()),
            _t: core::marker::PhantomData,
        })
    }
}

/// Iterates the elements of an array or tensor as scalar [`Value`]s.
#[derive(Debug, Clone)]
pub struct ElementIter<'a> {
    elems: Elements<'a>,
    next: usize,
}

impl Iterator for ElementIter<'_> {
    type Item = Value<'static>;
    fn next(&mut self) -> Option<Value<'static>> {
        let v = self.elems.get(self.next)?;
        self.next += 1;
        Some(v)
    }
    fn size_hint(&self) -> (usize, Option<usize>) {
        let n = self.elems.len().saturating_sub(self.next);
        (n, Some(n))
    }
}

impl ExactSizeIterator for ElementIter<'_> {}

mod sealed {
    pub trait Sealed {}
}

/// A native Rust type that is the element type of an array or tensor
/// (every [`ScalarType`] except f16, which has no native Rust type).
pub trait Element: Copy + 'static + sealed::Sealed {
    /// The scalar type this is.
    const TYPE: ScalarType;
    /// Reads one element from its little-endian bytes (exactly its width).
    fn from_le(bytes: &[u8]) -> Option<Self>;
    /// Writes its little-endian bytes to the first `TYPE.width()` bytes of
    /// `out` (which must be at least that long).
    fn write_le(self, out: &mut [u8]);
    /// The scalar value of exactly this type.
    fn into_value(self) -> Value<'static>;
    /// The number held by a scalar value of exactly this type.
    fn from_value(v: Value<'_>) -> Option<Self>;
}

macro_rules! element {
    ($($t:ty => $s:ident),* $(,)?) => {$(
        impl sealed::Sealed for $t {}
        impl Element for $t {
            const TYPE: ScalarType = ScalarType::$s;
            fn from_le(bytes: &[u8]) -> Option<Self> {
                Some(<$t>::from_le_bytes(bytes.try_into().ok()?))
            }
            fn write_le(self, out: &mut [u8]) {
                let b = self.to_le_bytes();
                out[..b.len()].copy_from_slice(&b);
            }
            fn into_value(self) -> Value<'static> {
                Value::$s(self)
            }
            fn from_value(v: Value<'_>) -> Option<Self> {
                match v {
                    Value::$s(x) => Some(x),
                    _ => None,
                }
            }
        }
    )*};
}

element!(
    i8 => I8, i16 => I16, i32 => I32, i64 => I64, i128 => I128,
    u8 => U8, u16 => U16, u32 => U32, u64 => U64, u128 => U128,
    f32 => F32, f64 => F64,
);

impl sealed::Sealed for bool {}
impl Element for bool {
    const TYPE: ScalarType = ScalarType::Bool;
    fn from_le(bytes: &[u8]) -> Option<Self> {
        match bytes {
            [0] => Some(false),
            [1] => Some(true),
            _ => None,
        }
    }
    fn write_le(self, out: &mut [u8]) {
        out[0] = self as u8;
    }
    fn into_value(self) -> Value<'static> {
        Value::Bool(self)
    }
    fn from_value(v: Value<'_>) -> Option<Self> {
        match v {
            Value::Bool(b) => Some(b),
            _ => None,
        }
    }
}

/// Iterates the elements of an array or tensor as native numbers.
#[derive(Debug, Clone)]
pub struct TypedIter<'a, T> {
    chunks: core::slice::ChunksExact<'a, u8>,
    _t: core::marker::PhantomData<T>,
}

impl<T: Element> Iterator for TypedIter<'_, T> {
    type Item = T;
    fn next(&mut self) -> Option<T> {
        T::from_le(self.chunks.next()?)
    }
    fn size_hint(&self) -> (usize, Option<usize>) {
        self.chunks.size_hint()
    }
}

impl<T: Element> ExactSizeIterator for TypedIter<'_, T> {}

/// A string held by a [`Value`]: borrowed, or (with the `alloc` feature)
/// owned. It dereferences to `str`; how it holds the string is private, so
/// turning the feature on changes no user's code.
#[derive(Clone)]
pub struct Text<'a>(TextRepr<'a>);

#[derive(Clone)]
enum TextRepr<'a> {
    Borrowed(&'a str),
    #[cfg(feature = "alloc")]
    Owned(String),
}

impl<'a> Text<'a> {
    /// A borrowed string.
    #[inline]
    pub const fn new(s: &'a str) -> Self {
        Text(TextRepr::Borrowed(s))
    }

    /// The string.
    #[inline]
    pub fn as_str(&self) -> &str {
        self
    }

    /// The string for all of `'a`, if it is borrowed (`None` if owned).
    #[inline]
    pub fn as_borrowed(&self) -> Option<&'a str> {
        match self.0 {
            TextRepr::Borrowed(s) => Some(s),
            #[cfg(feature = "alloc")]
            TextRepr::Owned(_) => None,
        }
    }

    /// The same string, owned.
    #[cfg(feature = "alloc")]
    pub fn into_owned(self) -> Text<'static> {
        match self.0 {
            TextRepr::Borrowed(s) => Text(TextRepr::Owned(s.to_owned())),
            TextRepr::Owned(s) => Text(TextRepr::Owned(s)),
        }
    }
}

impl Deref for Text<'_> {
    type Target = str;
    #[inline]
    fn deref(&self) -> &str {
        match &self.0 {
            TextRepr::Borrowed(s) => s,
            #[cfg(feature = "alloc")]
            TextRepr::Owned(s) => s,
        }
    }
}

impl AsRef<str> for Text<'_> {
    fn as_ref(&self) -> &str {
        self
    }
}

impl<'a> From<&'a str> for Text<'a> {
    fn from(s: &'a str) -> Self {
        Text::new(s)
    }
}

#[cfg(feature = "alloc")]
impl From<String> for Text<'_> {
    fn from(s: String) -> Self {
        Text(TextRepr::Owned(s))
    }
}

#[cfg(feature = "alloc")]
impl From<Text<'_>> for String {
    fn from(t: Text<'_>) -> String {
        match t.0 {
            TextRepr::Borrowed(s) => s.to_owned(),
            TextRepr::Owned(s) => s,
        }
    }
}

impl PartialEq for Text<'_> {
    fn eq(&self, other: &Self) -> bool {
        **self == **other
    }
}

impl Eq for Text<'_> {}

impl PartialEq<str> for Text<'_> {
    fn eq(&self, other: &str) -> bool {
        **self == *other
    }
}

impl PartialEq<&str> for Text<'_> {
    fn eq(&self, other: &&str) -> bool {
        **self == **other
    }
}

impl core::hash::Hash for Text<'_> {
    fn hash<H: core::hash::Hasher>(&self, state: &mut H) {
        (**self).hash(state)
    }
}

impl fmt::Debug for Text<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Debug::fmt(&**self, f)
    }
}

impl fmt::Display for Text<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Display::fmt(&**self, f)
    }
}

/// Bytes held by an [`Array`] or [`Tensor`]: borrowed, or (with the `alloc`
/// feature) owned. Private like [`Text`]'s.
#[derive(Clone)]
struct Bytes<'a>(BytesRepr<'a>);

#[derive(Clone)]
enum BytesRepr<'a> {
    Borrowed(&'a [u8]),
    #[cfg(feature = "alloc")]
    Owned(Vec<u8>),
}

impl<'a> Bytes<'a> {
    #[inline]
    const fn new(b: &'a [u8]) -> Self {
        Bytes(BytesRepr::Borrowed(b))
    }

    #[inline]
    fn get(&self) -> &[u8] {
        match &self.0 {
            BytesRepr::Borrowed(b) => b,
            #[cfg(feature = "alloc")]
            BytesRepr::Owned(b) => b,
        }
    }

    #[inline]
    fn reborrow(&self) -> Bytes<'_> {
        Bytes::new(self.get())
    }

    #[cfg(feature = "alloc")]
    fn into_owned(self) -> Bytes<'static> {
        match self.0 {
            BytesRepr::Borrowed(b) => Bytes(BytesRepr::Owned(b.to_vec())),
            BytesRepr::Owned(b) => Bytes(BytesRepr::Owned(b)),
        }
    }
}

/// A one-dimensional array of at most 65535 scalars: its elements borrowed,
/// or (with the `alloc` feature) owned.
#[derive(Clone)]
pub struct Array<'a> {
    elem: ScalarType,
    bytes: Bytes<'a>,
}

impl<'a> Array<'a> {
    /// An array of `elem` over its bare little-endian element bytes.
    ///
    /// Errors as [`Elements::new`], and [`ValueError::TooLarge`] for more
    /// than 65535 elements.
    pub fn new(elem: ScalarType, bytes: &'a [u8]) -> Result<Self, ValueError> {
        Array::from_elements(Elements::new(elem, bytes)?)
    }

    /// An array over already checked elements.
    pub fn from_elements(elems: Elements<'a>) -> Result<Self, ValueError> {
        if elems.len() > u16::MAX as usize {
            return Err(ValueError::TooLarge);
        }
        Ok(Array {
            elem: elems.elem,
            bytes: Bytes::new(elems.bytes),
        })
    }

    /// The element type.
    pub fn elem(&self) -> ScalarType {
        self.elem
    }

    /// The number of elements.
    pub fn len(&self) -> usize {
        self.bytes.get().len() / self.elem.width()
    }

    /// Whether the array is empty.
    pub fn is_empty(&self) -> bool {
        self.bytes.get().is_empty()
    }

    /// The raw little-endian element bytes.
    pub fn bytes(&self) -> &[u8] {
        self.bytes.get()
    }

    /// The elements.
    pub fn elements(&self) -> Elements<'_> {
        Elements {
            elem: self.elem,
            bytes: self.bytes.get(),
        }
    }

    /// Element `i` as a scalar value.
    pub fn get(&self, i: usize) -> Option<Value<'static>> {
        self.elements().get(i)
    }

    /// The elements as scalar values.
    pub fn iter(&self) -> ElementIter<'_> {
        self.elements().iter()
    }

    /// The elements as native numbers, if the element type is `T`'s.
    pub fn typed<T: Element>(&self) -> Option<TypedIter<'_, T>> {
        self.elements().typed()
    }

    /// The same array borrowing this one's bytes.
    pub fn reborrow(&self) -> Array<'_> {
        Array {
            elem: self.elem,
            bytes: self.bytes.reborrow(),
        }
    }

    /// The same array owning its bytes.
    #[cfg(feature = "alloc")]
    pub fn into_owned(self) -> Array<'static> {
        Array {
            elem: self.elem,
            bytes: self.bytes.into_owned(),
        }
    }

    /// An array of `elem` owning its bare little-endian element bytes.
    /// Errors as [`Array::new`].
    #[cfg(feature = "alloc")]
    pub fn from_vec(elem: ScalarType, bytes: Vec<u8>) -> Result<Array<'static>, ValueError> {
        Array::new(elem, &bytes)?;
        Ok(Array {
            elem,
            bytes: Bytes(BytesRepr::Owned(bytes)),
        })
    }
}

impl PartialEq for Array<'_> {
    fn eq(&self, other: &Self) -> bool {
        self.elem == other.elem && self.bytes() == other.bytes()
    }
}

impl Eq for Array<'_> {}

impl fmt::Debug for Array<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Array")
            .field("elem", &self.elem)
            .field("bytes", &self.bytes())
            .finish()
    }
}

#[derive(Clone, Copy)]
enum DimsRepr<'a> {
    /// Little-endian `u16`s as read from the wire.
    Wire(&'a [u8]),
    /// Dims given by the sender.
    Native(&'a [u16]),
}

/// A tensor's dims, outermost first.
#[derive(Clone, Copy)]
pub struct Dims<'a>(DimsRepr<'a>);

impl<'a> Dims<'a> {
    /// The number of dims (the tensor's rank).
    pub fn rank(&self) -> usize {
        match self.0 {
            DimsRepr::Wire(b) => b.len() / 2,
            DimsRepr::Native(d) => d.len(),
        }
    }

    /// Dim `i`.
    pub fn get(&self, i: usize) -> Option<u16> {
        match self.0 {
            DimsRepr::Wire(b) => {
                let start = i.checked_mul(2)?;
                let pair = b.get(start..start.checked_add(2)?)?;
                Some(u16::from_le_bytes([pair[0], pair[1]]))
            }
            DimsRepr::Native(d) => d.get(i).copied(),
        }
    }

    /// The dims, outermost first.
    pub fn iter(&self) -> DimsIter<'a> {
        DimsIter {
            dims: *self,
            next: 0,
        }
    }

    /// The product of the dims (1 for rank 0), or `None` if it overflows `usize`.
    pub fn element_count(&self) -> Option<usize> {
        self.iter()
            .try_fold(1usize, |acc, d| acc.checked_mul(d as usize))
    }
}

impl PartialEq for Dims<'_> {
    fn eq(&self, other: &Self) -> bool {
        self.rank() == other.rank() && self.iter().eq(other.iter())
    }
}

impl Eq for Dims<'_> {}

impl fmt::Debug for Dims<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_list().entries(self.iter()).finish()
    }
}

/// Iterates a tensor's dims.
#[derive(Debug, Clone)]
pub struct DimsIter<'a> {
    dims: Dims<'a>,
    next: usize,
}

impl Iterator for DimsIter<'_> {
    type Item = u16;
    fn next(&mut self) -> Option<u16> {
        let d = self.dims.get(self.next)?;
        self.next += 1;
        Some(d)
    }
}

/// How a [`Tensor`] holds its dims: as wire bytes (borrowed or owned) or as
/// the sender's borrowed `u16`s.
#[derive(Clone)]
enum TensorDims<'a> {
    Wire(Bytes<'a>),
    Native(&'a [u16]),
}

/// A row-major tensor of scalars: up to 255 dims of up to 65535 each; its
/// dims and elements borrowed, or (with the `alloc` feature) owned.
#[derive(Clone)]
pub struct Tensor<'a> {
    dims: TensorDims<'a>,
    elem: ScalarType,
    bytes: Bytes<'a>,
}

impl<'a> Tensor<'a> {
    /// A tensor of `elem` with `dims` (outermost first) over its bare,
    /// row-major, little-endian element bytes.
    ///
    /// Errors: [`ValueError::TooLarge`] for more than 255 dims or an element
    /// count that overflows, [`ValueError::ShapeMismatch`] if `bytes` is not
    /// exactly the product of the dims in elements, [`ValueError::BadBool`].
    pub fn new(elem: ScalarType, dims: &'a [u16], bytes: &'a [u8]) -> Result<Self, ValueError> {
        if dims.len() > u8::MAX as usize {
            return Err(ValueError::TooLarge);
        }
        let n = Dims(DimsRepr::Native(dims))
            .element_count()
            .and_then(|c| c.checked_mul(elem.width()))
            .ok_or(ValueError::TooLarge)?;
        if n != bytes.len() {
            return Err(ValueError::ShapeMismatch);
        }
        Elements::new(elem, bytes)?;
        Ok(Tensor {
            dims: TensorDims::Native(dims),
            elem,
            bytes: Bytes::new(bytes),
        })
    }

    /// A tensor owning its dims and its bare, row-major, little-endian
    /// element bytes. Errors as [`Tensor::new`].
    #[cfg(feature = "alloc")]
    pub fn from_vec(
        elem: ScalarType,
        dims: &[u16],
        bytes: Vec<u8>,
    ) -> Result<Tensor<'static>, ValueError> {
        Tensor::new(elem, dims, &bytes)?;
        let wire = dims.iter().flat_map(|d| d.to_le_bytes()).collect();
        Ok(Tensor {
            dims: TensorDims::Wire(Bytes(BytesRepr::Owned(wire))),
            elem,
            bytes: Bytes(BytesRepr::Owned(bytes)),
        })
    }

    /// The element type.
    pub fn elem(&self) -> ScalarType {
        self.elem
    }

    /// The dims, outermost first.
    pub fn dims(&self) -> Dims<'_> {
        match &self.dims {
            TensorDims::Wire(b) => Dims(DimsRepr::Wire(b.get())),
            TensorDims::Native(d) => Dims(DimsRepr::Native(d)),
        }
    }

    /// The number of dims.
    pub fn rank(&self) -> usize {
        self.dims().rank()
    }

    /// The number of elements (the product of the dims).
    pub fn len(&self) -> usize {
        self.bytes.get().len() / self.elem.width()
    }

    /// Whether the tensor has no elements (some dim is 0).
    pub fn is_empty(&self) -> bool {
        self.bytes.get().is_empty()
    }

    /// The raw little-endian element bytes, row-major.
    pub fn bytes(&self) -> &[u8] {
        self.bytes.get()
    }

    /// The elements, row-major.
    pub fn elements(&self) -> Elements<'_> {
        Elements {
            elem: self.elem,
            bytes: self.bytes.get(),
        }
    }

    /// The element at multi-index `index` (one entry per dim), if in range.
    pub fn get(&self, index: &[u16]) -> Option<Value<'static>> {
        if index.len() != self.rank() {
            return None;
        }
        let mut flat = 0usize;
        for (i, d) in index.iter().zip(self.dims().iter()) {
            if *i >= d {
                return None;
            }
            flat = flat.checked_mul(d as usize)?.checked_add(*i as usize)?;
        }
        self.elements().get(flat)
    }

    /// The same tensor borrowing this one's dims and bytes.
    pub fn reborrow(&self) -> Tensor<'_> {
        Tensor {
            dims: match &self.dims {
                TensorDims::Wire(b) => TensorDims::Wire(b.reborrow()),
                TensorDims::Native(d) => TensorDims::Native(d),
            },
            elem: self.elem,
            bytes: self.bytes.reborrow(),
        }
    }

    /// The same tensor owning its dims and bytes.
    #[cfg(feature = "alloc")]
    pub fn into_owned(self) -> Tensor<'static> {
        let dims = match self.dims {
            TensorDims::Wire(b) => b.into_owned(),
            TensorDims::Native(d) => Bytes(BytesRepr::Owned(
                d.iter().flat_map(|d| d.to_le_bytes()).collect(),
            )),
        };
        Tensor {
            dims: TensorDims::Wire(dims),
            elem: self.elem,
            bytes: self.bytes.into_owned(),
        }
    }
}

impl PartialEq for Tensor<'_> {
    fn eq(&self, other: &Self) -> bool {
        self.elem == other.elem && self.dims() == other.dims() && self.bytes() == other.bytes()
    }
}

impl Eq for Tensor<'_> {}

impl fmt::Debug for Tensor<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Tensor")
            .field("dims", &self.dims())
            .field("elem", &self.elem)
            .field("bytes", &self.bytes())
            .finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn enc(v: &Value<'_>) -> ([u8; 64], usize) {
        let mut b = [0u8; 64];
        let mut w = Writer::new(&mut b);
        v.encode(&mut w).unwrap();
        let n = w.len();
        (b, n)
    }

    #[test]
    fn scalars_round_trip() {
        for v in [
            Value::Null,
            Value::Bool(true),
            Value::I8(-5),
            Value::I128(i128::MIN),
            Value::U64(u64::MAX),
            Value::F16(0x3c00),
            Value::F32(1.5),
            Value::F64(-2.25),
            Value::ascii("hi"),
            Value::utf8("héllo"),
        ] {
            let (b, n) = enc(&v);
            assert_eq!(n, v.encoded_len().unwrap());
            assert_eq!(Value::from_bytes(&b[..n]), Ok(v));
        }
    }

    #[test]
    fn decode_rejects_bad_input() {
        assert_eq!(Value::from_bytes(&[1, 2]), Err(ValueError::BadBool(2)));
        assert_eq!(
            Value::from_bytes(&[48, 1, 0, 0xc3]),
            Err(ValueError::NotAscii)
        );
        assert_eq!(
            Value::from_bytes(&[49, 1, 0, 0xc3]),
            Err(ValueError::BadUtf8)
        );
        assert_eq!(
            Value::from_bytes(&[49, 5, 0, b'a']),
            Err(ValueError::Truncated)
        );
        assert_eq!(
            Value::from_bytes(&[0x62, 2, 0, 0, 0, 0]),
            Err(ValueError::Truncated)
        );
        assert_eq!(
            Value::from_bytes(&[0x41, 2, 0, 0, 7]),
            Err(ValueError::BadBool(7))
        );
        assert_eq!(Value::from_bytes(&[3]), Err(ValueError::ReservedType(3)));
        assert_eq!(Value::from_bytes(&[0, 0]), Err(ValueError::TrailingBytes));
        assert_eq!(Value::from_bytes(&[]), Err(ValueError::Truncated));
        // A rank-4 tensor of 65535^4 u128s overflows a 32-bit or 64-bit usize.
        let mut huge = [0xffu8; 10];
        huge[0] = 0x80 | 28;
        huge[1] = 4;
        let r = Value::from_bytes(&huge);
        assert!(matches!(
            r,
            Err(ValueError::TooLarge | ValueError::Truncated)
        ));
    }

    #[test]
    fn decode_leaves_reader_on_error() {
        let bytes = [49, 5, 0, b'a'];
        let mut r = Reader::new(&bytes);
        assert!(Value::decode(&mut r).is_err());
        assert_eq!(r.rest().len(), 4);
    }

    #[test]
    fn arrays_and_tensors() {
        let data = [1.0f32, 2.0, 3.0, 4.0, 5.0, 6.0];
        let mut bytes = [0u8; 24];
        for (c, x) in bytes.chunks_exact_mut(4).zip(data) {
            c.copy_from_slice(&x.to_le_bytes());
        }
        let a = Array::new(ScalarType::F32, &bytes).unwrap();
        assert_eq!(a.len(), 6);
        assert!(a.typed::<f32>().unwrap().eq(data));
        assert!(a.typed::<f64>().is_none());
        assert_eq!(a.get(2), Some(Value::F32(3.0)));
        assert_eq!(a.get(6), None);
        let (b, n) = enc(&Value::Array(a.clone()));
        assert_eq!(&b[..3], &[0x62, 6, 0]);
        assert_eq!(Value::from_bytes(&b[..n]), Ok(Value::Array(a)));

        let t = Tensor::new(ScalarType::F32, &[2, 3], &bytes).unwrap();
        assert_eq!(t.get(&[1, 0]), Some(Value::F32(4.0)));
        assert_eq!(t.get(&[0, 3]), None);
        assert_eq!(t.get(&[0]), None);
        let (b, n) = enc(&Value::Tensor(t.clone()));
        assert_eq!(&b[..6], &[0xa2, 2, 2, 0, 3, 0]);
        assert_eq!(Value::from_bytes(&b[..n]), Ok(Value::Tensor(t)));
        assert_eq!(
            Tensor::new(ScalarType::F32, &[2, 2], &bytes),
            Err(ValueError::ShapeMismatch)
        );
        assert_eq!(
            Array::new(ScalarType::F32, &bytes[..5]),
            Err(ValueError::ShapeMismatch)
        );
    }

    #[test]
    fn encode_refuses_without_partial_writes() {
        let mut b = [0u8; 3];
        let mut w = Writer::new(&mut b);
        assert_eq!(Value::U32(1).encode(&mut w), Err(ValueError::NoSpace));
        assert_eq!(w.len(), 0);
        assert_eq!(Value::ascii("é").encode(&mut w), Err(ValueError::NotAscii));
        assert_eq!(w.len(), 0);
    }

    #[test]
    fn display() {
        extern crate std;
        use std::string::ToString;
        assert_eq!(Value::utf8("a\"b").to_string(), "\"a\\\"b\"");
        assert_eq!(Value::U8(5).to_string(), "U8(5)");
        let bytes = [0u8; 8];
        let a = Array::new(ScalarType::U16, &bytes).unwrap();
        assert_eq!(Value::Array(a).to_string(), "arry_u16[8 bytes]");
        let t = Tensor::new(ScalarType::U16, &[2, 2], &bytes).unwrap();
        assert_eq!(Value::Tensor(t).to_string(), "tnsr_u16[2, 2]");
    }

    #[cfg(feature = "alloc")]
    mod owned {
        use super::*;
        use alloc::string::String;

        fn samples() -> [Value<'static>; 5] {
            [
                Value::ascii("hi"),
                Value::utf8("héllo"),
                Value::I64(-9),
                Value::array(&[1.5f32, -2.0, 3.25]).unwrap(),
                Value::tensor(&[2, 3], &[1u16, 2, 3, 4, 5, 6]).unwrap(),
            ]
        }

        #[test]
        fn owned_encodes_as_borrowed() {
            for v in samples() {
                let (b, n) = enc(&v);
                let borrowed = Value::from_bytes(&b[..n]).unwrap();
                let owned = borrowed.to_owned_value();
                assert_eq!(owned, borrowed);
                assert_eq!(owned, v);
                let (b2, n2) = enc(&owned);
                assert_eq!(&b[..n], &b2[..n2]);
                assert_eq!(owned.encoded_len(), borrowed.encoded_len());
                // Decoding the owned value's bytes gives it back.
                assert_eq!(Value::from_bytes(&b2[..n2]).unwrap(), owned);
            }
        }

        #[test]
        fn into_owned_preserves_equality() {
            let bytes = [1u8, 0, 2, 0, 3, 0, 4, 0];
            let native = [2u16, 2];
            let t = Value::Tensor(Tensor::new(ScalarType::U16, &native, &bytes).unwrap());
            let a = Value::Array(Array::new(ScalarType::U16, &bytes).unwrap());
            for v in [t, a, Value::utf8("x"), Value::Null, Value::F16(0x3c00)] {
                let owned = v.clone().into_owned();
                assert_eq!(owned, v);
                assert_eq!(owned.ty(), v.ty());
                assert_eq!(owned.reborrow(), v);
                assert_eq!(std::format!("{owned}"), std::format!("{v}"));
            }
        }

        #[test]
        fn constructors() {
            let v = Value::array(&[true, false]).unwrap();
            assert_eq!(v.ty(), Type::Array(ScalarType::Bool));
            assert_eq!(v.as_array().unwrap().bytes(), &[1, 0]);
            let v = Value::tensor(&[2], &[7i32, -1]).unwrap();
            let t = v.as_tensor().unwrap();
            assert_eq!(t.get(&[1]), Some(Value::I32(-1)));
            assert_eq!(t.dims().iter().collect::<alloc::vec::Vec<_>>(), [2]);
            assert_eq!(
                Value::tensor(&[3], &[1u8, 2]),
                Err(ValueError::ShapeMismatch)
            );
            assert_eq!(Value::array(&[0u8; 65536]), Err(ValueError::TooLarge));
            let s: Value<'static> = String::from("owned").into();
            assert_eq!(s, Value::utf8("owned"));
            assert_eq!(s.as_str(), Some("owned"));
            assert_eq!(Value::from(2.5f64).as_f64(), Some(2.5));
            assert_eq!(Value::from(7u8).as_f64(), Some(7.0));
            assert_eq!(Value::from(u64::MAX).as_f64(), None);
            let Value::Utf8(text) = s else { unreachable!() };
            assert_eq!(text, "owned");
            assert_eq!(text.as_borrowed(), None);
            assert_eq!(Text::new("b").as_borrowed(), Some("b"));
            assert_eq!(String::from(text), "owned");
        }
    }
}
