//! PIPES type keys (WIRE.md §6) and the project's type names.
//!
//! Every value on the wire starts with a one-byte type key. The keys are:
//!
//! | key | type | name |
//! |---|---|---|
//! | 0 | null | `null` |
//! | 1 | bool | `bool` |
//! | 3 | unknown | reserved: an error |
//! | 16..=20 | i8, i16, i32, i64, i128 | `i8` .. `i128` |
//! | 24..=28 | u8, u16, u32, u64, u128 | `u8` .. `u128` |
//! | 33, 34, 35 | f16, f32, f64 | `f16`, `f32`, `f64` |
//! | 36 | f128 | reserved: an error |
//! | 48, 49 | ascii, utf8 | `ascii`, `utf8` |
//! | `0x40 \| k` | array of scalar `k` | `arry_` + scalar name, e.g. `arry_f32` |
//! | `0x80 \| k` | tensor of scalar `k` | `tnsr_` + scalar name, e.g. `tnsr_f32` |
//!
//! Arrays and tensors hold fixed-width elements only: `k` must be one of the
//! [`ScalarType`]s (bool, the ten integers, f16, f32, f64). Arrays or tensors
//! of null, strings, reserved keys or of arrays are errors.

use core::fmt;

use crate::value::ValueError;

/// The key bit that marks an array of a scalar type.
pub const ARRAY_BIT: u8 = 0x40;
/// The key bit that marks a tensor of a scalar type.
pub const TENSOR_BIT: u8 = 0x80;

/// The key of `null`.
pub const KEY_NULL: u8 = 0;
/// The key of the reserved `unknown` type.
pub const KEY_UNKNOWN: u8 = 3;
/// The key of the reserved `f128` type.
pub const KEY_F128: u8 = 36;
/// The key of an ASCII string.
pub const KEY_ASCII: u8 = 48;
/// The key of a UTF-8 string.
pub const KEY_UTF8: u8 = 49;

/// A fixed-width scalar: the types a value can be on its own and the element
/// types of arrays and tensors. The discriminant is the wire key.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[repr(u8)]
pub enum ScalarType {
    /// A boolean, one byte: 0 or 1.
    Bool = 1,
    /// A signed 8-bit integer.
    I8 = 16,
    /// A signed 16-bit integer.
    I16 = 17,
    /// A signed 32-bit integer.
    I32 = 18,
    /// A signed 64-bit integer.
    I64 = 19,
    /// A signed 128-bit integer.
    I128 = 20,
    /// An unsigned 8-bit integer.
    U8 = 24,
    /// An unsigned 16-bit integer.
    U16 = 25,
    /// An unsigned 32-bit integer.
    U32 = 26,
    /// An unsigned 64-bit integer.
    U64 = 27,
    /// An unsigned 128-bit integer.
    U128 = 28,
    /// An IEEE 754 binary16 float.
    F16 = 33,
    /// An IEEE 754 binary32 float.
    F32 = 34,
    /// An IEEE 754 binary64 float.
    F64 = 35,
}

impl ScalarType {
    /// Every scalar type, in key order.
    pub const ALL: [ScalarType; 14] = [
        ScalarType::Bool,
        ScalarType::I8,
        ScalarType::I16,
        ScalarType::I32,
        ScalarType::I64,
        ScalarType::I128,
        ScalarType::U8,
        ScalarType::U16,
        ScalarType::U32,
        ScalarType::U64,
        ScalarType::U128,
        ScalarType::F16,
        ScalarType::F32,
        ScalarType::F64,
    ];

    /// The scalar type with wire key `key`, if `key` names one.
    pub const fn from_key(key: u8) -> Option<ScalarType> {
        Some(match key {
            1 => ScalarType::Bool,
            16 => ScalarType::I8,
            17 => ScalarType::I16,
            18 => ScalarType::I32,
            19 => ScalarType::I64,
            20 => ScalarType::I128,
            24 => ScalarType::U8,
            25 => ScalarType::U16,
            26 => ScalarType::U32,
            27 => ScalarType::U64,
            28 => ScalarType::U128,
            33 => ScalarType::F16,
            34 => ScalarType::F32,
            35 => ScalarType::F64,
            _ => return None,
        })
    }

    /// The wire key.
    pub const fn key(self) -> u8 {
        self as u8
    }

    /// How many bytes one value takes on the wire.
    pub const fn width(self) -> usize {
        match self {
            ScalarType::Bool | ScalarType::I8 | ScalarType::U8 => 1,
            ScalarType::I16 | ScalarType::U16 | ScalarType::F16 => 2,
            ScalarType::I32 | ScalarType::U32 | ScalarType::F32 => 4,
            ScalarType::I64 | ScalarType::U64 | ScalarType::F64 => 8,
            ScalarType::I128 | ScalarType::U128 => 16,
        }
    }

