//! End to end on an emulated RP2040: the release firmware a user flashes,
//! booted in rp2040js by the project's bridge (`firmware-rp2040/emulator`),
//! its USB CDC link bridged to a TCP socket and joined to a host runtime.
//!
//! The test scans the module (it appears with its functions), renames it
//! (the name survives an emulated reset, through the emulated flash),
//! calls its functions by RPC and times the round trip, waits for its
//! clock to follow the host's and checks the error, and streams spline
//! points whose step pulses, counted on the emulated step and direction
//! pins, must match the trajectory.
//!
//! It needs the release firmware and node with the bridge's packages, so it
//! is ignored by a plain `cargo test`; `scripts/emulator-test.sh` builds
//! both and runs it (CI does).

use osap_core::clock::SyncState;
use osap_core::route::Route;
use osap_host::link::stream::LinkHandle;
use osap_host::link::tcp;
use osap_host::netrunner::{Netrunner, ScanOptions, SyncGoal};
use osap_host::som::{FnRef, Manager, ManagerOptions, OwnedValue};
use osap_host::{Host, HostConfig};
use osap_module::functions::SIGNATURES;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::{Duration, Instant};
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
use tokio::net::TcpStream;
use tokio::process::{Child, Command};

/// The firmware's step and direction pins (see firmware-rp2040/README.md).
const STEP_PIN: u8 = 2;
const DIR_PIN: u8 = 3;
/// The firmware's limit-switch input.
const LIMIT_PIN: u8 = 5;
/// Limit edges whose time stamps are checked.
const EDGE_CHECKS: usize = 21;
/// How far a synchronized emulated module's time stamps may be from the
/// host's (median over the edges), µs. The emulator's pace against wall
/// time wanders by a millisecond or two and falls behind in bursts on a
/// busy machine; the error follows it (see the check).
const EMULATED_CLOCK_BOUND_US: i128 = 5_000;
/// How long to wait for each reply from the emulated module.
const PATIENCE: Duration = Duration::from_secs(2);
/// Full steps per unit the firmware starts with (osap-module's default).
const STEPS_PER_UNIT: f64 = 80.0;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn firmware_elf() -> PathBuf {
    std::env::var_os("OSAP_RP2040_ELF")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            repo().join("firmware-rp2040/target/thumbv6m-none-eabi/release/firmware-rp2040")
        })
}

/// The bridge process and its sockets; killed when dropped.
struct Emulator {
    _child: Child,
    usb: u16,
    control: u16,
}

impl Emulator {
    async fn start(flash: &Path) -> Emulator {
        let elf = firmware_elf();
        assert!(
            elf.exists(),
            "no firmware at {} (build it: cd firmware-rp2040 && cargo build --release)",
            elf.display()
        );
        let bridge = repo().join("firmware-rp2040/emulator/bridge.mjs");
        // Port 0: the bridge picks free ports and says which once it
        // listens, so there is no race for them and nothing to poll.
        let mut child = Command::new("node")
            .arg(&bridge)
            .arg("--elf")
            .arg(&elf)
            .args(["--usb", "0", "--control", "0", "--realtime"])
            .arg("--flash-image")
            .arg(flash)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .kill_on_drop(true)
            .spawn()
            .expect("node runs the bridge (is node installed?)");
        let stdout = child.stdout.take().expect("piped stdout");
        let mut ready = String::new();
        tokio::time::timeout(
            Duration::from_secs(20),
            BufReader::new(stdout).read_line(&mut ready),
        )
        .await
        .expect("the bridge never said it was ready")
        .expect("the bridge's stdout");
        let ready: Value = serde_json::from_str(&ready)
            .unwrap_or_else(|e| panic!("the bridge did not start: {ready:?} ({e})"));
        let port = |k: &str| {
            ready[k]
                .as_u64()
                .and_then(|p| u16::try_from(p).ok())
                .unwrap_or_else(|| panic!("no {k} port in {ready}"))
        };
        Emulator {
            usb: port("usb"),
            control: port("control"),
            _child: child,
        }
    }

