//! Link models on the wire: UART timing and stamps, corruption caught by the
//! CRC, USB frame quantisation, busy-module stamps.

mod common;

use common::{frames_from, pair, traced};
use osap_core::route::Route;
use osap_core::time::Duration;
use osap_sim::busy::{BusyModel, BusyTrigger};
use osap_sim::medium::{Side, Transmitter, UartParams, UsbParams};
use osap_sim::probe::ProbePort;
use osap_sim::rng::{Dist, Rng};
use osap_sim::sim::FrameRecord;
use osap_sim::{LinkModel, Sim};

const MS: u64 = 1_000_000;

/// Checks that every frame in `frames` (one direction of a UART at `baud`,
/// no propagation delay or jitter) took `bytes * 10 / baud` on the wire,
/// started when sent or when the previous frame ended, and was stamped with
/// its first byte's arrival on the receiver's clock.
fn check_uart_direction(sim: &Sim, frames: &[FrameRecord], baud: u64) {
    let mut prev_end = 0;
    for f in frames {
        let t = &f.transit;
        let wire = (t.bytes.len() as u64 * 10 * 1_000_000_000 + baud / 2) / baud;
        assert_eq!(t.complete_ns - t.first_byte_ns, wire, "wire time");
        assert_eq!(t.first_byte_ns, t.start_ns, "no propagation delay");
        assert_eq!(t.start_ns, t.sent_ns.max(prev_end), "FIFO start");
        assert_eq!(t.visible_ns, t.complete_ns);
        let receiver = sim.node(f.to).clock();
        assert_eq!(f.rx_stamp, Some(receiver.local_us(t.first_byte_ns)));
        prev_end = t.complete_ns;
    }
}

#[test]
fn uart_frames_take_their_wire_time_and_are_stamped_at_the_first_byte() {
    let baud = 1_000_000;
    let mut sim = traced(&pair(LinkModel::uart(baud as u32)), 3);
    let (host, m1) = (0, 1);
    sim.node_mut(host).add_port(Box::new(ProbePort::default()));
    let port = sim.node_mut(m1).add_port(Box::new(ProbePort::default()));
    let route = Route::through_links(&[0]).unwrap();
    let payload: Vec<u8> = std::iter::once(0).chain(1..=120).collect();
    sim.node_mut(host)
        .port_mut::<ProbePort>(0)
        .unwrap()
        .queue(route, port, 20_000, &payload);
    sim.wake(host, 200 * MS);
    sim.run_secs(1.0);

    let got = &sim.node(m1).port::<ProbePort>(0).unwrap().received;
    assert_eq!(got.len(), 1, "the probe packet arrived once");
    assert_eq!(got[0].payload, payload);
    // The runtime took the gateway's stamp as the packet's arrival.
    let big = frames_from(&sim, Side::A)
        .into_iter()
        .find(|f| f.transit.bytes.len() > 120)
        .expect("probe frame traced");
    assert_eq!(Some(got[0].arrival), big.rx_stamp);

    // Every frame either way (time sync and probe) obeys the wire model.
    let a_to_b = frames_from(&sim, Side::A);
    let b_to_a = frames_from(&sim, Side::B);
    assert!(b_to_a.len() >= 10, "time requests flowed");
    check_uart_direction(&sim, &a_to_b, baud);
    check_uart_direction(&sim, &b_to_a, baud);
}

#[test]
fn corrupted_bytes_are_caught_by_the_crc_and_counted() {
    let model = LinkModel::Uart(UartParams {
        corrupt_per_byte: 0.01,
        ..UartParams::default()
    });
    let mut sim = traced(&pair(model), 5);
    let (host, m1) = (0, 1);
    sim.node_mut(host).add_port(Box::new(ProbePort::default()));
    let port = sim.node_mut(m1).add_port(Box::new(ProbePort::default()));
    let route = Route::through_links(&[0]).unwrap();
    let sent: Vec<Vec<u8>> = (0..300u16)
        .map(|i| {
            let mut p = vec![0u8, (i >> 8) as u8, i as u8];
            p.extend(std::iter::repeat_n(i as u8 ^ 0x5a, 40));
            p
        })
        .collect();
    {
        let probe = sim.node_mut(host).port_mut::<ProbePort>(0).unwrap();
        for p in &sent {
            probe.queue(route, port, 50_000, p);
        }
    }
    // The probe sends as its quota allows; keep its runtime polling.
    for _ in 0..400 {
        let now = sim.now();
        sim.wake(host, now);
        sim.run_for(MS);
    }
    sim.run_secs(0.1);
    assert!(sim
        .node(host)
        .port::<ProbePort>(0)
        .unwrap()
        .outbox
        .is_empty());

    let got = &sim.node(m1).port::<ProbePort>(0).unwrap().received;
    let corrupted: u64 = sim.link_end(0, Side::A).stats().bytes_corrupted;
    let frames = sim.link_end(0, Side::B).frame_counters().unwrap();
    let bad = frames.crc_errors + frames.cobs_errors + frames.too_short + frames.oversize;
    assert!(corrupted > 50, "corruption happened ({corrupted} bytes)");
    assert!(bad > 20, "bad frames were counted ({frames:?})");
    assert!(got.len() > 100 && got.len() < sent.len(), "{}", got.len());
    // Nothing corrupted got through: every delivery is a sent packet, once.
    for (k, d) in got.iter().enumerate() {
        assert!(sent.contains(&d.payload), "delivery {k} was corrupted");
        assert!(
            !got[..k].iter().any(|e| e.payload == d.payload),
            "duplicate"
        );
    }
    assert_eq!(sim.node(m1).runtime().counters().malformed, 0);
}

