//! Network builders, the TOML form, link indices, and configuration
//! errors.

use osap_core::link::LinkGateway;
use osap_sim::clock::{ClockSpec, Param};
use osap_sim::medium::{Side, UartParams};
use osap_sim::network::{Gateway, NetLink};
use osap_sim::rng::Dist;
use osap_sim::{LinkModel, Network, NodeKind, NodeSpec, Sim, SimConfig, SimError};

fn link_types(t: &Network) -> Vec<&'static str> {
    t.links.iter().map(|l| l.model.type_name()).collect()
}

#[test]
fn built_in_shapes() {
    let chain = Network::chain4();
    let names: Vec<&str> = chain.nodes.iter().map(|n| n.name.as_str()).collect();
    assert_eq!(names, ["host", "hub1", "hub2", "m1"]);
    assert_eq!(link_types(&chain), ["usb_cdc", "uart", "uart"]);
    assert_eq!(chain.root(), Some(0));

    let star = Network::star8();
    let ends = star.endpoints();
    let hub = star.node_index("hub").unwrap();
    let hub_links = ends.iter().flatten().filter(|(n, _)| *n == hub).count();
    assert_eq!(hub_links, 9);

    let ring = Network::loop3();
    assert_eq!(ring.name, "loop");
    assert_eq!(
        link_types(&ring),
        ["usb_cdc", "uart", "uart", "uart", "uart"]
    );
    // Link indices at a node follow the order links were added: a's links
    // are USB (0), to b (1), from c (2).
    let a = ring.node_index("a").unwrap();
    assert_eq!(ring.endpoints()[3][1], (a, 2));

    let tree = Network::tree(2, 3);
    assert_eq!(tree.nodes.len(), 2 + 3 + 9);
    for name in ["chain4", "star8", "loop", "tree2x3", "chain2"] {
        Network::named(name).unwrap().validate().unwrap();
    }
    assert!(Network::named("star40").is_err());
    assert!(Network::named("mesh").is_err());
}

#[test]
fn toml_form_matches_the_builder() {
    // The format the simulated machines read; clocks drawn from the seed,
    // as the builders draw them.
    let text = r#"
        # host -> USB -> hub -> UART -> hub -> UART -> module
        name = "chain4"
        [host]
        clock = "drawn"
        [[module]]
        name = "hub1"
        type = "hub"
        clock = "drawn"
        [[module]]
        name = "hub2"
        type = "hub"
        clock = "drawn"
        [[module]]
        name = "m1"
        type = "hub"
        clock = "drawn"
        [[link]]
        a = "host"
        b = "hub1"
        kind = "usb"
        [[link]]
        a = "hub1"
        b = "hub2"
        kind = "uart"
        baud = 2000000
        [[link]]
        a = "hub2"
        b = "m1"
        kind = "uart"
    "#;
    let parsed = Network::from_toml(text).unwrap();
    assert_eq!(parsed, Network::chain4());

    let custom = Network::from_toml(
        r#"
        [host]
        kind = "mcu"
        busy = true
        [[module]]
        name = "a"
        type = "hub"
        root = true
        busy = true
        rate_ppm = -20.0
        offset_us = 1500.0
        wander_ppm = 1.0
        wander_period_s = 200.0
        [[link]]
        a = "host"
        b = "a"
        kind = "uart"
        baud = 3000000
        corrupt_per_byte = 0.001
        jitter_us = 2.0
        loss = 0.01
        name = "j4"
        [[link]]
        a = "a"
        b = "host"
        kind = "usb"
        loss = 0.1
        mtu = 64
        [[link]]
        a = "host"
        b = "a"
        kind = "memory"
        "#,
    )
    .unwrap();
    assert_eq!(custom.name, "custom");
    let (host, a) = (&custom.nodes[0], &custom.nodes[1]);
    assert_eq!((host.name.as_str(), host.kind), ("host", NodeKind::Mcu));
    assert!(!host.root && host.busy.is_some());
    assert_eq!(host.clock, ClockSpec::IDEAL);
    assert!(a.root && a.busy.is_some());
    assert_eq!(
        a.clock,
        ClockSpec {
            offset_us: Param::Fixed(1500.0),
            rate_ppm: Param::Fixed(-20.0),
            wander_ppm: Param::Fixed(1.0),
            wander_period_s: Param::Fixed(200.0),
        }
    );
    let LinkModel::Uart(u) = custom.links[0].model else {
        panic!("uart expected")
    };
    assert_eq!(
        (u.baud, u.corrupt_per_byte, u.loss, u.jitter),
        (3_000_000, 0.001, 0.01, Dist::uniform(0.0, 2.0))
    );
    assert_eq!(custom.links[0].name, "j4");
    // On USB the host is end A, whichever end the file names it.
    let usb = &custom.links[1];
    assert_eq!((usb.a.as_str(), usb.b.as_str()), ("host", "a"));
    let LinkModel::UsbCdc(p) = usb.model else {
        panic!("usb expected")
    };
    assert_eq!((p.loss, p.mtu), (0.1, 64));
    // A memory link is an instant UDP link.
    let LinkModel::Udp(p) = custom.links[2].model else {
        panic!("udp expected")
    };
    assert_eq!(p.latency, Dist::ZERO);
    assert_eq!(link_types(&custom), ["uart", "usb_cdc", "udp"]);
}

