//! The conversions a receiver applies to a value whose type differs from the
//! type its input declares.
//!
//! The principle: **a conversion may never change the value**. The value that
//! arrives is the value that was sent, or the receiver gets an error that says
//! why not. So:
//!
//! - integer → integer: always when the target holds every source value
//!   (u8→u16, i16→i32, u16→i32, ...); otherwise (narrowing, signed↔unsigned)
//!   only if this value fits, else [`ConvertReason::OutOfRange`];
//! - integer → float: always when every source value is exact in the target
//!   (i8/u8→f16, up to 16-bit→f32, up to 32-bit→f64); otherwise only if this
//!   value is exact, else [`ConvertReason::Lossy`] (or `OutOfRange` beyond
//!   ±65504 for f16);
//! - float → float: widening (f16→f32→f64) always; narrowing only if the value
//!   is exact in the target (NaN and ±∞ included), else `Lossy` (or
//!   `OutOfRange` for a finite value beyond the target's largest);
//! - float → integer: never (`Lossy`), whatever the value;
//! - bool ↔ anything but bool: never ([`ConvertReason::Impossible`]);
//! - ascii → utf8: always; utf8 → ascii only if every character is ASCII,
//!   else `OutOfRange`;
//! - arrays → arrays and tensors → tensors (same dims): element by element
//!   under the scalar rules; the error names the first element that fails;
//! - everything else (null ↔ anything else, strings ↔ numbers, scalar ↔ array,
//!   array ↔ tensor): never (`Impossible`).
//!
//! [`rule`] tells from the types alone which of these applies; [`convert`]
//! applies it to a value. `docs/pipes.md` has the full table (checked against
//! [`rule`] by the tests).

use core::fmt;

use osap_core::codec::Writer;

use crate::f16::{f16_to_f32, f32_to_f16_exact, f64_to_f16_exact, f64_to_f32_exact};
use crate::types::{ScalarType, Type};
use crate::value::{Dims, Element, Elements, Text, Value, ValueError};

/// Why a conversion failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ConvertReason {
    /// The value would change: float → integer, or a value that the target
    /// type cannot hold exactly (e.g. i32 16777217 → f32, f64 0.1 → f32).
    Lossy,
    /// The value lies outside the target type's range (e.g. i64 2^40 → i32,
    /// -1 → u8, "é" → ascii).
    OutOfRange,
    /// The types are not convertible at all (bool ↔ number, string ↔ number,
    /// null ↔ anything else, scalar ↔ array, array ↔ tensor).
    Impossible,
}

impl fmt::Display for ConvertReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            ConvertReason::Lossy => "the value would change (lossy)",
            ConvertReason::OutOfRange => "the value is out of the target type's range",
            ConvertReason::Impossible => "the types are not convertible",
        })
    }
}

/// A conversion that failed: what, and why.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct ConvertError {
    /// The type of the value.
    pub from: Type,
    /// The type it was to become.
    pub to: Type,
    /// Why it could not.
    pub reason: ConvertReason,
    /// For arrays and tensors: the (row-major) index of the first element
    /// that failed, if the failure depends on the values.
    pub element: Option<usize>,
}

impl fmt::Display for ConvertError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "cannot convert {} to {}", self.from, self.to)?;
        if let Some(i) = self.element {
            write!(f, " (element {i})")?;
        }
        write!(f, ": {}", self.reason)
    }
}

impl core::error::Error for ConvertError {}

/// Which conversion applies between two types, from the types alone.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Rule {
    /// The types are the same: the value passes unchanged.
    Identity,
    /// Every value of the source type converts exactly.
    Always,
    /// Only some values convert: those that fit the target exactly.
    IfExact,
    /// No value converts.
    Never(ConvertReason),
}

/// The conversion rule from `from` to `to` (see the module docs).
pub fn rule(from: &Type, to: &Type) -> Rule {
    if from == to {
        return Rule::Identity;
    }
    match (from, to) {
        (Type::Scalar(a), Type::Scalar(b)) => scalar_rule(*a, *b),
        (Type::Array(a), Type::Array(b)) | (Type::Tensor(a), Type::Tensor(b)) => {
            scalar_rule(*a, *b)
        }
        (Type::Ascii, Type::Utf8) => Rule::Always,
        (Type::Utf8, Type::Ascii) => Rule::IfExact,
        _ => Rule::Never(ConvertReason::Impossible),
    }
}

