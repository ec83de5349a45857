//! The kinds of module a machine knows, by the function set each presents,
//! and the check that a runtime is one of them.
//!
//! A module's firmware presents its functions in a fixed order (a scan
//! lists them by port). A runtime is a module of a kind when its first
//! functions are exactly the kind's: each function's name, inputs and
//! outputs, with their types, in port order (what the kind's function-set
//! id, `osap_module::functions::function_set_id`, identifies). Functions
//! after them (block instances made at run time) are not the kind's and
//! are ignored.

use osap_host::som::model::{SomArg, SomFunction, SomRuntime};
use osap_module::functions::{function_set_id, FunctionSetHasher};
use pipes_core::signature::{Arg, Signature};

/// A kind of module: the function set its firmware presents.
#[derive(Debug, Clone, Copy)]
pub struct ModuleKind {
    /// What the module is, for messages: `stepper`.
    pub name: &'static str,
    /// Its functions, in port order.
    pub signatures: &'static [&'static Signature],
}

impl ModuleKind {
    /// The kind's function-set id, as its firmware embeds it.
    pub fn id(&self) -> u32 {
        function_set_id(self.signatures)
    }
}

/// Every kind of module the machine knows. A new kind (a heater or a load
/// cell board) is one more entry here.
pub const KNOWN_KINDS: &[ModuleKind] = &[ModuleKind {
    name: "stepper",
    signatures: &osap_module::functions::SIGNATURES,
}];

/// Why a runtime is not a module of any known kind: measured against the
/// kind it comes closest to.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Mismatch {
    /// The kind it comes closest to.
    pub kind: &'static str,
    /// That kind's function-set id.
    pub expected_id: u32,
    /// That kind's function count.
    pub expected_count: usize,
    /// The function-set id of what the runtime presents (`None`: a type
    /// this build does not know).
    pub found_id: Option<u32>,
    /// How many functions the runtime presents.
    pub found_count: usize,
    /// The kind's functions the runtime does not have.
    pub missing: Vec<String>,
    /// Functions it has by name but with other inputs or outputs: what it
    /// has, then what the kind has.
    pub different: Vec<(String, String)>,
    /// The kind's functions it has, but not at the kind's place in port
    /// order.
    pub out_of_order: Vec<String>,
}

impl std::fmt::Display for Mismatch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "expected the {} function set (id {:#010x}, {} functions in port order), found ",
            self.kind, self.expected_id, self.expected_count
        )?;
        match (self.found_count, self.found_id) {
            (0, _) => write!(f, "no functions (a host or a hub, not a module)")?,
            (n, Some(id)) => write!(f, "{n} functions (id {id:#010x})")?,
            (n, None) => write!(f, "{n} functions (with a type this osap does not know)")?,
        }
        if !self.missing.is_empty() {
            write!(f, "; missing: {}", self.missing.join(", "))?;
        }
        for (found, expected) in &self.different {
            write!(f, "; {found} where the set has {expected}")?;
        }
        if !self.out_of_order.is_empty() {
            write!(f, "; out of order: {}", self.out_of_order.join(", "))?;
        }
        write!(
            f,
            ". Flash the module with this osap's firmware (`osap flash`), or name the right module in [modules]"
        )
    }
}

/// The kind of module `rt` is, or why it is none of [`KNOWN_KINDS`].
pub fn kind_of(rt: &SomRuntime) -> Result<&'static ModuleKind, Box<Mismatch>> {
    if let Some(kind) = KNOWN_KINDS.iter().find(|k| presents(rt, k)) {
        return Ok(kind);
    }
    // Measured against the kind it shares the most functions with.
    let closest = KNOWN_KINDS
        .iter()
        .max_by_key(|k| {
            k.signatures
                .iter()
                .filter(|s| rt.functions.iter().any(|f| f.name == s.name))
                .count()
        })
        .unwrap_or(&KNOWN_KINDS[0]);
    Err(Box::new(mismatch(rt, closest)))
}

/// Whether `rt`'s first functions are exactly `kind`'s.
fn presents(rt: &SomRuntime, kind: &ModuleKind) -> bool {
    rt.functions.len() >= kind.signatures.len()
        && rt
            .functions
            .iter()
            .zip(kind.signatures)
            .all(|(f, s)| same(f, s))
}

fn same(f: &SomFunction, s: &Signature) -> bool {
    f.name == s.name && same_args(&f.inputs, s.inputs) && same_args(&f.outputs, s.outputs)
}

fn same_args(found: &[SomArg], wanted: &[Arg]) -> bool {
    found.len() == wanted.len()
        && found
            .iter()
            .zip(wanted)
            .all(|(f, w)| f.name == w.name && f.type_name == w.ty.name())
}

fn mismatch(rt: &SomRuntime, kind: &ModuleKind) -> Mismatch {
    let mut missing = Vec::new();
    let mut different = Vec::new();
    let mut out_of_order = Vec::new();
    for (i, s) in kind.signatures.iter().enumerate() {
        match rt.functions.iter().position(|f| f.name == s.name) {
            None => missing.push(s.name.to_string()),
            Some(at) if !same(&rt.functions[at], s) => different.push((
                shown(
                    &rt.functions[at].name,
                    &rt.functions[at].inputs,
                    &rt.functions[at].outputs,
                ),
                shown_signature(s),
            )),
            Some(at) if at != i => out_of_order.push(s.name.to_string()),
            Some(_) => {}
        }
    }
    Mismatch {
        kind: kind.name,
        expected_id: kind.id(),
        expected_count: kind.signatures.len(),
        found_id: found_id(&rt.built_functions().collect::<Vec<_>>()),
        found_count: rt.built_functions().count(),
        missing,
        different,
        out_of_order,
    }
}

