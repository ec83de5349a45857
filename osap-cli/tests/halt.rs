//! The shipped plotter driven through `osap serve` over TCP (its machine
//! file names module z by route, counted from the served machine's entry
//! point), and `osap halt` from a third process stopping a job that
//! `osap run` drives there, pen up.

mod common;

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::{self, Receiver};
use std::time::{Duration, Instant};

use common::{Controlled, Killed};
use osap_machine::config::MachineFile;

/// The served machines run in real time: one test at a time.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn serial() -> std::sync::MutexGuard<'static, ()> {
    ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn plotter() -> PathBuf {
    root().join("examples/machines/plotter.toml")
}

/// `osap run plotter drawing.svg --tcp ADDR --no-home` with its standard
/// error read line by line (echoed, and sent on the receiver).
fn start_run(addr: &str, out: &std::path::Path) -> (Killed, Receiver<String>, Receiver<String>) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_osap"))
        .arg("run")
        .arg(plotter())
        .arg(root().join("examples/jobs/drawing.svg"))
        .args(["--tcp", addr, "--no-home", "--out"])
        .arg(out)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let stderr = lines(&mut child, "run (stderr)", |c| {
        Box::new(c.stderr.take().unwrap())
    });
    let stdout = lines(&mut child, "run", |c| Box::new(c.stdout.take().unwrap()));
    (Killed(child), stderr, stdout)
}