/// Magnitude bits every value of an integer type may need.
fn magnitude_bits(s: ScalarType) -> u32 {
    let bits = s.width() as u32 * 8;
    if s.is_signed() {
        bits - 1
    } else {
        bits
    }
}

/// Significand precision of a float type (bits, hidden bit included).
fn precision(s: ScalarType) -> u32 {
    match s {
        ScalarType::F16 => 11,
        ScalarType::F32 => 24,
        _ => 53,
    }
}

fn scalar_rule(a: ScalarType, b: ScalarType) -> Rule {
    use ScalarType::Bool;
    if a == b {
        return Rule::Identity;
    }
    if a == Bool || b == Bool {
        return Rule::Never(ConvertReason::Impossible);
    }
    let always_if = |ok: bool| if ok { Rule::Always } else { Rule::IfExact };
    match (a.is_integer(), b.is_integer()) {
        (true, true) => always_if(match (a.is_signed(), b.is_signed()) {
            (false, true) => b.width() > a.width(),
            (true, false) => false,
            _ => b.width() >= a.width(),
        }),
        // Every integer type that fits a float's precision also fits its range.
        (true, false) => always_if(magnitude_bits(a) <= precision(b)),
        (false, true) => Rule::Never(ConvertReason::Lossy),
        (false, false) => always_if(precision(b) >= precision(a)),
    }
}

/// An integer value, sign split off so every integer type fits.
#[derive(Clone, Copy)]
enum Int {
    /// A negative value.
    Neg(i128),
    /// Zero or a positive value.
    Pos(u128),
}

fn signed(v: i128) -> Int {
    u128::try_from(v).map_or(Int::Neg(v), Int::Pos)
}

/// A scalar value reduced to what conversion needs.
#[derive(Clone, Copy)]
enum Num {
    Bool(bool),
    Int(Int),
    F16(u16),
    F32(f32),
    F64(f64),
}

fn num(v: &Value<'_>) -> Option<Num> {
    Some(match *v {
        Value::Bool(b) => Num::Bool(b),
        Value::I8(x) => Num::Int(signed(x.into())),
        Value::I16(x) => Num::Int(signed(x.into())),
        Value::I32(x) => Num::Int(signed(x.into())),
        Value::I64(x) => Num::Int(signed(x.into())),
        Value::I128(x) => Num::Int(signed(x)),
        Value::U8(x) => Num::Int(Int::Pos(x.into())),
        Value::U16(x) => Num::Int(Int::Pos(x.into())),
        Value::U32(x) => Num::Int(Int::Pos(x.into())),
        Value::U64(x) => Num::Int(Int::Pos(x.into())),
        Value::U128(x) => Num::Int(Int::Pos(x)),
        Value::F16(h) => Num::F16(h),
        Value::F32(x) => Num::F32(x),
        Value::F64(x) => Num::F64(x),
        _ => return None,
    })
}

fn int_to_int(i: Int, to: ScalarType) -> Option<Value<'static>> {
    macro_rules! fit {
        ($t:ty, $v:ident) => {
            match i {
                Int::Neg(x) => <$t>::try_from(x).ok().map(Value::$v),
                Int::Pos(x) => <$t>::try_from(x).ok().map(Value::$v),
            }
        };
    }
    match to {
        ScalarType::I8 => fit!(i8, I8),
        ScalarType::I16 => fit!(i16, I16),
        ScalarType::I32 => fit!(i32, I32),
        ScalarType::I64 => fit!(i64, I64),
        ScalarType::I128 => fit!(i128, I128),
        ScalarType::U8 => fit!(u8, U8),
        ScalarType::U16 => fit!(u16, U16),
        ScalarType::U32 => fit!(u32, U32),
        ScalarType::U64 => fit!(u64, U64),
        ScalarType::U128 => fit!(u128, U128),
        _ => None,
    }
}