/// The function-set id of the functions `rt` was built with (not the
/// blocks made on it at run time); `None` if a type is unknown.
pub fn function_set_id_of(rt: &SomRuntime) -> Option<u32> {
    found_id(&rt.built_functions().collect::<Vec<_>>())
}

/// The function-set id of `functions` (`None` if a type is unknown).
fn found_id(functions: &[&SomFunction]) -> Option<u32> {
    fn keys(list: &[SomArg]) -> Option<Vec<(&str, u8)>> {
        list.iter()
            .map(|a| a.ty().map(|ty| (a.name.as_str(), ty.key())))
            .collect()
    }
    let mut id = FunctionSetHasher::new(functions.len());
    for f in functions {
        let (inputs, outputs) = (keys(&f.inputs)?, keys(&f.outputs)?);
        id.function(&f.name, inputs.into_iter(), outputs.into_iter());
    }
    Some(id.finish())
}

/// `name(a: u8, b: f32) -> (t: u64)`.
fn shown(name: &str, inputs: &[SomArg], outputs: &[SomArg]) -> String {
    let list = |a: &[SomArg]| {
        a.iter()
            .map(|a| format!("{}: {}", a.name, a.type_name))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let mut s = format!("{name}({})", list(inputs));
    if !outputs.is_empty() {
        s += &format!(" -> ({})", list(outputs));
    }
    s
}

fn shown_signature(s: &Signature) -> String {
    let args = |a: &[Arg]| {
        a.iter()
            .map(|a| SomArg {
                name: a.name.into(),
                type_name: a.ty.name().into(),
            })
            .collect::<Vec<_>>()
    };
    shown(s.name, &args(s.inputs), &args(s.outputs))
}

#[cfg(test)]
mod tests {
    use super::*;
    use osap_host::map::RuntimeRecord;
    use osap_host::som::model::{SomInputMode, SomOutputMode};
    use osap_module::functions::SIGNATURES;

    fn function(s: &Signature, port: u16) -> SomFunction {
        let args = |a: &[Arg]| {
            a.iter()
                .map(|a| SomArg {
                    name: a.name.into(),
                    type_name: a.ty.name().into(),
                })
                .collect()
        };
        SomFunction {
            name: s.name.into(),
            summary: String::new(),
            port,
            pipe_ports: Vec::new(),
            inputs: args(s.inputs),
            outputs: args(s.outputs),
            input_mode: SomInputMode::OnAnyFresh,
            output_mode: SomOutputMode::Always,
            pipe_slots: 0,
            pipes: Vec::new(),
        }
    }

    fn runtime(functions: Vec<SomFunction>) -> SomRuntime {
        SomRuntime {
            blocks: Vec::new(),
            record: RuntimeRecord {
                name: "a".into(),
                type_name: "stepper".into(),
                version: "0.1.0".into(),
                build: 3,
                function_set: 0,
                packet_size: 256,
                tier: 1,
                route: vec![0, 1],
                route_drops: Vec::new(),
                route_mtu: 256,
                links: Vec::new(),
                ports: Vec::new(),
            },
            functions,
        }
    }

    fn stepper() -> Vec<SomFunction> {
        SIGNATURES
            .iter()
            .enumerate()
            .map(|(i, s)| function(s, 1 + 3 * i as u16))
            .collect()
    }

    #[test]
    fn a_stepper_is_known_with_or_without_blocks_made_at_run_time() {
        assert_eq!(kind_of(&runtime(stepper())).unwrap().name, "stepper");
        // A block instance made at run time: ports after the set's.
        let mut more = stepper();
        let extra = Signature {
            name: "Timer.tick",
            inputs: &[],
            outputs: &[],
        };
        more.push(function(&extra, 200));
        assert_eq!(kind_of(&runtime(more)).unwrap().name, "stepper");
    }

    #[test]
    fn a_wrong_module_says_what_is_missing_or_different() {
        // A host or hub: no functions at all.
        let e = kind_of(&runtime(Vec::new())).unwrap_err();
        assert_eq!(e.found_count, 0);
        assert_eq!(e.missing.len(), SIGNATURES.len());
        assert!(e.to_string().contains("found no functions"), "{e}");
        assert!(
            e.to_string().starts_with(&format!(
                "expected the stepper function set (id {:#010x}, {} functions in port order)",
                osap_module::FUNCTION_SET_ID,
                SIGNATURES.len()
            )),
            "{e}"
        );

        // An older firmware: one function missing, one with another type.
        let mut old = stepper();
        old.retain(|f| f.name != "halt");
        old[0].inputs[1].type_name = "f64".into();
        let e = kind_of(&runtime(old)).unwrap_err();
        assert_eq!(e.missing, ["halt"]);
        assert_eq!(
            e.different,
            [(
                "add_point(time: u64, position: f64)".to_string(),
                "add_point(time: u64, position: f32)".to_string()
            )]
        );
        let text = e.to_string();
        assert!(text.contains("; missing: halt;"), "{text}");
        assert!(
            text.contains("add_point(time: u64, position: f64) where the set has add_point(time: u64, position: f32)"),
            "{text}"
        );
        assert!(text.contains("`osap flash`"), "{text}");
        assert_ne!(e.found_id, Some(e.expected_id));

        // The same functions in another order.
        let mut swapped = stepper();
        swapped.swap(0, 1);
        let e = kind_of(&runtime(swapped)).unwrap_err();
        assert!(e.missing.is_empty() && e.different.is_empty());
        assert_eq!(e.out_of_order, ["add_point", "set_interval"]);
    }
}
