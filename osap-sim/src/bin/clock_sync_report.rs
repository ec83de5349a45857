//! Clock-sync benchmark: runs chain4, star8 and loop from a cold start, a
//! hot start and with busy modules, and reports convergence, steady-state
//! error and spikes as a markdown table, with an SVG plot per run.
//!
//! ```text
//! cargo run --release -p osap-sim --features plot --bin clock_sync_report -- \
//!     [--minutes 10] [--seed 1] [--out DIR (default examples-out/clock-sync)] \
//!     [--topologies chain4,star8,loop] [--variants cold,hot,busy] [--jobs 2]
//! ```
//!
//! A topology is a built-in name (`chain<N>`, `star<N>`, `tree<D>x<F>`,
//! `loop`) or the path of a TOML topology file, the format the simulated
//! machines read (`osap-sim/topologies/*.toml`; see
//! `osap_sim::from_spec`), e.g. `--topologies
//! chain4,osap-sim/topologies/uart-chain.toml`. Runs use `--seed`, not a
//! file's `seed`.

use osap_sim::busy::BusyModel;
use osap_sim::metrics::Stats;
use osap_sim::plot::plot_errors;
use osap_sim::{Network, Scenario, SimError};
use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Mutex;

/// Targets: p99 of the error one hop adds.
const UART_HOP_P99_US: f64 = 5.0;
const USB_HOP_P99_US: f64 = 50.0;
/// Target: no spike beyond this with busy modules.
const BUSY_SPIKE_US: f64 = 100.0;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Variant {
    Cold,
    Hot,
    Busy,
}

impl Variant {
    fn name(self) -> &'static str {
        match self {
            Variant::Cold => "cold",
            Variant::Hot => "hot",
            Variant::Busy => "busy",
        }
    }

    fn label(self) -> &'static str {
        match self {
            Variant::Cold => "cold start",
            Variant::Hot => "hot start",
            Variant::Busy => "busy modules, cold start",
        }
    }

    fn parse(s: &str) -> Result<Self, String> {
        match s {
            "cold" => Ok(Variant::Cold),
            "hot" => Ok(Variant::Hot),
            "busy" => Ok(Variant::Busy),
            _ => Err(format!("unknown variant {s:?}: expected cold, hot or busy")),
        }
    }
}

struct Args {
    minutes: f64,
    seed: u64,
    out: PathBuf,
    topologies: Vec<String>,
    variants: Vec<Variant>,
    jobs: usize,
}

const USAGE: &str = "usage: clock_sync_report [--minutes M] [--seed N] [--out DIR] \
[--topologies chain4,star8,loop|FILE.toml,...] [--variants cold,hot,busy] [--jobs N]";

fn parse_args() -> Result<Args, String> {
    let mut args = Args {
        minutes: 10.0,
        seed: 1,
        out: PathBuf::from("examples-out/clock-sync"),
        topologies: vec!["chain4".into(), "star8".into(), "loop".into()],
        variants: vec![Variant::Cold, Variant::Hot, Variant::Busy],
        jobs: 2,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        if flag == "--help" || flag == "-h" {
            return Err(USAGE.into());
        }
        let value = it
            .next()
            .ok_or_else(|| format!("{flag} needs a value\n{USAGE}"))?;
        let bad = |what: &str| format!("{flag} {value}: expected {what}");
        match flag.as_str() {
            "--minutes" => {
                args.minutes = value
                    .parse()
                    .ok()
                    .filter(|m: &f64| m.is_finite() && *m > 0.0)
                    .ok_or_else(|| bad("a positive number"))?
            }
            "--seed" => args.seed = value.parse().map_err(|_| bad("an integer"))?,
            "--out" => args.out = PathBuf::from(&value),
            "--topologies" => args.topologies = value.split(',').map(str::to_string).collect(),
            "--variants" => {
                args.variants = value
                    .split(',')
                    .map(Variant::parse)
                    .collect::<Result<_, _>>()?
            }
            "--jobs" => {
                args.jobs = value
                    .parse()
                    .ok()
                    .filter(|&j| j >= 1)
                    .ok_or_else(|| bad("an integer >= 1"))?
            }
            _ => return Err(format!("unknown option {flag}\n{USAGE}")),
        }
    }
    Ok(args)
}

/// What one run measured.
struct Row {
    topology: String,
    variant: Variant,
    hot_applied: bool,
    conv50: Option<f64>,
    conv10: Option<f64>,
    /// Start of the steady-state window, s, and whether it is after
    /// convergence (otherwise it is the second half of the run).
    window: (f64, bool),
    pooled: Stats,
    uart: Option<Stats>,
    usb: Option<Stats>,
    speed: f64,
    plot: String,
}

/// A built-in topology by name, or one described in a TOML topology file.
fn load(name: &str) -> Result<Network, SimError> {
    let path = std::path::Path::new(name);
    if path.extension().is_some_and(|e| e == "topo") {
        return Err(SimError::config(format!(
            "{name}: the text topology format is gone; topologies are TOML files \
             (osap-sim/topologies/*.toml, see osap_sim::from_spec)"
        )));
    }
    if path.is_file() {
        return Network::load(path);
    }
    Network::named(name)
}

