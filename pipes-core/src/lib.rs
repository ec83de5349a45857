//! # pipes-core
//!
//! PIPES for osap-rs: plain functions on any device as typed dataflow blocks.
//! This crate is `no_std` and allocation-free by default. The `alloc`
//! feature lets a [`Value`] own its data (`Value<'static>`, what host code
//! keeps); the `std` feature implies it and adds `std::error::Error` impls.
//!
//! This first piece is the data layer every other part builds on:
//! - [`types`]: the type keys of WIRE.md §6 ([`Type`], [`ScalarType`]) and
//!   their names in the system object model (`f32`, `arry_f32`, `tnsr_u8`, ..).
//! - [`value`]: the [`Value`] (borrowed, or owned with `alloc`) and its
//!   `[type key][value]` codec,
//!   with [`Array`]s and [`Tensor`]s that read their elements in place.
//! - [`convert`](mod@convert): the conversion table a receiver applies when a value's type
//!   differs from its input's, which never changes a value silently.
//! - [`message`]: the dataflow message `[key][count] count × ([index][value])`.
//! - [`f16`](mod@f16): exact IEEE binary16 conversions.
//!
//! The byte layout, the conversion table and golden vectors are in
//! `docs/pipes.md`. Nothing here panics on input from the wire: malformed
//! data is an error value.
#![no_std]
#![deny(missing_docs)]
// Lints as policy: every public type can be printed, and `pub` means
// reachable from outside the crate.
#![warn(missing_debug_implementations, unreachable_pub)]
#![forbid(unsafe_code)]

#[cfg(feature = "alloc")]
extern crate alloc;
#[cfg(any(feature = "std", test))]
extern crate std;

pub mod control;
pub mod convert;
pub mod docs;
pub mod f16;
pub mod failure;
pub mod function;
pub mod manager;
pub mod message;
pub mod pipe;
pub mod signature;
pub mod types;
pub mod value;

pub use control::FailureCode;
pub use convert::{convert, ConvertError, ConvertReason, Converted, Rule};
pub use message::{Args, ArgsWriter, Message, MessageError, MessageKey};
/// osap-core's typed time, which PIPES classes and functions see.
pub use osap_core::time;
pub use types::{ScalarType, Type};
pub use value::{Array, Dims, Element, Elements, Tensor, Text, Value, ValueError};
pub mod class;
pub mod export;
pub use export::{FromPipes, PipesArgs, PipesOutputs, PipesType};
/// `#[pipes_core::class]` on an inherent `impl` block: see
/// [`pipes_macros::class`](macro@pipes_macros::class) and [`class`](mod@class).
pub use pipes_macros::class;
/// `pipes_core::doc_text!(/// ..)`: doc attributes as the text a function
/// publishes ([`docs`](mod@docs)); see
/// [`pipes_macros::doc_text`](macro@pipes_macros::doc_text).
pub use pipes_macros::doc_text;
/// `#[pipes_core::function(outputs = "a, b")]` on a plain `fn`: see
/// [`pipes_macros::function`](macro@pipes_macros::function).
pub use pipes_macros::function;
/// `#[derive(pipes_core::PipesArgs)]` on a struct with named fields: see
/// [`pipes_macros::PipesArgs`](derive@pipes_macros::PipesArgs) and
/// [`export::PipesArgs`].
pub use pipes_macros::PipesArgs;
