//! # pipes-macros
//!
//! The procedural macros behind `pipes_core::function` and
//! `pipes_core::class`. Use them through `pipes-core`, which re-exports
//! them: the generated code names `::pipes_core` paths only, so firmware
//! depends on `pipes-core` alone.
//!
//! - [`macro@function`] on a plain `fn` keeps it callable and adds a
//!   zero-sized implementation of `pipes_core::function::Implementation`
//!   with a static signature built from the Rust names and types.
//! - [`macro@class`] on an inherent `impl` block implements
//!   `pipes_core::class::PipesClass`: a constructor signature, one
//!   signature per exported member and an optional per-loop hook.
//! - [`derive@PipesArgs`] on a struct with named fields implements
//!   `pipes_core::export::PipesArgs`: the fields, in order, as a list of
//!   arguments (names and types) and their values.
//!
//! Every type in a signature goes through `pipes_core::export::PipesType`,
//! so a type with no PIPES encoding fails to compile with the message
//! "`T` has no PIPES encoding".
#![forbid(unsafe_code)]
#![deny(missing_docs)]

use proc_macro::TokenStream;
use proc_macro2::{Span, TokenStream as TokenStream2};
use quote::{format_ident, quote, quote_spanned};
use syn::parse::Parser;
use syn::spanned::Spanned;
use syn::{
    Attribute, Data, DeriveInput, Error, Expr, Fields, FnArg, Ident, ImplItem, ImplItemFn, ItemFn,
    ItemImpl, Lit, LitStr, Meta, Pat, ReturnType, Signature as FnSig, Type,
};

/// The most inputs, and the most outputs, of a PIPES function
/// (`pipes_core::signature::MAX_ARGS`).
const MAX_ARGS: usize = 8;

/// The longest documentation of a PIPES function, bytes
/// (`pipes_core::docs::MAX_DOCS`).
const MAX_DOCS: usize = 2048;

/// The text of the `///` doc comment in `attrs`, as rustdoc shows it: the
/// lines of every `#[doc = ".."]` joined by `\n`, their common leading
/// whitespace removed, trailing whitespace and blank lines at either end
/// dropped. Doc attributes that are not string literals are skipped.
/// Refused when longer than [`MAX_DOCS`]: the text travels with the
/// signature.
fn doc_text_of(attrs: &[Attribute]) -> syn::Result<String> {
    let mut lines: Vec<String> = Vec::new();
    let mut first: Option<Span> = None;
    for a in attrs.iter().filter(|a| a.path().is_ident("doc")) {
        let Meta::NameValue(nv) = &a.meta else {
            continue;
        };
        let Expr::Lit(syn::ExprLit {
            lit: Lit::Str(s), ..
        }) = &nv.value
        else {
            continue;
        };
        first.get_or_insert(a.span());
        lines.extend(s.value().split('\n').map(|l| l.trim_end().to_string()));
    }
    let indent = lines
        .iter()
        .filter(|l| !l.is_empty())
        .map(|l| l.len() - l.trim_start().len())
        .min()
        .unwrap_or(0);
    let lines: Vec<&str> = lines
        .iter()
        .map(|l| l.get(indent..).unwrap_or(""))
        .collect();
    let text = lines.join("\n").trim_matches('\n').to_string();
    if text.len() > MAX_DOCS {
        return Err(Error::new(
            first.unwrap_or_else(Span::call_site),
            format!(
                "this doc comment is {} bytes; a PIPES function's travels with its signature \
                 and may be at most {MAX_DOCS}: shorten it (move the details to the module docs)",
                text.len()
            ),
        ));
    }
    Ok(text)
}

