//! Scale: 32 steppers on four RS-485 buses behind hubs
//! (`topologies/bus32.toml`). Its scan completes in 2 s, in virtual time:
//! the scan walks the four buses side by side. That every clock is settled
//! (within 50 µs) 5 s after start is asserted too.
//!
//! `cargo test -p osap-sim --release --test bus32 -- --ignored --nocapture`
//! prints the growth curve (4, 8, 16, 32 modules) docs/performance.md
//! quotes.

use osap_host::netrunner::{scan, ScanOptions};
use osap_host::{Host, HostConfig};
use osap_sim::machine::{SimMachine, TimeMode};
use osap_sim::topology::{bus_tree, ModuleKind, SimSpec};
use std::time::Duration;
use tokio::time::Instant;

mod common;

/// How often the clocks are looked at (inside each module's task: no
/// network traffic).
const LOOK_EVERY: Duration = Duration::from_millis(10);

/// What one start of a bus tree came to.
struct Figures {
    modules: usize,
    runtimes: usize,
    /// The scan, started with the machine.
    scan: Duration,
    /// From the start until every clock said settled at once.
    settled: Option<Duration>,
    /// Looks after that at which some clock did not say settled, of all.
    unsettled_after: (usize, usize),
    /// Offsets and clock exchanges at the end: the largest offset any
    /// clock estimated, µs, and the drops' accepted and rejected samples.
    worst_offset_us: f64,
    accepted: u64,
    rejected: u64,
    /// The clocks not settled at the last look (module type, name, status).
    unsettled_at_end: Vec<String>,
    /// The largest offset any clock estimated at any look over the last
    /// 2 s of the run, µs.
    worst_offset_late_us: f64,
    /// The clock that first said settled last, and when (for the table).
    last_to_settle: Option<(String, Duration)>,
    /// Process CPU time over the run (the host and every simulated
    /// module: they run in this process).
    cpu: Duration,
    /// The run's virtual length.
    run: Duration,
}

/// This process's CPU time so far (user + system), from /proc.
fn cpu_time() -> Duration {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // Fields after the command's closing parenthesis; utime and stime are
    // the 14th and 15th of the whole line, in clock ticks (100 Hz).
    let rest = stat.rsplit(')').next().unwrap_or_default();
    let f: Vec<u64> = rest
        .split_whitespace()
        .map(|x| x.parse().unwrap_or(0))
        .collect();
    let ticks = f.get(11).copied().unwrap_or(0) + f.get(12).copied().unwrap_or(0);
    Duration::from_millis(ticks * 10)
}

/// Every module's clock status, by module order.
async fn statuses(sim: &SimMachine) -> Vec<osap_core::clock::ClockStatus> {
    let mut out = Vec::new();
    for m in sim.modules() {
        out.push(
            m.with_runtime(|rt, _| rt.clock().status())
                .await
                .expect("module runs"),
        );
    }
    out
}

/// Starts `spec` under a host, scans it at once, and watches every clock
/// for `run` of virtual time.
async fn measure(spec: &SimSpec, run: Duration, mode: TimeMode) -> Figures {
    let cpu0 = cpu_time();
    let host = Host::start(HostConfig::named("h")).unwrap();
    let t0 = Instant::now();
    let sim = SimMachine::start_with(&host, spec, mode).await.unwrap();
    let scanned = {
        let host = host.clone();
        tokio::spawn(async move {
            let r = scan(&host, &ScanOptions::default()).await.unwrap();
            (r, t0.elapsed())
        })
    };
    let mut settled = None;
    let mut unsettled_after = (0, 0);
    let mut last = Vec::new();
    let mut first_settled = vec![None; sim.modules().len()];
    let mut worst_late = 0f64;
    while t0.elapsed() < run {
        tokio::time::sleep(LOOK_EVERY).await;
        last = statuses(&sim).await;
        if t0.elapsed() + Duration::from_secs(2) >= run {
            for s in &last {
                worst_late = worst_late.max(s.offset_ns.unsigned_abs() as f64 / 1e3);
            }
        }
        for (first, s) in first_settled.iter_mut().zip(&last) {
            if first.is_none() && s.settled {
                *first = Some(t0.elapsed());
            }
        }
        let all = last.iter().all(|s| s.settled);
        match settled {
            None if all => settled = Some(t0.elapsed()),
            None => {}
            Some(_) => {
                unsettled_after.1 += 1;
                unsettled_after.0 += usize::from(!all);
            }
        }
    }
    // Which clocks were not settled at the last look, for the message.
    let unsettled_at_end = sim
        .modules()
        .iter()
        .zip(&last)
        .filter(|(_, s)| !s.settled)
        .map(|(m, s)| format!("{} {}: {s:?}", m.type_name(), m.name()))
        .collect();
    let last_to_settle = sim
        .modules()
        .iter()
        .zip(&first_settled)
        .filter_map(|(m, t)| t.map(|t| (m.name().to_string(), t)))
        .max_by_key(|(_, t)| *t);
    let (report, scan_time) = scanned.await.unwrap();
    assert!(report.failures.is_empty(), "{:?}", report.failures);
    let worst_offset_us = last
        .iter()
        .map(|s| s.offset_ns.unsigned_abs() as f64 / 1e3)
        .fold(0.0, f64::max);
    let drops = || {
        sim.modules()
            .iter()
            .zip(&last)
            .filter(|(m, _)| m.type_name() != "hub")
            .map(|(_, s)| s)
    };
    let accepted = drops().map(|s| u64::from(s.stats.accepted)).sum();
    let rejected = drops()
        .map(|s| u64::from(s.stats.rejected_rtt) + u64::from(s.stats.rejected_residual))
        .sum();
    let figures = Figures {
        modules: spec
            .modules
            .iter()
            .filter(|m| m.kind() == Some(ModuleKind::Stepper))
            .count(),
        runtimes: report.map.runtimes.len(),
        scan: scan_time,
        settled,
        unsettled_after,
        worst_offset_us,
        accepted,
        rejected,
        unsettled_at_end,
        last_to_settle,
        worst_offset_late_us: worst_late,
        cpu: cpu_time().saturating_sub(cpu0),
        run,
    };
    sim.stop().await.unwrap();
    figures
}

