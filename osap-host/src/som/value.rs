//! Owned PIPES values for host code.
//!
//! pipes-core's [`Value`] borrows its strings and element bytes (it is
//! allocation-free); a script wants values it can keep. [`OwnedValue`] owns
//! them and converts to and from [`Value`] without changing anything.

use pipes_core::{Array, ScalarType, Tensor, Type, Value, ValueError};
use std::fmt;

/// A PIPES value that owns its data.
#[derive(Debug, Clone, PartialEq)]
pub enum OwnedValue {
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
    /// An IEEE binary16 float, as its raw bits.
    F16(u16),
    /// An IEEE binary32 float.
    F32(f32),
    /// An IEEE binary64 float.
    F64(f64),
    /// An ASCII string.
    Ascii(String),
    /// A UTF-8 string.
    Utf8(String),
    /// An array: its element type and little-endian element bytes.
    Array {
        /// The element type.
        elem: ScalarType,
        /// The elements' little-endian bytes.
        bytes: Vec<u8>,
    },
    /// A row-major tensor: element type, dims and little-endian element bytes.
    Tensor {
        /// The element type.
        elem: ScalarType,
        /// The dims.
        dims: Vec<u16>,
        /// The elements' little-endian bytes.
        bytes: Vec<u8>,
    },
}

/// A native element type that [`OwnedValue::array`] takes.
pub trait LeElement: Copy {
    /// Its scalar type.
    const TYPE: ScalarType;
    /// Appends its little-endian bytes.
    fn put(self, out: &mut Vec<u8>);
}

macro_rules! le_element {
    ($($t:ty => $s:ident),* $(,)?) => {$(
        impl LeElement for $t {
            const TYPE: ScalarType = ScalarType::$s;
            fn put(self, out: &mut Vec<u8>) {
                out.extend_from_slice(&self.to_le_bytes());
            }
        }
        impl From<$t> for OwnedValue {
            fn from(v: $t) -> OwnedValue {
                OwnedValue::$s(v)
            }
        }
    )*};
}

le_element!(
    i8 => I8, i16 => I16, i32 => I32, i64 => I64, i128 => I128,
    u8 => U8, u16 => U16, u32 => U32, u64 => U64, u128 => U128,
    f32 => F32, f64 => F64,
);

impl LeElement for bool {
    const TYPE: ScalarType = ScalarType::Bool;
    fn put(self, out: &mut Vec<u8>) {
        out.push(self as u8);
    }
}

impl From<bool> for OwnedValue {
    fn from(v: bool) -> OwnedValue {
        OwnedValue::Bool(v)
    }
}

impl From<&str> for OwnedValue {
    fn from(v: &str) -> OwnedValue {
        OwnedValue::Utf8(v.to_string())
    }
}

impl From<String> for OwnedValue {
    fn from(v: String) -> OwnedValue {
        OwnedValue::Utf8(v)
    }
}

impl OwnedValue {
    /// An array of native numbers (or bools).
    pub fn array<T: LeElement>(elements: &[T]) -> OwnedValue {
        let mut bytes = Vec::with_capacity(elements.len() * T::TYPE.width());
        elements.iter().for_each(|e| e.put(&mut bytes));
        OwnedValue::Array {
            elem: T::TYPE,
            bytes,
        }
    }

    /// A tensor of native numbers (or bools), row-major.
    pub fn tensor<T: LeElement>(dims: &[u16], elements: &[T]) -> OwnedValue {
        let mut bytes = Vec::with_capacity(elements.len() * T::TYPE.width());
        elements.iter().for_each(|e| e.put(&mut bytes));
        OwnedValue::Tensor {
            elem: T::TYPE,
            dims: dims.to_vec(),
            bytes,
        }
    }

    /// A copy of a borrowed value.
    pub fn from_value(v: &Value<'_>) -> OwnedValue {
        match *v {
            Value::Null => OwnedValue::Null,
            Value::Bool(x) => OwnedValue::Bool(x),
            Value::I8(x) => OwnedValue::I8(x),
            Value::I16(x) => OwnedValue::I16(x),
            Value::I32(x) => OwnedValue::I32(x),
            Value::I64(x) => OwnedValue::I64(x),
            Value::I128(x) => OwnedValue::I128(x),
            Value::U8(x) => OwnedValue::U8(x),
            Value::U16(x) => OwnedValue::U16(x),
            Value::U32(x) => OwnedValue::U32(x),
            Value::U64(x) => OwnedValue::U64(x),
            Value::U128(x) => OwnedValue::U128(x),
            Value::F16(x) => OwnedValue::F16(x),
            Value::F32(x) => OwnedValue::F32(x),
            Value::F64(x) => OwnedValue::F64(x),
            Value::Ascii(s) => OwnedValue::Ascii(s.to_string()),
            Value::Utf8(s) => OwnedValue::Utf8(s.to_string()),
            Value::Array(a) => OwnedValue::Array {
                elem: a.elem(),
                bytes: a.bytes().to_vec(),
            },
            Value::Tensor(t) => OwnedValue::Tensor {
                elem: t.elem(),
                dims: t.dims().iter().collect(),
                bytes: t.bytes().to_vec(),
            },
        }
    }

