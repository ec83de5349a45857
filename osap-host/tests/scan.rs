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
    // Host runtimes are clock roots and send nothing by themselves: before
    // the scan nothing was heard on h's link to a.
    let runner = netrunner::Netrunner::new(&h).await.unwrap();
    let before = runner.link_info(&Route::local(), 0).await.unwrap();
    assert!(before.no_neighbour(), "{before:?}");
    let report = netrunner::scan(&h, &ScanOptions::default()).await.unwrap();
    assert!(report.failures.is_empty(), "{:?}", report.failures);
    let map = &report.map;
    let names: Vec<_> = map.runtimes.iter().map(|r| r.name.as_str()).collect();
    assert_eq!(names, ["h", "a", "b"]);
    // Each silent link answered the scan: mapped, with a neighbour.
    assert!(map
        .runtimes
        .iter()
        .flat_map(|r| &r.links)
        .all(|l| l.open && l.heard));
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
async fn a_scan_for_runtimes_maps_what_a_scan_maps_but_the_ports() {
    // h - a, a = b twice (two links between them: both probes of a batch
    // meet b), b - c - a (a ring).
    let (h, a, b, c) = (host("h"), host("a"), host("b"), host("c"));
    memory::connect(&h, &a).await.unwrap();
    memory::connect(&a, &b).await.unwrap();
    memory::connect(&a, &b).await.unwrap();
    memory::connect(&b, &c).await.unwrap();
    memory::connect(&c, &a).await.unwrap();
    let full = netrunner::scan(&h, &ScanOptions::default()).await.unwrap();
    let mut seen = Vec::new();
    let quick = netrunner::scan_runtimes(&h, &ScanOptions::default(), |r| {
        seen.push(r.name.clone());
        true
    })
    .await
    .unwrap();
    assert!(quick.failures.is_empty(), "{:?}", quick.failures);
    assert_eq!(seen, ["h", "a", "b", "c"]);
    assert_eq!(full.map.runtimes.len(), 4);
    let mut expected = full.map.clone();
    for r in &mut expected.runtimes {
        r.ports.clear();
    }
    let sorted = |mut m: NetworkMap| {
        m.links
            .sort_by_key(|e| (e.a.runtime, e.a.link, e.b.runtime, e.b.link));
        m
    };
    assert_eq!(sorted(quick.map), sorted(expected));
    assert!(full.map.runtimes.iter().all(|r| !r.ports.is_empty()));
}

