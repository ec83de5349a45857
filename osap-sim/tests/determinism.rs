//! Same seed, same run; another seed, another run.

mod common;

use osap_sim::{Network, Sim};

fn fingerprint(seed: u64) -> (Sim, Vec<u32>) {
    let mut sim = common::traced(&Network::star8(), seed);
    sim.run_secs(3.0);
    let counters = sim
        .nodes()
        .iter()
        .flat_map(|n| {
            let c = n.runtime().counters();
            [c.received, c.forwarded, c.system, c.expired, c.dropped()]
        })
        .collect();
    (sim, counters)
}

#[test]
fn same_seed_gives_the_same_trace() {
    let (a, ca) = fingerprint(42);
    let (b, cb) = fingerprint(42);
    assert!(a.frames().len() > 100, "too little traffic to compare");
    assert_eq!(a.events(), b.events());
    assert_eq!(a.frames(), b.frames());
    assert_eq!(a.metrics(), b.metrics());
    assert_eq!(ca, cb);
}

#[test]
fn another_seed_gives_another_trace() {
    let (a, _) = fingerprint(1);
    let (b, _) = fingerprint(2);
    assert_ne!(a.frames(), b.frames());
    assert_ne!(a.metrics().error_us, b.metrics().error_us);
}
