//! Typed Rust proxies from a system object model (`docs/proxygen.md`).
//!
//! [`generate`] turns a [`Som`] (from a scan, or its JSON) into a Rust
//! module: one file per runtime type with one proxy struct (all runtimes of
//! the type share it, bound by name), one async method per function, and a
//! `mod.rs` with the errors and the signature check run at bind time.
//! [`starter`] adds a small binary crate around them. The code is rendered
//! from the `minijinja` templates in `proxygen/templates/`.

pub mod names;
pub mod types;

use names::Scope;
use osap_host::som::model::{SomArg, SomFunction};
use osap_host::som::Som;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::PathBuf;

/// The templates, compiled into the crate.
pub const TEMPLATES: &[(&str, &str)] = &[
    ("mod.rs", include_str!("../templates/mod.rs.jinja")),
    ("device.rs", include_str!("../templates/device.rs.jinja")),
    (
        "starter_main.rs",
        include_str!("../templates/starter_main.rs.jinja"),
    ),
    (
        "starter_cargo.toml",
        include_str!("../templates/starter_cargo.toml.jinja"),
    ),
];

/// What to generate.
#[derive(Debug, Clone, Default)]
pub struct Options {
    /// Also generate a proxy for runtime 0, the host that built the model
    /// (its functions are the scanning script's own; left out by default).
    pub include_host: bool,
}

/// One generated file: its path relative to the output directory.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct GeneratedFile {
    /// Relative path (`mod.rs`, `stepper.rs`, ..).
    pub path: PathBuf,
    /// Its text.
    pub contents: String,
}

/// Why generation failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A template failed to render (a bug in a template).
    #[error("template {name}: {source}")]
    Template {
        /// The template.
        name: &'static str,
        /// Why.
        #[source]
        source: minijinja::Error,
    },
    /// The model has no runtime with functions to generate proxies for.
    #[error("no runtime in the system object model has functions or classes")]
    Empty,
}

#[derive(Debug, Serialize)]
struct ArgCtx {
    name: String,
    ident: String,
    ty: String,
    param: String,
    owned: String,
    key: String,
    fallible: bool,
}

#[derive(Debug, Serialize)]
struct FnCtx {
    name: String,
    ident: String,
    handle_ident: String,
    ref_ident: String,
    constructor: bool,
    inputs: Vec<ArgCtx>,
    outputs: Vec<ArgCtx>,
    kind: &'static str,
    ret: String,
    out_struct: Option<String>,
    /// The function's summary as `///` lines (none if it sent none).
    docs: Vec<String>,
}

#[derive(Debug, Serialize)]
struct ClassCtx {
    name: String,
    field: String,
    struct_name: String,
    constructor: FnCtx,
    members: Vec<FnCtx>,
}

#[derive(Debug, Serialize)]
struct DeviceCtx {
    type_name: String,
    version: String,
    module: String,
    struct_name: String,
    runtimes: Vec<String>,
    functions: Vec<FnCtx>,
    all_functions: Vec<FnCtx>,
    classes: Vec<ClassCtx>,
    uses_raw: bool,
}

/// Methods every proxy struct has besides its functions'.
const STRUCT_METHODS: &[&str] = &["bind", "check", "runtime"];
/// Items of the generated `mod.rs`.
const MOD_ITEMS: &[&str] = &[
    "BindError",
    "CallError",
    "Difference",
    "DEVICES",
    "support",
    "fmt",
    "FnRef",
    "SomError",
];

fn args(list: &[SomArg], scope: &mut Scope) -> Vec<ArgCtx> {
    list.iter()
        .map(|a| {
            let t = types::rust_type(&a.type_name);
            ArgCtx {
                name: a.name.clone(),
                ident: scope.snake(&a.name),
                ty: a.type_name.clone(),
                param: t.param,
                owned: t.owned,
                key: t.key,
                fallible: t.fallible,
            }
        })
        .collect()
}

