//! The function cache (`osap_host::som::SomCache`): a refresh of a network
//! whose module builds the cache knows takes their ports and built
//! functions' signatures from it and builds the same model as a refresh
//! that asks everything; a module that reports another build than the
//! cache holds (another function-set id) is read in full, never taken
//! stale.

use osap_host::som::{Manager, Som, SomCache};
use osap_sim::machine::SimMachine;
use osap_sim::topology::SimSpec;

mod common;

/// Per runtime: its name, ports and functions (what the cache stands in
/// for; tiers and the like change between scans).
fn read_parts(som: &Som) -> Vec<(String, String, usize, Vec<String>)> {
    som.runtimes
        .iter()
        .map(|r| {
            (
                r.record.name.clone(),
                format!("{:?}", r.record.ports),
                r.functions.len(),
                r.functions.iter().map(|f| format!("{f:?}")).collect(),
            )
        })
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cached_refresh_builds_the_same_model_and_a_changed_build_is_read_afresh() {
    let host = common::host("h");
    let topology = SimSpec::load(common::shipped("small-machine.toml"))
        .unwrap()
        .with_zero_latency(true);
    let sim = SimMachine::start(&host, &topology).await.unwrap();
    let mut m = Manager::new(&host).await.unwrap();
    common::refresh(&mut m).await;
    let asked = read_parts(m.som());
    let steppers = m
        .som()
        .runtimes
        .iter()
        .filter(|r| r.record.type_name == "stepper")
        .count();
    assert_eq!(steppers, 4);
    let functions = m.som().runtimes[2].functions.len();
    assert!(functions > 40, "{functions}");

    // An empty cache learns the one stepper build (the hub and the host
    // report no function set).
    let mut cache = SomCache::new();
    let (report, learnt) = m.refresh_cached(&mut cache, |_| {}).await.unwrap();
    assert!(learnt && report.from_cache == 0, "{report:?}");
    assert_eq!(cache.builds(), 1);
    assert_eq!(read_parts(m.som()), asked);

    // Kept and read back, it stands in for every stepper's signatures.
    let dir = std::env::temp_dir().join(format!("osap-som-cache-{}", std::process::id()));
    let path = dir.join("small.json");
    cache.save(&path).unwrap();
    let mut cache = SomCache::load(&path).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    let (report, learnt) = m.refresh_cached(&mut cache, |_| {}).await.unwrap();
    assert!(!learnt, "nothing new");
    assert_eq!(report.from_cache, steppers * functions, "{report:?}");
    assert!(report.function_failures.is_empty() && report.scan_failures.is_empty());
    assert_eq!(read_parts(m.som()), asked);

    // A cache whose build says another function-set id (other firmware),
    // with a signature that is not the module's: not used.
    let mut json = serde_json::to_value(&cache).unwrap();
    let build = &mut json["builds"][0];
    let id = build["identity"]["function_set"].as_u64().unwrap();
    build["identity"]["function_set"] = (id ^ 1).into();
    build["functions"][0]["name"] = "stale".into();
    let mut stale: SomCache = serde_json::from_value(json).unwrap();
    let (report, learnt) = m.refresh_cached(&mut stale, |_| {}).await.unwrap();
    assert_eq!(report.from_cache, 0, "{report:?}");
    assert!(learnt, "the modules' own build is learnt");
    assert_eq!(read_parts(m.som()), asked);
    assert!(m
        .som()
        .runtimes
        .iter()
        .all(|r| r.functions.iter().all(|f| f.name != "stale")));
    sim.stop().await.unwrap();
}