    /// One command on the control channel, its JSON answer.
    async fn control(&self, cmd: Value) -> Value {
        let mut s = TcpStream::connect(("127.0.0.1", self.control))
            .await
            .expect("control channel");
        s.write_all(format!("{cmd}\n").as_bytes()).await.unwrap();
        let mut line = String::new();
        BufReader::new(s).read_line(&mut line).await.unwrap();
        serde_json::from_str(&line).unwrap_or_else(|e| panic!("bad answer {line:?}: {e}"))
    }
}

/// Joins the emulated module's USB link to `host` (retrying while the
/// firmware enumerates).
async fn join(host: &Host, emu: &Emulator) -> LinkHandle {
    let addr = format!("127.0.0.1:{}", emu.usb);
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        match tcp::connect(host, &addr).await {
            Ok(link) => return link,
            Err(e) => {
                assert!(Instant::now() < deadline, "USB link never came up: {e}");
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
        }
    }
}

/// The module's name: the runtime on the other end of `route`, retried
/// while the firmware boots.
async fn module_name(nr: &Netrunner, route: &Route) -> String {
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        match nr.name(route).await {
            Ok(name) => return name,
            Err(e) => {
                assert!(Instant::now() < deadline, "the module never answered: {e}");
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
        }
    }
}

/// The host's monotonic clock (CLOCK_MONOTONIC, the clock the bridge
/// reports instants on), ns.
fn monotonic_ns() -> i128 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes the timespec it is given; CLOCK_MONOTONIC
    // always exists on Linux.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    assert_eq!(rc, 0, "clock_gettime(CLOCK_MONOTONIC)");
    i128::from(ts.tv_sec) * 1_000_000_000 + i128::from(ts.tv_nsec)
}

/// The host runtime's system time minus the monotonic clock, ns: from the
/// narrowest of many brackets of a system-time read (in-process, so a few
/// µs wide).
async fn host_minus_monotonic_ns(host: &Host) -> i128 {
    let mut best = (i128::MAX, 0);
    for _ in 0..200 {
        let before = monotonic_ns();
        let system_us = host.system_time().await.unwrap();
        let after = monotonic_ns();
        if after - before < best.0 {
            best = (
                after - before,
                i128::from(system_us) * 1000 - (before + after) / 2,
            );
        }
    }
    assert!(best.0 < 1_000_000, "no system-time read under 1 ms");
    best.1
}

/// The module's limit switch: time of the last edge (synchronized µs),
/// level, edges since boot.
async fn read_limit(f: &osap_host::som::FunctionHandle) -> (u64, bool, u32) {
    let out = f.call(&[]).await.unwrap();
    match out.as_slice() {
        [OwnedValue::U64(t), OwnedValue::Bool(level), OwnedValue::U32(edges)] => {
            (*t, *level, *edges)
        }
        other => panic!("read_limit gave {other:?}"),
    }
}

/// What a streamed move did.
struct Moved {
    /// The bridge's count of edges on the step and direction pins.
    counts: Value,
    /// The firmware's `get_steps`.
    steps: Vec<OwnedValue>,
    /// Points the firmware refused.
    refused: u32,
    /// Emulated CPU cycles executed over cycles elapsed during the move.
    load: f64,
}

