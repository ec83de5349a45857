//! `RUST_LOG` in the example binaries (`osap_examples::init_logging`): the
//! mill script on its simulated machine, run until the machine is up (its
//! system object model read, which osap-host logs at debug), logs to
//! stderr when asked and prints nothing there otherwise; stdout is the
//! script's own either way.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// Runs `mill_square --fast` until it prints its "machine .. up" line,
/// then stops it: that line, and everything it wrote to stderr.
fn until_up(rust_log: Option<&str>) -> (String, String) {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_mill_square"));
    cmd.arg("--fast")
        .env_remove("RUST_LOG")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    if let Some(filter) = rust_log {
        cmd.env("RUST_LOG", filter);
    }
    let mut child = cmd.spawn().expect("start mill_square");
    let stderr = child.stderr.take().expect("stderr");
    let err = std::thread::spawn(move || std::io::read_to_string(stderr).unwrap_or_default());
    let started = Instant::now();
    let mut first = String::new();
    BufReader::new(child.stdout.take().expect("stdout"))
        .read_line(&mut first)
        .expect("read stdout");
    let _ = child.kill();
    let _ = child.wait();
    assert!(
        started.elapsed() < Duration::from_secs(120),
        "the machine took {:?} to come up",
        started.elapsed()
    );
    (first, err.join().unwrap_or_default())
}

#[test]
fn rust_log_reaches_stderr_and_nothing_logs_without_it() {
    let (up, log) = until_up(Some("osap_host=debug"));
    assert!(up.starts_with("machine mill up: "), "stdout: {up:?}\n{log}");
    assert!(
        log.lines()
            .any(|l| l.contains("DEBUG") && l.contains("system object model read in")),
        "no debug log on stderr:\n{log}"
    );

    let (quiet_up, quiet) = until_up(None);
    assert_eq!(quiet_up, up, "stdout changed");
    assert!(quiet.is_empty(), "logged without RUST_LOG:\n{quiet}");
}
