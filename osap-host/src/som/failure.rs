//! Remote refusals by name: which devices' failure codes the host knows.
//!
//! A function's failure code (`ControlError::CallFailed(code)`) is a bare
//! byte whose meaning is the function's own. The host names it only for a
//! runtime that presents osap-module's function set exactly (every
//! function's name, inputs and outputs, with their types, in port order:
//! what `osap_module::FUNCTION_SET_ID` identifies). Then its functions are
//! osap-module's and their codes are those of [`osap_module::failure`].
//!
//! Neither a function's name nor the runtime's type name is enough: another
//! device may have an `add_point` with codes of its own, and a type name is
//! whatever the firmware says. A runtime with a different or larger set (an
//! osap-rs firmware older or newer than this build, or with functions of
//! its own) gets its codes printed as numbers, never a wrong name.

use super::model::SomRuntime;
pub use osap_module::failure::Failure;
use osap_module::functions::SIGNATURES;
use pipes_core::signature::Arg;

/// Whether `rt`'s functions are exactly osap-module's (see the module
/// docs): its failure codes are then named by [`failure`].
pub fn is_osap_module(rt: &SomRuntime) -> bool {
    let same_args = |found: &[super::model::SomArg], wanted: &[Arg]| {
        found.len() == wanted.len()
            && found
                .iter()
                .zip(wanted)
                .all(|(f, w)| f.name == w.name && f.type_name == w.ty.name())
    };
    rt.functions.len() == SIGNATURES.len()
        && rt.functions.iter().zip(SIGNATURES).all(|(f, s)| {
            f.name == s.name && same_args(&f.inputs, s.inputs) && same_args(&f.outputs, s.outputs)
        })
}

/// What failure `code` of function `function` on runtime `rt` means, if
/// the host knows: `rt` is an osap-rs module ([`is_osap_module`]) and
/// `code` is one its function returns.
pub fn failure(rt: &SomRuntime, function: &str, code: u8) -> Option<Failure> {
    if is_osap_module(rt) {
        osap_module::failure::failure(function, code)
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::RuntimeRecord;
    use crate::som::model::{SomArg, SomFunction, SomInputMode, SomOutputMode};

    fn function(name: &str, port: u16) -> SomFunction {
        SomFunction {
            name: name.into(),
            port,
            pipe_ports: Vec::new(),
            inputs: Vec::new(),
            outputs: Vec::new(),
            input_mode: SomInputMode::OnAnyFresh,
            output_mode: SomOutputMode::Always,
            pipe_slots: 0,
            pipes: Vec::new(),
        }
    }

    fn module_runtime() -> SomRuntime {
        let args = |a: &[Arg]| {
            a.iter()
                .map(|a| SomArg {
                    name: a.name.into(),
                    type_name: a.ty.name().into(),
                })
                .collect::<Vec<_>>()
        };
        let functions = SIGNATURES
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let mut f = function(s.name, i as u16 + 1);
                f.inputs = args(s.inputs);
                f.outputs = args(s.outputs);
                f
            })
            .collect();
        SomRuntime {
            record: RuntimeRecord {
                name: "a".into(),
                type_name: "stepper".into(),
                version: "0.1.0".into(),
                build: 3,
                packet_size: 256,
                tier: 1,
                route: vec![0],
                route_drops: Vec::new(),
                route_mtu: 256,
                links: Vec::new(),
                ports: Vec::new(),
            },
            functions,
        }
    }

    #[test]
    fn only_the_whole_module_function_set_gets_names() {
        let rt = module_runtime();
        assert!(is_osap_module(&rt));
        assert_eq!(failure(&rt, "add_point", 8).unwrap().name, "QueueFull");
        assert_eq!(failure(&rt, "add_point", 42), None);

        // One function of the same name on another device: its own codes.
        let mut other = rt.clone();
        other.functions.retain(|f| f.name == "add_point");
        assert!(!is_osap_module(&other));
        assert_eq!(failure(&other, "add_point", 8), None);

        // The same names with another type.
        let mut retyped = rt.clone();
        retyped.functions[0].inputs[1].type_name = "f64".into();
        assert!(!is_osap_module(&retyped));

        // More functions than the module has.
        let mut larger = rt.clone();
        larger.functions.push(function("extra", 99));
        assert!(!is_osap_module(&larger));
    }

    #[test]
    fn a_remote_refusal_prints_by_name_only_when_known() {
        use crate::som::{FnRef, SomError};
        use pipes_core::control::ControlError;
        let remote = |failure| SomError::Remote {
            function: FnRef::new("a", "add_point"),
            request: "call",
            error: ControlError::CallFailed(pipes_core::FailureCode::Other(8)),
            failure,
        };
        let named = remote(osap_module::failure::failure("add_point", 8).map(Box::new)).to_string();
        assert!(
            named.ends_with(
                "call refused: QueueFull (code 8): the module's queue is full \
                 (stream too far ahead): send points closer to their time"
            ),
            "{named}"
        );
        let bare = remote(None).to_string();
        assert!(
            bare.ends_with("call refused: the function failed with code 8"),
            "{bare}"
        );
    }
}