#[test]
fn a_stepper_has_the_firmware_links_in_both_simulators() {
    // s's UART is listed before its USB; t is reached only over a UART.
    let t = Network::from_toml(
        r#"
        [[module]]
        name = "hub"
        type = "hub"
        [[module]]
        name = "s"
        type = "stepper"
        [[module]]
        name = "t"
        type = "stepper"
        [[link]]
        a = "host"
        b = "hub"
        kind = "usb"
        [[link]]
        a = "hub"
        b = "s"
        kind = "uart"
        [[link]]
        a = "s"
        b = "host"
        kind = "usb"
        [[link]]
        a = "hub"
        b = "t"
        kind = "rs485"
        "#,
    )
    .unwrap();
    let n = |name: &str| t.node_index(name).unwrap();
    let (host, hub, s, tt) = (n("host"), n("hub"), n("s"), n("t"));
    assert_eq!(
        t.endpoints(),
        [
            [(host, 0), (hub, 0)],
            [(hub, 1), (s, 1)],
            [(host, 1), (s, 0)],
            [(hub, 2), (tt, 1)],
        ]
    );
    let gateways = t.gateways().unwrap();
    assert_eq!(gateways[tt][0], Gateway::Unconnected(0));
    assert_eq!(t.unconnected[0].model.type_name(), "usb_cdc");
    // In the simulation t's link 0 is there, closed for good, and its
    // link 1 is the RS-485 line to the hub.
    let mut sim = Sim::new(&t, SimConfig::default()).unwrap();
    let t_links = sim.node(tt).links();
    assert_eq!(t_links.len(), 2);
    assert!(!t_links[0].is_connected() && !t_links[0].is_open());
    assert_eq!(t_links[0].info().type_name, "usb_cdc");
    assert!(t_links[1].is_connected() && t_links[1].is_open());
    assert_eq!(t_links[1].info().type_name, "rs485");
    sim.node_mut(tt).link_mut(0).unwrap().set_open(true);
    assert!(!sim.node(tt).links()[0].is_open());
    sim.run_secs(3.0);
    let worst = sim.metrics().worst_abs().last().copied().unwrap();
    assert!(worst < 100.0, "worst error {worst} µs");
}

