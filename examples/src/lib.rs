//! What the example scripts share.

use std::future::Future;
use std::process::ExitCode;

/// Sends the libraries' log to stderr: as `RUST_LOG` says (e.g.
/// `RUST_LOG=osap_host=debug`), else warnings and errors only, so an
/// example's output is what it always was. Every example binary calls it
/// first ([`run_virtual`] does it for its scripts); stdout stays the
/// example's own.
pub fn init_logging() {
    use tracing_subscriber::EnvFilter;
    let filter = match EnvFilter::try_from_default_env() {
        Ok(f) => f,
        Err(e) => {
            if std::env::var_os("RUST_LOG").is_some() {
                eprintln!("warning: RUST_LOG not used ({e}); give e.g. RUST_LOG=osap_host=debug");
            }
            EnvFilter::new("warn")
        }
    };
    // A second call (or a test's own subscriber) keeps the first.
    let _ = tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_env_filter(filter)
        .try_init();
}

/// A script's result as its exit code: an error prints with Display
/// (`error: …`), never Debug.
pub fn exit_code(result: Result<(), Box<dyn std::error::Error>>) -> ExitCode {
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

/// Runs a script's `main` future on a virtual-time runtime (simulated
/// machines run as fast as the host computes them) and turns its result
/// into the exit code, printing the error. Logging is set up first
/// ([`init_logging`]).
pub fn run_virtual<F>(script: F) -> ExitCode
where
    F: Future<Output = Result<(), Box<dyn std::error::Error>>>,
{
    init_logging();
    let runtime = match osap_sim::machine::virtual_runtime() {
        Ok(r) => r,
        Err(e) => {
            eprintln!("error: cannot start the runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    exit_code(runtime.block_on(script))
}
