//! Keyed links from the command line: `osap keygen`, `osap serve --key`,
//! `--key` on a client, and the errors that name the fix.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};

fn shipped(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../osap-sim/topologies")
        .join(name)
}

fn osap() -> Command {
    Command::new(env!("CARGO_BIN_EXE_osap"))
}

/// Kills the server when dropped.
struct Killed(Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// `osap serve` on a free loopback port with `extra` arguments; the server
/// and the address it printed.
fn serve(extra: &[&str]) -> (Killed, String) {
    let mut server = Killed(
        osap()
            .args(["serve", "--tcp", "127.0.0.1:0", "--sim"])
            .arg(shipped("small-machine.toml"))
            .args(extra)
            .stdout(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let mut line = String::new();
    BufReader::new(server.0.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let addr = line
        .split_whitespace()
        .find(|w| w.starts_with("127.0.0.1:"))
        .unwrap_or_else(|| panic!("no address in {line:?}"))
        .trim_end_matches(';')
        .to_string();
    (server, addr)
}

fn text(out: &Output) -> String {
    format!(
        "{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

fn temp(tag: &str) -> PathBuf {
    let p = std::env::temp_dir().join(format!("osap-cli-key-{}-{tag}", std::process::id()));
    let _ = std::fs::remove_file(&p);
    p
}

fn keygen(path: &Path) {
    let out = osap().arg("keygen").arg(path).output().unwrap();
    assert!(out.status.success(), "{}", text(&out));
}

#[test]
fn a_keyed_server_is_scanned_with_the_key_and_refuses_without() {
    let key = temp("good");
    keygen(&key);
    let (_server, addr) = serve(&["--key", key.to_str().unwrap()]);

    let out = osap()
        .args(["scan", "--tcp", &addr, "--key"])
        .arg(&key)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", text(&out));
    assert!(text(&out).contains("7 runtimes"), "{}", text(&out));

    // Without the key: a clear error.
    let out = osap().args(["scan", "--tcp", &addr]).output().unwrap();
    assert!(!out.status.success());
    assert!(text(&out).contains("--key"), "{}", text(&out));

    // With another key: a clear error.
    let other = temp("other");
    keygen(&other);
    let out = osap()
        .args(["scan", "--tcp", &addr, "--key"])
        .arg(&other)
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(text(&out).contains("key may be wrong"), "{}", text(&out));
    let _ = std::fs::remove_file(&key);
    let _ = std::fs::remove_file(&other);
}

#[test]
fn key_files_and_remote_serving_are_checked() {
    let key = temp("perm");
    keygen(&key);
    // keygen never overwrites.
    let out = osap().arg("keygen").arg(&key).output().unwrap();
    assert!(!out.status.success());
    assert!(text(&out).contains("exists"), "{}", text(&out));
    // A key file others can read is refused, naming the fix.
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&key, std::fs::Permissions::from_mode(0o644)).unwrap();
        let out = osap()
            .args(["scan", "--tcp", "127.0.0.1:1", "--key"])
            .arg(&key)
            .output()
            .unwrap();
        assert!(!out.status.success());
        assert!(text(&out).contains("chmod 600"), "{}", text(&out));
    }
    // --allow-remote needs --key.
    let out = osap()
        .args(["serve", "--tcp", "0.0.0.0:0", "--allow-remote", "--sim"])
        .arg(shipped("small-machine.toml"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(text(&out).contains("--key"), "{}", text(&out));
    let _ = std::fs::remove_file(&key);
}

#[test]
fn the_connection_limit_is_a_clear_refusal() {
    let mut server = Killed(
        osap()
            .args([
                "serve",
                "--tcp",
                "127.0.0.1:0",
                "--max-connections",
                "1",
                "--sim",
            ])
            .arg(shipped("small-machine.toml"))
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let mut line = String::new();
    BufReader::new(server.0.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let addr = line
        .split_whitespace()
        .find(|w| w.starts_with("127.0.0.1:"))
        .unwrap()
        .trim_end_matches(';')
        .to_string();
    // One raw client holds the only place: served once its greeting (a
    // lone delimiter) arrives.
    let mut holder = std::net::TcpStream::connect(&addr).unwrap();
    let mut greeting = [1u8; 1];
    std::io::Read::read_exact(&mut holder, &mut greeting).unwrap();
    assert_eq!(greeting, [0]);
    let out = osap().args(["scan", "--tcp", &addr]).output().unwrap();
    assert!(!out.status.success());
    assert!(text(&out).contains("connection limit"), "{}", text(&out));
    // The server says whom it refused, and why.
    drop(holder);
    let _ = server.0.kill();
    let mut log = String::new();
    std::io::Read::read_to_string(&mut server.0.stderr.take().unwrap(), &mut log).unwrap();
    assert!(
        log.contains("refused a connection from 127.0.0.1") && log.contains("--max-connections"),
        "{log}"
    );
}
