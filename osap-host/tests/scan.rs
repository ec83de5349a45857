//! Network scans over host runtimes joined in-process.

use osap_core::route::Route;
use osap_host::link::memory;
use osap_host::map::NetworkMap;
use osap_host::netrunner::{self, ScanOptions};
use std::time::Duration;

mod common;
use common::host;

#[tokio::test]
async fn scans_a_chain_and_round_trips_the_map_through_json() {
    let (h, a, b) = (host("h"), host("a"), host("b"));
    memory::connect(&h, &a).await.unwrap();
    memory::connect(&a, &b).await.unwrap();
    let report = netrunner::scan(&h, &ScanOptions::default()).await.unwrap();
    assert!(report.failures.is_empty(), "{:?}", report.failures);
    let map = &report.map;
    let names: Vec<_> = map.runtimes.iter().map(|r| r.name.as_str()).collect();
    assert_eq!(names, ["h", "a", "b"]);
    assert_eq!(map.find("b").unwrap().route, vec![0, 1]);
    assert_eq!(map.links.len(), 2);
    // h's link 0 meets a's link 0; a's link 1 meets b's link 0.
    assert_eq!(
        (
            map.links[0].a.link,
            map.links[0].b.runtime,
            map.links[0].b.link
        ),
        (0, 1, 0)
    );
    assert_eq!(
        (
            map.links[1].a.runtime,
            map.links[1].a.link,
            map.links[1].b.link
        ),
        (1, 1, 0)
    );
    let ports = &map.find("a").unwrap().ports;
    assert_eq!(ports[0].type_name, "netresponder");
    let json = map.to_json();
    assert_eq!(&NetworkMap::from_json(&json).unwrap(), map);
    assert!(map.tree().contains("via memory link 1: b"));
}

#[tokio::test]
async fn a_loop_is_found_once() {
    // h - a - b - c - a: a ring of three behind the host.
    let (h, a, b, c) = (host("h"), host("a"), host("b"), host("c"));
    memory::connect(&h, &a).await.unwrap();
    memory::connect(&a, &b).await.unwrap();
    memory::connect(&b, &c).await.unwrap();
    memory::connect(&c, &a).await.unwrap();
    let report = netrunner::scan(&h, &ScanOptions::default()).await.unwrap();
    let map = &report.map;
    assert!(report.failures.is_empty(), "{:?}", report.failures);
    assert_eq!(map.runtimes.len(), 4, "each runtime once");
    assert_eq!(map.links.len(), 4, "each link once");
    assert!(map.tree().contains("closes a loop"), "{}", map.tree());
}

#[tokio::test]
async fn renames_survive_a_rescan() {
    let (h, a) = (host("h"), host("a"));
    memory::connect(&h, &a).await.unwrap();
    let route = Route::through_links(&[0]).unwrap();
    assert_eq!(
        netrunner::rename(&h, &route, "x-axis").await.unwrap(),
        "x-axis"
    );
    let map = netrunner::scan(&h, &ScanOptions::default())
        .await
        .unwrap()
        .map;
    assert!(map.find("x-axis").is_some());
    assert!(map.find("a").is_none());
}

#[tokio::test]
async fn an_unanswering_runtime_gives_a_partial_map_not_a_hang() {
    let (h, a) = (host("h"), host("a"));
    memory::connect(&h, &a).await.unwrap();
    // A link that is open but leads nowhere answers nothing.
    let (_, io) = h
        .add_link(osap_host::LinkConfig::new("memory", "dead end"))
        .await
        .unwrap();
    io.set_open(true);
    let options = ScanOptions {
        timeout: Duration::from_millis(30),
        retries: 1,
        ..ScanOptions::default()
    };
    let report = netrunner::scan(&h, &options).await.unwrap();
    assert_eq!(report.map.runtimes.len(), 2);
    assert_eq!(report.failures.len(), 1);
    assert_eq!(report.failures[0].route, vec![1]);
    assert!(
        report.failures[0].error.contains("no reply"),
        "{:?}",
        report.failures
    );
}

#[tokio::test]
async fn time_configuration_and_clock_status_over_the_network() {
    use osap_core::clock::{SyncState, TimeConfig};
    use osap_host::netrunner::Netrunner;
    // `a` takes clock writes from (and follows) its link to `h`: a root
    // trusting no link would refuse them (see tests/clock_authority.rs).
    let h = host("h");
    let a = osap_host::Host::start(osap_host::HostConfig {
        trust: osap_core::clock::Trust::ALL,
        ..osap_host::HostConfig::named("a")
    })
    .unwrap();
    memory::connect(&h, &a).await.unwrap();
    let runner = Netrunner::new(&h).await.unwrap();
    let route = Route::through_links(&[0]).unwrap();
    // Host runtimes are roots by default; make `a` follow instead.
    let follower = TimeConfig {
        root: false,
        interval_us: 10_000,
        ..runner.time_config(&route).await.unwrap()
    };
    let applied = runner.set_time_config(&route, &follower).await.unwrap();
    assert_eq!(applied, follower);
    assert_eq!(runner.time_config(&route).await.unwrap(), follower);
    // It synchronises to the host: wait for tier 1 (bounded).
    let status = tokio::time::timeout(Duration::from_secs(5), async {
        loop {
            let s = runner.clock_status(&route).await.unwrap();
            if s.state == SyncState::Synced {
                return s;
            }
            tokio::task::yield_now().await;
        }
    })
    .await
    .expect("a synchronises within 5 s");
    assert_eq!(status.tier, 1);
    assert!(status.stats.accepted > 0);
    // A bad configuration is refused and named.
    let bad = TimeConfig {
        interval_us: 10,
        ..follower
    };
    let err = runner.set_time_config(&route, &bad).await.unwrap_err();
    assert!(err.to_string().contains("InvalidValue"), "{err}");
}
