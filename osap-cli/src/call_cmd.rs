//! `osap call RUNTIME FUNCTION [ARGS..]`: one call of a PIPES function
//! from the command line, its outputs printed one a line, a refusal by
//! name.

use crate::Connect;
use osap_host::som::model::SomArg;
use osap_host::som::{parse_value, FnRef, SomError, Value};
use pipes_core::control::ControlError;
use std::process::ExitCode;

/// Exit code of a call the function refused with a failure code of its
/// own (anything else that fails exits with 1).
pub(crate) const REFUSED: u8 = 3;

/// `osap call`'s arguments.
#[derive(clap::Args)]
pub(crate) struct CallArgs {
    #[command(flatten)]
    connect: Connect,
    /// The runtime's name (`osap scan` lists them).
    runtime: String,
    /// The function's name (`osap scan -f` lists every runtime's).
    function: String,
    /// One value per input, in input order, e.g. `motor set_interval 1024`.
    #[arg(allow_negative_numbers = true, value_name = "ARG")]
    args: Vec<String>,
}

/// Calls the function once (never retried: a call may have effects) and
/// prints `name = value` per output.
pub(crate) async fn call(args: CallArgs) -> Result<ExitCode, String> {
    let (c, manager) = crate::connection::connect_scanned(&args.connect).await?;
    let fref = FnRef::new(args.runtime.as_str(), args.function.as_str());
    let handle = manager
        .function(&fref)
        .map_err(|e| format!("{e} (`osap scan -f` lists every runtime's functions)"))?
        .with_timeout(c.timeout);
    let inputs = handle.inputs().to_vec();
    let what = format!("{}.{}", args.runtime, args.function);
    let values = parse_inputs(&what, &inputs, &args.args)?;
    match handle.call(&values).await {
        Ok(outputs) => {
            for (o, v) in handle.outputs().iter().zip(&outputs) {
                println!("{} = {}", o.name, plain(v));
            }
            Ok(ExitCode::SUCCESS)
        }
        Err(e) => match refusal(&args.runtime, &args.function, &e) {
            Some(line) => {
                eprintln!("error: {line}");
                Ok(ExitCode::from(REFUSED))
            }
            None => Err(e.to_string()),
        },
    }
}

/// The values of `texts` for `inputs` (one each, in order), or what is
/// wrong with them, naming `what` takes them.
pub(crate) fn parse_inputs(
    what: &str,
    inputs: &[SomArg],
    texts: &[String],
) -> Result<Vec<Value<'static>>, String> {
    if texts.len() != inputs.len() {
        return Err(format!(
            "{what} takes {} input(s) ({}), {} given",
            inputs.len(),
            osap_host::som::describe(inputs),
            texts.len()
        ));
    }
    let mut values = Vec::new();
    for (input, text) in inputs.iter().zip(texts) {
        let ty = input.ty().ok_or_else(|| {
            format!(
                "input {}: type {} is unknown to this build of osap (update it)",
                input.name, input.type_name
            )
        })?;
        values.push(
            parse_value(&ty, text)
                .map_err(|e| format!("input {} ({}): {e}", input.name, input.type_name))?,
        );
    }
    Ok(values)
}

/// A refusal with a failure code, as one line: by name when the host knows
/// the device's codes (an osap-rs module), else by number.
fn refusal(runtime: &str, function: &str, e: &SomError) -> Option<String> {
    let SomError::Remote {
        error: ControlError::CallFailed(code),
        failure,
        ..
    } = e
    else {
        return None;
    };
    Some(match failure {
        Some(f) => format!("{runtime}.{function} refused: {f}"),
        None => format!(
            "{runtime}.{function} refused with failure code {} (not an osap-rs module's \
             function: the device's own documentation names its codes)",
            code.code()
        ),
    })
}

/// A value as a person types it.
pub(crate) fn plain(v: &Value<'static>) -> String {
    osap_host::som::value_text(v)
}

#[cfg(test)]
mod tests {
    use super::*;
    use osap_module::failure::failure;

    fn remote(function: &str, code: u8, named: bool) -> SomError {
        SomError::Remote {
            function: FnRef::new("a", function),
            request: "call",
            error: ControlError::CallFailed(code.into()),
            failure: if named {
                failure(function, code).map(|f| Box::new(f.into()))
            } else {
                None
            },
        }
    }

    #[test]
    fn refusals_print_by_name_when_known_and_by_number_otherwise() {
        assert_eq!(
            refusal("a", "add_point", &remote("add_point", 8, true)).unwrap(),
            "a.add_point refused: QueueFull (code 8): the module's queue is full \
             (stream too far ahead): send points closer to their time"
        );
        let other = refusal("a", "add_point", &remote("add_point", 8, false)).unwrap();
        assert!(other.contains("failure code 8"), "{other}");
        assert!(!other.contains("QueueFull"), "{other}");
        let e = SomError::NoSuchRuntime("a".into());
        assert_eq!(refusal("a", "add_point", &e), None);
    }
}