/// [`measure`] in virtual time, or with `OSAP_BUS_REAL_TIME=1` in real
/// time (2 tokio workers; frames timed to the µs on the wire thread).
fn run(spec: &SimSpec, length: Duration) -> Figures {
    common::on_bus_runtime(|mode| measure(spec, length, mode))
}

fn print(f: &Figures) {
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    println!(
        "| {} | {} | {:.0} | {} | {} | {}/{} | {:.1} | {:.1} | {} / {} | {:.2} |",
        f.modules,
        f.runtimes,
        ms(f.scan),
        f.settled
            .map_or("never".into(), |d| format!("{:.0}", ms(d))),
        f.last_to_settle
            .as_ref()
            .map_or("none".into(), |(name, d)| format!("{name} {:.0}", ms(*d))),
        f.unsettled_after.0,
        f.unsettled_after.1,
        f.worst_offset_us,
        f.worst_offset_late_us,
        f.accepted,
        f.rejected,
        f.cpu.as_secs_f64() / f.run.as_secs_f64(),
    );
}

const HEADER: &str = "| modules | runtimes | scan ms | all settled ms | last clock to say settled, ms | looks unsettled after / looks | worst offset µs at end | worst offset µs, last 2 s | drops' samples accepted / rejected | process CPU s per virtual s |\n|---|---|---|---|---|---|---|---|---|---|";

#[test]
fn bus32_toml_is_the_bus_tree_of_four_by_eight() {
    let file = SimSpec::load(common::shipped("bus32.toml")).unwrap();
    assert_eq!(file, bus_tree(4, 8).unwrap());
    assert_eq!(file.modules.len(), 37);
    assert_eq!(file.buses.len(), 4);
}

fn bus32() -> Figures {
    let spec = SimSpec::load(common::shipped("bus32.toml")).unwrap();
    let f = run(&spec, Duration::from_secs(6));
    println!("{HEADER}");
    print(&f);
    f
}

#[test]
fn bus32_scans_within_2_s() {
    let f = bus32();
    assert_eq!(f.runtimes, 38, "host, root, 4 hubs and 32 drops");
    assert!(f.scan <= Duration::from_secs(2), "scan {:?}", f.scan);
}

/// Every clock says settled within 5 s of start and stays so: the root
/// hub on USB by the rate its one-way envelopes learned (its fit's scatter
/// never lets a slope be trusted there), a hub that asks twice an interval
/// by its full fit window's rate, the rest by a trusted fitted slope
/// (docs/performance.md, "Scale: clocks on bus32 (settle)"). Before, the
/// first two never did.
#[test]
fn bus32_clocks_settle_within_5_s() {
    let f = bus32();
    let settled = f
        .settled
        .unwrap_or_else(|| panic!("not every clock settled: {:#?}", f.unsettled_at_end));
    assert!(settled <= Duration::from_secs(5), "settled at {settled:?}");
    // Once settled, they stay so (a clock that left it would be caught
    // by most looks of the last second).
    assert!(
        f.unsettled_after.0 * 10 <= f.unsettled_after.1,
        "unsettled at {} of {} looks after settling",
        f.unsettled_after.0,
        f.unsettled_after.1
    );
}

/// The growth curve: 4, 8, 16 and 32 modules on buses of up to 8 drops.
#[test]
#[ignore = "prints docs/performance.md's scale curve; about a minute in release"]
fn growth_curve() {
    println!("{HEADER}");
    for (buses, drops) in [(1, 4), (1, 8), (2, 8), (4, 8)] {
        let spec = bus_tree(buses, drops).unwrap();
        let f = run(&spec, Duration::from_secs(8));
        print(&f);
    }
}
