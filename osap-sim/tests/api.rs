//! The one-call API and the metrics it returns.

use osap_sim::{run, Network, Scenario};

#[test]
fn one_call_run_samples_every_node() {
    let m = run(&Network::chain4(), 1, 1.0).unwrap();
    // Samples at 0, 10 ms, ..., 1 s.
    assert_eq!(m.sample_count(), 101);
    assert_eq!(m.node_count(), 4);
    assert_eq!(m.names[m.root], "host");
    assert!(m.error_us[m.root].iter().all(|&e| e == 0.0));
    assert!(m.tier[m.root].iter().all(|&t| t == 0));
    // Each node's way to the root, for hop errors.
    let parent = |n: &str| m.parents[m.node(n).unwrap()].clone().unwrap();
    assert_eq!(
        (
            m.names[parent("hub1").node].as_str(),
            parent("hub1").link_type
        ),
        ("host", "usb_cdc")
    );
    assert_eq!(
        (m.names[parent("m1").node].as_str(), parent("m1").depth),
        ("hub2", 3)
    );
    assert_eq!(m.hop_error(m.root), None);
    assert!(m.hop_stats("uart", 0.0).is_some());
}

#[test]
fn scenario_options_apply() {
    let outcome = Scenario::new(Network::loop3())
        .seed(3)
        .seconds(0.5)
        .sample_period_us(50_000)
        .hot_start(true)
        .run()
        .unwrap();
    assert_eq!(outcome.metrics.sample_count(), 11);
    assert!(outcome.hot_start_applied);
    assert!(outcome.sim.events() > 0);
    assert!(Scenario::new(Network::loop3())
        .seconds(f64::NAN)
        .run()
        .is_err());
}

#[test]
fn hot_start_presets_each_clock_to_the_root_rate() {
    use osap_sim::clock::ClockSpec;
    use osap_sim::{LinkModel, NodeSpec};
    let topology = Network::new("pair")
        .with_node(NodeSpec::host("host").with_clock(ClockSpec::fixed(0.0, -20.0)))
        .with_node(NodeSpec::mcu("m1").with_clock(ClockSpec::fixed(3e6, 80.0)))
        .with_link("host", "m1", LinkModel::uart(2_000_000));
    for hot in [false, true] {
        let (mut sim, applied) = Scenario::new(topology.clone())
            .hot_start(hot)
            .build()
            .unwrap();
        assert_eq!(applied, hot);
        // Without sync, only the preset rate moves m1's system time.
        sim.configure_clocks(|_, cfg| cfg.enabled = false).unwrap();
        sim.run_secs(10.0);
        let e = &sim.metrics().error_us[1];
        let drift = e[e.len() - 1] - e[0];
        if hot {
            assert!(drift.abs() <= 2.0, "hot start drifted {drift} µs in 10 s");
        } else {
            // 100 ppm apart: a millisecond in 10 s.
            assert!((drift - 1000.0).abs() <= 2.0, "{drift}");
        }
    }
}

#[test]
fn a_simulation_can_move_to_another_thread() {
    fn assert_send<T: Send>() {}
    assert_send::<osap_sim::Sim>();
    let handle = std::thread::spawn(|| run(&Network::star(2), 1, 0.1).map(|m| m.sample_count()));
    assert_eq!(handle.join().unwrap(), Ok(11));
}