fn run_one(args: &Args, topology: &str, variant: Variant) -> Result<Row, SimError> {
    let loaded = load(topology)?;
    // Files are named after the description's own name.
    let topology = loaded.name.clone();
    let topology = topology.as_str();
    let mut scenario = Scenario::new(loaded)
        .seed(args.seed)
        .seconds(args.minutes * 60.0);
    match variant {
        Variant::Cold => {}
        Variant::Hot => scenario = scenario.hot_start(true),
        Variant::Busy => scenario = scenario.busy_modules(BusyModel::MOTOR),
    }
    let outcome = scenario.run()?;
    let m = &outcome.metrics;
    let summary = m.summary();
    let window = (summary.window_from_s, summary.window_after_convergence);
    let file = format!("{topology}-{}.svg", variant.name());
    let title = format!("{topology}, {}, seed {}", variant.label(), args.seed);
    plot_errors(&args.out.join(&file), &title, m, window.0)?;
    Ok(Row {
        topology: topology.to_string(),
        variant,
        hot_applied: outcome.hot_start_applied,
        conv50: summary.converged_50us_s,
        conv10: summary.converged_10us_s,
        window,
        pooled: summary.error,
        uart: summary.uart_hops,
        usb: summary.usb_hops,
        speed: outcome.speed(),
        plot: file,
    })
}

fn secs(t: Option<f64>) -> String {
    t.map_or("never".into(), |t| format!("{t:.2}"))
}

fn hop(s: &Option<Stats>) -> String {
    s.map_or("–".into(), |s| format!("{:.1} / {:.1}", s.p99, s.max))
}

fn verdict(row: &Row) -> String {
    let mut notes = Vec::new();
    if !row.window.1 {
        notes.push("not converged to 50 µs".to_string());
    }
    if let Some(u) = row.uart.filter(|u| u.p99 >= UART_HOP_P99_US) {
        notes.push(format!("UART hop p99 {:.1} ≥ {UART_HOP_P99_US}", u.p99));
    }
    if let Some(u) = row.usb.filter(|u| u.p99 >= USB_HOP_P99_US) {
        notes.push(format!("USB hop p99 {:.1} ≥ {USB_HOP_P99_US}", u.p99));
    }
    if row.variant == Variant::Busy && row.pooled.max > BUSY_SPIKE_US {
        notes.push(format!("spike {:.0} > {BUSY_SPIKE_US}", row.pooled.max));
    }
    if row.variant == Variant::Hot && !row.hot_applied {
        notes.push("hot start not applied".to_string());
    }
    if notes.is_empty() {
        "pass".into()
    } else {
        notes.join("; ")
    }
}

fn table(args: &Args, rows: &[Row]) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "Clock sync, {} simulated minutes per run, seed {}. Errors are each node's \
         system time minus the root's, sampled every 10 ms of true time; statistics \
         are over all non-root nodes from the time every node stayed within 50 µs \
         (or over the second half of the run if that never happened). A hop's error \
         is a node's error minus its parent's (the neighbour one hop nearer the root). \
         Targets: UART hop p99 < {UART_HOP_P99_US} µs, USB hop p99 < {USB_HOP_P99_US} µs, \
         no spike > {BUSY_SPIKE_US} µs with busy modules.\n",
        args.minutes, args.seed
    );
    s.push_str(
        "| topology | start | to 50 µs (s) | to 10 µs (s) | \\|err\\| p50 (µs) | p99 | max (spike) | UART hop p99 / max | USB hop p99 / max | result | plot |\n",
    );
    s.push_str("|---|---|---|---|---|---|---|---|---|---|---|\n");
    for r in rows {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {:.1} | {:.1} | {:.1} | {} | {} | {} | [svg]({}) |",
            r.topology,
            r.variant.name(),
            secs(r.conv50),
            secs(r.conv10),
            r.pooled.p50,
            r.pooled.p99,
            r.pooled.max,
            hop(&r.uart),
            hop(&r.usb),
            verdict(r),
            r.plot
        );
    }
    s
}

fn main() -> ExitCode {
    let args = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("{e}");
            return ExitCode::from(2);
        }
    };
    // Check the topology names before spending time on runs.
    for t in &args.topologies {
        if let Err(e) = load(t) {
            eprintln!("{e}");
            return ExitCode::from(2);
        }
    }
    if let Err(e) = std::fs::create_dir_all(&args.out) {
        eprintln!("cannot create {}: {e}", args.out.display());
        return ExitCode::FAILURE;
    }
    let jobs: Vec<(usize, &str, Variant)> = args
        .topologies
        .iter()
        .flat_map(|t| args.variants.iter().map(move |&v| (t.as_str(), v)))
        .enumerate()
        .map(|(i, (t, v))| (i, t, v))
        .collect();
    let queue = Mutex::new(jobs.clone());
    let results = Mutex::new(Vec::new());
    let started = std::time::Instant::now();
    std::thread::scope(|s| {
        for _ in 0..args.jobs.min(jobs.len()).max(1) {
            s.spawn(|| loop {
                let job = queue.lock().map(|mut q| q.pop()).ok().flatten();
                let Some((i, topology, variant)) = job else {
                    break;
                };
                let row = run_one(&args, topology, variant);
                if let Ok(r) = &row {
                    eprintln!(
                        "{topology} {}: done, {:.0}x real time",
                        variant.name(),
                        r.speed
                    );
                }
                if let Ok(mut out) = results.lock() {
                    out.push((i, row));
                }
            });
        }
    });
    let mut results = results.into_inner().unwrap_or_default();
    results.sort_by_key(|(i, _)| *i);
    let mut rows = Vec::new();
    for (_, r) in results {
        match r {
            Ok(r) => rows.push(r),
            Err(e) => {
                eprintln!("run failed: {e}");
                return ExitCode::FAILURE;
            }
        }
    }
    let report = table(&args, &rows);
    println!("{report}");
    eprintln!(
        "{} runs in {:.1} s wall",
        rows.len(),
        started.elapsed().as_secs_f64()
    );
    let path = args.out.join("report.md");
    if let Err(e) = std::fs::write(&path, &report) {
        eprintln!("cannot write {}: {e}", path.display());
        return ExitCode::FAILURE;
    }
    ExitCode::SUCCESS
}
