//! Points never overtake: motion over host → `osap serve` → hub → module,
//! in real time, while one busy thread spins on a core.
//!
//! `osap serve --sim examples/machines/mill.toml` runs in its own process,
//! as a user runs it; this test's process is the script's host
//! (`Machine::connect` over TCP) and keeps queueing moves for the whole run.
//! Each hop rebuilds a packet's deadline from its own arrival, so a point
//! sent after a scheduling delay can carry an earlier deadline than the one
//! before it; the stacks must still hand one stream's points on in the
//! order they came (docs/protocol.md §8). Any point the module refuses as
//! stale or as a gap stops the machine, and the module's own counters must
//! show no refused point and no filled one.
//!
//! CI runs 2 minutes of motion; `OSAP_ORDER_SOAK_SECS` sets another
//! length (600 for the 10-minute run docs/protocol.md reports).

mod common;

use osap_host::som::FnRef;
use osap_machine::config::MachineFile;
use osap_machine::machine::Link;
use osap_machine::{FaultKind, Machine, MachineError, MachineEvent};
use osap_module::stepper::StepperError;
use pipes_core::Value;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::broadcast;

/// Seconds of motion in CI.
const CI_SECS: u64 = 120;

fn mill_file() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../examples/machines/mill.toml")
}

fn soak_secs() -> u64 {
    match std::env::var("OSAP_ORDER_SOAK_SECS") {
        Ok(s) => s
            .parse()
            .unwrap_or_else(|_| panic!("OSAP_ORDER_SOAK_SECS={s:?} is not whole seconds")),
        Err(_) => CI_SECS,
    }
}

/// A thread that spins on a core until dropped: it competes with the
/// server's and this host's tasks for the CPU.
struct Busy {
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<u64>>,
}

impl Busy {
    fn start() -> Busy {
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        let thread = std::thread::spawn(move || {
            let mut spins = 0u64;
            while !flag.load(Ordering::Relaxed) {
                spins = spins.wrapping_add(1);
                std::hint::spin_loop();
            }
            spins
        });
        Busy {
            stop,
            thread: Some(thread),
        }
    }
}

