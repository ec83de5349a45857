//! Host runtimes on tokio: ports, requests, in-process links.

use osap_core::netresponder::key;
use osap_core::route::Route;
use osap_core::transport::Transport;
use osap_host::link::memory;
use osap_host::HostError;
use std::time::Duration;

mod common;
use common::host;

#[tokio::test]
async fn request_to_a_neighbours_netresponder() {
    let a = host("a");
    let b = host("b");
    let (la, _lb) = memory::connect(&a, &b).await.unwrap();
    let port = a.open_port("test").await.unwrap();
    let route = Route::through_links(&[la]).unwrap();
    let reply = port
        .request(&route, 0, &[key::NAME], Duration::from_secs(1))
        .await
        .unwrap();
    assert_eq!(reply.transport, Transport::Reply(0));
    // [key][status][str8]
    assert_eq!(&reply.body[..3], &[key::NAME, 0, 1]);
    assert_eq!(&reply.body[3..], b"b");
}

#[tokio::test]
async fn ports_talk_across_hosts_and_back() {
    let a = host("a");
    let b = host("b");
    let (la, _) = memory::connect(&a, &b).await.unwrap();
    let client = a.open_port("client").await.unwrap();
    let server = b.open_port("echo").await.unwrap();
    let dst = server.index();
    let serve = tokio::spawn(async move {
        for _ in 0..3 {
            let req = server.recv().await;
            server.reply(&req, &req.body).await.unwrap();
        }
    });
    let route = Route::through_links(&[la]).unwrap();
    for i in 0..3u8 {
        let r = client
            .request(&route, dst, &[i, 1, 2], Duration::from_secs(1))
            .await
            .unwrap();
        assert_eq!(r.body, vec![i, 1, 2]);
    }
    serve.await.unwrap();
}

#[tokio::test]
async fn unanswered_requests_time_out_with_the_route_named() {
    let a = host("a");
    let port = a.open_port("client").await.unwrap();
    // Link 3 does not exist: the packet is dropped, nothing answers.
    let route = Route::through_links(&[3]).unwrap();
    let err = port
        .request(&route, 0, &[key::NAME], Duration::from_millis(50))
        .await
        .unwrap_err();
    assert!(matches!(err, HostError::Timeout { port: 0, .. }), "{err}");
    assert!(err.to_string().contains("[L3]"), "{err}");
}

#[tokio::test]
async fn the_host_is_the_clock_root() {
    let a = host("a");
    let status = a.clock_status().await.unwrap();
    assert_eq!(status.tier, 0);
    let t1 = a.system_time().await.unwrap();
    let t2 = a.system_time().await.unwrap();
    assert!(t2 >= t1);
}
