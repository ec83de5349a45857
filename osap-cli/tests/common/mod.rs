//! What the CLI's test binaries share: an `osap serve` child process.

use std::io::{BufRead, BufReader, Write};
use std::path::Path;
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};

/// Kills the child when dropped, so a failed test leaves no server behind.
pub(crate) struct Killed(pub Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Starts `osap serve --sim FILE` on a free loopback port; the server and
/// the address it printed.
#[allow(dead_code)] // not every test binary uses it
pub(crate) fn serve(file: &Path) -> (Killed, String) {
    let (server, addr, _) = spawn(file, &[]);
    (server, addr)
}

/// A served machine taking fault-injection commands (`--control`).
#[allow(dead_code)] // not every test binary injects faults
pub(crate) struct Controlled {
    pub server: Killed,
    pub addr: String,
    stdin: ChildStdin,
    stdout: BufReader<ChildStdout>,
}

#[allow(dead_code)]
impl Controlled {
    /// Starts `osap serve --control --sim FILE`.
    pub(crate) fn start(file: &Path) -> Controlled {
        let (mut server, addr, stdout) = spawn(file, &["--control"]);
        let stdin = server.0.stdin.take().unwrap();
        Controlled {
            server,
            addr,
            stdin,
            stdout,
        }
    }

    /// Sends one control command and returns the server's answer line.
    pub(crate) fn command(&mut self, line: &str) -> String {
        writeln!(self.stdin, "{line}").unwrap();
        self.stdin.flush().unwrap();
        let mut answer = String::new();
        self.stdout.read_line(&mut answer).unwrap();
        answer.trim_end().to_string()
    }
}

/// Starts `osap serve --tcp 127.0.0.1:0 --sim FILE EXTRA..`; the server,
/// the address it printed, and the rest of its standard output.
fn spawn(file: &Path, extra: &[&str]) -> (Killed, String, BufReader<ChildStdout>) {
    let mut server = Killed(
        Command::new(env!("CARGO_BIN_EXE_osap"))
            .args(["serve", "--tcp", "127.0.0.1:0", "--sim"])
            .arg(file)
            .args(extra)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let mut line = String::new();
    let mut stdout = BufReader::new(server.0.stdout.take().unwrap());
    stdout.read_line(&mut line).unwrap();
    let addr = line
        .split_whitespace()
        .find(|w| w.starts_with("127.0.0.1:"))
        .unwrap_or_else(|| panic!("no address in {line:?}"))
        .trim_end_matches(';')
        .to_string();
    (server, addr, stdout)
}

/// The first number after `word` in `line`.
#[allow(dead_code)] // not every test binary reads numbers from output
pub(crate) fn number_after(line: &str, word: &str) -> Option<u64> {
    let rest = &line[line.find(word)? + word.len()..];
    rest.split(|c: char| !c.is_ascii_digit())
        .find(|s| !s.is_empty())?
        .parse()
        .ok()
}

/// A free loopback port (bound and released).
#[allow(dead_code)] // not every test binary needs one
pub(crate) fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}
