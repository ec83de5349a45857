//! Rust names for device types, functions and arguments.
//!
//! The rules (also in `docs/proxygen.md`), applied in this order:
//!
//! 1. **Words.** A name is split into words at every character that is not
//!    an ASCII letter or digit (`-`, `.`, ` `, `µ`, ..), at every
//!    lower-to-upper case change (`getPosition` → `get`, `Position`) and
//!    before the last capital of a run followed by a lower-case letter
//!    (`HTTPServer` → `HTTP`, `Server`).
//! 2. **Case.** [`snake`] joins the lower-cased words with `_`
//!    (functions, arguments, fields, modules); [`camel`] capitalizes each
//!    word and joins them (structs).
//! 3. **Empty or leading digit.** A name without words becomes `unnamed`
//!    (`Unnamed`); one that starts with a digit gets a prefix: `_` in
//!    snake case (`3d` → `_3d`), `T` in camel case (`3d` → `T3d`).
//! 4. **Keywords.** A Rust keyword (strict, reserved or weak, 2021
//!    edition) gets a trailing `_`: `type` → `type_`, `self` → `self_`,
//!    `Self` → `Self_`.
//! 5. **Duplicates.** Within one scope (a module's items, a struct's
//!    methods, a function's arguments or output fields) a name already
//!    taken gets the smallest numeric suffix from 2 that is free:
//!    `_2`, `_3`, .. in snake case, `2`, `3`, .. in camel case. Scopes are
//!    filled in the order of the model (runtime, then port), so the
//!    suffixes are stable for a given SOM.

use std::collections::HashSet;

/// Rust keywords (2021 edition: strict, reserved and the weak ones that
/// matter as identifiers).
const KEYWORDS: &[&str] = &[
    "as",
    "async",
    "await",
    "break",
    "const",
    "continue",
    "crate",
    "dyn",
    "else",
    "enum",
    "extern",
    "false",
    "fn",
    "for",
    "if",
    "impl",
    "in",
    "let",
    "loop",
    "match",
    "mod",
    "move",
    "mut",
    "pub",
    "ref",
    "return",
    "self",
    "Self",
    "static",
    "struct",
    "super",
    "trait",
    "true",
    "type",
    "unsafe",
    "use",
    "where",
    "while",
    "abstract",
    "become",
    "box",
    "do",
    "final",
    "gen",
    "macro",
    "override",
    "priv",
    "try",
    "typeof",
    "unsized",
    "virtual",
    "yield",
    "union",
    "macro_rules",
    "raw",
    "safe",
];

/// Whether `s` is a Rust keyword.
pub fn is_keyword(s: &str) -> bool {
    KEYWORDS.contains(&s)
}

/// The words of `name` (rule 1).
pub fn words(name: &str) -> Vec<String> {
    let mut words = Vec::new();
    for part in name.split(|c: char| !c.is_ascii_alphanumeric()) {
        let chars: Vec<char> = part.chars().collect();
        let mut cur = String::new();
        for (i, &c) in chars.iter().enumerate() {
            if !cur.is_empty() && c.is_ascii_uppercase() {
                let prev = chars[i - 1];
                let next_lower = chars.get(i + 1).is_some_and(|n| n.is_ascii_lowercase());
                if prev.is_ascii_lowercase()
                    || prev.is_ascii_digit()
                    || (prev.is_ascii_uppercase() && next_lower)
                {
                    words.push(std::mem::take(&mut cur));
                }
            }
            cur.push(c);
        }
        if !cur.is_empty() {
            words.push(cur);
        }
    }
    words
}

fn finish(mut s: String, digit_prefix: &str, empty: &str) -> String {
    if s.is_empty() {
        return empty.into();
    }
    if s.starts_with(|c: char| c.is_ascii_digit()) {
        s.insert_str(0, digit_prefix);
    }
    if is_keyword(&s) {
        s.push('_');
    }
    s
}

/// `name` in snake case, escaped (rules 1 to 4).
pub fn snake(name: &str) -> String {
    let s = words(name)
        .iter()
        .map(|w| w.to_ascii_lowercase())
        .collect::<Vec<_>>()
        .join("_");
    finish(s, "_", "unnamed")
}