fn int_to_float(i: Int, to: ScalarType) -> Result<Value<'static>, ConvertReason> {
    let mag = match i {
        Int::Neg(x) => x.unsigned_abs(),
        Int::Pos(x) => x,
    };
    let bits = if mag == 0 {
        0
    } else {
        128 - mag.leading_zeros() - mag.trailing_zeros()
    };
    if to == ScalarType::F16 && mag > 65504 {
        return Err(ConvertReason::OutOfRange);
    }
    if bits > precision(to) {
        return Err(ConvertReason::Lossy);
    }
    // Exact: the significant bits fit the target's precision.
    let x = match i {
        Int::Neg(x) => x as f64,
        Int::Pos(x) => x as f64,
    };
    match to {
        ScalarType::F64 => Ok(Value::F64(x)),
        ScalarType::F32 => Ok(Value::F32(x as f32)),
        _ => f64_to_f16_exact(x)
            .map(Value::F16)
            .ok_or(ConvertReason::Lossy),
    }
}

/// Why narrowing a float failed: out of range if finite and too big.
fn narrow_reason(x: f64, max: f64) -> ConvertReason {
    if x.is_finite() && x.abs() > max {
        ConvertReason::OutOfRange
    } else {
        ConvertReason::Lossy
    }
}

const F16_MAX: f64 = 65504.0;

/// Converts one scalar value to scalar type `to`.
fn convert_scalar(v: &Value<'_>, to: ScalarType) -> Result<Value<'static>, ConvertReason> {
    use ScalarType as S;
    let n = num(v).ok_or(ConvertReason::Impossible)?;
    match (n, to) {
        (Num::Bool(b), S::Bool) => Ok(Value::Bool(b)),
        (Num::Bool(_), _) | (_, S::Bool) => Err(ConvertReason::Impossible),
        (Num::Int(i), _) if to.is_integer() => int_to_int(i, to).ok_or(ConvertReason::OutOfRange),
        (Num::Int(i), _) => int_to_float(i, to),
        (_, _) if to.is_integer() => Err(ConvertReason::Lossy),
        (Num::F16(h), S::F16) => Ok(Value::F16(h)),
        (Num::F16(h), S::F32) => Ok(Value::F32(f16_to_f32(h))),
        (Num::F16(h), _) => Ok(Value::F64(f16_to_f32(h) as f64)),
        (Num::F32(x), S::F16) => f32_to_f16_exact(x)
            .map(Value::F16)
            .ok_or_else(|| narrow_reason(x as f64, F16_MAX)),
        (Num::F32(x), S::F32) => Ok(Value::F32(x)),
        (Num::F32(x), _) => Ok(Value::F64(x as f64)),
        (Num::F64(x), S::F16) => f64_to_f16_exact(x)
            .map(Value::F16)
            .ok_or_else(|| narrow_reason(x, F16_MAX)),
        (Num::F64(x), S::F32) => f64_to_f32_exact(x)
            .map(Value::F32)
            .ok_or_else(|| narrow_reason(x, f32::MAX as f64)),
        (Num::F64(x), _) => Ok(Value::F64(x)),
    }
}

/// The elements of an array or tensor, converted to another element type as
/// they are read. Every element was checked when the conversion was made, so
/// reading them cannot fail.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ConvertedElements<'a> {
    src: Elements<'a>,
    to: ScalarType,
}

impl<'a> ConvertedElements<'a> {
    /// The element type after conversion.
    pub fn elem(&self) -> ScalarType {
        self.to
    }

    /// The elements as they arrived.
    pub fn source(&self) -> Elements<'a> {
        self.src
    }

    /// The number of elements.
    pub fn len(&self) -> usize {
        self.src.len()
    }

    /// Whether there are no elements.
    pub fn is_empty(&self) -> bool {
        self.src.is_empty()
    }

    /// Element `i`, converted.
    pub fn get(&self, i: usize) -> Option<Value<'static>> {
        convert_scalar(&self.src.get(i)?, self.to).ok()
    }

    /// The elements, converted.
    pub fn iter(&self) -> impl ExactSizeIterator<Item = Value<'static>> + 'a {
        let to = self.to;
        // Conversions cannot fail here (all were checked); the fallback only
        // keeps this free of panics.
        self.src
            .iter()
            .map(move |v| convert_scalar(&v, to).unwrap_or(Value::Null))
    }

    /// The elements, converted, as native numbers, if the target element type
    /// is `T`'s.
    pub fn typed<T: Element>(&self) -> Option<impl Iterator<Item = T> + 'a> {
        (T::TYPE == self.to).then(|| self.iter().filter_map(T::from_value))
    }

    /// The converted elements' encoded size in bytes.
    pub fn byte_len(&self) -> usize {
        self.len() * self.to.width()
    }

    fn write(&self, w: &mut Writer<'_>) -> Result<(), ValueError> {
        for v in self.iter() {
            v.encode_body(w)?;
        }
        Ok(())
    }
}

