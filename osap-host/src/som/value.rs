//! Values as people type them.
//!
//! Host code keeps PIPES values as pipes-core's own [`Value`], owning its
//! data (`Value<'static>`, with pipes-core's `alloc` feature). This module
//! adds the host-only pieces: reading a value of a known type from text,
//! as the command line and the viewer take it, and writing one as JSON, as
//! the viewer and the zenoh bridge send it.

use pipes_core::{ScalarType, Type, Value};

/// Why [`parse_value`] refused a text.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum ParseValueError {
    /// An integer type was given something that is not a decimal integer.
    #[error("{text:?} is not an integer")]
    NotAnInteger {
        /// The text given.
        text: String,
    },
    /// The integer is outside the range of its type.
    #[error("{text:?} is out of range for {ty}")]
    OutOfRange {
        /// The text given.
        text: String,
        /// The type it was meant for.
        ty: Type,
    },
    /// A bool was given something other than `true`, `false`, `1` or `0`.
    #[error("{text:?}: write true or false")]
    NotABool {
        /// The text given.
        text: String,
    },
    /// A float type was given something that is not a number.
    #[error("{text:?} is not a number")]
    NotANumber {
        /// The text given.
        text: String,
    },
    /// A float type was given an infinity or NaN.
    #[error("{text:?} is not a finite number")]
    NotFinite {
        /// The text given.
        text: String,
    },
    /// An ascii value was given a non-ASCII text.
    #[error("{text:?} is not ASCII")]
    NotAscii {
        /// The text given.
        text: String,
    },
    /// The type has no text form (null, arrays, tensors).
    #[error("a {0} cannot be given as text")]
    NoTextForm(Type),
}

/// The value of type `ty` written as `text`, as a person types it: integers
/// and floats in decimal, bools as `true`/`false` or `1`/`0`, strings as
/// they are (surrounding whitespace is trimmed first). Out-of-range integers,
/// non-finite floats and types without a text form (null, arrays, tensors)
/// are refused, saying why. f16 values are given as f32s, which the receiver
/// converts exactly or refuses.
pub fn parse_value(ty: &Type, text: &str) -> Result<Value<'static>, ParseValueError> {
    let text = text.trim();
    let owned = || text.to_string();
    let int = || {
        text.parse::<i128>()
            .map_err(|_| ParseValueError::NotAnInteger { text: owned() })
    };
    let range = |_| ParseValueError::OutOfRange {
        text: owned(),
        ty: *ty,
    };
    Ok(match ty {
        Type::Scalar(s) => match s {
            ScalarType::Bool => match text {
                "true" | "1" => Value::Bool(true),
                "false" | "0" => Value::Bool(false),
                _ => return Err(ParseValueError::NotABool { text: owned() }),
            },
            ScalarType::F16 | ScalarType::F32 | ScalarType::F64 => {
                let x: f64 = text
                    .parse()
                    .map_err(|_| ParseValueError::NotANumber { text: owned() })?;
                if !x.is_finite() {
                    return Err(ParseValueError::NotFinite { text: owned() });
                }
                match s {
                    ScalarType::F64 => Value::F64(x),
                    _ => Value::F32(x as f32),
                }
            }
            ScalarType::U8 => Value::U8(int()?.try_into().map_err(range)?),
            ScalarType::U16 => Value::U16(int()?.try_into().map_err(range)?),
            ScalarType::U32 => Value::U32(int()?.try_into().map_err(range)?),
            ScalarType::U64 => Value::U64(int()?.try_into().map_err(range)?),
            ScalarType::U128 => Value::U128(int()?.try_into().map_err(range)?),
            ScalarType::I8 => Value::I8(int()?.try_into().map_err(range)?),
            ScalarType::I16 => Value::I16(int()?.try_into().map_err(range)?),
            ScalarType::I32 => Value::I32(int()?.try_into().map_err(range)?),
            ScalarType::I64 => Value::I64(int()?.try_into().map_err(range)?),
            ScalarType::I128 => Value::I128(int()?),
        },
        Type::Utf8 => Value::utf8(owned()),
        Type::Ascii if text.is_ascii() => Value::ascii(owned()),
        Type::Ascii => return Err(ParseValueError::NotAscii { text: owned() }),
        other => return Err(ParseValueError::NoTextForm(*other)),
    })
}

