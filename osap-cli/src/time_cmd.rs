//! `osap time`: every runtime's clock-sync status, once or every interval,
//! as a table or as JSON lines.

use crate::{connect, scan, Connect};
use clap::Args;
use osap_core::clock::{ClockStatus, SyncState, TIER_UNSYNCED};
use osap_host::map::NetworkMap;
use osap_host::netrunner::Netrunner;
use std::process::ExitCode;
use std::time::{Duration, Instant};

/// The arguments of `osap time`.
#[derive(Args, Clone)]
pub(crate) struct TimeArgs {
    #[command(flatten)]
    pub connect: Connect,
    /// Reprint every interval until Ctrl-C.
    #[arg(short = 'w', long)]
    pub watch: bool,
    /// The interval of --watch, ms.
    #[arg(long, value_name = "MS", default_value_t = 1000)]
    pub interval: u64,
    /// Print one JSON object per runtime and sample instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// One runtime's reading in one round.
struct Sample {
    name: String,
    route: String,
    status: Result<ClockStatus, String>,
}

/// Runs `osap time`. Exits 1 when a runtime could not be read (in the
/// last round, with `--watch`).
pub(crate) async fn time(args: TimeArgs) -> Result<ExitCode, String> {
    let c = connect(&args.connect).await?;
    let report = scan(&c, 2).await?;
    for f in &report.failures {
        let hops: Vec<String> = f.route.iter().map(u8::to_string).collect();
        eprintln!("warning: route {}: {}", hops.join(","), f.error);
    }
    let mut runner = Netrunner::new(&c.host).await.map_err(|e| e.to_string())?;
    runner.timeout = c.timeout;
    let started = Instant::now();
    let interval = Duration::from_millis(args.interval.max(10));
    loop {
        let round = read_all(&runner, &report.map).await;
        let failed = round.iter().filter(|s| s.status.is_err()).count() + report.failures.len();
        let t = started.elapsed().as_secs_f64();
        if args.json {
            for s in &round {
                println!("{}", json_line(t, s));
            }
        } else {
            if args.watch {
                println!("-- {t:.1} s");
            }
            print_table(&round);
        }
        if !args.watch {
            return Ok(exit_code(failed));
        }
        tokio::select! {
            signal = tokio::signal::ctrl_c() => {
                signal.map_err(|e| format!("cannot wait for Ctrl-C: {e}"))?;
                return Ok(exit_code(failed));
            }
            _ = tokio::time::sleep(interval) => {}
        }
    }
}

fn exit_code(failed: usize) -> ExitCode {
    if failed == 0 {
        ExitCode::SUCCESS
    } else {
        eprintln!(
            "{failed} runtime(s) could not be read: check their links, or raise --timeout-ms"
        );
        ExitCode::FAILURE
    }
}

async fn read_all(runner: &Netrunner, map: &NetworkMap) -> Vec<Sample> {
    let mut out = Vec::with_capacity(map.runtimes.len());
    for r in &map.runtimes {
        let route = r.route();
        out.push(Sample {
            name: r.name.clone(),
            route: route.to_string(),
            status: runner.clock_status(&route).await.map_err(|e| e.to_string()),
        });
    }
    out
}

fn state_name(state: SyncState) -> &'static str {
    match state {
        SyncState::Root => "root",
        SyncState::Synced => "synced",
        SyncState::Holdover => "holdover",
        SyncState::Unsynced => "unsynced",
    }
}

fn print_table(round: &[Sample]) {
    println!(
        "{:<16} {:>4} {:<9} {:<7} {:>11} {:>10} {:>7} {:>8} {:>8} {:>5} {:>9}",
        "runtime",
        "tier",
        "state",
        "settled",
        "offset µs",
        "rate ppm",
        "rtt µs",
        "accepted",
        "rejected",
        "jumps",
        "untrusted"
    );
    for s in round {
        match &s.status {
            Ok(st) => println!(
                "{:<16} {:>4} {:<9} {:<7} {:>11.1} {:>10.3} {:>7} {:>8} {:>8} {:>5} {:>9}",
                s.name,
                if st.tier == TIER_UNSYNCED {
                    "-".into()
                } else {
                    st.tier.to_string()
                },
                state_name(st.state),
                if st.settled { "yes" } else { "no" },
                st.offset_ns as f64 / 1000.0,
                f64::from(st.rate_ppb) / 1000.0,
                st.min_rtt_us,
                st.stats.accepted,
                st.stats.rejected_rtt + st.stats.rejected_residual,
                st.stats.jumps,
                st.stats.untrusted
            ),
            Err(e) => println!("{:<16} unreadable: {e}", s.name),
        }
    }
}

/// One sample as a JSON object: `t_s` (seconds since the first round),
/// the runtime's name and route, and its status or `error`.
fn json_line(t: f64, s: &Sample) -> serde_json::Value {
    let mut v = serde_json::json!({
        "t_s": (t * 1000.0).round() / 1000.0,
        "runtime": s.name,
        "route": s.route,
    });
    match &s.status {
        Ok(st) => {
            let fields = serde_json::json!({
                "tier": (st.tier != TIER_UNSYNCED).then_some(st.tier),
                "state": state_name(st.state),
                "settled": st.settled,
                "motion_active": st.motion_active,
                "offset_us": st.offset_ns as f64 / 1000.0,
                "rate_ppm": f64::from(st.rate_ppb) / 1000.0,
                "following": st.following,
                "last_rtt_us": st.last_rtt_us,
                "min_rtt_us": st.min_rtt_us,
                "samples": st.stats.samples,
                "accepted": st.stats.accepted,
                "rejected_rtt": st.stats.rejected_rtt,
                "rejected_residual": st.stats.rejected_residual,
                "bogus": st.stats.bogus,
                "jumps": st.stats.jumps,
                "untrusted": st.stats.untrusted,
                "deferred_steps": st.stats.deferred_steps,
            });
            if let (Some(obj), serde_json::Value::Object(more)) = (v.as_object_mut(), fields) {
                obj.extend(more);
            }
        }
        Err(e) => v["error"] = serde_json::Value::String(e.clone()),
    }
    v
}
