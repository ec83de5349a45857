//! Simulated machines in virtual time: a CoreXY job runs faster than real
//! time, and the same seed gives the same steps.

#[path = "../benches/corexy_job.rs"]
mod corexy_job;

use osap_sim::machine::{virtual_runtime, TimeMode};
use std::time::Instant;

fn job(seconds: f64, seed: u64) -> corexy_job::JobRun {
    virtual_runtime()
        .expect("a current-thread runtime")
        .block_on(corexy_job::run(seconds, seed, TimeMode::Virtual))
}

#[test]
fn one_seed_gives_the_same_step_edges() {
    let wall = Instant::now();
    let first = job(3.0, 7);
    let wall_s = wall.elapsed().as_secs_f64();
    let second = job(3.0, 7);
    for (motor, (x, y)) in ["a", "b"].iter().zip(first.edges.iter().zip(&second.edges)) {
        assert!(x.len() > 1000, "{motor} made only {} steps", x.len());
        assert_eq!(x.len(), y.len(), "{motor}: step counts differ");
        let first_difference = x.iter().zip(y).position(|(p, q)| p != q);
        assert_eq!(first_difference, None, "{motor}: step edges differ");
    }
    assert_eq!(first.faults, 0);
    assert_eq!(first.refused, 0);
    eprintln!(
        "{:.1} s simulated in {wall_s:.2} s of wall time ({:.0}x); {} + {} steps",
        first.simulated_s,
        first.simulated_s / wall_s,
        first.edges[0].len(),
        first.edges[1].len()
    );
    // Far faster than real time even on a loaded 2-core machine.
    assert!(
        first.simulated_s > wall_s,
        "virtual time ran slower than real time"
    );
}