/// A value as a person types it, the form [`parse_value`] reads back:
/// numbers and bools bare (`0.5`, `true`), strings as they are, anything
/// else (arrays, tensors) as the value prints.
pub fn value_text(v: &Value<'_>) -> String {
    match v {
        Value::Bool(x) => x.to_string(),
        Value::I8(x) => x.to_string(),
        Value::I16(x) => x.to_string(),
        Value::I32(x) => x.to_string(),
        Value::I64(x) => x.to_string(),
        Value::I128(x) => x.to_string(),
        Value::U8(x) => x.to_string(),
        Value::U16(x) => x.to_string(),
        Value::U32(x) => x.to_string(),
        Value::U64(x) => x.to_string(),
        Value::U128(x) => x.to_string(),
        Value::F32(x) => x.to_string(),
        Value::F64(x) => x.to_string(),
        Value::Utf8(s) | Value::Ascii(s) => s.as_str().to_string(),
        other => other.to_string(),
    }
}

/// A value as JSON: bools, integers and strings as themselves, floats as
/// numbers (null when not finite), anything else (arrays, tensors, 128-bit
/// integers) as its text.
pub fn value_json(v: &Value<'static>) -> serde_json::Value {
    use serde_json::Value as Json;
    let float = |x: f64| serde_json::Number::from_f64(x).map_or(Json::Null, Json::Number);
    match v {
        Value::Null => Json::Null,
        Value::Bool(x) => (*x).into(),
        Value::I8(x) => (*x).into(),
        Value::I16(x) => (*x).into(),
        Value::I32(x) => (*x).into(),
        Value::I64(x) => (*x).into(),
        Value::U8(x) => (*x).into(),
        Value::U16(x) => (*x).into(),
        Value::U32(x) => (*x).into(),
        Value::U64(x) => (*x).into(),
        Value::F32(x) => float(f64::from(*x)),
        Value::F64(x) => float(*x),
        Value::Utf8(s) | Value::Ascii(s) => s.as_str().into(),
        other => match (other.ty(), other.as_f64()) {
            (Type::Scalar(ScalarType::F16), Some(x)) => float(x),
            _ => other.to_string().into(),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_what_people_type() {
        let u8t = Type::Scalar(ScalarType::U8);
        assert_eq!(parse_value(&u8t, " 200 "), Ok(Value::U8(200)));
        assert_eq!(
            parse_value(&u8t, "300"),
            Err(ParseValueError::OutOfRange {
                text: "300".into(),
                ty: u8t
            })
        );
        assert!(matches!(
            parse_value(&u8t, "x"),
            Err(ParseValueError::NotAnInteger { .. })
        ));
        let b = Type::Scalar(ScalarType::Bool);
        assert_eq!(parse_value(&b, "1"), Ok(Value::Bool(true)));
        assert!(matches!(
            parse_value(&b, "yes"),
            Err(ParseValueError::NotABool { .. })
        ));
        let f = Type::Scalar(ScalarType::F64);
        assert_eq!(parse_value(&f, "-2.5"), Ok(Value::F64(-2.5)));
        assert!(matches!(
            parse_value(&f, "inf"),
            Err(ParseValueError::NotFinite { .. })
        ));
        assert!(matches!(
            parse_value(&f, "one"),
            Err(ParseValueError::NotANumber { .. })
        ));
        assert_eq!(
            parse_value(&Type::Scalar(ScalarType::F16), "1.5"),
            Ok(Value::F32(1.5))
        );
        assert_eq!(parse_value(&Type::Utf8, "héllo"), Ok(Value::utf8("héllo")));
        assert_eq!(parse_value(&Type::Ascii, "hi"), Ok(Value::ascii("hi")));
        assert!(matches!(
            parse_value(&Type::Ascii, "é"),
            Err(ParseValueError::NotAscii { .. })
        ));
        let arr = Type::Array(ScalarType::F32);
        assert_eq!(
            parse_value(&arr, "1"),
            Err(ParseValueError::NoTextForm(arr))
        );
        assert_eq!(
            ParseValueError::NoTextForm(arr).to_string(),
            "a arry_f32 cannot be given as text"
        );
    }
}
