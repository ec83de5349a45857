//! Rust types as PIPES types: what the [`function`](macro@crate::function)
//! and [`class`](macro@crate::class) macros build signatures and calls from.
//!
//! - [`PipesType`]: a Rust type with a PIPES type ([`PipesType::TYPE`]) and
//!   a way to write a value of it ([`PipesType::to_value`]). Implemented for
//!   `bool`, `i8`..`i128`, `u8`..`u128`, `f32`, `f64` and `&str` (`utf8`).
//! - [`FromPipes`]: reading an input value back into the Rust type.
//! - [`PipesOutputs`]: what a function returns, written to its
//!   [`Outputs`]: `()` (no outputs) and tuples of up to
//!   [`MAX_ARGS`](crate::signature::MAX_ARGS) [`PipesType`]s.
//! - [`PipesArgs`]: a struct whose named fields are a function's inputs
//!   (or outputs), in order: `#[derive(pipes_core::PipesArgs)]` takes the
//!   argument names from the field names and the types from the field
//!   types, so a function defined at run time (a host function that
//!   captures state) still has its signature written once, in Rust.
//!
//! A type with none of these fails to compile with "`T` has no PIPES
//! encoding". Everything here is `no_std` and allocation-free.
//!
//! The generated calls fail with [`CallError::Failed`] and one of the codes
//! below only if the function machinery hands over an input that is not of
//! its declared type, or if a class's state is already borrowed.

use crate::function::{CallError, Outputs};
use crate::signature::Arg;
use crate::types::{ScalarType, Type};
use crate::value::{Text, Value};

/// [`CallError::Failed`] code: an input was missing or not of its declared
/// type (the machinery converts inputs before a call, so this means a bug).
pub const INPUT_DECODE_FAILED: u8 = 255;
/// [`CallError::Failed`] code: a class member ran while the class state was
/// borrowed elsewhere.
pub const STATE_BUSY: u8 = 254;
/// [`CallError::Failed`] code: a class was asked for a member it does not have.
pub const NO_SUCH_MEMBER: u8 = 253;

/// A Rust type with a PIPES encoding.
#[diagnostic::on_unimplemented(
    message = "`{Self}` has no PIPES encoding",
    label = "not a PIPES type",
    note = "PIPES functions take and return bool, i8..i128, u8..u128, f32, f64 and &str; several outputs are a tuple of these (at most 8)"
)]
pub trait PipesType {
    /// The PIPES type of the Rust type.
    const TYPE: Type;

    /// The value as a PIPES value.
    fn to_value(&self) -> Value<'_>;
}

/// A Rust type that can be read from a PIPES input value of its
/// [`PipesType::TYPE`].
#[diagnostic::on_unimplemented(
    message = "`{Self}` has no PIPES encoding",
    label = "not a PIPES type",
    note = "PIPES functions take and return bool, i8..i128, u8..u128, f32, f64 and &str"
)]
pub trait FromPipes<'a>: PipesType + Sized {
    /// The Rust value of `v`, if `v` is of type [`PipesType::TYPE`]. It may
    /// borrow from `v` (a `&str` does).
    fn from_value(v: &'a Value<'_>) -> Option<Self>;
}

macro_rules! scalar {
    ($($t:ty => $variant:ident, $scalar:ident;)*) => {$(
        impl PipesType for $t {
            const TYPE: Type = Type::Scalar(ScalarType::$scalar);
            fn to_value(&self) -> Value<'_> {
                Value::$variant(*self)
            }
        }

        impl FromPipes<'_> for $t {
            fn from_value(v: &Value<'_>) -> Option<Self> {
                match v {
                    Value::$variant(x) => Some(*x),
                    _ => None,
                }
            }
        }
    )*};
}

scalar! {
    bool => Bool, Bool;
    i8 => I8, I8;
    i16 => I16, I16;
    i32 => I32, I32;
    i64 => I64, I64;
    i128 => I128, I128;
    u8 => U8, U8;
    u16 => U16, U16;
    u32 => U32, U32;
    u64 => U64, U64;
    u128 => U128, U128;
    f32 => F32, F32;
    f64 => F64, F64;
}

impl PipesType for &str {
    const TYPE: Type = Type::Utf8;
    fn to_value(&self) -> Value<'_> {
        Value::Utf8(Text::new(self))
    }
}

