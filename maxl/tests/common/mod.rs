//! Helpers shared by the integration tests: each test file declares
//! `mod common;` and takes what it needs, so items that some test files do
//! not use carry `#[allow(dead_code)]`.

pub(crate) mod rng;

#[cfg(feature = "std")]
use pipes_core::class::PipesClass;
#[cfg(feature = "std")]
use pipes_core::signature::{Arg, Signature};

/// A signature as text, `name(input: type, ..) -> (output: type, ..)`.
#[cfg(feature = "std")]
#[allow(dead_code)]
pub(crate) fn render(s: &Signature) -> String {
    let args = |a: &[Arg]| {
        a.iter()
            .map(|a| format!("{}: {}", a.name, a.ty))
            .collect::<Vec<_>>()
            .join(", ")
    };
    format!("{}({}) -> ({})", s.name, args(s.inputs), args(s.outputs))
}

/// The class name, constructor and members of `C`, rendered, after checking
/// that every one of those signatures is valid.
#[cfg(feature = "std")]
#[allow(dead_code)]
pub(crate) fn wire_api<C: PipesClass>() -> (&'static str, String, Vec<String>) {
    let members = C::MEMBERS.iter().map(|s| render(s)).collect();
    for s in C::MEMBERS.iter().chain([&C::CONSTRUCTOR]) {
        s.check().unwrap();
    }
    (C::NAME, render(C::CONSTRUCTOR), members)
}

/// Asserts that `C`'s wire API is exactly the class `name`, the rendered
/// constructor `ctor` and the rendered `members` in order, and that every
/// signature is valid.
#[cfg(feature = "std")]
#[allow(dead_code)]
pub(crate) fn assert_wire_api<C: PipesClass>(name: &str, ctor: &str, members: &[&str]) {
    let (n, c, m) = wire_api::<C>();
    assert_eq!(n, name);
    assert_eq!(c, ctor);
    assert_eq!(m, members);
}