#[test]
fn usb_transfers_are_quantised_to_frames() {
    let p = UsbParams {
        in_frame_aligned: true,
        sof_phase_us: 300.0,
        slot: Dist::Const(12.0),
        host_tx_latency: Dist::Const(30.0),
        host_rx_latency: Dist::Const(40.0),
        ..UsbParams::default()
    };
    let mut sim = traced(&pair(LinkModel::UsbCdc(p)), 9);
    sim.run_secs(2.0);
    let next_sof = |t: u64| 300_000 + (t.max(300_000) - 300_000).div_ceil(MS) * MS;

    // OUT (host to device): after the host's software latency, at the slot
    // of the next frame (or right after a transfer already in that frame:
    // the clock's discovery bursts send a request about every millisecond);
    // the device stamps the bus time exactly.
    let out = frames_from(&sim, Side::A);
    assert!(out.len() >= 20, "{} host frames", out.len());
    let mut bus_free = 0;
    for f in &out {
        let t = &f.transit;
        let slot = next_sof(t.sent_ns + 30_000) + 12_000;
        assert_eq!(t.start_ns, slot.max(bus_free));
        assert!(t.start_ns < next_sof(slot), "moved to a later frame");
        assert_eq!(t.first_byte_ns, t.start_ns);
        assert_eq!(f.rx_stamp, Some(sim.node(1).clock().local_us(t.start_ns)));
        bus_free = t.complete_ns;
    }
    // IN (device to host): at the slot of the next frame (or after one
    // already in it); the host sees it (and stamps it) after its receive
    // latency.
    let inn = frames_from(&sim, Side::B);
    assert!(inn.len() >= 20, "{} device frames", inn.len());
    let mut bus_free = 0;
    for f in &inn {
        let t = &f.transit;
        let slot = next_sof(t.sent_ns) + 12_000;
        assert_eq!(t.start_ns, slot.max(bus_free));
        assert!(t.start_ns < next_sof(slot), "moved to a later frame");
        assert_eq!(t.visible_ns, t.complete_ns + 40_000);
        assert_eq!(f.rx_stamp, Some(sim.node(0).clock().local_us(t.visible_ns)));
        bus_free = t.complete_ns;
    }
}

#[test]
fn usb_device_queue_delay_predicts_the_bus_slot() {
    let p = UsbParams {
        in_frame_aligned: true,
        sof_phase_us: 250.0,
        slot: Dist::Const(15.0),
        ..UsbParams::default()
    };
    let host = Transmitter::new(LinkModel::UsbCdc(p), Side::A, Rng::new(1));
    for now in [0, 250_000, 250_001, 1_100_000, 7_249_999] {
        let mut device = Transmitter::new(LinkModel::UsbCdc(p), Side::B, Rng::new(1));
        let delay = device.queue_delay_ns(now);
        let t = device.transmit(now, vec![1; 20]);
        assert_eq!(now + delay, t.start_ns, "at {now}");
        assert_eq!((t.start_ns - 250_000) % MS, 15_000);
        // The host cannot know when its OUT transfer goes.
        assert_eq!(host.queue_delay_ns(now), 0);
    }
    // A second frame queues behind the first in the same slot.
    let mut device = Transmitter::new(LinkModel::UsbCdc(p), Side::B, Rng::new(1));
    let first = device.transmit(0, vec![1; 20]);
    assert_eq!(
        device.queue_delay_ns(0),
        first.start_ns + device.wire_ns(20)
    );
    assert_eq!(device.transmit(0, vec![1; 20]).start_ns, first.complete_ns);
    // 20 bytes in one 64-byte packet with 13 bytes of overhead at 12 Mbit/s.
    assert_eq!(
        device.wire_ns(20),
        (33 * 8 * 1_000_000_000u64 + 6_000_000) / 12_000_000
    );
}