impl<'a> FromPipes<'a> for &'a str {
    fn from_value(v: &'a Value<'_>) -> Option<Self> {
        match v {
            Value::Utf8(s) | Value::Ascii(s) => Some(s),
            _ => None,
        }
    }
}

/// Input `index` of `inputs` as a `T`; fails with [`INPUT_DECODE_FAILED`].
pub fn input<'a, T: FromPipes<'a>>(inputs: &'a [Value<'_>], index: usize) -> Result<T, CallError> {
    inputs
        .get(index)
        .and_then(T::from_value)
        .ok_or(CallError::Failed(
            crate::control::FailureCode::InputDecodeFailed,
        ))
}

/// What a function returns: `()` for no outputs, a tuple for one or more.
#[diagnostic::on_unimplemented(
    message = "`{Self}` is not a list of PIPES outputs",
    note = "outputs are `()` or a tuple of at most 8 of bool, i8..i128, u8..u128, f32, f64 and &str"
)]
pub trait PipesOutputs {
    /// The number of outputs.
    const ARITY: usize;

    /// Sets output `i` to element `i`, for every element.
    fn write(&self, outputs: &mut Outputs<'_>) -> Result<(), CallError>;
}

impl PipesOutputs for () {
    const ARITY: usize = 0;
    fn write(&self, _outputs: &mut Outputs<'_>) -> Result<(), CallError> {
        Ok(())
    }
}

macro_rules! tuple {
    ($n:expr; $($t:ident $i:tt),*) => {
        impl<$($t: PipesType),*> PipesOutputs for ($($t,)*) {
            const ARITY: usize = $n;
            fn write(&self, outputs: &mut Outputs<'_>) -> Result<(), CallError> {
                $(outputs.set($i, &self.$i.to_value())?;)*
                Ok(())
            }
        }
    };
}

tuple!(1; A 0);
tuple!(2; A 0, B 1);
tuple!(3; A 0, B 1, C 2);
tuple!(4; A 0, B 1, C 2, D 3);
tuple!(5; A 0, B 1, C 2, D 3, E 4);
tuple!(6; A 0, B 1, C 2, D 3, E 4, F 5);
tuple!(7; A 0, B 1, C 2, D 3, E 4, F 5, G 6);
tuple!(8; A 0, B 1, C 2, D 3, E 4, F 5, G 6, H 7);

/// A list of PIPES arguments as a Rust struct: its named fields, in order,
/// are a function's inputs (or its outputs).
///
/// `#[derive(pipes_core::PipesArgs)]` implements it for a struct with
/// named fields of [`PipesType`]s (at most
/// [`MAX_ARGS`](crate::signature::MAX_ARGS), no generics, so no `&str`):
///
/// ```
/// use pipes_core::export::PipesArgs;
/// use pipes_core::Value;
///
/// #[derive(pipes_core::PipesArgs)]
/// struct Reading {
///     time: u64,
///     value: f32,
/// }
///
/// assert_eq!(Reading::ARGS[1].name, "value");
/// let r = Reading::from_values(&[Value::U64(7), Value::F32(0.5)]).unwrap();
/// assert_eq!((r.time, r.value), (7, 0.5));
/// assert_eq!(r.value(0), Some(Value::U64(7)));
/// ```
///
/// `()` is the empty list.
#[diagnostic::on_unimplemented(
    message = "`{Self}` is not a list of PIPES arguments",
    note = "derive it: `#[derive(pipes_core::PipesArgs)]` on a struct with named fields of PIPES types"
)]
pub trait PipesArgs: Sized {
    /// The arguments: each field's name and PIPES type, in field order.
    const ARGS: &'static [Arg];

    /// The struct from values in argument order; fails with
    /// [`INPUT_DECODE_FAILED`] when one is missing or not of its type.
    fn from_values(values: &[Value<'_>]) -> Result<Self, CallError>;

    /// Argument `index`'s value (`None` past the last).
    fn value(&self, index: usize) -> Option<Value<'_>>;
}

impl PipesArgs for () {
    const ARGS: &'static [Arg] = &[];

    fn from_values(_values: &[Value<'_>]) -> Result<Self, CallError> {
        Ok(())
    }

    fn value(&self, _index: usize) -> Option<Value<'_>> {
        None
    }
}