    /// Whether this is one of the ten integer types.
    pub const fn is_integer(self) -> bool {
        self.is_signed() || self.is_unsigned()
    }

    /// Whether this is a signed integer type.
    pub const fn is_signed(self) -> bool {
        matches!(
            self,
            ScalarType::I8 | ScalarType::I16 | ScalarType::I32 | ScalarType::I64 | ScalarType::I128
        )
    }

    /// Whether this is an unsigned integer type.
    pub const fn is_unsigned(self) -> bool {
        matches!(
            self,
            ScalarType::U8 | ScalarType::U16 | ScalarType::U32 | ScalarType::U64 | ScalarType::U128
        )
    }

    /// Whether this is one of the float types.
    pub const fn is_float(self) -> bool {
        matches!(self, ScalarType::F16 | ScalarType::F32 | ScalarType::F64)
    }

    /// The type's name: `bool`, `i8`..`i128`, `u8`..`u128`, `f16`, `f32`, `f64`.
    pub const fn name(self) -> &'static str {
        match self {
            ScalarType::Bool => "bool",
            ScalarType::I8 => "i8",
            ScalarType::I16 => "i16",
            ScalarType::I32 => "i32",
            ScalarType::I64 => "i64",
            ScalarType::I128 => "i128",
            ScalarType::U8 => "u8",
            ScalarType::U16 => "u16",
            ScalarType::U32 => "u32",
            ScalarType::U64 => "u64",
            ScalarType::U128 => "u128",
            ScalarType::F16 => "f16",
            ScalarType::F32 => "f32",
            ScalarType::F64 => "f64",
        }
    }

    const fn array_name(self) -> &'static str {
        match self {
            ScalarType::Bool => "arry_bool",
            ScalarType::I8 => "arry_i8",
            ScalarType::I16 => "arry_i16",
            ScalarType::I32 => "arry_i32",
            ScalarType::I64 => "arry_i64",
            ScalarType::I128 => "arry_i128",
            ScalarType::U8 => "arry_u8",
            ScalarType::U16 => "arry_u16",
            ScalarType::U32 => "arry_u32",
            ScalarType::U64 => "arry_u64",
            ScalarType::U128 => "arry_u128",
            ScalarType::F16 => "arry_f16",
            ScalarType::F32 => "arry_f32",
            ScalarType::F64 => "arry_f64",
        }
    }

    const fn tensor_name(self) -> &'static str {
        match self {
            ScalarType::Bool => "tnsr_bool",
            ScalarType::I8 => "tnsr_i8",
            ScalarType::I16 => "tnsr_i16",
            ScalarType::I32 => "tnsr_i32",
            ScalarType::I64 => "tnsr_i64",
            ScalarType::I128 => "tnsr_i128",
            ScalarType::U8 => "tnsr_u8",
            ScalarType::U16 => "tnsr_u16",
            ScalarType::U32 => "tnsr_u32",
            ScalarType::U64 => "tnsr_u64",
            ScalarType::U128 => "tnsr_u128",
            ScalarType::F16 => "tnsr_f16",
            ScalarType::F32 => "tnsr_f32",
            ScalarType::F64 => "tnsr_f64",
        }
    }
}

impl fmt::Display for ScalarType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A PIPES type: what a type key names.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Type {
    /// No value (key 0).
    Null,
    /// A fixed-width scalar.
    Scalar(ScalarType),
    /// A string of ASCII characters (key 48).
    Ascii,
    /// A UTF-8 string (key 49).
    Utf8,
    /// A one-dimensional array of scalars (key `0x40 | k`).
    Array(ScalarType),
    /// A row-major tensor of scalars (key `0x80 | k`).
    Tensor(ScalarType),
}

impl Type {
    /// Every type, in key order of its kind: null, scalars, strings, arrays, tensors.
    pub fn all() -> impl Iterator<Item = Type> {
        let scalars = ScalarType::ALL.into_iter();
        [Type::Null]
            .into_iter()
            .chain(scalars.clone().map(Type::Scalar))
            .chain([Type::Ascii, Type::Utf8])
            .chain(scalars.clone().map(Type::Array))
            .chain(scalars.map(Type::Tensor))
    }

