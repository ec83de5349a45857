//! Runtimes joined by in-memory links: packets cross chains, trees and loops,
//! replies come back over the reversed route, expired packets are dropped
//! and a stalled link does not hold up the others.

use osap_core::packet::Instruction;
use osap_core::route::Route;
use osap_tests::{raw, Net};

const TTL: u16 = 10_000;

/// Sends `payload` from port 1 of `from` along `route` to port 1 of the far
/// node, whose port 1 echoes; returns after the echo is back.
fn round_trip(net: &mut Net, from: usize, to: usize, route: Route, payload: &[u8]) {
    net.port(to, 1).echo = true;
    net.port(from, 1).queue(route, 1, TTL, payload);
    let steps = net.run_until(10, 100, |n| !n.nodes[from].ports[0].received.is_empty());
    assert!(steps.is_some(), "echo never came back");
    let there = &net.nodes[to].ports[0].received;
    assert_eq!(there.len(), 1);
    assert_eq!(there[0].payload, payload);
    assert_eq!(there[0].source_port, 1);
    // The far side's way back is the forward route reversed, as rewritten
    // hop by hop on the way.
    let back = &net.nodes[from].ports[0].received[0];
    assert_eq!(back.payload, payload);
    assert_eq!(back.source_port, 1);
    assert_eq!(back.reply_route.hop_count(), route.hop_count());
}

#[test]
fn chain_of_four_forward_and_reply() {
    let mut net = Net::new();
    // a[1] - [0]b[1] - [0]c[1] - [0]d
    let a = net.node("a", 2, 1);
    let b = net.node("b", 2, 1);
    let c = net.node("c", 2, 1);
    let d = net.node("d", 2, 1);
    net.wire(a, 1, b, 0);
    net.wire(b, 1, c, 0);
    net.wire(c, 1, d, 0);
    let route = Route::through_links(&[1, 1, 1]).unwrap();
    round_trip(&mut net, a, d, route, &raw(b"hello d"));
    let back = net.nodes[d].ports[0].received[0].reply_route;
    let hops: Vec<_> = back.hops().collect();
    assert_eq!(hops, vec![Instruction::LinkForward(0); 3]);
    for n in [b, c] {
        assert_eq!(net.nodes[n].runtime.counters().forwarded, 2);
        assert_eq!(net.nodes[n].runtime.counters().dropped(), 0);
    }
}

#[test]
fn tree_leaf_to_leaf() {
    let mut net = Net::new();
    //        root
    //   [0] /    \ [1]
    //      x      y
    //  [1]/ \[2]
    //   x1   x2
    let root = net.node("root", 2, 1);
    let x = net.node("x", 3, 1);
    let y = net.node("y", 1, 1);
    let x1 = net.node("x1", 1, 1);
    let x2 = net.node("x2", 1, 1);
    net.wire(root, 0, x, 0);
    net.wire(root, 1, y, 0);
    net.wire(x, 1, x1, 0);
    net.wire(x, 2, x2, 0);
    // x2 -> x (link 0) -> root (x's link 0) -> y (root's link 1)
    let route = Route::through_links(&[0, 0, 1]).unwrap();
    round_trip(&mut net, x2, y, route, &raw(&[1, 2, 3]));
    let back: Vec<_> = net.nodes[y].ports[0].received[0]
        .reply_route
        .hops()
        .collect();
    // y's way back: its link 0 to root, root's link 0 to x, x's link 2 to x2.
    assert_eq!(
        back,
        vec![
            Instruction::LinkForward(0),
            Instruction::LinkForward(0),
            Instruction::LinkForward(2)
        ]
    );
    assert_eq!(net.nodes[x1].runtime.counters().received, 0);
}

#[test]
fn loop_network_routes_around_and_back_to_itself() {
    let mut net = Net::new();
    // a[0] - [0]b[1] - [0]c[1] - [1]a : a triangle.
    let a = net.node("a", 2, 2);
    let b = net.node("b", 2, 1);
    let c = net.node("c", 2, 1);
    net.wire(a, 0, b, 0);
    net.wire(b, 1, c, 0);
    net.wire(c, 1, a, 1);
    // Twice around the loop from a's port 1 to a's own port 2.
    let route = Route::through_links(&[0, 1, 1, 0, 1, 1]).unwrap();
    net.port(a, 2).echo = true;
    net.port(a, 1).queue(route, 2, TTL, &raw(b"loop"));
    net.run_until(10, 100, |n| !n.nodes[a].ports[0].received.is_empty())
        .expect("echo around the loop");
    let got = &net.nodes[a].ports[1].received[0];
    assert_eq!(got.payload, raw(b"loop"));
    assert_eq!(got.reply_route.hop_count(), 6);
    // Each of b and c forwarded the packet twice each way.
    assert_eq!(net.nodes[b].runtime.counters().forwarded, 4);
    assert_eq!(net.nodes[c].runtime.counters().forwarded, 4);
}