fn lines(
    child: &mut Child,
    who: &'static str,
    take: impl FnOnce(&mut Child) -> Box<dyn std::io::Read + Send>,
) -> Receiver<String> {
    let reader = BufReader::new(take(child));
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in reader.lines().map_while(Result::ok) {
            println!("{who}> {line}");
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    rx
}

/// Waits for a line containing `part`; every line read on the way.
fn wait_line(rx: &Receiver<String>, part: &str, limit: Duration) -> Vec<String> {
    let end = Instant::now() + limit;
    let mut seen = Vec::new();
    loop {
        let left = end.saturating_duration_since(Instant::now());
        match rx.recv_timeout(left) {
            Ok(line) => {
                let hit = line.contains(part);
                seen.push(line);
                if hit {
                    return seen;
                }
            }
            Err(e) => panic!("no line with {part:?} within {limit:?} ({e}); read: {seen:#?}"),
        }
    }
}

/// Every line left, once the child has exited.
fn rest(rx: &Receiver<String>) -> Vec<String> {
    rx.iter().collect()
}

/// Waits for the child to exit; its exit code.
fn exit_code(child: &mut Killed, limit: Duration) -> Option<i32> {
    let end = Instant::now() + limit;
    loop {
        if let Some(status) = child.0.try_wait().unwrap() {
            return status.code();
        }
        assert!(
            Instant::now() < end,
            "the process did not exit within {limit:?}"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Where the served carriage is, x and y (mm), from the belt motors' own
/// positions (`position MODULE` on the server's control input).
fn carriage(served: &mut Controlled, cfg: &MachineFile) -> [f64; 2] {
    let mut motor = |m: &str| -> f64 {
        let answer = served.command(&format!("position {m}"));
        let prefix = format!("ok position {m}: ");
        answer
            .strip_prefix(&prefix)
            .and_then(|r| r.split_whitespace().next())
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("{answer:?}"))
    };
    let (a, b) = (motor("a"), motor("b"));
    let at = |axis: &str| {
        osap_machine::sim::axis_form(cfg, axis)
            .unwrap()
            .value(|m| if m == "a" { a } else { b })
    };
    [at("x"), at("y")]
}

fn out_dir(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("osap-halt-{name}-{}", std::process::id()))
}

/// The first number after `word` in `line`, as a float.
fn float_after(line: &str, word: &str) -> f64 {
    let rest = &line[line
        .find(word)
        .unwrap_or_else(|| panic!("{word:?} in {line:?}"))
        + word.len()..];
    rest.split(|c: char| !(c.is_ascii_digit() || c == '.'))
        .find(|s| !s.is_empty())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("a number after {word:?} in {line:?}"))
}

/// The shipped plotter, unchanged, runs its drawing on a served machine:
/// z = [0, 3] counts from the served host, not from the connecting one.
#[test]
fn the_shipped_plotter_runs_its_drawing_through_serve() {
    let _one = serial();
    let served = Controlled::start(&plotter());
    let out = out_dir("drawing");
    let (mut run, stderr, stdout) = start_run(&served.addr, &out);
    let code = exit_code(&mut run, Duration::from_secs(120));
    let (stderr, stdout) = (rest(&stderr), rest(&stdout));
    assert_eq!(code, Some(0), "{stderr:#?}\n{stdout:#?}");
    assert!(
        stderr
            .iter()
            .any(|l| l.contains("machine plotter ready (3 modules")),
        "{stderr:#?}"
    );
    assert!(stdout.iter().any(|l| l == "faults: none"), "{stdout:#?}");
    let _ = std::fs::remove_dir_all(&out);
}

/// `osap halt` from a third process stops a job `osap run` drives on a
/// served plotter: the run exits 3 naming the halt, the carriage stands
/// within the distance a controlled stop would need, and the halt itself
/// is quick.
#[test]
fn osap_halt_stops_a_served_job_from_a_third_process() {
    let _one = serial();
    let cfg = MachineFile::load(plotter()).unwrap();
    let mut served = Controlled::start(&plotter());
    let out = out_dir("halted");
    let (mut run, stderr, _stdout) = start_run(&served.addr, &out);
    wait_line(&stderr, "first job move queued", Duration::from_secs(60));
    // Moving: the carriage left where it stood.
    let still = carriage(&mut served, &cfg);
    let end = Instant::now() + Duration::from_secs(10);
    while carriage(&mut served, &cfg) == still {
        if let Some(status) = run.0.try_wait().unwrap() {
            panic!(
                "the run ended before the halt ({status}): {:#?}",
                rest(&stderr)
            );
        }
        assert!(Instant::now() < end, "the carriage never moved");
    }

    let before = carriage(&mut served, &cfg);
    let t0 = Instant::now();
    let halt = Command::new(env!("CARGO_BIN_EXE_osap"))
        .arg("halt")
        .arg(plotter())
        .args(["--tcp", &served.addr])
        .output()
        .unwrap();
    let wall = t0.elapsed();
    let halted_at = carriage(&mut served, &cfg);
    let stdout = String::from_utf8_lossy(&halt.stdout);
    let stderr_halt = String::from_utf8_lossy(&halt.stderr);
    println!(
        "osap halt ({:.0} ms wall):\n{stdout}{stderr_halt}",
        wall.as_secs_f64() * 1e3
    );
    assert_eq!(halt.status.code(), Some(0), "{stdout}{stderr_halt}");
    for (key, name, route) in [
        ("a", "a", "0,0,1"),
        ("b", "b", "0,0,2"),
        ("z", "z", "0,0,3"),
    ] {
        let line = stdout
            .lines()
            .find(|l| l.starts_with(&format!("  {key}  halted: \"{name}\" at route {route}, ")))
            .unwrap_or_else(|| panic!("module {key} in {stdout}"));
        // Found, then halted within 100 ms.
        let (found, sent) = (float_after(line, "found "), float_after(line, "sent "));
        assert!(sent - found < 100.0, "{line}");
    }
    assert!(stdout.contains("tool pen off (pwm 0 at 0.05)"), "{stdout}");
    // The pen is up: z's PWM output 0 at the pen's off duty.
    let outputs = served.command("outputs z");
    assert!(outputs.starts_with("ok pwm0=0.050 "), "{outputs}");
    let done = stdout
        .lines()
        .find(|l| l.starts_with("halted every module of plotter "))
        .unwrap_or_else(|| panic!("{stdout}"));
    let own_ms = float_after(done, "plotter ");

    // The run stops on the halt: a machine fault, exit 3, named.
    let code = exit_code(&mut run, Duration::from_secs(30));
    let stderr = rest(&stderr);
    assert_eq!(code, Some(3), "{stderr:#?}");
    assert!(
        stderr
            .iter()
            .any(|l| l.starts_with("error: ") && l.contains("halted")),
        "{stderr:#?}"
    );

    // Nothing moved after the halt was confirmed, though the run went on
    // sending its stop for a while: a halted module steps no more.
    let rest_at = carriage(&mut served, &cfg);
    assert_eq!(rest_at, halted_at, "moved after the halt");
    // From the moment `osap halt` started, the carriage came to rest
    // within what the job could cover at the machine's top speed until the
    // last module confirmed (the halt's own time, which a loaded computer
    // stretches) plus the braking distance v²/2a a controlled stop would
    // need beyond it: a halt that lands stops the carriage at once.
    let v = cfg.limits.velocity;
    let a = cfg.limits.acceleration;
    let allowed = v * own_ms * 1e-3 + v * v / (2.0 * a);
    let moved = ((rest_at[0] - before[0]).powi(2) + (rest_at[1] - before[1]).powi(2)).sqrt();
    println!(
        "halt: {own_ms:.0} ms from its start to halted ({:.0} ms wall); the carriage ran {moved:.2} mm (allowed {allowed:.1} mm)",
        wall.as_secs_f64() * 1e3
    );
    assert!(moved <= allowed, "{moved} mm > {allowed} mm");
    // The halt's own time, from its process's start to every module
    // confirmed: less than the time the carriage takes, at the job's feed
    // (half the velocity limit), to run what a controlled stop needs (the
    // points already sent, v·lead, and braking, v²/2a: 33 mm, 264 ms), so
    // a halt is never slower than a controlled stop would be.
    let lead = f64::from(osap_machine::machine::LEAD_US) * 1e-6;
    let controlled = v * lead + v * v / (2.0 * a);
    let feed = v / 2.0;
    let bound_ms = controlled / feed * 1e3;
    assert!(own_ms < bound_ms, "{own_ms} ms >= {bound_ms:.0} ms");
    let _ = std::fs::remove_dir_all(&out);
}
