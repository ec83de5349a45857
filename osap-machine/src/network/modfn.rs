//! Typed handles for the functions every osap-rs module presents, built at
//! compile time from osap-module's own table
//! ([`osap_module::module_function_table!`], the table that builds the
//! firmware's function set), so a misspelt function or argument is a
//! compile error here and the two cannot drift apart.
//!
//! One module per function, named as the function is (`get_status`):
//! - `NAME` and `ID`: its name as a scan lists it, and its
//!   [`FnId`];
//! - `on(runtime)`: the function on one module, for the manager;
//! - `Inputs` and `Outputs`: its inputs and its outputs as structs, with
//!   one field per argument (names and types as the module declares them);
//!   `Inputs` is a [`ModuleCall`] and both are [`PipesArgs`], so a host
//!   function that takes a module function's outputs takes its `Outputs`
//!   ([`HostFunction::typed`](osap_host::som::HostFunction::typed));
//! - `input` and `output`: each argument's name as a constant, for pipes
//!   connected by name
//!   ([`Manager::connect_named`](osap_host::som::Manager::connect_named)).
//!
//! ```
//! use osap_machine::network::modfn::{add_point, get_position, ModuleCall};
//! use osap_host::som::FnRef;
//!
//! assert_eq!(add_point::on("x"), FnRef::new("x", "add_point"));
//! assert_eq!(add_point::input::position, "position");
//! let call = add_point::Inputs { time: 4096, position: 1.5 };
//! assert_eq!(call.values().len(), 2);
//! assert_eq!(get_position::Inputs::NAME, "get_position");
//! ```

use osap_host::som::{FnRef, Value};
pub use osap_module::functions::FnId;
use pipes_core::export::PipesArgs;

/// A call of a module function: its inputs (one module's `Inputs`), with
/// the function they go to and the outputs it answers with.
pub trait ModuleCall: PipesArgs {
    /// Which function.
    const ID: FnId;
    /// Its name, as a scan lists it.
    const NAME: &'static str;
    /// What it answers with.
    type Outputs: PipesArgs;

    /// The inputs as values, in argument order, for a call.
    fn values(&self) -> Vec<Value<'static>> {
        values(self)
    }
}

/// `args`' values in argument order.
pub fn values<A: PipesArgs>(args: &A) -> Vec<Value<'static>> {
    (0..A::ARGS.len())
        .map_while(|k| args.value(k).map(|v| v.to_owned_value()))
        .collect()
}

/// The names of `A`'s arguments, each paired with itself: the argmap of a
/// pipe from a function whose outputs are `A` into one whose inputs are
/// `A` (a module function into the host function that takes its reports).
pub fn same_names<A: PipesArgs>() -> Vec<(&'static str, &'static str)> {
    A::ARGS.iter().map(|a| (a.name, a.name)).collect()
}

macro_rules! typed_functions {
    ($(
        // The documentation: osap-module's, which its `FnId` shows.
        $(#[doc = $doc:tt])*
        $f:ident ( $($in:ident : $inty:ty),* ) $(-> ( $($out:ident : $outty:ty),* ))? ;
    )*) => {
    $(
        #[doc = concat!("The module function `", stringify!($f), "`.")]
        pub mod $f {
            use super::{FnId, FnRef, ModuleCall};

            /// Its name, as a scan lists it.
            pub const NAME: &str = stringify!($f);
            /// Which function it is.
            pub const ID: FnId = FnId::$f;

            /// The function on the module whose runtime is `runtime`.
            pub fn on(runtime: &str) -> FnRef {
                FnRef::new(runtime, NAME)
            }

            #[doc = concat!("`", stringify!($f), "`'s inputs.")]
            #[derive(Debug, Clone, Copy, PartialEq, Default, ::pipes_core::PipesArgs)]
            pub struct Inputs {
                $(
                    #[doc = concat!("`", stringify!($in), "`")]
                    pub $in: $inty,
                )*
            }

            #[doc = concat!("`", stringify!($f), "`'s outputs.")]
            #[derive(Debug, Clone, Copy, PartialEq, Default, ::pipes_core::PipesArgs)]
            pub struct Outputs {
                $($(
                    #[doc = concat!("`", stringify!($out), "`")]
                    pub $out: $outty,
                )*)?
            }

            impl ModuleCall for Inputs {
                const ID: FnId = ID;
                const NAME: &'static str = NAME;
                type Outputs = Outputs;
            }

            /// Its inputs' names.
            #[allow(non_upper_case_globals)]
            pub mod input {
                $(
                    #[doc = concat!("`", stringify!($in), "`")]
                    pub const $in: &str = stringify!($in);
                )*
            }

            /// Its outputs' names.
            #[allow(non_upper_case_globals)]
            pub mod output {
                $($(
                    #[doc = concat!("`", stringify!($out), "`")]
                    pub const $out: &str = stringify!($out);
                )*)?
            }
        }
    )*

        /// Every handle, in the table's order: its id, name, inputs and
        /// outputs.
        #[cfg(test)]
        const HANDLES: &[(FnId, &str, &[pipes_core::signature::Arg], &[pipes_core::signature::Arg])] = &[$((
            $f::ID,
            $f::NAME,
            <$f::Inputs as PipesArgs>::ARGS,
            <$f::Outputs as PipesArgs>::ARGS,
        )),*];
    };
}

osap_module::module_function_table!(typed_functions);

#[cfg(test)]
mod tests {
    use super::*;
    use osap_module::functions::{ALL, SIGNATURES};

    /// One handle per function, with the module's names and types: what
    /// `typed_functions!` builds from the table, read back against the
    /// firmware's signatures.
    #[test]
    fn the_handles_are_the_modules_signatures() {
        assert_eq!(HANDLES.len(), ALL.len());
        for (k, (id, name, inputs, outputs)) in HANDLES.iter().enumerate() {
            let sig = SIGNATURES[k];
            assert_eq!(*id, ALL[k]);
            assert_eq!(
                (*name, *inputs, *outputs),
                (sig.name, sig.inputs, sig.outputs)
            );
        }
        fn call<C: ModuleCall>() -> (FnId, &'static str) {
            (C::ID, C::NAME)
        }
        assert_eq!(call::<get_fault::Inputs>(), (FnId::get_fault, "get_fault"));
        assert_eq!(get_status::output::faults, "faults");
        assert_eq!(
            same_names::<read_limit::Outputs>(),
            [("time", "time"), ("level", "level"), ("edges", "edges")]
        );
        let call = set_limits::Inputs {
            max_vel: 1.0,
            max_acc: 2.0,
            max_jerk: 3.0,
        };
        assert_eq!(
            call.values(),
            [Value::F32(1.0), Value::F32(2.0), Value::F32(3.0)]
        );
    }
}