#[test]
fn link_indices_asked_for_are_checked() {
    let two = || {
        Network::new("x")
            .with_node(NodeSpec::host("h"))
            .with_node(NodeSpec::mcu("m"))
    };
    // An index asked for is kept; the others fill the lowest free ones.
    let mut t = two();
    t.add_link_spec(NetLink::new("h", "m", LinkModel::usb_cdc()).at(Side::B, 1));
    t.add_link("h", "m", LinkModel::uart(2_000_000));
    assert_eq!(t.endpoints(), [[(0, 0), (1, 1)], [(0, 1), (1, 0)]]);
    t.validate().unwrap();

    let err = |t: Network| t.validate().unwrap_err().to_string();
    let mut gap = two();
    gap.add_link_spec(NetLink::new("h", "m", LinkModel::usb_cdc()).at(Side::B, 2));
    let e = err(gap);
    assert!(e.contains("node m") && e.contains("link index 0"), "{e}");
    let mut twice = two();
    twice.add_link_spec(NetLink::new("h", "m", LinkModel::usb_cdc()).at(Side::B, 0));
    twice.add_unconnected("m", 0, LinkModel::usb_cdc());
    let e = err(twice);
    assert!(e.contains("link index 0 is asked for twice"), "{e}");
    let mut far = two();
    far.add_unconnected("m", 16, LinkModel::usb_cdc());
    assert!(err(far).contains("more than 16 links"));
    let mut nowhere = two();
    nowhere.add_unconnected("q", 0, LinkModel::usb_cdc());
    assert!(err(nowhere).contains("no node named \"q\""));
}

#[test]
fn bad_descriptions_get_clear_errors() {
    let toml_err = |text: &str| Network::from_toml(text).unwrap_err().to_string();
    const HUB: &str = "[[module]]\nname = \"m\"\ntype = \"hub\"\n";
    let link = |kind: &str, extra: &str| {
        format!("{HUB}[[link]]\na = \"host\"\nb = \"m\"\nkind = \"{kind}\"\n{extra}")
    };
    let e = toml_err(&link("uart", "speed = 9\n"));
    assert!(e.contains("speed"), "{e}");
    let e = toml_err(&link("uart", "baud = 5\n"));
    assert!(e.contains("baud"), "{e}");
    let e = toml_err(&link("usb", "jitter_us = 2.0\n"));
    assert!(e.contains("jitter_us applies to uart and rs485"), "{e}");
    let e = toml_err(&link("usb", "corrupt_per_byte = 0.1\n"));
    assert!(e.contains("corrupt_per_byte applies to uart"), "{e}");
    let e = toml_err(&link("memory", "loss = 0.1\n"));
    assert!(e.contains("remove loss"), "{e}");
    let e = toml_err(&link("uart", "loss = 1.5\n"));
    assert!(e.contains("loss 1.5 must be a probability"), "{e}");
    let e = toml_err(&format!(
        "zero_latency = true\n{}",
        link("uart", "loss = 0.5\n")
    ));
    assert!(e.contains("zero_latency"), "{e}");
    let e = toml_err(&format!("sync = false\n{}", link("uart", "")));
    assert!(e.contains("always runs clock sync"), "{e}");
    let e = toml_err(&format!("[host]\nkind = \"pc\"\n{}", link("uart", "")));
    assert!(e.contains("pc"), "{e}");
    let e = toml_err(&format!(
        "{}[[module]]\nname = \"n\"\ntype = \"hub\"\nroot = true\n\
         [[module]]\nname = \"o\"\ntype = \"hub\"\nroot = true\n\
         [[link]]\na = \"m\"\nb = \"n\"\nkind = \"uart\"\n\
         [[link]]\na = \"m\"\nb = \"o\"\nkind = \"uart\"\n",
        link("uart", "")
    ));
    assert!(e.contains("already the clock root"), "{e}");
    // A name the machines take but the simulator does not.
    let e = toml_err(
        "[[module]]\nname = \"a b\"\ntype = \"hub\"\n\
         [[link]]\na = \"host\"\nb = \"a b\"\nkind = \"usb\"\n",
    );
    assert!(e.contains("whitespace"), "{e}");

    // Too many links at one node, and a bad parameter, via the builder.
    let crowded = Network::star(16);
    assert!(matches!(
        Sim::new(&crowded, SimConfig::default()),
        Err(SimError::Config(m)) if m.contains("more than 16 links")
    ));
    let lossy = Network::new("x")
        .with_node(NodeSpec::host("h"))
        .with_node(NodeSpec::mcu("m"))
        .with_link(
            "h",
            "m",
            LinkModel::Uart(UartParams {
                loss: 1.5,
                ..UartParams::default()
            }),
        );
    let e = Sim::new(&lossy, SimConfig::default())
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("loss") && e.contains("h - m"), "{e}");
}
