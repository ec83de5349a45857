//! Pipes named by their arguments: [`Manager::connect_named`] looks each
//! name up in the functions' scanned signatures, so a renamed or missing
//! argument is an error at bind time that names both ends.

use super::handle::describe;
use super::manager::{Manager, PipeOptions};
use super::model::{SomArg, SomPipe};
use super::{FnRef, NoSuchArgument, SomError};

impl Manager {
    /// Pipes `source`'s outputs to `dest`'s inputs, by name: each pair is
    /// `(output, input)`. The names are looked up in the functions'
    /// signatures as the model holds them, then the pipe is set up as
    /// [`connect`](Self::connect) sets it (the same checks of the argmap,
    /// the types and the route).
    ///
    /// A name the function does not have is refused with
    /// [`SomError::NoSuchArgument`], which names both functions, both
    /// arguments, and the arguments the function does have.
    pub async fn connect_named(
        &mut self,
        source: &FnRef,
        dest: &FnRef,
        pairs: &[(&str, &str)],
        options: PipeOptions,
    ) -> Result<SomPipe, SomError> {
        let (outputs, inputs) = self.argmap(source, dest, pairs)?;
        self.connect(source, dest, &outputs, &inputs, options).await
    }

    /// The indices of `pairs`' outputs of `source` and inputs of `dest`.
    fn argmap(
        &self,
        source: &FnRef,
        dest: &FnRef,
        pairs: &[(&str, &str)],
    ) -> Result<(Vec<u8>, Vec<u8>), SomError> {
        let (_, sf) = self.locate(source)?;
        let (_, df) = self.locate(dest)?;
        let missing = |output: &str, input: &str, detail: String| {
            SomError::NoSuchArgument(Box::new(NoSuchArgument {
                source_fn: source.clone(),
                output: output.to_string(),
                dest_fn: dest.clone(),
                input: input.to_string(),
                detail,
            }))
        };
        let mut outputs = Vec::with_capacity(pairs.len());
        let mut inputs = Vec::with_capacity(pairs.len());
        for &(output, input) in pairs {
            let o = index(&sf.outputs, output).ok_or_else(|| {
                missing(
                    output,
                    input,
                    format!(
                        "{source} has no output {output:?} (outputs: {})",
                        describe(&sf.outputs)
                    ),
                )
            })?;
            let i = index(&df.inputs, input).ok_or_else(|| {
                missing(
                    output,
                    input,
                    format!(
                        "{dest} has no input {input:?} (inputs: {})",
                        describe(&df.inputs)
                    ),
                )
            })?;
            outputs.push(o);
            inputs.push(i);
        }
        Ok((outputs, inputs))
    }
}

/// The index of the argument named `name` (`None`: none is, or it is past
/// the 255 a pipe can address).
fn index(args: &[SomArg], name: &str) -> Option<u8> {
    args.iter()
        .position(|a| a.name == name)
        .and_then(|i| u8::try_from(i).ok())
}