/// A value after conversion.
#[derive(Debug, Clone, PartialEq)]
pub enum Converted<'a> {
    /// A value of the target type (scalars, strings, and arrays or tensors
    /// whose element type did not change).
    Value(Value<'a>),
    /// An array whose elements are converted as they are read.
    Array(ConvertedElements<'a>),
    /// A tensor whose elements are converted as they are read.
    Tensor {
        /// The tensor's dims.
        dims: Dims<'a>,
        /// Its elements, row-major.
        elements: ConvertedElements<'a>,
    },
}

impl Converted<'_> {
    /// The type after conversion.
    pub fn ty(&self) -> Type {
        match self {
            Converted::Value(v) => v.ty(),
            Converted::Array(e) => Type::Array(e.to),
            Converted::Tensor { elements, .. } => Type::Tensor(elements.to),
        }
    }

    /// How many bytes [`encode`](Converted::encode) writes.
    pub fn encoded_len(&self) -> Result<usize, ValueError> {
        match self {
            Converted::Value(v) => v.encoded_len(),
            Converted::Array(e) => Ok(3 + e.byte_len()),
            Converted::Tensor { dims, elements } => Ok(2 + 2 * dims.rank() + elements.byte_len()),
        }
    }

    /// Writes the converted value as `[type key][value]` of its new type.
    /// On error nothing is written.
    pub fn encode(&self, w: &mut Writer<'_>) -> Result<(), ValueError> {
        if self.encoded_len()? > w.remaining() {
            return Err(ValueError::NoSpace);
        }
        match self {
            Converted::Value(v) => v.encode(w),
            Converted::Array(e) => {
                w.u8(Type::Array(e.to).key())?;
                // The source array had at most 65535 elements.
                w.u16(e.len() as u16)?;
                e.write(w)
            }
            Converted::Tensor { dims, elements } => {
                w.u8(Type::Tensor(elements.to).key())?;
                w.u8(dims.rank() as u8)?;
                for d in dims.iter() {
                    w.u16(d)?;
                }
                elements.write(w)
            }
        }
    }
}

/// Checks every element converts; the index and reason of the first that does not.
fn check_elements(src: Elements<'_>, to: ScalarType) -> Result<(), (usize, ConvertReason)> {
    for (i, v) in src.iter().enumerate() {
        convert_scalar(&v, to).map_err(|r| (i, r))?;
    }
    Ok(())
}