#[tokio::test]
async fn a_scan_for_runtimes_ends_when_told() {
    let (h, a, b, c) = (host("h"), host("a"), host("b"), host("c"));
    memory::connect(&h, &a).await.unwrap();
    memory::connect(&a, &b).await.unwrap();
    memory::connect(&b, &c).await.unwrap();
    let report = netrunner::scan_runtimes(&h, &ScanOptions::default(), |r| r.name != "b")
        .await
        .unwrap();
    let names: Vec<_> = report
        .map
        .runtimes
        .iter()
        .map(|r| r.name.as_str())
        .collect();
    assert_eq!(names, ["h", "a", "b"]);
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

/// Options for scans that wait on silent links: short timeouts.
fn quick() -> ScanOptions {
    ScanOptions {
        timeout: Duration::from_millis(30),
        retries: 2,
        ..ScanOptions::default()
    }
}

/// A packet as a neighbour on the far end of a link would send it: to a
/// port the host lacks, so nothing answers it.
fn stray_packet() -> Vec<u8> {
    let mut buf = [0u8; 64];
    let n = Route::through_links(&[0])
        .unwrap()
        .write_packet(
            &mut buf,
            osap_core::Instruction::PortHandle { src: 1, dst: 200 },
            10_000,
            64,
            b"hello",
        )
        .unwrap();
    buf[..n].to_vec()
}

#[tokio::test]
async fn an_open_link_with_nothing_on_it_has_no_neighbour() {
    let (h, a) = (host("h"), host("a"));
    memory::connect(&h, &a).await.unwrap();
    // A link that is open but leads nowhere: nothing is heard on it and
    // nothing answers (an unwired UART).
    let (index, io) = h
        .add_link(osap_host::LinkConfig::new("uart", "uart0"))
        .await
        .unwrap();
    io.set_open(true);
    let report = netrunner::scan(&h, &quick()).await.unwrap();
    assert!(report.failures.is_empty(), "{:?}", report.failures);
    assert_eq!(report.map.runtimes.len(), 2);
    let dead = &report.map.runtimes[0].links[usize::from(index)];
    assert!(dead.open && !dead.heard && dead.no_neighbour(), "{dead:?}");
    // Asked once, without retries (the host is a clock root: it sends
    // nothing else there).
    assert_eq!(io.stats().sent, 1);
    // The link to `a`, silent before the scan too, answered: a neighbour.
    let to_a = &report.map.runtimes[0].links[0];
    assert!(to_a.heard && !to_a.no_neighbour(), "{to_a:?}");
    assert!(
        report
            .map
            .tree()
            .contains(&format!("  link {index} uart \"uart0\" (no neighbour)\n")),
        "{}",
        report.map.tree()
    );
    // It survives a round trip through JSON; a map from before the field
    // reads every link as heard.
    let json = report.map.to_json();
    assert_eq!(NetworkMap::from_json(&json).unwrap(), report.map);
    let old: String = json.lines().filter(|l| !l.contains("\"heard\"")).collect();
    assert!(NetworkMap::from_json(&old).unwrap().runtimes[0]
        .links
        .iter()
        .all(|l| l.heard));
}

#[tokio::test]
async fn a_heard_neighbour_that_does_not_answer_is_a_failure() {
    let (h, a) = (host("h"), host("a"));
    memory::connect(&h, &a).await.unwrap();
    let (index, io) = h
        .add_link(osap_host::LinkConfig::new("uart", "uart0"))
        .await
        .unwrap();
    io.set_open(true);
    // Something was there a moment ago, and has stopped answering.
    assert!(io.deliver(stray_packet()));
    let options = quick();
    let report = netrunner::scan(&h, &options).await.unwrap();
    assert_eq!(report.map.runtimes.len(), 2);
    assert_eq!(report.failures.len(), 1, "{:?}", report.failures);
    assert_eq!(report.failures[0].route, vec![index]);
    assert!(
        report.failures[0].error.contains("no reply"),
        "{:?}",
        report.failures
    );
    let link = &report.map.runtimes[0].links[usize::from(index)];
    assert!(link.heard && !link.no_neighbour(), "{link:?}");
    // Asked with every retry.
    assert_eq!(io.stats().sent, 1 + u64::from(options.retries));
    assert!(!report.map.tree().contains("no neighbour"));
}

#[tokio::test]
async fn a_neighbour_silent_for_longer_than_the_window_is_still_a_failure() {
    use osap_core::netresponder::NEIGHBOUR_HEARD;
    let h = host("h");
    let (index, io) = h
        .add_link(osap_host::LinkConfig::new("uart", "uart0"))
        .await
        .unwrap();
    io.set_open(true);
    // Something was there, then went silent (hung, or lost its power
    // behind a UART that stays open) for longer than the window.
    assert!(io.deliver(stray_packet()));
    tokio::time::sleep(Duration::from_micros(NEIGHBOUR_HEARD.as_micros() + 100_000)).await;
    let runner = netrunner::Netrunner::new(&h).await.unwrap();
    let now = runner.link_info(&Route::local(), index).await.unwrap();
    assert!(now.no_neighbour(), "nothing heard lately: {now:?}");
    let report = netrunner::scan(&h, &quick()).await.unwrap();
    assert_eq!(report.failures.len(), 1, "{:?}", report.failures);
    assert_eq!(report.failures[0].route, vec![index]);
    assert!(
        report.failures[0].error.contains("went silent"),
        "{:?}",
        report.failures
    );
    let link = &report.map.runtimes[0].links[usize::from(index)];
    assert!(!link.no_neighbour(), "{link:?}");
}

#[tokio::test]
async fn a_neighbour_heard_only_after_the_first_try_is_retried() {
    let h = host("h");
    let (index, io) = h
        .add_link(osap_host::LinkConfig::new("uart", "uart0"))
        .await
        .unwrap();
    io.set_open(true);
    // Silent until asked; then it sends something, but never an answer.
    let far = io.clone();
    let talker = tokio::spawn(async move {
        let mut asked = 0u64;
        while far.next_tx().await.is_some() {
            asked += 1;
            if asked == 1 {
                far.deliver(stray_packet());
            }
        }
        asked
    });
    let options = quick();
    let report = netrunner::scan(&h, &options).await.unwrap();
    assert_eq!(report.failures.len(), 1, "{:?}", report.failures);
    assert_eq!(report.failures[0].route, vec![index]);
    assert!(!report.map.runtimes[0].links[usize::from(index)].no_neighbour());
    io.set_open(false);
    // The first try, then the request again with every retry.
    assert_eq!(talker.await.unwrap(), 2 + u64::from(options.retries));
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

#[tokio::test]
async fn a_scan_does_not_ask_back_the_way_it_came() {
    // h - a - b - c: each runtime is reached from the one before it, on
    // the link it would be asked back across.
    let (h, a, b, c) = (host("h"), host("a"), host("b"), host("c"));
    memory::connect(&h, &a).await.unwrap();
    memory::connect(&a, &b).await.unwrap();
    memory::connect(&b, &c).await.unwrap();
    let report = netrunner::scan(&h, &ScanOptions::default()).await.unwrap();
    assert!(report.failures.is_empty(), "{:?}", report.failures);
    let map = &report.map;
    let names: Vec<_> = map.runtimes.iter().map(|r| r.name.as_str()).collect();
    assert_eq!(names, ["h", "a", "b", "c"]);
    // Every link once, from the end found first, with both ends heard.
    let ends: Vec<_> = map
        .links
        .iter()
        .map(|e| (e.a.runtime, e.a.link, e.b.runtime, e.b.link))
        .collect();
    assert_eq!(ends, [(0, 0, 1, 0), (1, 1, 2, 0), (2, 1, 3, 0)]);
    assert!(map
        .runtimes
        .iter()
        .flat_map(|r| &r.links)
        .all(|l| l.open && l.heard));
    let runner = netrunner::Netrunner::new(&h).await.unwrap();
    // What the scan sent into the chain (docs/performance.md, "Scale:
    // scan completeness").
    let sent = runner.link_counters(&Route::local(), 0).await.unwrap().sent;
    println!("packets the host sent into the chain during its scan: {sent}");
    // c, at the end, took in only what was for it: no probe of c's asking
    // back to b (in through c and out again, then its reply) passed it.
    let counters = runner
        .query(
            &Route::through_links(&[0, 1, 1]).unwrap(),
            &[osap_core::netresponder::key::COUNTERS],
        )
        .await
        .unwrap();
    let word = |i: usize| u32::from_le_bytes(counters[i * 4..i * 4 + 4].try_into().unwrap());
    // (This request is counted received, but delivered only once its
    // reply is written: one more in than delivered. Before the way back
    // was skipped, three more.)
    let (received, delivered) = (word(0), word(2));
    assert_eq!(
        received,
        delivered + 1,
        "c passed {} packets on",
        received - delivered - 1
    );
}