/// Turns a plain function into a PIPES function.
///
/// ```ignore
/// #[pipes_core::function(outputs = "time, in_bounds")]
/// fn get_comparator_reading(lower: f32, upper: f32) -> (u64, bool) { .. }
///
/// // The function stays callable as is; its PIPES form is
/// let f = PipesFunction::<_, 2, 2, 64>::new(get_comparator_reading::pipes())?;
/// ```
///
/// Next to the function (same name, type namespace) it defines a braced
/// zero-sized struct with:
/// - `SIGNATURE: &'static Signature`: the function's name, its argument names
///   and types, and the output names of `outputs = ".."` with the types of
///   the returned tuple (or single value; `()` or nothing means no outputs);
/// - `pipes()`: the value to hand to `PipesFunction::new`;
/// - an `Implementation` that decodes the inputs, calls the function and sets
///   every output, and whose `docs()` is the function's `///` doc comment
///   (sent with the signature when a host asks: `pipes_core::docs`; at most
///   2048 bytes, in flash).
///
/// A function that can fail returns `Result<T, E>` with `E:
/// Into<CallError>` (e.g. `CallError` itself, or a type with a `From` impl
/// that picks a failure code): `Ok(T)` sets the outputs as `T` would, `Err`
/// is reported to the caller (`CallError::Failed(code)` as its code).
///
/// Options: `outputs = "a, b"` (required when the function returns
/// something; one name per returned value), `name = ".."` (the signature
/// name; default the Rust name).
///
/// Errors at compile time: a type with no PIPES encoding, a count of output
/// names that differs from the returned values, more than 8 inputs or
/// outputs, generic, async or method functions, and pattern arguments.
#[proc_macro_attribute]
pub fn function(attr: TokenStream, item: TokenStream) -> TokenStream {
    let item2: TokenStream2 = item.clone().into();
    match function_impl(attr.into(), item.into()) {
        Ok(t) => t.into(),
        Err(e) => {
            let e = e.to_compile_error();
            quote!(#e #item2).into()
        }
    }
}

/// Turns an inherent `impl` block into a PIPES class.
///
/// ```ignore
/// #[pipes_core::class]
/// impl Comparator {
///     #[constructor]
///     fn new(lower: f32, upper: f32) -> Self { .. }
///     fn setup(&mut self, lower: f32, upper: f32) { .. }
///     #[outputs = "time, in_bounds"]
///     fn reading(&mut self) -> (u64, bool) { .. }
///     fn _private(&self) { .. }            // leading underscore: not exported
///     #[loop_hook]
///     fn tick(&mut self, now: SystemInstant) { .. } // called from the class port's poll
/// }
/// ```
///
/// The block is kept as written (minus the helper attributes) and
/// `pipes_core::class::PipesClass` is implemented for the type:
/// - exactly one `#[constructor]` associated function returning `Self`, or
///   `Result<Self, E>` (`E: Into<CallError>`) when arguments can be
///   refused: the class's constructor signature (named after the type);
/// - every method taking `&self` or `&mut self` whose name does not start
///   with `_` is an exported member, signature `"Type.method"`, with output
///   names from `#[outputs = ".."]` and `Result` returns as for
///   [`macro@function`];
/// - the `///` doc comments of the constructor and of each member are
///   their documentation (`CONSTRUCTOR_DOCS`, `MEMBER_DOCS`; see
///   [`macro@function`]);
/// - at most one `#[loop_hook]` method
///   `fn(&mut self, now: pipes_core::time::SystemInstant)`, given the
///   runtime's synchronized system time.
///
/// Options: `name = ".."` (the class name; default the type's name).
#[proc_macro_attribute]
pub fn class(attr: TokenStream, item: TokenStream) -> TokenStream {
    let item2: TokenStream2 = item.clone().into();
    match class_impl(attr.into(), item.into()) {
        Ok(t) => t.into(),
        Err(e) => {
            let e = e.to_compile_error();
            // Keep the block (without the helper attributes, which mean
            // nothing to the compiler) so only the real error is reported.
            let item = match syn::parse2::<ItemImpl>(item2.clone()) {
                Ok(mut imp) => {
                    strip_helpers(&mut imp);
                    quote!(#imp)
                }
                Err(_) => item2,
            };
            quote!(#e #item).into()
        }
    }
}

/// The text of the doc attributes given, as one string literal: the
/// documentation a PIPES function publishes, read exactly as
/// [`macro@function`] reads a doc comment (lines joined by `\n`, common
/// indentation removed; at most 2048 bytes).
///
/// For tables of functions written by `macro_rules!` (osap-module's
/// `module_function_table!`), whose `///` lines arrive as `#[doc = ".."]`
/// attributes:
///
/// ```ignore
/// const DOCS: &str = pipes_core::doc_text!(
///     /// Queues a control point:
///     ///   at `time`.
/// );
/// assert_eq!(DOCS, "Queues a control point:\n  at `time`.");
/// ```
#[proc_macro]
pub fn doc_text(item: TokenStream) -> TokenStream {
    let parsed =
        Parser::parse2(Attribute::parse_outer, item.into()).and_then(|attrs| doc_text_of(&attrs));
    match parsed {
        Ok(text) => quote!(#text).into(),
        Err(e) => e.to_compile_error().into(),
    }
}

/// Implements `pipes_core::export::PipesArgs` for a struct with named
/// fields: its fields, in order, are a PIPES function's arguments.
///
/// ```ignore
/// #[derive(pipes_core::PipesArgs)]
/// struct Status { mode: u8, queued: u16, enabled: bool, faults: u32 }
///
/// // Status::ARGS: mode: u8, queued: u16, enabled: bool, faults: u32
/// let s = Status::from_values(&values)?;
/// ```
///
/// Each field's name (without `r#`) is the argument's name and its type
/// goes through `pipes_core::export::PipesType`. Errors at compile time: a
/// tuple or unit struct, an enum or union, generics (a `&str` field needs
/// one: use owned scalars), more than 8 fields, and a field type with no
/// PIPES encoding.
#[proc_macro_derive(PipesArgs)]
pub fn pipes_args(item: TokenStream) -> TokenStream {
    match pipes_args_impl(item.into()) {
        Ok(t) => t.into(),
        Err(e) => e.to_compile_error().into(),
    }
}

fn pipes_args_impl(item: TokenStream2) -> syn::Result<TokenStream2> {
    let input: DeriveInput = syn::parse2(item)?;
    let ident = &input.ident;
    if !input.generics.params.is_empty() || input.generics.where_clause.is_some() {
        return Err(Error::new(
            input.generics.span(),
            "PIPES argument lists cannot be generic: their signature is fixed at compile time",
        ));
    }
    let Data::Struct(data) = &input.data else {
        return Err(Error::new(
            ident.span(),
            "`PipesArgs` is derived for a struct with named fields: one per argument",
        ));
    };
    let fields: Vec<&syn::Field> = match &data.fields {
        Fields::Named(n) => n.named.iter().collect(),
        Fields::Unit => Vec::new(),
        Fields::Unnamed(u) => {
            return Err(Error::new(
                u.span(),
                "`PipesArgs` needs named fields: each field's name is its argument's name",
            ))
        }
    };
    if fields.len() > MAX_ARGS {
        return Err(Error::new(
            ident.span(),
            format!(
                "a PIPES function has at most {MAX_ARGS} inputs or outputs, `{ident}` has {} fields",
                fields.len()
            ),
        ));
    }
    let mut names = Vec::new();
    let mut idents = Vec::new();
    let mut types = Vec::new();
    for f in &fields {
        let Some(fi) = &f.ident else {
            return Err(Error::new(f.span(), "expected a named field"));
        };
        let s = fi.to_string();
        let name = s.strip_prefix("r#").map(str::to_string).unwrap_or(s);
        check_name(&name, fi.span())?;
        names.push(name);
        idents.push(fi.clone());
        types.push(f.ty.clone());
    }
    let args = names.iter().zip(&types).map(|(n, t)| {
        quote_spanned!(t.span()=> ::pipes_core::signature::Arg::new(#n, <#t as ::pipes_core::export::PipesType>::TYPE))
    });
    let values = format_ident!("__pipes_values");
    let decode = idents.iter().zip(&types).enumerate().map(|(i, (fi, t))| {
        quote_spanned!(t.span()=> #fi: ::pipes_core::export::input::<#t>(#values, #i)?)
    });
    let index = format_ident!("__pipes_index");
    let arms = idents.iter().enumerate().map(|(i, fi)| {
        quote!(#i => ::core::option::Option::Some(::pipes_core::export::PipesType::to_value(&self.#fi)),)
    });
    let construct = if matches!(data.fields, Fields::Unit) {
        quote!(#ident)
    } else {
        quote!(#ident { #(#decode),* })
    };
    Ok(quote! {
        impl ::pipes_core::export::PipesArgs for #ident {
            const ARGS: &'static [::pipes_core::signature::Arg] = &[#(#args),*];

            #[allow(unused_variables)]
            fn from_values(
                #values: &[::pipes_core::Value<'_>],
            ) -> ::core::result::Result<Self, ::pipes_core::function::CallError> {
                ::core::result::Result::Ok(#construct)
            }

            fn value(&self, #index: usize) -> ::core::option::Option<::pipes_core::Value<'_>> {
                match #index {
                    #(#arms)*
                    _ => ::core::option::Option::None,
                }
            }
        }
    })
}

/// Removes `#[constructor]`, `#[loop_hook]` and `#[outputs]` from the block.
fn strip_helpers(imp: &mut ItemImpl) {
    for it in imp.items.iter_mut() {
        if let ImplItem::Fn(f) = it {
            f.attrs.retain(|a| {
                !["constructor", "loop_hook", "outputs"]
                    .iter()
                    .any(|n| a.path().is_ident(n))
            });
        }
    }
}

/// The options of `#[function(..)]` and `#[class(..)]`.
#[derive(Default)]
struct Options {
    outputs: Option<LitStr>,
    name: Option<LitStr>,
}

fn parse_options(attr: TokenStream2, allow_outputs: bool) -> syn::Result<Options> {
    let mut o = Options::default();
    let parser = syn::meta::parser(|meta| {
        if allow_outputs && meta.path.is_ident("outputs") {
            o.outputs = Some(meta.value()?.parse()?);
            Ok(())
        } else if meta.path.is_ident("name") {
            o.name = Some(meta.value()?.parse()?);
            Ok(())
        } else if allow_outputs {
            Err(meta.error("expected `outputs = \"a, b\"` or `name = \"..\"`"))
        } else {
            Err(meta.error("expected `name = \"..\"`"))
        }
    });
    parser.parse2(attr)?;
    Ok(o)
}

/// One input: its name and type.
struct Input {
    name: String,
    ty: Type,
}

/// The returned values: their types, whether the Rust type is a tuple, and
/// whether they come wrapped in a `Result` (the function can fail).
struct Returned {
    types: Vec<Type>,
    tuple: bool,
    fallible: bool,
    span: Span,
}

/// `T` of a `Result<T, E>` (by its last path segment), if `ty` is one.
fn result_ok_type(ty: &Type) -> Option<&Type> {
    let Type::Path(p) = ty else { return None };
    let last = p.path.segments.last()?;
    if last.ident != "Result" {
        return None;
    }
    let syn::PathArguments::AngleBracketed(args) = &last.arguments else {
        return None;
    };
    args.args.iter().find_map(|a| match a {
        syn::GenericArgument::Type(t) => Some(t),
        _ => None,
    })
}

fn returned(ret: &ReturnType) -> Returned {
    match ret {
        ReturnType::Default => Returned {
            types: Vec::new(),
            tuple: true,
            fallible: false,
            span: Span::call_site(),
        },
        ReturnType::Type(_, ty) => {
            let mut t: &Type = ty;
            while let Type::Paren(p) = t {
                t = &p.elem;
            }
            let fallible = result_ok_type(t).is_some();
            if let Some(ok) = result_ok_type(t) {
                t = ok;
                while let Type::Paren(p) = t {
                    t = &p.elem;
                }
            }
            match t {
                Type::Tuple(tup) => Returned {
                    types: tup.elems.iter().cloned().collect(),
                    tuple: true,
                    fallible,
                    span: ty.span(),
                },
                other => Returned {
                    types: vec![other.clone()],
                    tuple: false,
                    fallible,
                    span: ty.span(),
                },
            }
        }
    }
}

/// The call `call`, with a `Result`'s error turned into the `CallError` the
/// function reports (`E: Into<CallError>`) and returned early.
fn unwrap_call(ret: &Returned, call: TokenStream2) -> TokenStream2 {
    if ret.fallible {
        quote_spanned!(ret.span=> (#call).map_err(
            ::core::convert::Into::<::pipes_core::function::CallError>::into
        )?)
    } else {
        call
    }
}

/// Checks a PIPES name: non-empty and at most 255 bytes.
fn check_name(name: &str, span: Span) -> syn::Result<()> {
    if name.is_empty() {
        return Err(Error::new(span, "a PIPES name must not be empty"));
    }
    if name.len() > 255 {
        return Err(Error::new(
            span,
            "a PIPES name must be at most 255 bytes long",
        ));
    }
    Ok(())
}

/// The output names of `outputs = ".."`, checked against the returned values.
fn output_names(outputs: Option<&LitStr>, ret: &Returned, what: &str) -> syn::Result<Vec<String>> {
    let n = ret.types.len();
    let Some(lit) = outputs else {
        if n == 0 {
            return Ok(Vec::new());
        }
        let example = (0..n)
            .map(|i| format!("out{i}"))
            .collect::<Vec<_>>()
            .join(", ");
        return Err(Error::new(
            ret.span,
            format!(
                "{what} returns {n} value{s}: name {them} with `outputs = \"{example}\"`",
                s = if n == 1 { "" } else { "s" },
                them = if n == 1 { "it" } else { "them" },
            ),
        ));
    };
    let text = lit.value();
    let names: Vec<String> = if text.trim().is_empty() {
        Vec::new()
    } else {
        text.split(',').map(|s| s.trim().to_string()).collect()
    };
    if names.len() != n {
        let values = if n == 1 {
            "1 value".to_string()
        } else {
            format!("{n} values")
        };
        return Err(Error::new(
            lit.span(),
            format!(
                "`outputs` names {} output{} but {what} returns {values}: give one name per returned value",
                names.len(),
                if names.len() == 1 { "" } else { "s" },
            ),
        ));
    }
    if n > MAX_ARGS {
        return Err(Error::new(
            ret.span,
            format!("a PIPES function has at most {MAX_ARGS} outputs, {what} returns {n}"),
        ));
    }
    for (i, name) in names.iter().enumerate() {
        check_name(name, lit.span())?;
        if names[..i].contains(name) {
            return Err(Error::new(
                lit.span(),
                format!("output `{name}` is named twice"),
            ));
        }
    }
    Ok(names)
}

/// The typed inputs of a function, skipping a `self` receiver.
fn inputs(sig: &FnSig) -> syn::Result<Vec<Input>> {
    let mut out = Vec::new();
    for arg in &sig.inputs {
        let FnArg::Typed(pt) = arg else { continue };
        let name = match &*pt.pat {
            Pat::Ident(p) if p.by_ref.is_none() && p.subpat.is_none() => {
                let s = p.ident.to_string();
                s.strip_prefix("r#").map(str::to_string).unwrap_or(s)
            }
            other => return Err(Error::new(
                other.span(),
                "PIPES arguments must be plain names (`x: f32`): the name goes into the signature",
            )),
        };
        out.push(Input {
            name,
            ty: (*pt.ty).clone(),
        });
    }
    if out.len() > MAX_ARGS {
        return Err(Error::new(
            sig.inputs.span(),
            format!(
                "a PIPES function has at most {MAX_ARGS} inputs, `{}` takes {}",
                sig.ident,
                out.len()
            ),
        ));
    }
    Ok(out)
}

fn check_plain(sig: &FnSig) -> syn::Result<()> {
    if !sig.generics.params.is_empty() || sig.generics.where_clause.is_some() {
        return Err(Error::new(
            sig.generics.span(),
            "PIPES functions cannot be generic: the signature is fixed at compile time",
        ));
    }
    if let Some(a) = &sig.asyncness {
        return Err(Error::new(a.span(), "PIPES functions cannot be async"));
    }
    if let Some(v) = &sig.variadic {
        return Err(Error::new(v.span(), "PIPES functions cannot be variadic"));
    }
    Ok(())
}

/// `static SIG: Signature = ..; &SIG` as a block expression.
fn signature_expr(
    name: &str,
    inputs: &[Input],
    outputs: &[String],
    ret: &Returned,
) -> TokenStream2 {
    let ins = inputs.iter().map(|i| {
        let (n, t) = (&i.name, &i.ty);
        quote_spanned!(t.span()=> ::pipes_core::signature::Arg::new(#n, <#t as ::pipes_core::export::PipesType>::TYPE))
    });
    let outs = outputs.iter().zip(&ret.types).map(|(n, t)| {
        quote_spanned!(t.span()=> ::pipes_core::signature::Arg::new(#n, <#t as ::pipes_core::export::PipesType>::TYPE))
    });
    quote! {{
        static SIGNATURE: ::pipes_core::signature::Signature = ::pipes_core::signature::Signature {
            name: #name,
            inputs: &[#(#ins),*],
            outputs: &[#(#outs),*],
        };
        &SIGNATURE
    }}
}

/// The decoded inputs as call arguments.
fn decode_args(inputs: &[Input], values: &Ident) -> Vec<TokenStream2> {
    inputs
        .iter()
        .enumerate()
        .map(|(i, inp)| {
            let t = &inp.ty;
            quote_spanned!(t.span()=> ::pipes_core::export::input::<#t>(#values, #i)?)
        })
        .collect()
}

/// Writes `ret` (the returned value) to `outputs`.
fn write_outputs(ret: &Returned, value: &Ident, outputs: &Ident) -> TokenStream2 {
    if ret.tuple {
        quote_spanned!(ret.span=> ::pipes_core::export::PipesOutputs::write(&#value, #outputs))
    } else {
        quote_spanned!(ret.span=> ::pipes_core::export::PipesOutputs::write(&(#value,), #outputs))
    }
}

fn function_impl(attr: TokenStream2, item: TokenStream2) -> syn::Result<TokenStream2> {
    let opts = parse_options(attr, true)?;
    let f: ItemFn = syn::parse2(item)?;
    let sig = &f.sig;
    check_plain(sig)?;
    if let Some(r) = sig.receiver() {
        return Err(Error::new(
            r.span(),
            "`#[pipes_core::function]` is for free functions; put methods in a `#[pipes_core::class]` impl block",
        ));
    }
    let ident = &sig.ident;
    let name = match &opts.name {
        Some(n) => {
            check_name(&n.value(), n.span())?;
            n.value()
        }
        None => ident.to_string(),
    };
    let ins = inputs(sig)?;
    let ret = returned(&sig.output);
    let outs = output_names(opts.outputs.as_ref(), &ret, &format!("`{ident}`"))?;
    let sig_expr = signature_expr(&name, &ins, &outs, &ret);
    let values = format_ident!("__pipes_inputs");
    let outputs = format_ident!("__pipes_outputs");
    let value = format_ident!("__pipes_returned");
    let args = decode_args(&ins, &values);
    let write = write_outputs(&ret, &value, &outputs);
    let call = unwrap_call(&ret, quote!(#ident(#(#args),*)));
    let docs = doc_text_of(&f.attrs)?;
    let docs_fn = (!docs.is_empty()).then(|| {
        quote! {
            fn docs(&self) -> &'static str {
                #docs
            }
        }
    });
    let vis = &f.vis;
    let doc = format!(
        "The PIPES function of [`{ident}()`]: hand [`{ident}::pipes()`] to \
         `pipes_core::function::PipesFunction::new`."
    );
    Ok(quote! {
        #f

        #[doc = #doc]
        #[allow(non_camel_case_types)]
        #[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
        #vis struct #ident {}

        impl #ident {
            /// The signature: the function's name, argument names and types,
            /// and its output names and types.
            pub const SIGNATURE: &'static ::pipes_core::signature::Signature = #sig_expr;

            /// The implementation to wrap in a `PipesFunction`.
            pub const fn pipes() -> Self {
                #ident {}
            }
        }

        impl ::pipes_core::function::Implementation for #ident {
            fn signature(&self) -> &'static ::pipes_core::signature::Signature {
                Self::SIGNATURE
            }

            fn call(
                &mut self,
                #values: &[::pipes_core::Value<'_>],
                #outputs: &mut ::pipes_core::function::Outputs<'_>,
            ) -> ::core::result::Result<(), ::pipes_core::function::CallError> {
                #[allow(clippy::let_unit_value, clippy::unit_arg, clippy::useless_conversion)]
                let #value = #call;
                #write
            }

            #docs_fn
        }
    })
}

/// Removes the attribute named `name` from `attrs` and returns it.
fn take_attr(attrs: &mut Vec<Attribute>, name: &str) -> Option<Attribute> {
    let i = attrs.iter().position(|a| a.path().is_ident(name))?;
    Some(attrs.remove(i))
}

/// Reads `#[outputs = "a, b"]` (or `#[outputs("a, b")]`).
fn outputs_attr(a: &Attribute) -> syn::Result<LitStr> {
    match &a.meta {
        Meta::NameValue(nv) => match &nv.value {
            Expr::Lit(l) => match &l.lit {
                Lit::Str(s) => Ok(s.clone()),
                other => Err(Error::new(other.span(), "expected `#[outputs = \"a, b\"]`")),
            },
            other => Err(Error::new(other.span(), "expected `#[outputs = \"a, b\"]`")),
        },
        Meta::List(l) => l.parse_args::<LitStr>(),
        Meta::Path(p) => Err(Error::new(p.span(), "expected `#[outputs = \"a, b\"]`")),
    }
}

fn expect_bare(a: &Attribute, what: &str) -> syn::Result<()> {
    match &a.meta {
        Meta::Path(_) => Ok(()),
        other => Err(Error::new(
            other.span(),
            format!("`#[{what}]` takes no arguments"),
        )),
    }
}

struct MemberFn {
    ident: Ident,
    name: String,
    docs: String,
    inputs: Vec<Input>,
    ret: Returned,
    outputs: Vec<String>,
}

fn class_impl(attr: TokenStream2, item: TokenStream2) -> syn::Result<TokenStream2> {
    let opts = parse_options(attr, false)?;
    let mut imp: ItemImpl = syn::parse2(item)?;
    if let Some((_, path, _)) = &imp.trait_ {
        return Err(Error::new(
            path.span(),
            "`#[pipes_core::class]` goes on an inherent impl block (`impl Type { .. }`), not a trait impl",
        ));
    }
    if !imp.generics.params.is_empty() || imp.generics.where_clause.is_some() {
        return Err(Error::new(
            imp.generics.span(),
            "PIPES classes cannot be generic: their signatures are fixed at compile time",
        ));
    }
    let self_ty = imp.self_ty.clone();
    let class_name = match (&opts.name, &*self_ty) {
        (Some(n), _) => {
            check_name(&n.value(), n.span())?;
            n.value()
        }
        (None, Type::Path(p)) => match p.path.segments.last() {
            Some(s) => s.ident.to_string(),
            None => return Err(Error::new(p.span(), "expected a type name")),
        },
        (None, other) => return Err(Error::new(
            other.span(),
            "a PIPES class is a named type; or name it with `#[pipes_core::class(name = \"..\")]`",
        )),
    };

    let mut constructor: Option<(Ident, Vec<Input>, Span)> = None;
    let mut ctor_docs = String::new();
    let mut ctor_fallible = false;
    let mut hook: Option<Ident> = None;
    let mut members: Vec<MemberFn> = Vec::new();
    for it in imp.items.iter_mut() {
        let ImplItem::Fn(f) = it else { continue };
        let is_ctor = take_attr(&mut f.attrs, "constructor");
        let is_hook = take_attr(&mut f.attrs, "loop_hook");
        let outputs = take_attr(&mut f.attrs, "outputs");
        let ImplItemFn { sig, .. } = &*f;
        let fname = sig.ident.to_string();
        if let Some(a) = is_ctor {
            expect_bare(&a, "constructor")?;
            check_plain(sig)?;
            if let Some(r) = sig.receiver() {
                return Err(Error::new(
                    r.span(),
                    "the `#[constructor]` is an associated function returning `Self`, without `self`",
                ));
            }
            if let Some(o) = &outputs {
                return Err(Error::new(
                    o.span(),
                    "a `#[constructor]` has no outputs: it returns the new state",
                ));
            }
            if let Some((_, _, span)) = &constructor {
                let mut e = Error::new(sig.ident.span(), "a PIPES class has one `#[constructor]`");
                e.combine(Error::new(*span, "the other `#[constructor]`"));
                return Err(e);
            }
            constructor = Some((sig.ident.clone(), inputs(sig)?, sig.ident.span()));
            ctor_docs = doc_text_of(&f.attrs)?;
            ctor_fallible = returned(&sig.output).fallible;
            continue;
        }
        if let Some(a) = is_hook {
            expect_bare(&a, "loop_hook")?;
            if hook.is_some() {
                return Err(Error::new(
                    sig.ident.span(),
                    "a PIPES class has at most one `#[loop_hook]`",
                ));
            }
            hook = Some(sig.ident.clone());
            continue;
        }
        let Some(receiver) = sig.receiver() else {
            if let Some(o) = &outputs {
                return Err(Error::new(
                    o.span(),
                    "`#[outputs]` is for exported members, which take `&self` or `&mut self`",
                ));
            }
            continue;
        };
        if fname.starts_with('_') {
            continue;
        }
        if receiver.reference.is_none() {
            return Err(Error::new(
                receiver.span(),
                format!(
                    "exported PIPES member `{fname}` must take `&self` or `&mut self` \
                     (start its name with `_` to keep it private)"
                ),
            ));
        }
        check_plain(sig)?;
        let ins = inputs(sig)?;
        let ret = returned(&sig.output);
        let out_lit = outputs.as_ref().map(outputs_attr).transpose()?;
        let outs = output_names(out_lit.as_ref(), &ret, &format!("`{fname}`"))?;
        let name = format!(
            "{class_name}.{}",
            fname.strip_prefix("r#").unwrap_or(&fname)
        );
        check_name(&name, sig.ident.span())?;
        members.push(MemberFn {
            ident: sig.ident.clone(),
            name,
            docs: doc_text_of(&f.attrs)?,
            inputs: ins,
            ret,
            outputs: outs,
        });
    }

    let Some((ctor_ident, ctor_inputs, _)) = constructor else {
        return Err(Error::new(
            imp.self_ty.span(),
            "a PIPES class needs a `#[constructor]`: an associated function returning `Self`",
        ));
    };
    let no_ret = Returned {
        types: Vec::new(),
        tuple: true,
        fallible: false,
        span: Span::call_site(),
    };
    let ctor_sig = signature_expr(&class_name, &ctor_inputs, &[], &no_ret);
    let values = format_ident!("__pipes_inputs");
    let outputs = format_ident!("__pipes_outputs");
    let value = format_ident!("__pipes_returned");
    let ctor_args = decode_args(&ctor_inputs, &values);
    let member_docs = members.iter().map(|m| &m.docs);
    let member_sigs = members
        .iter()
        .map(|m| signature_expr(&m.name, &m.inputs, &m.outputs, &m.ret));
    let arms = members.iter().enumerate().map(|(i, m)| {
        let ident = &m.ident;
        let args = decode_args(&m.inputs, &values);
        let write = write_outputs(&m.ret, &value, &outputs);
        let call = unwrap_call(&m.ret, quote!(self.#ident(#(#args),*)));
        quote! {
            #i => {
                #[allow(clippy::let_unit_value, clippy::unit_arg, clippy::useless_conversion)]
                let #value = #call;
                #write
            }
        }
    });
    let construct = if ctor_fallible {
        quote!(<#self_ty>::#ctor_ident(#(#ctor_args),*).map_err(
            ::core::convert::Into::<::pipes_core::function::CallError>::into
        ))
    } else {
        quote!(::core::result::Result::Ok(<#self_ty>::#ctor_ident(#(#ctor_args),*)))
    };
    let hook_fn = hook.map(|h| {
        quote! {
            fn loop_hook(&mut self, now: ::pipes_core::time::SystemInstant) {
                self.#h(now)
            }
        }
    });

    Ok(quote! {
        #imp

        impl ::pipes_core::class::PipesClass for #self_ty {
            const NAME: &'static str = #class_name;
            const CONSTRUCTOR: &'static ::pipes_core::signature::Signature = #ctor_sig;
            const MEMBERS: &'static [&'static ::pipes_core::signature::Signature] =
                &[#(#member_sigs),*];
            const CONSTRUCTOR_DOCS: &'static str = #ctor_docs;
            const MEMBER_DOCS: &'static [&'static str] = &[#(#member_docs),*];

            #[allow(clippy::useless_conversion)]
            fn construct(
                #values: &[::pipes_core::Value<'_>],
            ) -> ::core::result::Result<Self, ::pipes_core::function::CallError> {
                #construct
            }

            #[allow(unused_variables)]
            fn call_member(
                &mut self,
                index: usize,
                #values: &[::pipes_core::Value<'_>],
                #outputs: &mut ::pipes_core::function::Outputs<'_>,
            ) -> ::core::result::Result<(), ::pipes_core::function::CallError> {
                match index {
                    #(#arms)*
                    _ => ::core::result::Result::Err(::pipes_core::function::CallError::Failed(
                        ::pipes_core::control::FailureCode::NoSuchMember,
                    )),
                }
            }

            #hook_fn
        }
    })
}