/// `name` in camel case, escaped (rules 1 to 4).
pub fn camel(name: &str) -> String {
    let s: String = words(name)
        .iter()
        .map(|w| {
            let lower = w.to_ascii_lowercase();
            let mut c = lower.chars();
            match c.next() {
                Some(f) => f.to_ascii_uppercase().to_string() + c.as_str(),
                None => String::new(),
            }
        })
        .collect();
    finish(s, "T", "Unnamed")
}

/// `name` + `suffix`, without the keyword escape's trailing `_` of `name`
/// when the suffix starts with `_` (`type_` + `_ref` → `type_ref`).
pub fn suffixed(name: &str, suffix: &str) -> String {
    if suffix.starts_with('_') && name.ends_with('_') && name.len() > 1 {
        format!("{}{suffix}", &name[..name.len() - 1])
    } else {
        format!("{name}{suffix}")
    }
}

/// One scope of names (rule 5).
#[derive(Debug, Default, Clone)]
pub struct Scope {
    used: HashSet<String>,
}

impl Scope {
    /// A scope where `reserved` are taken already.
    pub fn with_reserved(reserved: &[&str]) -> Scope {
        Scope {
            used: reserved.iter().map(|s| s.to_string()).collect(),
        }
    }

    /// Takes `base`, or `base` with the smallest free numeric suffix
    /// (`sep` between them), such that every name `base + s` for `s` in
    /// `suffixes` is free as well (a keyword's trailing `_` is dropped
    /// before a suffix: `type_` + `_ref` is `type_ref`); takes all of them.
    pub fn take_with(&mut self, base: &str, sep: &str, suffixes: &[&str]) -> String {
        let free = |used: &HashSet<String>, b: &str| {
            !used.contains(b) && suffixes.iter().all(|s| !used.contains(&suffixed(b, s)))
        };
        let mut name = base.to_string();
        let mut n = 2;
        while !free(&self.used, &name) {
            name = format!("{base}{sep}{n}");
            n += 1;
        }
        self.used.insert(name.clone());
        for s in suffixes {
            self.used.insert(suffixed(&name, s));
        }
        name
    }

    /// A snake-case name for `raw`, unique in this scope.
    pub fn snake(&mut self, raw: &str) -> String {
        self.take_with(&snake(raw), "_", &[])
    }

    /// A camel-case name for `raw`, unique in this scope.
    pub fn camel(&mut self, raw: &str) -> String {
        self.take_with(&camel(raw), "", &[])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cases() {
        assert_eq!(snake("get_position"), "get_position");
        assert_eq!(snake("getPosition"), "get_position");
        assert_eq!(snake("HTTPServer"), "http_server");
        assert_eq!(snake("Tally.add"), "tally_add");
        assert_eq!(snake("temp-°C"), "temp_c");
        assert_eq!(snake("type"), "type_");
        assert_eq!(snake("self"), "self_");
        assert_eq!(snake("3d"), "_3d");
        assert_eq!(snake("--"), "unnamed");
        assert_eq!(camel("stepper"), "Stepper");
        assert_eq!(camel("osap_host"), "OsapHost");
        assert_eq!(camel("my-dev.v2"), "MyDevV2");
        assert_eq!(camel("Self"), "Self_");
        assert_eq!(camel("3d printer"), "T3dPrinter");
        assert_eq!(camel(""), "Unnamed");
    }

    #[test]
    fn duplicates() {
        let mut s = Scope::with_reserved(&["bind"]);
        assert_eq!(s.snake("bind"), "bind_2");
        assert_eq!(s.snake("a-b"), "a_b");
        assert_eq!(s.snake("a.b"), "a_b_2");
        assert_eq!(s.snake("A_B"), "a_b_3");
        let mut s = Scope::default();
        assert_eq!(s.take_with("get", "_", &["_ref"]), "get");
        assert_eq!(s.take_with("get_ref", "_", &["_ref"]), "get_ref_2");
    }
}
