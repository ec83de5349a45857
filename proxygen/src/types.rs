//! SOM type names → Rust types of the generated proxies.
//!
//! | SOM type | argument | output |
//! |---|---|---|
//! | `null` | `()` | `()` |
//! | `bool`, `i8`..`i128`, `u8`..`u128`, `f32`, `f64` | the same | the same |
//! | `f16` | `u16` (IEEE binary16 bits) | `u16` |
//! | `ascii`, `utf8` | `&str` | `String` |
//! | `arry_<s>` (`s` a scalar above except `f16`, `null`) | `&[s]` | `Vec<s>` |
//! | anything else (`arry_f16`, `tnsr_*`, unknown names) | `Value<'static>` | `Value<'static>` |
//!
//! Each mapping names a conversion pair in `osap_host::som::proxy::support`:
//! `support::to_<key>` (argument → `Value<'static>`; for arrays a `Result`,
//! as an array past 65535 elements cannot be sent) and `support::from_<key>`
//! (`Value<'static>` → output, `None` if the value has another type).

/// How one SOM type appears in generated code.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RustType {
    /// The type of a method argument.
    pub param: String,
    /// The type of a returned value.
    pub owned: String,
    /// The suffix of the `support::to_*` / `support::from_*` pair.
    pub key: String,
    /// Whether `support::to_<key>` returns a `Result` (arrays, which
    /// cannot pass 65535 elements) rather than the value itself.
    pub fallible: bool,
}

const SCALARS: &[&str] = &[
    "bool", "i8", "i16", "i32", "i64", "i128", "u8", "u16", "u32", "u64", "u128", "f32", "f64",
];

/// The Rust form of SOM type `name`.
pub fn rust_type(name: &str) -> RustType {
    let t = |param: &str, owned: &str, key: &str| RustType {
        param: param.into(),
        owned: owned.into(),
        key: key.into(),
        fallible: false,
    };
    if SCALARS.contains(&name) {
        return t(name, name, name);
    }
    match name {
        "null" => return t("()", "()", "null"),
        "f16" => return t("u16", "u16", "f16"),
        "ascii" => return t("&str", "String", "ascii"),
        "utf8" => return t("&str", "String", "utf8"),
        _ => {}
    }
    if let Some(elem) = name.strip_prefix("arry_") {
        if SCALARS.contains(&elem) {
            return RustType {
                fallible: true,
                ..t(&format!("&[{elem}]"), &format!("Vec<{elem}>"), name)
            };
        }
    }
    t("Value<'static>", "Value<'static>", "raw")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mapping() {
        assert_eq!(rust_type("u64").param, "u64");
        assert_eq!(rust_type("utf8").param, "&str");
        assert_eq!(rust_type("utf8").owned, "String");
        assert_eq!(rust_type("arry_f32").owned, "Vec<f32>");
        assert_eq!(rust_type("arry_f32").key, "arry_f32");
        assert_eq!(rust_type("arry_f16").key, "raw");
        assert_eq!(rust_type("tnsr_u8").owned, "Value<'static>");
        assert!(rust_type("arry_f32").fallible);
        assert!(!rust_type("f32").fallible && !rust_type("tnsr_u8").fallible);
        assert_eq!(rust_type("f16").key, "f16");
    }
}
