//! The macros' compile errors: a type with no PIPES encoding, output names
//! that do not match the returned values, class mistakes, a doc comment
//! longer than a function may publish. The expected
//! messages are the `.stderr` files next to each case in `tests/ui/`
//! (regenerate with `TRYBUILD=overwrite cargo test -p pipes-core --test compile_fail`).

#[test]
fn macro_errors() {
    let t = trybuild::TestCases::new();
    t.compile_fail("tests/ui/*.rs");
}
