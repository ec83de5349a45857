//! Clock authority between host runtimes: a host follows only the links it
//! trusts, and a root cannot be demoted over a link it does not trust. And
//! a host's configured pace is the pace of its system time.

use osap_core::clock::{SyncState, TimeConfig};
use osap_core::netresponder::{key, Status};
use osap_core::route::Route;
use osap_host::link::memory;
use osap_host::netrunner::Netrunner;
use osap_host::{Host, HostConfig, HostError};
use std::time::Duration;

mod common;
use common::host;

fn follower(name: &str) -> Host {
    let mut config = HostConfig::named(name);
    config.time.root = false;
    Host::start(config).unwrap()
}

#[tokio::test(start_paused = true)]
async fn a_root_refuses_clock_writes_over_an_untrusted_link() {
    let (h, a) = (host("h"), host("a"));
    memory::connect(&h, &a).await.unwrap();
    let runner = Netrunner::new(&h).await.unwrap();
    let route = Route::through_links(&[0]).unwrap();
    let demote = TimeConfig {
        root: false,
        ..runner.time_config(&route).await.unwrap()
    };
    let err = runner.set_time_config(&route, &demote).await.unwrap_err();
    assert!(
        matches!(
            err,
            HostError::Remote {
                status: Status::Refused,
                ..
            }
        ),
        "{err}"
    );
    // Nor may it retune the root's rate.
    let mut body = vec![key::SET_CLOCK_RATE];
    body.extend_from_slice(&400_000i32.to_le_bytes());
    let err = runner.query(&route, &body).await.unwrap_err();
    assert!(err.to_string().contains("Refused"), "{err}");
    let status = a.clock_status().await.unwrap();
    assert_eq!(status.state, SyncState::Root);
    assert_eq!(status.rate_ppb, 0);
    assert_eq!(status.stats.untrusted, 2);
    // The same status, read over the network.
    assert_eq!(
        runner.clock_status(&route).await.unwrap().stats.untrusted,
        2
    );
    // Its own configuration it may still change (from a local port).
    let local = Netrunner::new(&a).await.unwrap();
    let here = Route::through_links(&[]).unwrap();
    local.set_time_config(&here, &demote).await.unwrap();
    assert_eq!(a.clock_status().await.unwrap().tier, 255);
}

#[tokio::test(start_paused = true)]
async fn a_host_follows_the_trusted_root_and_counts_the_other() {
    // Two roots 5 s apart: `rogue` started first, so its time is ahead.
    let rogue = host("rogue");
    tokio::time::advance(Duration::from_secs(5)).await;
    let root = host("root");
    let f = follower("f");
    let (to_root, _) = memory::connect(&f, &root).await.unwrap();
    let (to_rogue, _) = memory::connect(&f, &rogue).await.unwrap();
    f.trust_time_link(to_root).await.unwrap();
    tokio::time::sleep(Duration::from_secs(4)).await;
    let s = f.clock_status().await.unwrap();
    assert_eq!((s.state, s.tier, s.following), (SyncState::Synced, 1, 1));
    assert!(s.settled, "{s:?}");
    assert!(s.stats.untrusted > 0, "{s:?}");
    let (ours, theirs) = (
        f.system_time().await.unwrap(),
        root.system_time().await.unwrap(),
    );
    assert!(
        ours.abs_diff(theirs).as_micros() < 100,
        "{ours} vs {theirs}"
    );
    // Trust moved to the other link: the clock now follows the rogue
    // (a step: no motion here), and no longer the first root.
    f.distrust_time_link(to_root).await.unwrap();
    f.trust_time_link(to_rogue).await.unwrap();
    tokio::time::sleep(Duration::from_secs(3)).await;
    let (ours, theirs) = (
        f.system_time().await.unwrap(),
        rogue.system_time().await.unwrap(),
    );
    assert!(
        ours.abs_diff(theirs).as_micros() < 100,
        "{ours} vs {theirs}"
    );
    assert_eq!(f.clock_status().await.unwrap().tier, 1);
}

#[tokio::test(start_paused = true)]
async fn a_paced_host_keeps_its_pace_in_system_time() {
    let half = Host::start(HostConfig {
        pace: osap_host::Pace::new(1, 2).unwrap(),
        ..HostConfig::named("half")
    })
    .unwrap();
    let real = host("real");
    let (h0, r0) = (
        half.system_time().await.unwrap(),
        real.system_time().await.unwrap(),
    );
    tokio::time::advance(Duration::from_secs(4)).await;
    let (h1, r1) = (
        half.system_time().await.unwrap(),
        real.system_time().await.unwrap(),
    );
    let span = |a: osap_core::SystemInstant, b: osap_core::SystemInstant| (b - a).as_micros();
    assert_eq!(span(r0, r1), 4_000_000);
    assert_eq!(span(h0, h1), 2_000_000);
    assert_eq!(half.clock().pace(), osap_host::Pace::new(1, 2).unwrap());
}