    /// The type a wire key names.
    ///
    /// Errors: [`ValueError::ReservedType`] for `unknown` (3) and `f128` (36),
    /// also as array or tensor elements; [`ValueError::UnknownType`] for every
    /// other key that names no type (including arrays and tensors of null,
    /// strings, and keys with both the array and tensor bits set).
    pub const fn from_key(key: u8) -> Result<Type, ValueError> {
        let base = key & !(ARRAY_BIT | TENSOR_BIT);
        if base == KEY_UNKNOWN || base == KEY_F128 {
            return Err(ValueError::ReservedType(key));
        }
        match key & (ARRAY_BIT | TENSOR_BIT) {
            0 => match key {
                KEY_NULL => Ok(Type::Null),
                KEY_ASCII => Ok(Type::Ascii),
                KEY_UTF8 => Ok(Type::Utf8),
                _ => match ScalarType::from_key(key) {
                    Some(s) => Ok(Type::Scalar(s)),
                    None => Err(ValueError::UnknownType(key)),
                },
            },
            ARRAY_BIT => match ScalarType::from_key(base) {
                Some(s) => Ok(Type::Array(s)),
                None => Err(ValueError::UnknownType(key)),
            },
            TENSOR_BIT => match ScalarType::from_key(base) {
                Some(s) => Ok(Type::Tensor(s)),
                None => Err(ValueError::UnknownType(key)),
            },
            _ => Err(ValueError::UnknownType(key)),
        }
    }

    /// The wire key.
    pub const fn key(&self) -> u8 {
        match self {
            Type::Null => KEY_NULL,
            Type::Scalar(s) => s.key(),
            Type::Ascii => KEY_ASCII,
            Type::Utf8 => KEY_UTF8,
            Type::Array(s) => ARRAY_BIT | s.key(),
            Type::Tensor(s) => TENSOR_BIT | s.key(),
        }
    }

    /// The type's name as the system object model spells it: `null`, the
    /// scalar names (`bool`, `i8`, .., `f64`), `ascii`, `utf8`, and
    /// `arry_<scalar>` / `tnsr_<scalar>` (`arry_f32`, `tnsr_u8`, ..).
    pub const fn name(&self) -> &'static str {
        match self {
            Type::Null => "null",
            Type::Scalar(s) => s.name(),
            Type::Ascii => "ascii",
            Type::Utf8 => "utf8",
            Type::Array(s) => s.array_name(),
            Type::Tensor(s) => s.tensor_name(),
        }
    }

    /// The type whose [`name`](Type::name) is `name`.
    pub fn from_name(name: &str) -> Option<Type> {
        Type::all().find(|t| t.name() == name)
    }

    /// The scalar type if this is a scalar.
    pub const fn scalar(&self) -> Option<ScalarType> {
        match self {
            Type::Scalar(s) => Some(*s),
            _ => None,
        }
    }

    /// The element type if this is an array or a tensor.
    pub const fn element(&self) -> Option<ScalarType> {
        match self {
            Type::Array(s) | Type::Tensor(s) => Some(*s),
            _ => None,
        }
    }

    /// How many bytes a value of this type takes after its key, if that is
    /// fixed (null and scalars); `None` for strings, arrays and tensors.
    pub const fn fixed_width(&self) -> Option<usize> {
        match self {
            Type::Null => Some(0),
            Type::Scalar(s) => Some(s.width()),
            _ => None,
        }
    }
}

impl fmt::Display for Type {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_key_parses_or_errs_and_round_trips() {
        let mut count = 0;
        for key in 0..=255u8 {
            if let Ok(t) = Type::from_key(key) {
                assert_eq!(t.key(), key);
                assert_eq!(Type::from_name(t.name()), Some(t));
                count += 1;
            }
        }
        // null, 14 scalars, 2 strings, 14 arrays, 14 tensors.
        assert_eq!(count, 45);
        assert_eq!(Type::all().count(), 45);
    }

    #[test]
    fn reserved_and_unknown_keys() {
        assert_eq!(Type::from_key(3), Err(ValueError::ReservedType(3)));
        assert_eq!(Type::from_key(36), Err(ValueError::ReservedType(36)));
        assert_eq!(
            Type::from_key(0x40 | 36),
            Err(ValueError::ReservedType(0x64))
        );
        assert_eq!(Type::from_key(2), Err(ValueError::UnknownType(2)));
        assert_eq!(Type::from_key(0x40), Err(ValueError::UnknownType(0x40)));
        assert_eq!(
            Type::from_key(0x40 | 48),
            Err(ValueError::UnknownType(0x70))
        );
        assert_eq!(
            Type::from_key(0xC0 | 34),
            Err(ValueError::UnknownType(0xE2))
        );
    }

    #[test]
    fn names_and_widths() {
        assert_eq!(Type::Array(ScalarType::F32).name(), "arry_f32");
        assert_eq!(Type::Tensor(ScalarType::U8).name(), "tnsr_u8");
        assert_eq!(Type::Array(ScalarType::F32).key(), 0x62);
        assert_eq!(Type::Tensor(ScalarType::F32).key(), 0xA2);
        assert_eq!(ScalarType::I128.width(), 16);
        assert_eq!(ScalarType::F16.width(), 2);
        assert_eq!(Type::Null.fixed_width(), Some(0));
        assert_eq!(Type::Utf8.fixed_width(), None);
    }
}