impl Drop for Busy {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// What the modules' `get_counters` say, summed over the three.
#[derive(Debug, Default, Clone)]
struct Counters {
    points: u64,
    refused: u64,
    filled: u64,
    /// Per module: its four counters as read.
    each: Vec<(String, [u64; 4])>,
}

/// Refusals the machine's events reported, by cause; a fault reported
/// again (the module repeats its latest fault) is counted once.
#[derive(Debug, Default)]
struct Heard {
    stale: u64,
    gap: u64,
    other: Vec<String>,
    lagged: u64,
    seen: std::collections::BTreeSet<(String, u8, u32, u64)>,
}

fn listen(heard: &mut Heard, events: &mut broadcast::Receiver<MachineEvent>) {
    let stale = u32::from(StepperError::Stale.code());
    let gap = u32::from(StepperError::Gap.code());
    loop {
        match events.try_recv() {
            Ok(MachineEvent::Fault {
                module,
                kind,
                detail,
                time,
                reason,
            }) => {
                if !heard
                    .seen
                    .insert((module.clone(), kind as u8, detail, time))
                {
                    continue;
                }
                match kind {
                    FaultKind::Refused if detail == stale => heard.stale += 1,
                    FaultKind::Refused if detail == gap => heard.gap += 1,
                    _ => heard.other.push(format!("{module}: {reason}")),
                }
            }
            Ok(MachineEvent::LinkLost { module }) => heard.other.push(format!("{module}: lost")),
            Ok(_) => {}
            Err(broadcast::error::TryRecvError::Lagged(n)) => heard.lagged += n,
            Err(_) => return,
        }
    }
}

/// Reads the three modules' `get_counters` (a read: asked again if its
/// reply is lost, as the machine asks its own reads).
async fn counters(m: &Machine) -> Result<Counters, MachineError> {
    let mut sum = Counters::default();
    for key in ["x", "y", "z"] {
        let runtime = m.modules()[key].runtime.clone();
        let f = m
            .manager()
            .lock()
            .await
            .function(&FnRef::new(runtime.as_str(), "get_counters"))?;
        let out = f
            .call_idempotent(&[])
            .await
            .map_err(|e| MachineError::Unsupported(format!("get_counters on {key}: {e}")))?;
        let n = |i: usize| out.get(i).and_then(Value::as_f64).unwrap_or(f64::NAN) as u64;
        sum.points += n(0);
        sum.refused += n(1);
        sum.filled += n(3);
        sum.each.push((key.to_string(), [n(0), n(1), n(2), n(3)]));
    }
    Ok(sum)
}

/// `osap scan -v` of the served machine: every runtime's link counters.
fn scan(addr: &str) -> String {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_osap"))
        .args(["scan", "-v", "--tcp", addr])
        .output()
        .unwrap();
    format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

/// A rectangle in x and y with z stepping between two heights: every motor
/// gets a changing point every interval.
const PATH: [[f64; 3]; 4] = [
    [120.0, 80.0, -10.0],
    [180.0, 80.0, -6.0],
    [180.0, 120.0, -10.0],
    [120.0, 120.0, -6.0],
];

#[test]
fn points_reach_the_module_in_order_through_serve() {
    let secs = soak_secs();
    let (_server, addr) = common::serve(&mill_file());
    let cfg = MachineFile::load(mill_file()).unwrap();
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async move {
        let m = Machine::connect(&cfg, &[Link::Tcp(addr.clone())])
            .await
            .unwrap();
        // The busy thread competes with the motion, not with the set-up.
        let busy = Busy::start();
        let mut events = m.events();
        let mut heard = Heard::default();
        let before = counters(&m).await.unwrap();
        m.set_position([120.0, 120.0, -6.0]).unwrap();
        let started = Instant::now();
        let mut moves = 0u64;
        let mut ran: Result<(), MachineError> = Ok(());
        'run: while started.elapsed() < Duration::from_secs(secs) {
            // A few rectangles ahead of the motors, so the run ends about
            // when asked (the queue would take thousands of moves).
            if let Err(e) = m.wait_queued_at_most(2 * PATH.len()).await {
                ran = Err(e);
                break 'run;
            }
            for (k, p) in PATH.iter().enumerate() {
                // Two speeds, so the stream holds cruises and corners.
                let rate = if k % 2 == 0 { 45.0 } else { 25.0 };
                if let Err(e) = m.goto_via_queue(p, rate).await {
                    ran = Err(e);
                    break 'run;
                }
                moves += 1;
                listen(&mut heard, &mut events);
            }
        }
        if ran.is_ok() {
            ran = m.idle().await;
        }
        let elapsed = started.elapsed();
        listen(&mut heard, &mut events);
        let after = counters(&m).await.unwrap_or_else(|e| {
            panic!(
                "after {:.1} s of motion ({ran:?}; {heard:?}) the counters: {e}",
                elapsed.as_secs_f64()
            )
        });
        let points = after.points - before.points;
        let refused = after.refused - before.refused;
        let filled = after.filled - before.filled;
        eprintln!(
            "served motion: {secs} s asked, {:.1} s run, {moves} moves, {points} points \
             accepted by 3 modules, {refused} refused (events: {} stale, {} gap), \
             {filled} filled; other faults: {:?}; modules (points, refused, last code, \
             filled): {:?}",
            elapsed.as_secs_f64(),
            heard.stale,
            heard.gap,
            heard.other,
            after.each
        );
        let mut result = format!(
            "{ran:?}: {refused} refused ({} stale, {} gap), {filled} filled, other {:?}",
            heard.stale, heard.gap, heard.other
        );
        if ran.is_err() || refused > 0 || filled > 0 {
            // Where packets went: each runtime's per-link counts.
            result.push_str(&format!("\nthe network's counters:\n{}", scan(&addr)));
        }
        assert!(ran.is_ok(), "{result}");
        assert_eq!(heard.lagged, 0, "the event stream lagged: {result}");
        assert_eq!((heard.stale, heard.gap), (0, 0), "{result}");
        assert_eq!(refused, 0, "{result}");
        assert_eq!(filled, 0, "{result}");
        assert!(heard.other.is_empty(), "{result}");
        // Every interval of the run reached each of the three modules: the
        // motion never stopped between moves (each motor is fed a point per
        // 2.048 ms interval while the queue holds moves).
        let intervals = elapsed.as_secs_f64() / 2.048e-3;
        assert!(
            points as f64 >= 3.0 * intervals * 0.95,
            "{points} points over {intervals:.0} intervals: the stream ran dry"
        );
        drop(busy);
        m.stop().await.unwrap();
    });
}
