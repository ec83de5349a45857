//! A 60 s CoreXY motion job on simulated modules in virtual time: how much
//! faster than real time it runs. `cargo bench -p osap-sim --bench
//! virtual_time` (optionally `-- SECONDS`; `-- --test` or `-- --quick` runs
//! a 3 s job and checks it, as CI does for every benchmark).

mod corexy_job;

use osap_sim::machine::{virtual_runtime, TimeMode};
use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let quick = args.iter().any(|a| a == "--test" || a == "--quick");
    let seconds: f64 = args
        .iter()
        .find_map(|a| a.parse().ok())
        .unwrap_or(if quick { 3.0 } else { 60.0 });
    let wall = Instant::now();
    let run = virtual_runtime()
        .expect("a current-thread runtime")
        .block_on(corexy_job::run(seconds, 1, TimeMode::Virtual));
    let wall_s = wall.elapsed().as_secs_f64();
    println!(
        "virtual time: a {seconds:.0} s CoreXY job ({:.1} s simulated from its first line to its last step, {} + {} steps, {} faults, {} refused) ran in {wall_s:.2} s of wall time: {:.1}x real time",
        run.simulated_s,
        run.edges[0].len(),
        run.edges[1].len(),
        run.faults,
        run.refused,
        run.simulated_s / wall_s
    );
    // The job draws whole squares on both belts with every point accepted:
    // a run that lost its motion or its modules should fail, not print a
    // rate.
    assert!(
        run.faults == 0 && run.refused == 0,
        "{} faults, {} refused points",
        run.faults,
        run.refused
    );
    assert!(
        !run.edges[0].is_empty() && !run.edges[1].is_empty(),
        "both motors stepped"
    );
    assert!(
        run.simulated_s >= seconds,
        "the job ran its {seconds} s ({:.1} s)",
        run.simulated_s
    );
}