#[test]
fn uart_transmit_buffer_pushes_back() {
    let model = LinkModel::uart(2_000_000);
    let mut tx = Transmitter::new(model, Side::A, Rng::new(1));
    assert!(tx.clear_to_send(0));
    let a = tx.transmit(0, vec![1; 100]);
    let b = tx.transmit(0, vec![1; 100]);
    assert_eq!(a.complete_ns, 500_000);
    assert_eq!(b.start_ns, a.complete_ns);
    // Two frames fill the default buffer until the first has left.
    assert!(!tx.clear_to_send(0));
    assert_eq!(tx.next_free(0), Some(500_000));
    assert_eq!(tx.queue_delay_ns(100_000), 900_000);
    assert!(tx.clear_to_send(500_000));
}

#[test]
fn busy_receivers_stamp_late_only_when_their_interrupts_are_preempted() {
    for late_stamps in [true, false] {
        let busy = BusyModel {
            trigger: BusyTrigger::PerEvent { probability: 0.3 },
            duration: Dist::uniform(20.0, 200.0),
            late_stamps,
        };
        let topology = pair(LinkModel::uart(2_000_000)).with_busy_modules(busy);
        let mut sim = traced(&topology, 11);
        sim.run_secs(5.0);
        let to_module = frames_from(&sim, Side::A);
        assert!(to_module.len() > 50);
        let clock = *sim.node(1).clock();
        let mut late = 0;
        for f in &to_module {
            let exact = clock.local_us(f.transit.first_byte_ns);
            let stamp = f.rx_stamp.unwrap();
            assert!(stamp >= exact);
            assert!(
                stamp - exact <= Duration::from_micros(2_000),
                "late by {} µs",
                stamp - exact
            );
            late += usize::from(stamp > exact);
        }
        if late_stamps {
            assert!(late > to_module.len() / 10, "{late} late stamps");
        } else {
            assert_eq!(late, 0);
        }
        assert!(sim.node(1).busy_spells() > 0);
    }
}

#[test]
fn udp_carries_bare_packets_and_loses_some() {
    let model = LinkModel::Udp(osap_sim::medium::IpParams {
        loss: 0.3,
        ..osap_sim::medium::IpParams::LOOPBACK
    });
    let mut sim = traced(&pair(model), 4);
    sim.run_secs(3.0);
    let end = sim.link_end(0, Side::B);
    assert!(end.frame_counters().is_none(), "datagrams are not framed");
    let stats = end.stats();
    assert!(stats.frames_lost > 0 && stats.frames_lost < stats.frames_sent);
    // A time request is a bare 15-byte packet.
    let first = sim.frames().iter().find(|f| f.from == 1).unwrap();
    assert_eq!(first.transit.bytes[0], 5, "starts with the packet header");
}

#[test]
fn usb_out_transfers_can_skip_the_frame_wait() {
    let p = UsbParams {
        out_frame_aligned: false,
        host_tx_latency: Dist::Const(30.0),
        ..UsbParams::default()
    };
    let mut host = Transmitter::new(LinkModel::UsbCdc(p), Side::A, Rng::new(1));
    let t = host.transmit(123_456, vec![1; 20]);
    assert_eq!(t.start_ns, 123_456 + 30_000);
    // IN can wait for the next frame too, when configured so.
    let framed = UsbParams {
        in_frame_aligned: true,
        ..p
    };
    let mut device = Transmitter::new(LinkModel::UsbCdc(framed), Side::B, Rng::new(1));
    let t = device.transmit(123_456, vec![1; 20]);
    assert!(t.start_ns >= 1_000_000);
}

#[test]
fn usb_in_is_polled_continuously_by_default() {
    let p = UsbParams {
        in_poll_delay: Dist::Const(7.0),
        ..UsbParams::default()
    };
    let mut device = Transmitter::new(LinkModel::UsbCdc(p), Side::B, Rng::new(1));
    let t = device.transmit(123_456, vec![1; 20]);
    // Leaves after the poll delay, mid-frame; the device cannot predict it.
    assert_eq!(t.start_ns, 123_456 + 7_000);
    assert_eq!(device.queue_delay_ns(200_000), 0);
}
