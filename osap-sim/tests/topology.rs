//! Topology builders, the text form, and configuration errors.

use osap_sim::medium::UartParams;
use osap_sim::{LinkModel, NodeSpec, Sim, SimConfig, SimError, Topology};

fn link_types(t: &Topology) -> Vec<&'static str> {
    t.links.iter().map(|l| l.model.type_name()).collect()
}

#[test]
fn built_in_shapes() {
    let chain = Topology::chain4();
    let names: Vec<&str> = chain.nodes.iter().map(|n| n.name.as_str()).collect();
    assert_eq!(names, ["host", "hub1", "hub2", "m1"]);
    assert_eq!(link_types(&chain), ["usb_cdc", "uart", "uart"]);
    assert_eq!(chain.root(), Some(0));

    let star = Topology::star8();
    let ends = star.endpoints();
    let hub = star.node_index("hub").unwrap();
    let hub_links = ends.iter().flatten().filter(|(n, _)| *n == hub).count();
    assert_eq!(hub_links, 9);

    let ring = Topology::loop3();
    assert_eq!(ring.name, "loop");
    assert_eq!(
        link_types(&ring),
        ["usb_cdc", "uart", "uart", "uart", "uart"]
    );
    // Link indices at a node follow the order links were added: a's links
    // are USB (0), to b (1), from c (2).
    let a = ring.node_index("a").unwrap();
    assert_eq!(ring.endpoints()[3][1], (a, 2));

    let tree = Topology::tree(2, 3);
    assert_eq!(tree.nodes.len(), 2 + 3 + 9);
    for name in ["chain4", "star8", "loop", "tree2x3", "chain2"] {
        Topology::named(name).unwrap().validate().unwrap();
    }
    assert!(Topology::named("star40").is_err());
    assert!(Topology::named("mesh").is_err());
}

#[test]
fn text_form_matches_the_builder() {
    let text = "
        # host -> USB -> hub -> UART -> hub -> UART -> module
        name chain4
        node host host root
        node hub1 mcu
        node hub2 mcu
        node m1 mcu
        link host hub1 usb_cdc
        link hub1 hub2 uart baud=2000000
        link hub2 m1 uart baud=2000000
    ";
    let parsed = Topology::parse(text).unwrap();
    assert_eq!(parsed, Topology::chain4());

    let custom = Topology::parse(
        "node pc host root\nnode a mcu busy rate_ppm=-20\n\
         link pc a uart baud=3000000 corrupt=0.001 jitter_us=2 asym_us=1.5\n\
         link pc a udp preset=lan loss=0.1",
    )
    .unwrap();
    let LinkModel::Uart(u) = custom.links[0].model else {
        panic!("uart expected")
    };
    assert_eq!(
        (u.baud, u.corrupt_per_byte, u.asymmetry_us),
        (3_000_000, 0.001, 1.5)
    );
    assert!(custom.nodes[1].busy.is_some());
}

#[test]
fn bad_descriptions_get_clear_errors() {
    let parse_err = |text: &str| Topology::parse(text).unwrap_err().to_string();
    let e = parse_err("node h host root\nnode m mcu\nlink h m uart speed=9");
    assert!(e.contains("line 3") && e.contains("speed"), "{e}");
    let e = parse_err("node h host root\nlink h x uart");
    assert!(e.contains("no node named \"x\""), "{e}");
    let e = parse_err("node h host\nnode m mcu\nlink h m uart");
    assert!(e.contains("no clock root"), "{e}");
    let e = parse_err("node h host root\nnode h mcu");
    assert!(e.contains("used twice"), "{e}");
    let e = parse_err("node h host root\nnode m mcu\nlink h m uart baud=5");
    assert!(e.contains("baud"), "{e}");
    let e = parse_err("node h host root\nnode m mcu\nlink h m tcp loss=0.1");
    assert!(e.contains("TCP"), "{e}");

    // Too many links at one node, and a bad parameter, via the builder.
    let crowded = Topology::star(16);
    assert!(matches!(
        Sim::new(&crowded, SimConfig::default()),
        Err(SimError::Config(m)) if m.contains("more than 16 links")
    ));
    let lossy = Topology::new("x")
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