/// The context of one function; `methods` is the struct's method scope,
/// `items` the module's type scope.
#[allow(clippy::too_many_arguments)]
fn function(
    name: &str,
    short: &str,
    summary: &str,
    inputs: &[SomArg],
    outputs: &[SomArg],
    owner: &str,
    methods: &mut Scope,
    items: &mut Scope,
) -> FnCtx {
    let ident = methods.take_with(&names::snake(short), "_", &["_handle", "_ref"]);
    // `self`, `h`, `values` and `out` are the method body's own names.
    let mut arg_scope = Scope::with_reserved(&["self", "h", "values", "out"]);
    let inputs = args(inputs, &mut arg_scope);
    let outputs = args(outputs, &mut Scope::default());
    let named = outputs.iter().all(|a| !a.name.is_empty());
    let (kind, ret, out_struct) = match outputs.len() {
        0 => ("unit", "()".to_string(), None),
        1 => ("single", outputs[0].owned.clone(), None),
        _ if named => {
            let s = items.camel(&format!("{owner} {short} outputs"));
            ("struct", s.clone(), Some(s))
        }
        _ => (
            "tuple",
            format!(
                "({})",
                outputs
                    .iter()
                    .map(|a| a.owned.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
            None,
        ),
    };
    FnCtx {
        name: name.to_string(),
        handle_ident: names::suffixed(&ident, "_handle"),
        ref_ident: names::suffixed(&ident, "_ref"),
        ident,
        constructor: false,
        inputs,
        outputs,
        kind,
        ret,
        out_struct,
        docs: doc_lines(summary),
    }
}

/// A function's summary (the first sentence of its docs, as the model
/// holds it) as the lines of a generated `///` comment. Intra-doc links
/// (``[`crate::fault`]``) name items of the device's crate, not of the
/// proxy's: they are kept as code spans.
fn doc_lines(summary: &str) -> Vec<String> {
    summary
        .replace("[`", "`")
        .replace("`]", "`")
        .lines()
        .map(|l| l.trim_end().to_string())
        .collect()
}

fn plain(f: &SomFunction, owner: &str, methods: &mut Scope, items: &mut Scope) -> FnCtx {
    function(
        &f.name, &f.name, &f.summary, &f.inputs, &f.outputs, owner, methods, items,
    )
}

fn devices(som: &Som, options: &Options) -> Vec<DeviceCtx> {
    // Runtime types in model order; the first runtime of a type is its
    // reference (functions, version).
    let mut order: Vec<&str> = Vec::new();
    let mut found: BTreeMap<&str, Vec<usize>> = BTreeMap::new();
    for (i, r) in som.runtimes.iter().enumerate() {
        if i == 0 && !options.include_host {
            continue;
        }
        let has_classes = som.classes.iter().any(|c| c.runtime == i);
        if r.functions.is_empty() && !has_classes {
            continue;
        }
        if !found.contains_key(r.record.type_name.as_str()) {
            order.push(&r.record.type_name);
        }
        found.entry(&r.record.type_name).or_default().push(i);
    }
    let mut modules = Scope::with_reserved(&["support", "mod"]);
    let mut structs = Scope::with_reserved(MOD_ITEMS);
    let mut out = Vec::new();
    for type_name in order {
        let instances = &found[type_name];
        let ri = instances[0];
        let r = &som.runtimes[ri];
        let module = modules.snake(type_name);
        let struct_name = structs.camel(type_name);
        let mut items = Scope::with_reserved(&[
            struct_name.as_str(),
            "support",
            "BindError",
            "CallError",
            "FnRef",
            "FunctionHandle",
            "Manager",
            "Som",
            "Value",
        ]);
        let mut methods = Scope::with_reserved(STRUCT_METHODS);
        let classes: Vec<_> = som.classes.iter().filter(|c| c.runtime == ri).collect();
        let is_member = |name: &str| classes.iter().any(|c| c.members.iter().any(|m| m == name));
        // Class accessors first (they are few and named after the class).
        let class_fields: Vec<String> = classes.iter().map(|c| methods.snake(&c.name)).collect();
        let functions: Vec<FnCtx> = r
            .functions
            .iter()
            .filter(|f| !is_member(&f.name))
            .map(|f| plain(f, "", &mut methods, &mut items))
            .collect();
        let mut class_ctx = Vec::new();
        for (c, field) in classes.iter().zip(class_fields) {
            let struct_name = items.camel(&format!("{type_name} {}", c.name));
            let mut cmethods = Scope::default();
            let mut constructor = function(
                &c.name,
                "construct",
                "",
                &c.constructor,
                &[],
                &c.name,
                &mut cmethods,
                &mut items,
            );
            constructor.constructor = true;
            let prefix = format!("{}.", c.name);
            let members = c
                .members
                .iter()
                .filter_map(|m| r.functions.iter().find(|f| &f.name == m))
                .map(|f| {
                    let short = f.name.strip_prefix(&prefix).unwrap_or(&f.name);
                    function(
                        &f.name,
                        short,
                        &f.summary,
                        &f.inputs,
                        &f.outputs,
                        &c.name,
                        &mut cmethods,
                        &mut items,
                    )
                })
                .collect();
            class_ctx.push(ClassCtx {
                name: c.name.clone(),
                field,
                struct_name,
                constructor,
                members,
            });
        }
        // Every function, class members included, for the signature check.
        let mut throwaway = (Scope::default(), Scope::default());
        let all_functions = r
            .functions
            .iter()
            .map(|f| plain(f, "", &mut throwaway.0, &mut throwaway.1))
            .collect();
        let raw = |fs: &[FnCtx]| {
            fs.iter()
                .any(|f| f.inputs.iter().chain(&f.outputs).any(|a| a.key == "raw"))
        };
        let uses_raw = raw(&functions)
            || class_ctx
                .iter()
                .any(|c| raw(&c.members) || raw(std::slice::from_ref(&c.constructor)));
        out.push(DeviceCtx {
            type_name: type_name.to_string(),
            version: r.record.version.clone(),
            module,
            struct_name,
            runtimes: instances
                .iter()
                .map(|&i| som.runtimes[i].record.name.clone())
                .collect(),
            functions,
            all_functions,
            classes: class_ctx,
            uses_raw,
        });
    }
    out
}

/// A Rust string literal of `s` (the `rust_str` template filter).
fn rust_str(s: String) -> String {
    format!("{s:?}")
}

fn environment() -> minijinja::Environment<'static> {
    let mut env = minijinja::Environment::new();
    env.set_trim_blocks(true);
    env.set_lstrip_blocks(true);
    env.set_keep_trailing_newline(true);
    env.add_filter("rust_str", rust_str);
    // TOML basic strings escape like Rust's for the characters that matter.
    env.add_filter("toml_str", rust_str);
    for (name, text) in TEMPLATES {
        env.add_template(name, text)
            .unwrap_or_else(|e| panic!("template {name} does not parse: {e}"));
    }
    env
}

fn render(
    env: &minijinja::Environment<'_>,
    name: &'static str,
    ctx: minijinja::Value,
) -> Result<String, Error> {
    env.get_template(name)
        .and_then(|t| t.render(ctx))
        .map_err(|source| Error::Template { name, source })
}

/// The proxies of every runtime type in `som`: `mod.rs` and one
/// `<type>.rs` per type, in model order.
pub fn generate(som: &Som, options: &Options) -> Result<Vec<GeneratedFile>, Error> {
    let devices = devices(som, options);
    if devices.is_empty() {
        return Err(Error::Empty);
    }
    let env = environment();
    let mut files = vec![GeneratedFile {
        path: "mod.rs".into(),
        contents: render(&env, "mod.rs", minijinja::context! { devices => &devices })?,
    }];
    for d in &devices {
        files.push(GeneratedFile {
            path: format!("{}.rs", d.module).into(),
            contents: render(&env, "device.rs", minijinja::context! { d => d })?,
        });
    }
    Ok(files)
}

/// How a starter crate is made.
#[derive(Debug, Clone)]
pub struct StarterOptions {
    /// The crate's name.
    pub name: String,
    /// The path of the `osap-host` crate, as written in its `Cargo.toml`
    /// (relative to the starter's directory, or absolute).
    pub osap_host: String,
    /// The path of the `osap-sim` crate (the starter's `--sim`), written
    /// the same way.
    pub osap_sim: String,
    /// Generation options for its proxies.
    pub proxies: Options,
}

/// A starter script: a binary crate (`Cargo.toml`, `src/main.rs` and the
/// proxies in `src/proxies/`) that connects (`--sim FILE` or `--port
/// PATH`), binds every device of `som` by name and prints what it found.
pub fn starter(som: &Som, options: &StarterOptions) -> Result<Vec<GeneratedFile>, Error> {
    let devices = devices(som, &options.proxies);
    let mut vars = Scope::with_reserved(&["args", "host", "manager", "main", "proxies"]);
    let bindings: Vec<_> = devices
        .iter()
        .flat_map(|d| d.runtimes.iter().map(move |r| (d, r)))
        .map(|(d, r)| {
            minijinja::context! { var => vars.snake(r), struct_name => &d.struct_name, runtime => r }
        })
        .collect();
    let mut files = vec![
        GeneratedFile {
            path: "Cargo.toml".into(),
            contents: render(
                &generate_env(),
                "starter_cargo.toml",
                minijinja::context! {
                    name => &options.name,
                    osap_host => &options.osap_host,
                    osap_sim => &options.osap_sim,
                },
            )?,
        },
        GeneratedFile {
            path: "src/main.rs".into(),
            contents: render(
                &generate_env(),
                "starter_main.rs",
                minijinja::context! { bindings => bindings, name => &options.name },
            )?,
        },
    ];
    for f in generate(som, &options.proxies)? {
        files.push(GeneratedFile {
            path: PathBuf::from("src/proxies").join(f.path),
            contents: f.contents,
        });
    }
    Ok(files)
}

fn generate_env() -> minijinja::Environment<'static> {
    environment()
}

/// Writes `files` under `dir`, creating directories as needed.
pub fn write(dir: &std::path::Path, files: &[GeneratedFile]) -> std::io::Result<()> {
    for f in files {
        let path = dir.join(&f.path);
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent)?;
        }
        std::fs::write(path, &f.contents)?;
    }
    Ok(())
}
