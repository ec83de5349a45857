//! What the example scripts share.

use std::future::Future;
use std::process::ExitCode;

/// Runs a script's `main` future on a virtual-time runtime (simulated
/// machines run as fast as the host computes them) and turns its result
/// into the exit code, printing the error.
pub fn run_virtual<F>(script: F) -> ExitCode
where
    F: Future<Output = Result<(), Box<dyn std::error::Error>>>,
{
    let runtime = match osap_sim::machine::virtual_runtime() {
        Ok(r) => r,
        Err(e) => {
            eprintln!("error: cannot start the runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    match runtime.block_on(script) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