/// Streams a smoothstep from `from` to `to` units over `n` intervals of
/// `iv` µs (with rests before and after), starting 300 ms from now, and
/// waits until the module has run it.
async fn smooth_move(
    host: &Host,
    emu: &Emulator,
    f: &impl Fn(&str) -> osap_host::som::FunctionHandle,
    iv: u64,
    from: f64,
    to: f64,
    n: usize,
) -> Moved {
    let load_before = emu.control(json!({"cmd": "stats"})).await;
    let counting = emu
        .control(json!({"cmd": "count", "step": STEP_PIN, "dir": DIR_PIN}))
        .await;
    assert_eq!(counting["ok"], json!(true), "{counting}");
    let now = host.system_time().await.unwrap();
    let t0 = (now + 300_000) / iv * iv;
    let mut points = vec![from; 4];
    for k in 1..=n {
        let x = k as f64 / n as f64;
        points.push(from + (to - from) * x * x * (3.0 - 2.0 * x));
    }
    points.extend([to; 6]);
    let add = f("add_point");
    for (k, p) in points.iter().enumerate() {
        add.call(&[
            OwnedValue::U64(t0 + k as u64 * iv),
            OwnedValue::F32(*p as f32),
        ])
        .await
        .unwrap_or_else(|e| panic!("point {k}: {e}"));
    }
    let end = t0 + points.len() as u64 * iv + 200_000;
    while host.system_time().await.unwrap() < end {
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    // Then until the module itself has run the stream to its end: its own
    // clock is past the last point and it has stopped tracking (a lagging
    // emulator runs it late, by the wall clock).
    let last_point = t0 + (points.len() as u64 - 1) * iv;
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let OwnedValue::U64(module_now) = f("get_position").call(&[]).await.unwrap()[0] else {
            panic!("get_position's first output is its time")
        };
        let tracking = f("get_status").call(&[]).await.unwrap()[0] == OwnedValue::U8(2);
        if module_now > last_point && !tracking {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "the move never ended (module time {module_now}, last point {last_point})"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let counts = emu.control(json!({"cmd": "counts"})).await;
    let load_after = emu.control(json!({"cmd": "stats"})).await;
    println!("step pins: {counts}");
    let steps = f("get_steps").call(&[]).await.unwrap();
    println!("firmware step counts: {steps:?}");
    let status = f("get_status").call(&[]).await.unwrap();
    let counters = f("get_counters").call(&[]).await.unwrap();
    println!("firmware status {status:?}, counters {counters:?}");
    let cycles = |s: &Value, k: &str| s[k].as_f64().unwrap_or(f64::NAN);
    let load = (cycles(&load_after, "cycles_executed") - cycles(&load_before, "cycles_executed"))
        / (cycles(&load_after, "cycles_total") - cycles(&load_before, "cycles_total"));
    println!(
        "CPU load while moving (emulated cycles executed / elapsed): {:.1} %",
        load * 100.0
    );
    let OwnedValue::U32(refused) = counters[1] else {
        panic!("{counters:?}")
    };
    Moved {
        counts,
        steps,
        refused,
        load,
    }
}

fn pct(sorted: &[Duration], p: f64) -> Duration {
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs the release firmware and node: scripts/emulator-test.sh runs it"]
async fn the_firmware_runs_on_an_emulated_rp2040() {
    let dir = std::env::temp_dir().join(format!("osap-emulator-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let flash = dir.join("flash.bin");
    let _ = std::fs::remove_file(&flash);
    let emu = Emulator::start(&flash).await;
    let host = Host::start(HostConfig::named("script")).unwrap();
    let link = join(&host, &emu).await;
    let route = Route::through_links(&[link.index()]).unwrap();
    let mut nr = Netrunner::new(&host).await.unwrap();
    // An emulated core runs slower than a real one while busy: be patient.
    nr.timeout = PATIENCE;

    // 1. It answers a scan, with every function of the module set.
    let name = module_name(&nr, &route).await;
    println!("module found: {name:?}");
    let options = ManagerOptions {
        scan: ScanOptions {
            timeout: PATIENCE,
            ..ScanOptions::default()
        },
        timeout: PATIENCE,
        retries: 2,
    };
    let mut m = Manager::with_options(&host, options).await.unwrap();
    let report = m.refresh().await.unwrap();
    assert!(
        report.function_failures.is_empty(),
        "{:?}",
        report.function_failures
    );
    let rt = m
        .som()
        .runtimes
        .iter()
        .find(|r| r.record.name == name)
        .expect("the module is in the model");
    for sig in SIGNATURES {
        assert!(
            rt.functions.iter().any(|f| f.name == sig.name),
            "{} missing from the scan",
            sig.name
        );
    }

    // 2. RPC round trips.
    let f = |fname: &str| m.function(&FnRef::new(&name, fname)).unwrap();
    let mut rtts = Vec::new();
    for k in 0..40 {
        let t = Instant::now();
        f("get_status")
            .call(&[])
            .await
            .unwrap_or_else(|e| panic!("call {k}: {e}"));
        rtts.push(t.elapsed());
    }
    rtts.sort();
    println!(
        "RPC round trip over emulated USB: median {:?}, p90 {:?}, max {:?}",
        pct(&rtts, 0.5),
        pct(&rtts, 0.9),
        rtts[rtts.len() - 1]
    );

    // 3. Its clock follows the host's.
    let goal = SyncGoal {
        max_offset: Duration::from_micros(500),
        quiet: Duration::from_secs(1),
        timeout: Duration::from_secs(60),
    };
    let started = Instant::now();
    let status = nr.wait_synchronised(&route, goal).await.unwrap();
    assert_eq!(status.state, SyncState::Synced);
    println!(
        "clock: settled within 500 µs after {:?}; offset estimate {} µs, rate {} ppb, min round trip {} µs",
        started.elapsed(),
        status.offset_ns / 1000,
        status.rate_ppb,
        status.min_rtt_us
    );
    // An independent check: limit-switch edges made by the bridge at known
    // instants, time-stamped by the module. The bridge paces emulated time
    // to wall time through an anchor, so every emulated instant stands for
    // one instant on the host's monotonic clock: the one the module's clock
    // must agree with. Each edge's stamp is compared with the host's time at
    // that instant. Emulator lag is not taken off: the module really is
    // behind then, and synchronization has to cope with it.
    let host_offset_ns = host_minus_monotonic_ns(&host).await;
    let mut errors = Vec::new();
    let mut behind = Vec::new();
    let (_, _, mut edges) = read_limit(&f("read_limit")).await;
    for k in 0..EDGE_CHECKS {
        // Pressed (low) and released (high) in turn.
        let level = k % 2;
        let answer = emu
            .control(json!({"cmd": "input", "pin": LIMIT_PIN, "level": level}))
            .await;
        assert_eq!(answer["ok"], json!(true), "{answer}");
        let at_ns: i128 = answer["monotonic_ns"]
            .as_str()
            .and_then(|t| t.parse().ok())
            .unwrap_or_else(|| panic!("no monotonic time in {answer}"));
        behind.push(answer["behind_ms"].as_f64().unwrap_or(0.0));
        let host_at_us = (at_ns + host_offset_ns) / 1000;
        let deadline = Instant::now() + PATIENCE;
        let stamp = loop {
            let (time, read_level, now_edges) = read_limit(&f("read_limit")).await;
            if now_edges != edges {
                assert_eq!(now_edges, edges.wrapping_add(1), "one edge per change");
                assert_eq!(read_level, level == 1);
                edges = now_edges;
                break time;
            }
            assert!(Instant::now() < deadline, "edge {k} never seen");
            tokio::time::sleep(Duration::from_millis(5)).await;
        };
        errors.push(stamp as i128 - host_at_us);
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    // Released: the pin follows its pull-up again.
    emu.control(json!({"cmd": "input", "pin": LIMIT_PIN, "level": null}))
        .await;
    let mut abs: Vec<i128> = errors.iter().map(|e| e.abs()).collect();
    abs.sort_unstable();
    let median = abs[abs.len() / 2];
    let p90 = abs[(abs.len() - 1) * 9 / 10];
    let worst = abs[abs.len() - 1];
    let most_behind = behind.iter().copied().fold(0.0f64, f64::max);
    println!(
        "clock error on {EDGE_CHECKS} limit edges (module stamp − host time of the edge): |median| {median} µs, p90 {p90} µs, worst {worst} µs; signed {errors:?}; emulator behind by up to {most_behind:.2} ms: {behind:.2?}"
    );
    // While the emulator is behind wall time by λ, the module's clock is
    // too: the error plus λ is what synchronization itself left.
    let mut residual: Vec<i128> = errors
        .iter()
        .zip(&behind)
        .map(|(e, b)| e + (b * 1000.0) as i128)
        .collect();
    residual.sort_unstable();
    let mid = residual[residual.len() / 2];
    let mut spread: Vec<i128> = residual.iter().map(|r| (r - mid).abs()).collect();
    spread.sort_unstable();
    println!(
        "error + emulator lag: median {mid} µs, within ±{} µs of it for 90 % of edges (±{} µs all)",
        spread[(spread.len() - 1) * 9 / 10],
        spread[spread.len() - 1]
    );
    assert!(
        median <= EMULATED_CLOCK_BOUND_US,
        "module time is {median} µs off the host's (median of {EDGE_CHECKS} edges)"
    );

    // 4. Motion: a smooth move of 2 units (160 full steps) stamped in
    // synchronized time, sent ahead; the step pins must show exactly it.
    f("set_enable")
        .call(&[OwnedValue::Bool(true)])
        .await
        .unwrap();
    let slow = smooth_move(&host, &emu, &f, 2048, 0.0, 2.0, 40).await;
    let expect = (2.0 * STEPS_PER_UNIT) as i64;
    assert_eq!(slow.counts["up"], json!(expect), "{}", slow.counts);
    assert_eq!(slow.counts["down"], json!(0), "{}", slow.counts);
    assert_eq!(slow.steps[0], OwnedValue::I64(expect), "{:?}", slow.steps);
    // Ticks that owed two steps (the steps still went out) are reported
    // above, not failed: a clock that jumped while the emulator caught up
    // makes some, which measures the emulator, not the firmware.
    assert_eq!(slow.refused, 0);

    // And faster: back to 0 at 2000 steps per unit (4 000 steps) in 0.6 s,
    // a peak of about 10 000 steps/s, with 16 ms between points. (The step
    // generator's ceiling is one step per two 10 µs ticks, 50 000/s; the
    // emulator's stalls make faster moves here catch up in bursts.)
    f("set_interval")
        .call(&[OwnedValue::U32(16_384)])
        .await
        .unwrap();
    f("set_scale")
        .call(&[OwnedValue::F32(2000.0)])
        .await
        .unwrap();
    let fast = smooth_move(&host, &emu, &f, 16_384, 2.0, 0.0, 36).await;
    // Net 4 000 steps down on the pins, and the firmware counted every
    // edge the pins show. (A clock correction while the emulator catches
    // up moves the target back a little: a few steps up and down again.)
    assert_eq!(fast.counts["position"], json!(-4_000), "{}", fast.counts);
    assert_eq!(fast.steps[0], OwnedValue::I64(0), "{:?}", fast.steps);
    assert_eq!(
        [fast.steps[1].clone(), fast.steps[2].clone()],
        [
            OwnedValue::U64(fast.counts["up"].as_u64().unwrap_or(u64::MAX)),
            OwnedValue::U64(fast.counts["down"].as_u64().unwrap_or(u64::MAX))
        ],
        "firmware {:?} against pins {}",
        fast.steps,
        fast.counts
    );
    assert_eq!(fast.refused, 0);
    let span_s = |c: &Value| {
        (c["last_edge_us"].as_f64().unwrap_or(0.0) - c["first_edge_us"].as_f64().unwrap_or(0.0))
            / 1e6
    };
    // A smoothstep's peak speed is 1.5 times its mean.
    let commanded_s = 36.0 * 16_384e-6;
    println!(
        "fast move: 4 000 steps commanded over {commanded_s:.3} s (peak {:.0} steps/s); on the pins over {:.3} s of emulated time (less when the module's clock caught up after the emulator fell behind: {:?} overruns); CPU load {:.1} % (slow move: {:.1} %)",
        1.5 * 4000.0 / commanded_s,
        span_s(&fast.counts),
        fast.steps[3],
        fast.load * 100.0,
        slow.load * 100.0
    );

    // 5. A new name survives a reset (written to the emulated flash).
    let rom_before = emu.control(json!({"cmd": "stats"})).await["rom_calls"].clone();
    let renamed = nr.set_name(&route, "x-axis").await.unwrap();
    assert_eq!(renamed, "x-axis");
    // The firmware writes the record just after it answers the rename,
    // through the boot ROM's flash routines: wait for those calls.
    let deadline = Instant::now() + Duration::from_secs(10);
    while emu.control(json!({"cmd": "stats"})).await["rom_calls"] == rom_before {
        assert!(
            Instant::now() < deadline,
            "the firmware never wrote its flash"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    tokio::time::sleep(Duration::from_millis(100)).await;
    let reset = emu.control(json!({"cmd": "reset"})).await;
    assert_eq!(reset["ok"], json!(true), "{reset}");
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        if let Ok(n) = nr.name(&route).await {
            if n == "x-axis" {
                break;
            }
            panic!("after a reset the module is named {n:?}, not \"x-axis\"");
        }
        assert!(Instant::now() < deadline, "the module never came back");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let stats = emu.control(json!({"cmd": "stats"})).await;
    println!("emulator: {stats}");
    let _ = std::fs::remove_dir_all(&dir);
}