#[test]
fn expired_packets_are_dropped_not_delivered() {
    let mut net = Net::new();
    let a = net.node("a", 1, 1);
    let b = net.node("b", 2, 1);
    let c = net.node("c", 1, 1);
    net.wire(a, 0, b, 0);
    net.wire(b, 1, c, 0);
    // c's port is busy for longer than the packet has to live: the packet
    // waits in c's stack, expires there and is never delivered.
    net.port(c, 1).busy = true;
    let route = Route::through_links(&[0, 1]).unwrap();
    net.port(a, 1).queue(route, 1, 250, &raw(b"late"));
    net.run_until(100, 5, |_| false);
    net.port(c, 1).busy = false;
    net.run_until(100, 5, |_| false);
    assert!(net.nodes[c].ports[0].received.is_empty());
    assert_eq!(net.nodes[c].runtime.counters().expired, 1);
    // A packet with enough time makes it.
    net.port(a, 1).queue(route, 1, 1_000, &raw(b"on time"));
    net.run_until(100, 20, |n| !n.nodes[c].ports[0].received.is_empty())
        .expect("delivered");
}

#[test]
fn wire_time_counts_against_the_deadline() {
    let mut net = Net::new();
    let a = net.node("a", 1, 1);
    let b = net.node("b", 1, 1);
    let w = net.wire(a, 0, b, 0);
    net.wires[w].stalled = true; // keep what a sends in its outbox to look at
                                 // 100 µs per packet on the wire.
    net.nodes[a].links[0] = osap_tests::TestLink::new().with_wire_time(100, 0);
    let route = Route::through_links(&[0]).unwrap();
    net.port(a, 1).queue(route, 1, 1_000, &raw(b"x"));
    net.step(10);
    let sent = net.nodes[a].links[0].take_sent().expect("sent");
    assert_eq!(u16::from_le_bytes([sent[1], sent[2]]), 900);
    // One that would land after its deadline is not sent at all.
    net.port(a, 1).queue(route, 1, 99, &raw(b"y"));
    net.step(10);
    assert!(net.nodes[a].links[0].take_sent().is_none());
    assert_eq!(net.nodes[a].runtime.counters().expired, 1);
}

#[test]
fn ttl_is_rewritten_to_time_left() {
    let mut net = Net::new();
    let a = net.node("a", 1, 1);
    let b = net.node("b", 2, 0);
    net.wire(a, 0, b, 0);
    // b forwards onto its link 1, which nothing drains: inspect what it sent.
    let route = Route::through_links(&[0, 1]).unwrap();
    net.port(a, 1).queue(route, 1, 5_000, &raw(b"x"));
    net.step(300); // a sends at t=0
    net.step(300); // b takes it in and forwards at t=300
    let sent = net.nodes[b].links[1].take_sent().expect("forwarded");
    let ttl = u16::from_le_bytes([sent[1], sent[2]]);
    // arrived at b at t=300 with 5000 left (a forwarded at t=0, no wire time),
    // left b at t=300: still 5000.
    assert_eq!(ttl, 5_000);
    // b rewrote the first hop on arrival and sends the second unmodified;
    // c will rewrite that one when it takes the packet in.
    assert_eq!(sent[0], 6);
    assert_eq!(sent[5], 0x40, "way back from b: its link 0");
    assert_eq!(sent[6], 0x41, "next hop still link_forward(1)");
}

#[test]
fn saturated_link_does_not_stall_other_traffic() {
    let mut net = Net::new();
    //  a[0] - [0]hub[1] - [0]c   (hub->c stalled: c stopped reading)
    //  d[0] - [2]hub
    let a = net.node("a", 1, 1);
    let hub = net.node("hub", 3, 0);
    let c = net.node("c", 1, 1);
    let d = net.node("d", 1, 1);
    net.wire(a, 0, hub, 0);
    let stalled = net.wire(hub, 1, c, 0);
    net.wire(d, 0, hub, 2);
    net.wires[stalled].stalled = true;
    let to_c = Route::through_links(&[0, 1]).unwrap();
    let d_to_a = Route::through_links(&[0, 0]).unwrap();
    for i in 0..40u8 {
        net.port(a, 1).queue(to_c, 1, 2_000, &raw(&[i]));
        net.port(d, 1).queue(d_to_a, 1, 2_000, &raw(&[i]));
    }
    net.run_until(10, 2_000, |n| n.nodes[a].ports[0].received.len() == 40)
        .expect("d's traffic to a keeps flowing past the stalled link");
    let got: Vec<u8> = net.nodes[a].ports[0]
        .received
        .iter()
        .map(|r| r.payload[1])
        .collect();
    assert_eq!(got, (0..40).collect::<Vec<_>>(), "in order, none lost");
    // Packets for c fill the stalled link's buffer, then wait in the hub
    // only up to a's quota there; they expire instead of blocking anything.
    net.run_until(10, 300, |_| false);
    let hub_counters = *net.nodes[hub].runtime.counters();
    assert!(hub_counters.expired > 0);
    assert!(net.nodes[hub].runtime.stack().len() <= 4 + 4);
}