/// Converts `value` to type `to` under the conversion table (module docs).
/// The result borrows `value`'s data.
pub fn convert<'a>(value: &'a Value<'_>, to: &Type) -> Result<Converted<'a>, ConvertError> {
    let from = value.ty();
    let err = |reason, element| ConvertError {
        from,
        to: *to,
        reason,
        element,
    };
    let rule = rule(&from, to);
    match rule {
        Rule::Identity => return Ok(Converted::Value(value.reborrow())),
        Rule::Never(reason) => return Err(err(reason, None)),
        Rule::Always | Rule::IfExact => {}
    }
    let checked = |src: Elements<'a>, elem: ScalarType| {
        if rule == Rule::IfExact {
            check_elements(src, elem).map_err(|(i, r)| err(r, Some(i)))?;
        }
        Ok(ConvertedElements { src, to: elem })
    };
    match (value, to) {
        (Value::Array(a), Type::Array(s)) => Ok(Converted::Array(checked(a.elements(), *s)?)),
        (Value::Tensor(t), Type::Tensor(s)) => Ok(Converted::Tensor {
            dims: t.dims(),
            elements: checked(t.elements(), *s)?,
        }),
        (Value::Ascii(s), Type::Utf8) => Ok(Converted::Value(Value::Utf8(Text::new(s)))),
        (Value::Utf8(s), Type::Ascii) if s.is_ascii() => {
            Ok(Converted::Value(Value::Ascii(Text::new(s))))
        }
        (Value::Utf8(_), Type::Ascii) => Err(err(ConvertReason::OutOfRange, None)),
        (_, Type::Scalar(s)) => convert_scalar(value, *s)
            .map(Converted::Value)
            .map_err(|r| err(r, None)),
        _ => Err(err(ConvertReason::Impossible, None)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ScalarType as S;

    fn to<'a>(v: &'a Value<'_>, s: ScalarType) -> Result<Value<'a>, ConvertReason> {
        match convert(v, &Type::Scalar(s)) {
            Ok(Converted::Value(v)) => Ok(v),
            Ok(other) => panic!("unexpected {other:?}"),
            Err(e) => Err(e.reason),
        }
    }

    #[test]
    fn integers() {
        assert_eq!(to(&Value::U8(200), S::U16), Ok(Value::U16(200)));
        assert_eq!(to(&Value::U8(200), S::I16), Ok(Value::I16(200)));
        assert_eq!(to(&Value::I32(-7), S::I64), Ok(Value::I64(-7)));
        assert_eq!(
            to(&Value::I64(1 << 40), S::I32),
            Err(ConvertReason::OutOfRange)
        );
        assert_eq!(to(&Value::I64(-5), S::I32), Ok(Value::I32(-5)));
        assert_eq!(to(&Value::I8(-1), S::U64), Err(ConvertReason::OutOfRange));
        assert_eq!(
            to(&Value::U128(u128::MAX), S::I128),
            Err(ConvertReason::OutOfRange)
        );
        assert_eq!(
            to(&Value::I128(i128::MIN), S::I128),
            Ok(Value::I128(i128::MIN))
        );
    }

    #[test]
    fn integers_to_floats() {
        assert_eq!(
            to(&Value::I32(i32::MIN), S::F64),
            Ok(Value::F64(-2147483648.0))
        );
        assert_eq!(to(&Value::I16(-300), S::F32), Ok(Value::F32(-300.0)));
        assert_eq!(to(&Value::U16(65535), S::F32), Ok(Value::F32(65535.0)));
        assert_eq!(
            to(&Value::I32(16_777_216), S::F32),
            Ok(Value::F32(16_777_216.0))
        );
        assert_eq!(
            to(&Value::I32(16_777_217), S::F32),
            Err(ConvertReason::Lossy)
        );
        assert_eq!(
            to(&Value::U128(1 << 100), S::F32),
            Ok(Value::F32(2f32.powi(100)))
        );
        assert_eq!(
            to(&Value::U128(u128::MAX), S::F64),
            Err(ConvertReason::Lossy)
        );
        assert_eq!(to(&Value::U16(2048), S::F16), Ok(Value::F16(0x6800)));
        assert_eq!(to(&Value::U16(2049), S::F16), Err(ConvertReason::Lossy));
        assert_eq!(
            to(&Value::U32(65536), S::F16),
            Err(ConvertReason::OutOfRange)
        );
    }

    #[test]
    fn floats() {
        assert_eq!(to(&Value::F32(0.1), S::F64), Ok(Value::F64(0.1f32 as f64)));
        assert_eq!(
            to(&Value::F16(0x3555), S::F32),
            Ok(Value::F32(f16_to_f32(0x3555)))
        );
        assert_eq!(to(&Value::F64(0.5), S::F32), Ok(Value::F32(0.5)));
        assert_eq!(to(&Value::F64(0.1), S::F32), Err(ConvertReason::Lossy));
        assert_eq!(
            to(&Value::F64(1e300), S::F32),
            Err(ConvertReason::OutOfRange)
        );
        assert_eq!(to(&Value::F64(1e5), S::F16), Err(ConvertReason::OutOfRange));
        assert_eq!(
            to(&Value::F64(f64::INFINITY), S::F32),
            Ok(Value::F32(f32::INFINITY))
        );
        assert_eq!(to(&Value::F32(1.0), S::I32), Err(ConvertReason::Lossy));
        assert_eq!(to(&Value::F16(0), S::U8), Err(ConvertReason::Lossy));
    }

    #[test]
    fn impossible() {
        assert_eq!(
            to(&Value::Bool(true), S::U8),
            Err(ConvertReason::Impossible)
        );
        assert_eq!(to(&Value::U8(1), S::Bool), Err(ConvertReason::Impossible));
        assert_eq!(
            to(&Value::ascii("1"), S::U8),
            Err(ConvertReason::Impossible)
        );
        assert_eq!(to(&Value::Null, S::U8), Err(ConvertReason::Impossible));
        assert_eq!(
            convert(&Value::U8(1), &Type::Null).unwrap_err().reason,
            ConvertReason::Impossible
        );
    }

    #[test]
    fn strings() {
        assert_eq!(
            convert(&Value::ascii("ab"), &Type::Utf8),
            Ok(Converted::Value(Value::utf8("ab")))
        );
        assert_eq!(
            convert(&Value::utf8("ab"), &Type::Ascii),
            Ok(Converted::Value(Value::ascii("ab")))
        );
        assert_eq!(
            convert(&Value::utf8("é"), &Type::Ascii).unwrap_err().reason,
            ConvertReason::OutOfRange
        );
    }

    #[test]
    fn arrays_element_wise() {
        use crate::value::Array;
        let bytes = [1, 0, 2, 0, 0, 1, 255, 255];
        let a = Value::Array(Array::new(S::I16, &bytes).unwrap());
        let c = convert(&a, &Type::Array(S::I32)).unwrap();
        let Converted::Array(e) = c else {
            panic!("{c:?}")
        };
        assert!(e.typed::<i32>().unwrap().eq([1, 2, 256, -1]));
        let mut buf = [0u8; 32];
        let mut w = Writer::new(&mut buf);
        c.encode(&mut w).unwrap();
        assert_eq!(w.len(), c.encoded_len().unwrap());
        assert_eq!(&buf[..5], &[0x52, 4, 0, 1, 0]);

        let e = convert(&a, &Type::Array(S::U8)).unwrap_err();
        assert_eq!((e.reason, e.element), (ConvertReason::OutOfRange, Some(2)));
        let e = convert(&a, &Type::Array(S::Bool)).unwrap_err();
        assert_eq!((e.reason, e.element), (ConvertReason::Impossible, None));
        let e = convert(&a, &Type::Tensor(S::I16)).unwrap_err();
        assert_eq!(e.reason, ConvertReason::Impossible);
    }

    #[test]
    fn error_messages() {
        extern crate std;
        use std::string::ToString;
        let e = convert(&Value::I32(16_777_217), &Type::Scalar(S::F32)).unwrap_err();
        assert_eq!(
            e.to_string(),
            "cannot convert i32 to f32: the value would change (lossy)"
        );
        let e = ConvertError {
            from: Type::Array(S::I16),
            to: Type::Array(S::U8),
            reason: ConvertReason::OutOfRange,
            element: Some(2),
        };
        assert_eq!(
            e.to_string(),
            "cannot convert arry_i16 to arry_u8 (element 2): the value is out of the target type's range"
        );
    }

    #[test]
    fn rule_agrees_with_values() {
        // Where the rule says Always, the extreme values convert; where it
        // says IfExact, some extreme value does not.
        fn extremes(s: ScalarType) -> [Value<'static>; 2] {
            match s {
                S::Bool => [Value::Bool(false), Value::Bool(true)],
                S::I8 => [Value::I8(i8::MIN), Value::I8(i8::MAX)],
                S::I16 => [Value::I16(i16::MIN), Value::I16(i16::MAX)],
                S::I32 => [Value::I32(i32::MIN), Value::I32(i32::MAX)],
                S::I64 => [Value::I64(i64::MIN), Value::I64(i64::MAX)],
                S::I128 => [Value::I128(i128::MIN), Value::I128(i128::MAX)],
                S::U8 => [Value::U8(0), Value::U8(u8::MAX)],
                S::U16 => [Value::U16(0), Value::U16(u16::MAX)],
                S::U32 => [Value::U32(0), Value::U32(u32::MAX)],
                S::U64 => [Value::U64(0), Value::U64(u64::MAX)],
                S::U128 => [Value::U128(0), Value::U128(u128::MAX)],
                S::F16 => [Value::F16(0x7bff), Value::F16(0x3555)],
                S::F32 => [Value::F32(f32::MAX), Value::F32(0.1)],
                S::F64 => [Value::F64(f64::MAX), Value::F64(0.1)],
            }
        }
        for a in ScalarType::ALL {
            for b in ScalarType::ALL {
                let results = extremes(a).map(|v| to(&v, b).map(|_| ()));
                match rule(&Type::Scalar(a), &Type::Scalar(b)) {
                    Rule::Identity | Rule::Always => {
                        assert!(results.iter().all(Result::is_ok), "{a}->{b}")
                    }
                    Rule::IfExact => assert!(results.iter().any(Result::is_err), "{a}->{b}"),
                    Rule::Never(r) => assert!(results.iter().all(|x| *x == Err(r)), "{a}->{b}"),
                }
            }
        }
    }
}