    /// The value, borrowed. Errors if an array's or tensor's bytes do not
    /// match its element type and shape, or it is too large to encode.
    pub fn as_value(&self) -> Result<Value<'_>, ValueError> {
        Ok(match self {
            OwnedValue::Null => Value::Null,
            OwnedValue::Bool(x) => Value::Bool(*x),
            OwnedValue::I8(x) => Value::I8(*x),
            OwnedValue::I16(x) => Value::I16(*x),
            OwnedValue::I32(x) => Value::I32(*x),
            OwnedValue::I64(x) => Value::I64(*x),
            OwnedValue::I128(x) => Value::I128(*x),
            OwnedValue::U8(x) => Value::U8(*x),
            OwnedValue::U16(x) => Value::U16(*x),
            OwnedValue::U32(x) => Value::U32(*x),
            OwnedValue::U64(x) => Value::U64(*x),
            OwnedValue::U128(x) => Value::U128(*x),
            OwnedValue::F16(x) => Value::F16(*x),
            OwnedValue::F32(x) => Value::F32(*x),
            OwnedValue::F64(x) => Value::F64(*x),
            OwnedValue::Ascii(s) => Value::Ascii(s),
            OwnedValue::Utf8(s) => Value::Utf8(s),
            OwnedValue::Array { elem, bytes } => Value::Array(Array::new(*elem, bytes)?),
            OwnedValue::Tensor { elem, dims, bytes } => {
                Value::Tensor(Tensor::new(*elem, dims, bytes)?)
            }
        })
    }

    /// The value's type.
    pub fn ty(&self) -> Type {
        match self {
            OwnedValue::Array { elem, .. } => Type::Array(*elem),
            OwnedValue::Tensor { elem, .. } => Type::Tensor(*elem),
            // Every other variant converts without fail.
            other => other.as_value().map_or(Type::Null, |v| v.ty()),
        }
    }

    /// The number, as an f64, for every integer and float that an f64
    /// holds exactly (and bools as 0 or 1); `None` otherwise.
    pub fn as_f64(&self) -> Option<f64> {
        let v = self.as_value().ok()?;
        match pipes_core::convert(&v, &Type::Scalar(ScalarType::F64)).ok()? {
            pipes_core::Converted::Value(Value::F64(x)) => Some(x),
            _ => None,
        }
    }

    /// The value of type `ty` written as `text`, as a person types it:
    /// integers and floats in decimal, bools as `true`/`false` or `1`/`0`,
    /// strings as they are. Out-of-range integers, non-finite floats and
    /// types without a text form (arrays, tensors) are refused, saying why.
    pub fn parse(ty: &Type, text: &str) -> Result<OwnedValue, String> {
        let text = text.trim();
        let int = || {
            text.parse::<i128>()
                .map_err(|_| format!("{text:?} is not an integer"))
        };
        let range = |_| format!("{text:?} is out of range for {ty}");
        Ok(match ty {
            Type::Scalar(s) => match s {
                ScalarType::Bool => match text {
                    "true" | "1" => OwnedValue::Bool(true),
                    "false" | "0" => OwnedValue::Bool(false),
                    _ => return Err(format!("{text:?}: write true or false")),
                },
                ScalarType::F16 | ScalarType::F32 | ScalarType::F64 => {
                    let x: f64 = text
                        .parse()
                        .map_err(|_| format!("{text:?} is not a number"))?;
                    if !x.is_finite() {
                        return Err(format!("{text:?} is not a finite number"));
                    }
                    match s {
                        ScalarType::F64 => OwnedValue::F64(x),
                        _ => OwnedValue::F32(x as f32),
                    }
                }
                ScalarType::U8 => OwnedValue::U8(int()?.try_into().map_err(range)?),
                ScalarType::U16 => OwnedValue::U16(int()?.try_into().map_err(range)?),
                ScalarType::U32 => OwnedValue::U32(int()?.try_into().map_err(range)?),
                ScalarType::U64 => OwnedValue::U64(int()?.try_into().map_err(range)?),
                ScalarType::U128 => OwnedValue::U128(int()?.try_into().map_err(range)?),
                ScalarType::I8 => OwnedValue::I8(int()?.try_into().map_err(range)?),
                ScalarType::I16 => OwnedValue::I16(int()?.try_into().map_err(range)?),
                ScalarType::I32 => OwnedValue::I32(int()?.try_into().map_err(range)?),
                ScalarType::I64 => OwnedValue::I64(int()?.try_into().map_err(range)?),
                ScalarType::I128 => OwnedValue::I128(int()?),
            },
            Type::Utf8 => OwnedValue::Utf8(text.to_string()),
            Type::Ascii if text.is_ascii() => OwnedValue::Ascii(text.to_string()),
            Type::Ascii => return Err(format!("{text:?} is not ASCII")),
            other => return Err(format!("a {other} cannot be given as text")),
        })
    }
}

impl fmt::Display for OwnedValue {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            OwnedValue::Ascii(s) | OwnedValue::Utf8(s) => write!(f, "{s:?}"),
            OwnedValue::Array { elem, bytes } => {
                write!(f, "arry_{elem}[{} bytes]", bytes.len())
            }
            OwnedValue::Tensor { elem, dims, .. } => write!(f, "tnsr_{elem}{dims:?}"),
            other => match other.as_value() {
                Ok(v) => write!(f, "{v:?}"),
                Err(e) => write!(f, "<{e}>"),
            },
        }
    }
}