#[test]
fn busy_port_waits_then_receives() {
    let mut net = Net::new();
    let a = net.node("a", 1, 1);
    let b = net.node("b", 1, 2);
    net.wire(a, 0, b, 0);
    net.port(b, 1).busy = true;
    let route = Route::through_links(&[0]).unwrap();
    net.port(a, 1).queue(route, 1, 5_000, &raw(b"to busy"));
    net.port(a, 1).queue(route, 2, 5_000, &raw(b"to free"));
    net.run_until(10, 50, |n| !n.nodes[b].ports[1].received.is_empty())
        .expect("the free port is served while the busy one waits");
    assert!(net.nodes[b].ports[0].received.is_empty());
    net.port(b, 1).busy = false;
    net.run_until(10, 5, |n| !n.nodes[b].ports[0].received.is_empty())
        .expect("served once clear");
}

#[test]
fn unknown_port_and_link_are_counted_drops() {
    let mut net = Net::new();
    let a = net.node("a", 1, 1);
    let b = net.node("b", 1, 1);
    net.wire(a, 0, b, 0);
    net.port(a, 1)
        .queue(Route::through_links(&[0]).unwrap(), 7, TTL, &raw(b"?"));
    net.port(a, 1)
        .queue(Route::through_links(&[0, 3]).unwrap(), 1, TTL, &raw(b"?"));
    net.port(a, 1)
        .queue(Route::through_links(&[5]).unwrap(), 1, TTL, &raw(b"?"));
    net.run_until(10, 20, |_| false);
    let bc = net.nodes[b].runtime.counters();
    assert_eq!(bc.no_port, 1);
    assert_eq!(bc.no_route, 1);
    assert_eq!(net.nodes[a].runtime.counters().no_route, 1);
}

#[test]
fn closed_link_drops_with_a_count() {
    let mut net = Net::new();
    let a = net.node("a", 1, 1);
    let b = net.node("b", 1, 1);
    net.wire(a, 0, b, 0);
    net.nodes[a].links[0].set_open(false);
    net.port(a, 1)
        .queue(Route::through_links(&[0]).unwrap(), 1, TTL, &raw(b"x"));
    net.run_until(10, 5, |_| false);
    assert_eq!(net.nodes[a].runtime.counters().link_closed, 1);
    assert!(net.nodes[b].ports[0].received.is_empty());
}

#[test]
fn local_route_reaches_a_port_in_the_same_runtime() {
    let mut net = Net::new();
    let a = net.node("a", 0, 2);
    net.port(a, 2).echo = true;
    net.port(a, 1).queue(Route::local(), 2, TTL, &raw(b"self"));
    net.run_until(1, 5, |n| !n.nodes[a].ports[0].received.is_empty())
        .expect("local echo");
    assert!(net.nodes[a].ports[1].received[0].reply_route.is_empty());
}

#[test]
fn clocks_synchronise_across_a_chain() {
    use osap_core::clock::SyncState;
    let mut net = Net::new();
    // root[0] - [0]a[1] - [0]b, with a and b far off and drifting.
    let root = net.node("root", 1, 0);
    let a = net.node("a", 2, 0);
    let b = net.node("b", 1, 0);
    net.wire(root, 0, a, 0);
    net.wire(a, 1, b, 0);
    net.sync(root, true);
    net.sync(a, false);
    net.sync(b, false);
    net.nodes[a].clock_offset = 5_000_000;
    net.nodes[a].clock_ppm = 80.0;
    net.nodes[b].clock_offset = 123_456;
    net.nodes[b].clock_ppm = -60.0;
    net.run_until(100, 30_000, |_| false); // 3 s
    for (n, tier) in [(a, 1), (b, 2)] {
        let status = net.nodes[n].runtime.clock().status();
        assert_eq!(status.tier, tier);
        assert_eq!(status.state, SyncState::Synced);
        assert!(status.stats.accepted > 10);
        let err = net.nodes[n]
            .system_time(net.now)
            .signed_micros_since(net.nodes[root].system_time(net.now));
        // Every leg here takes exactly one step each way: symmetric, so the
        // only error left is rounding.
        assert!(err.abs() <= 2, "node {n}: {err} µs off the root");
    }
    let status = net.nodes[a].runtime.clock().status();
    assert!(
        (status.rate_ppb + 80_000).abs() < 5_000,
        "rate {}",
        status.rate_ppb
    );
}
