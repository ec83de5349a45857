//! Simulated modules on a real host: the shipped topologies, routes from the
//! file, drifting clocks, modules that die and come back, link latency.

use osap_core::clock::SyncState;
use osap_core::netresponder::key;
use osap_core::packet::Instruction;
use osap_core::route::Route;
use osap_core::transport::Transport;
use osap_host::netrunner::{self, Netrunner, ScanOptions};
use osap_host::{Host, HostConfig, HostError, PortHandle};
use osap_sim::machine::SimMachine;
use osap_sim::topology::{LinkKind, LinkSpec, ModuleKind, ModuleSpec, SimSpec, HOST};
use std::time::{Duration, Instant};

mod common;
use common::shipped;

fn host() -> Host {
    Host::start(HostConfig::default()).unwrap()
}

/// Asks the netresponder at the end of `route` for its name.
async fn name_at(port: &PortHandle, route: &Route, timeout: Duration) -> Result<String, HostError> {
    let reply = port.request(route, 0, &[key::NAME], timeout).await?;
    assert!(matches!(reply.transport, Transport::Reply(_)));
    // [key][status][str8]
    assert_eq!(&reply.body[..2], &[key::NAME, 0], "{:?}", reply.body);
    Ok(String::from_utf8(reply.body[3..].to_vec()).unwrap())
}

fn route(links: &[u8]) -> Route {
    Route::through_links(links).unwrap()
}

const ANSWER: Duration = Duration::from_secs(1);

#[test]
fn shipped_topologies_load() {
    let single = SimSpec::load(shipped("single-usb.toml")).unwrap();
    assert_eq!(single.modules.len(), 1);
    assert_eq!(single.links.len(), 1);
    assert_eq!(single.links[0].kind, LinkKind::Usb);

    let small = SimSpec::load(shipped("small-machine.toml")).unwrap();
    assert_eq!(small.name, "small-machine");
    assert_eq!(small.modules.len(), 5);
    assert_eq!(small.links_of("hub"), vec![0, 1, 2, 3, 4]);
    let uarts = small.links.iter().filter(|l| l.kind == LinkKind::Uart);
    assert_eq!(uarts.count(), 4);
    assert_eq!(small.modules[1].rate_ppm, 40.0);

    let looped = SimSpec::load(shipped("loop.toml")).unwrap();
    assert_eq!(looped.modules.len(), 4);
    // c's links in file order: b–c, c–a, c–m1.
    assert_eq!(looped.links_of("c"), vec![2, 3, 4]);
    assert!(!looped.zero_latency && looped.sync);
}

#[tokio::test]
async fn single_module_on_usb_answers() {
    let host = host();
    let topology = SimSpec::load(shipped("single-usb.toml")).unwrap();
    let machine = SimMachine::start(&host, &topology).await.unwrap();
    assert_eq!(machine.host_links(), &[0]);
    let motor = machine.route_to("motor").unwrap();
    assert_eq!(motor, route(&[0]));
    let port = host.open_port("test").await.unwrap();
    assert_eq!(name_at(&port, &motor, ANSWER).await.unwrap(), "motor");
    let reply = port
        .request(&motor, 0, &[key::TYPE_NAME], ANSWER)
        .await
        .unwrap();
    assert_eq!(&reply.body[3..], b"stepper");
    // Identified as a simulated module with a module's packet size.
    let nr = Netrunner::new(&host).await.unwrap();
    let info = nr.runtime_info(&motor, 1).await.unwrap();
    assert_eq!(info.build, 3, "BuildKey::RustSimulated");
    assert_eq!(info.packet_size, 256);
    // The module firmware's two links: USB (link 0, this one) and a UART
    // (link 1), which nothing joins here, so it never opens.
    assert_eq!(info.link_count, 2);
    assert_eq!(info.arrival_link, 0);
    let link = nr.link_info(&motor, 0).await.unwrap();
    assert_eq!(link.type_name, "usb_cdc");
    assert!(link.open);
    let uart = nr.link_info(&motor, 1).await.unwrap();
    assert_eq!(uart.type_name, "uart");
    assert!(!uart.open);
}

#[tokio::test]
async fn small_machine_modules_answer_over_the_routes_in_the_file() {
    let host = host();
    let topology = SimSpec::load(shipped("small-machine.toml")).unwrap();
    let machine = SimMachine::start(&host, &topology).await.unwrap();
    let h = machine.host_links()[0];
    // From the file: the hub's link 0 is the USB to the host, then one UART
    // per module in the order they are listed.
    let expected = [
        ("hub", vec![h]),
        ("x", vec![h, 1]),
        ("y", vec![h, 2]),
        ("z", vec![h, 3]),
        ("tool", vec![h, 4]),
    ];
    let port = host.open_port("test").await.unwrap();
    for (name, links) in expected {
        let r = route(&links);
        assert_eq!(machine.route_to(name), Some(r), "{name}");
        assert_eq!(name_at(&port, &r, ANSWER).await.unwrap(), name);
    }
    // Each stepper's link 1, the firmware's UART, leads back to the hub;
    // its link 0, the firmware's USB, is joined to nothing and stays closed.
    assert_eq!(
        name_at(&port, &route(&[h, 3, 1]), ANSWER).await.unwrap(),
        "hub"
    );
    let nr = Netrunner::new(&host).await.unwrap();
    let uart = nr.link_info(&route(&[h, 4]), 1).await.unwrap();
    assert_eq!(uart.type_name, "uart");
    assert_eq!(uart.mtu, 256);
    assert!(uart.open);
    let usb = nr.link_info(&route(&[h, 4]), 0).await.unwrap();
    assert_eq!(usb.type_name, "usb_cdc");
    assert!(!usb.open);
    let err = name_at(&port, &route(&[h, 4, 0]), Duration::from_millis(100))
        .await
        .unwrap_err();
    assert!(matches!(err, HostError::Timeout { .. }), "{err}");
}

#[tokio::test]
async fn loop_modules_answer_both_ways_round_the_loop() {
    let host = host();
    let topology = SimSpec::load(shipped("loop.toml")).unwrap();
    let machine = SimMachine::start(&host, &topology).await.unwrap();
    let h = machine.host_links()[0];
    let port = host.open_port("test").await.unwrap();
    // Shortest routes: a: host→a; b: a's link 1; c: a's link 2 (c–a);
    // m1: then c's link 2.
    let expected = [
        ("a", vec![h]),
        ("b", vec![h, 1]),
        ("c", vec![h, 2]),
        ("m1", vec![h, 2, 2]),
    ];
    for (name, links) in expected {
        let r = route(&links);
        assert_eq!(machine.route_to(name), Some(r), "{name}");
        assert_eq!(name_at(&port, &r, ANSWER).await.unwrap(), name);
    }
    // The long way round: a → b → c → m1, and all the way back to a.
    let long = route(&[h, 1, 1, 2]);
    assert_eq!(name_at(&port, &long, ANSWER).await.unwrap(), "m1");
    let round = route(&[h, 1, 1, 1]);
    assert_eq!(name_at(&port, &round, ANSWER).await.unwrap(), "a");
    // m1 is a stepper: c is behind its link 1, the firmware's UART.
    let back = route(&[h, 2, 2, 1]);
    assert_eq!(name_at(&port, &back, ANSWER).await.unwrap(), "c");
}

#[tokio::test]
async fn a_scan_maps_the_loop_as_the_file_describes_it() {
    for zero_latency in [true, false] {
        scan_matches_the_file("loop.toml", zero_latency).await;
    }
}

#[tokio::test]
async fn a_scan_maps_the_small_machine_as_the_file_describes_it() {
    scan_matches_the_file("small-machine.toml", false).await;
}

#[tokio::test]
async fn a_scan_maps_the_single_usb_module_as_the_file_describes_it() {
    scan_matches_the_file("single-usb.toml", false).await;
}

async fn scan_matches_the_file(file: &str, zero_latency: bool) {
    let host = host();
    let topology = SimSpec::load(shipped(file))
        .unwrap()
        .with_zero_latency(zero_latency);
    let machine = SimMachine::start(&host, &topology).await.unwrap();
    let report = netrunner::scan(&host, &ScanOptions::default())
        .await
        .unwrap();
    assert!(report.failures.is_empty(), "{:?}", report.failures);
    let map = &report.map;
    assert_eq!(map.runtimes.len(), 1 + topology.modules.len());
    // Every link in the file is one edge of the map, between the right
    // link indices.
    assert_eq!(map.links.len(), topology.links.len());
    for spec in &topology.links {
        let end = |name: &str, other: &str| -> (usize, u8) {
            let runtime = map
                .runtimes
                .iter()
                .position(|r| r.name == if name == HOST { "host" } else { name })
                .unwrap();
            // The link's index at this end: a stepper's follows the
            // firmware (USB is link 0, a UART link 1), others' their
            // position among this end's links in the file.
            let position = topology
                .links_of(name)
                .iter()
                .position(|&i| {
                    let l = &topology.links[i];
                    (l.a == name && l.b == other) || (l.b == name && l.a == other)
                })
                .unwrap();
            let stepper = topology
                .modules
                .iter()
                .any(|m| m.name == name && m.kind() == Some(ModuleKind::Stepper));
            let index = if name == HOST {
                machine.host_links()[position]
            } else if stepper {
                match topology.links[topology.links_of(name)[position]].kind {
                    LinkKind::Usb => 0,
                    _ => 1,
                }
            } else {
                position as u8
            };
            (runtime, index)
        };
        let a = end(&spec.a, &spec.b);
        let b = end(&spec.b, &spec.a);
        let found = map.links.iter().any(|e| {
            let x = (e.a.runtime, e.a.link);
            let y = (e.b.runtime, e.b.link);
            (x, y) == (a, b) || (x, y) == (b, a)
        });
        assert!(found, "{spec:?} not in {:?}", map.links);
    }
    for m in machine.modules() {
        let record = map.find(m.name()).unwrap();
        assert_eq!(record.type_name, m.type_name());
        assert_eq!(record.build, 3);
    }
}

#[tokio::test]
async fn module_clocks_drift_as_configured() {
    let host = host();
    let topology = SimSpec::load(shipped("small-machine.toml")).unwrap();
    let machine = SimMachine::start(&host, &topology).await.unwrap();
    for (m, spec) in machine.modules().iter().zip(&topology.modules) {
        let clock = m.clock();
        assert_eq!(clock.rate_ppm(), spec.rate_ppm);
        // Over ten seconds the counter gains rate_ppm × 10 µs (± the
        // wander's effect and rounding).
        let t0 = Instant::now() + Duration::from_secs(1);
        let t1 = t0 + Duration::from_secs(10);
        let gained = (clock.local_at(t1) - clock.local_at(t0)).as_micros() as f64 - 10e6;
        let tolerance = 2.0 + spec.wander_ppm * 10.0;
        assert!(
            (gained - spec.rate_ppm * 10.0).abs() <= tolerance,
            "{}: gained {gained} µs, expected {}",
            spec.name,
            spec.rate_ppm * 10.0
        );
        // The inverse: a wake-up at local time T is the first instant the
        // counter reads T.
        let target = clock.local_at(t1);
        let at = clock.instant_at(target);
        assert!(clock.local_at(at) >= target);
        assert!(clock.local_at(at - Duration::from_micros(2)) < target);
        // The runtime runs on this clock.
        let before = Instant::now();
        let now = m.with_runtime(|_, now| now).await.unwrap();
        let after = Instant::now();
        assert!(
            clock.local_at(before) <= now && now <= clock.local_at(after),
            "{}",
            spec.name
        );
    }
}

#[tokio::test]
async fn a_drifting_module_synchronises_to_the_host() {
    let host = host();
    let topology = SimSpec::new("drift")
        .with_module(ModuleSpec::new("fast", "stepper").with_rate_ppm(150.0))
        .with_link(LinkSpec::new("host", "fast", LinkKind::Uart));
    let machine = SimMachine::start(&host, &topology).await.unwrap();
    let fast = machine.module("fast").unwrap();
    let nr = Netrunner::new(&host).await.unwrap();
    let r = machine.route_to("fast").unwrap();
    // Wait (bounded) until the module follows the host and has learned
    // its oscillator's rate: a correction of about −150 ppm.
    let give_up = Instant::now() + Duration::from_secs(20);
    let status = loop {
        let status = nr.clock_status(&r).await.unwrap();
        let learned = (f64::from(status.rate_ppb) / 1000.0 + 150.0).abs() < 10.0;
        if status.state == SyncState::Synced && learned {
            break status;
        }
        assert!(Instant::now() < give_up, "not synchronised: {status:?}");
        tokio::time::sleep(Duration::from_millis(100)).await;
    };
    eprintln!("synchronised: {status:?}");
    assert_eq!(status.tier, 1);
    // Its system time now agrees with the host's (within scheduling noise).
    let host_before = host.system_time().await.unwrap().as_micros();
    let module = fast
        .with_runtime(|rt, now| rt.system_time(now).as_micros())
        .await
        .unwrap();
    let host_after = host.system_time().await.unwrap().as_micros();
    let slack = 500;
    assert!(
        host_before.saturating_sub(slack) <= module && module <= host_after + slack,
        "module {module} outside host [{host_before}, {host_after}]"
    );
}

#[tokio::test]
async fn a_killed_module_stops_answering_and_the_others_go_on() {
    let host = host();
    let topology = SimSpec::load(shipped("small-machine.toml")).unwrap();
    let machine = SimMachine::start(&host, &topology).await.unwrap();
    let port = host.open_port("test").await.unwrap();
    let x = machine.module("x").unwrap();
    let rx = machine.route_to("x").unwrap();
    assert_eq!(name_at(&port, &rx, ANSWER).await.unwrap(), "x");

    x.kill().await.unwrap();
    assert!(!x.is_running());
    assert_eq!(machine.link_is_up(1), Some(false)); // hub – x
    assert_eq!(machine.link_is_up(2), Some(true));
    let err = name_at(&port, &rx, Duration::from_millis(100))
        .await
        .unwrap_err();
    assert!(matches!(err, HostError::Timeout { .. }), "{err}");
    assert!(x.with_runtime(|_, now| now).await.is_err());
    for other in ["hub", "y", "z", "tool"] {
        let r = machine.route_to(other).unwrap();
        assert_eq!(name_at(&port, &r, ANSWER).await.unwrap(), other);
    }

    // Back from the dead: a fresh boot, answering again.
    x.restart().await.unwrap();
    assert!(x.is_running());
    assert_eq!(machine.link_is_up(1), Some(true));
    assert_eq!(name_at(&port, &rx, ANSWER).await.unwrap(), "x");
    assert!(
        x.local_now() < osap_core::Instant::from_micros(10_000_000),
        "the clock restarted at boot"
    );
}

#[tokio::test]
async fn killing_the_hub_cuts_off_everything_behind_it() {
    let host = host();
    let topology = SimSpec::load(shipped("small-machine.toml"))
        .unwrap()
        .with_zero_latency(true);
    let machine = SimMachine::start(&host, &topology).await.unwrap();
    let port = host.open_port("test").await.unwrap();
    let hub = machine.module("hub").unwrap();
    hub.kill().await.unwrap();
    for l in 0..topology.links.len() {
        assert_eq!(machine.link_is_up(l), Some(false), "link {l}");
    }
    for m in machine.modules() {
        let r = machine.route_to(m.name()).unwrap();
        let err = name_at(&port, &r, Duration::from_millis(50)).await;
        assert!(
            matches!(err, Err(HostError::Timeout { .. })),
            "{}",
            m.name()
        );
    }
    // The modules behind it kept running: they answer once it is back.
    hub.restart().await.unwrap();
    for m in machine.modules() {
        let r = machine.route_to(m.name()).unwrap();
        assert_eq!(name_at(&port, &r, ANSWER).await.unwrap(), m.name());
    }
}

#[tokio::test]
async fn a_restarted_module_keeps_the_name_the_network_gave_it() {
    let host = host();
    let topology = SimSpec::load(shipped("single-usb.toml"))
        .unwrap()
        .with_zero_latency(true);
    let machine = SimMachine::start(&host, &topology).await.unwrap();
    let r = machine.route_to("motor").unwrap();
    assert_eq!(
        netrunner::rename(&host, &r, "x-axis").await.unwrap(),
        "x-axis"
    );
    let motor = &machine.modules()[0];
    motor.kill().await.unwrap();
    motor.restart().await.unwrap();
    let port = host.open_port("test").await.unwrap();
    assert_eq!(name_at(&port, &r, ANSWER).await.unwrap(), "x-axis");
}

/// host –memory– hub –UART at `baud`– m.
fn uart_pair(baud: u32, zero: bool) -> SimSpec {
    let uart = LinkSpec {
        baud: Some(baud),
        ..LinkSpec::new("hub", "m", LinkKind::Uart)
    };
    SimSpec {
        sync: false,
        ..SimSpec::new("uart-pair")
    }
    .with_module(ModuleSpec::new("hub", "hub"))
    .with_module(ModuleSpec::new("m", "stepper"))
    .with_link(LinkSpec::new("host", "hub", LinkKind::Memory))
    .with_link(uart)
    .with_zero_latency(zero)
}

async fn median_round_trip(host: &Host, r: &Route, n: usize) -> Duration {
    let port = host.open_port("timing").await.unwrap();
    let mut times = Vec::with_capacity(n);
    for _ in 0..n {
        let t = Instant::now();
        name_at(&port, r, ANSWER).await.unwrap();
        times.push(t.elapsed());
    }
    times.sort();
    times[n / 2]
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn uart_latency_adds_the_wire_time_of_request_and_reply() {
    const BAUD: u32 = 115_200;
    let host = host();
    let zero = SimMachine::start(&host, &uart_pair(BAUD, true))
        .await
        .unwrap();
    let timed = SimMachine::start(&host, &uart_pair(BAUD, false))
        .await
        .unwrap();
    let r_zero = zero.route_to("m").unwrap();
    let r_timed = timed.route_to("m").unwrap();
    let fast = median_round_trip(&host, &r_zero, 21).await;
    let slow = median_round_trip(&host, &r_timed, 21).await;

    // Both packets cross the UART whole: header with the route, then the
    // payload (request: transport + key; reply: transport + key, status,
    // the name as str8). Each takes (len + 4) × 10 bits.
    let terminal = Instruction::PortHandle { src: 1, dst: 0 };
    let request = r_timed.header_len(terminal) + 3 + 1;
    let reply = r_timed.reversed().header_len(terminal) + 3 + 3 + 1;
    let wire = |len: usize| Duration::from_secs_f64((len + 4) as f64 * 10.0 / f64::from(BAUD));
    let expected = wire(request) + wire(reply);
    let added = slow.saturating_sub(fast);
    eprintln!("zero {fast:?}, uart {slow:?}, added {added:?}, wire {expected:?}");
    assert!(fast < Duration::from_millis(1), "zero latency: {fast:?}");
    assert!(
        added >= expected.mul_f64(0.95) && added <= expected + Duration::from_millis(1),
        "UART added {added:?}, wire time {expected:?} (zero {fast:?}, uart {slow:?})"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn usb_round_trips_wait_for_the_bus_frame() {
    let host = host();
    let topology = SimSpec::load(shipped("single-usb.toml")).unwrap();
    let machine = SimMachine::start(&host, &topology).await.unwrap();
    let r = machine.route_to("motor").unwrap();
    let median = median_round_trip(&host, &r, 21).await;
    // OUT waits for the next 1 ms frame (0.5 ms on average), then software
    // latencies of tens of µs each way.
    assert!(
        median >= Duration::from_micros(150) && median <= Duration::from_millis(3),
        "{median:?}"
    );
}

fn parse_error(text: &str) -> String {
    match SimSpec::parse(text) {
        Ok(t) => panic!("accepted: {t:?}"),
        Err(e) => e.to_string(),
    }
}

const HUB: &str = "[[module]]\nname = \"hub\"\ntype = \"hub\"\n";
const HOST_HUB: &str = "[[link]]\na = \"host\"\nb = \"hub\"\nkind = \"usb\"\n";
const STEPPER: &str = "[[module]]\nname = \"s\"\ntype = \"stepper\"\n";
const HUB_S: &str = "[[link]]\na = \"hub\"\nb = \"s\"\nkind = \"uart\"\n";

#[test]
fn bad_topologies_are_refused_with_reasons() {
    let cases: Vec<(String, &str)> = vec![
        (
            format!("{HUB}{HOST_HUB}[[link]]\na = \"hub\"\nb = \"q\"\nkind = \"uart\"\n"),
            "no module is named \"q\"",
        ),
        (
            format!("{HUB}{HUB}{HOST_HUB}"),
            "module 1 is also named \"hub\"",
        ),
        (
            format!(
                "[[module]]\nname = \"{}\"\ntype = \"stepper\"\n[[link]]\na = \"host\"\nb = \"{0}\"\nkind = \"usb\"\n",
                "n".repeat(32)
            ),
            "is 32 bytes long; names are at most 31 bytes",
        ),
        (HUB.to_string(), "no link joins a module to the host"),
        (
            format!("{HUB}[[module]]\nname = \"lost\"\ntype = \"stepper\"\n{HOST_HUB}"),
            "module \"lost\" is not connected to the host",
        ),
        (
            format!("{HUB}[[link]]\na = \"host\"\nb = \"hub\"\nkind = \"usb\"\nbaud = 9600\n"),
            "baud applies to uart and rs485 links",
        ),
        (
            format!("{HUB}[[link]]\na = \"host\"\nb = \"hub\"\nkind = \"carrier-pigeon\"\n"),
            "unknown variant",
        ),
        (format!("{HUB}{HOST_HUB}colour = \"red\"\n"), "unknown field"),
        (
            format!("[[module]]\nname = \"host\"\ntype = \"hub\"\n{HOST_HUB}"),
            "reserved for the host runtime",
        ),
        (
            format!("{HUB}{HOST_HUB}[[link]]\na = \"hub\"\nb = \"hub\"\nkind = \"uart\"\n"),
            "must join two different runtimes",
        ),
        (
            format!("[[module]]\nname = \"hub\"\ntype = \"hub\"\nrate_ppm = 1e6\n{HOST_HUB}"),
            "rate_ppm",
        ),
        (String::new(), "no modules"),
        // Only the module firmware and a hub can be simulated.
        (
            format!("{HUB}{HOST_HUB}[[module]]\nname = \"m\"\ntype = \"m\"\n"),
            "unknown type \"m\"; a simulated module is \"stepper\" (the module firmware) or \"hub\"",
        ),
        (
            format!("{HUB}{HOST_HUB}[[module]]\nname = \"z\"\ntype = \"axis\"\n"),
            "(an \"axis\" is now a \"stepper\": its [module.axis] table becomes [module.motor])",
        ),
        (
            format!("{HUB}[module.motor]\nlimit_min = -2.0\n{HOST_HUB}"),
            "[module.motor] and [module.io] are for modules of type \"stepper\", not \"hub\"",
        ),
        (
            format!("{HUB}{HOST_HUB}{STEPPER}[module.motor]\nlimit_min = -2.0\nlimit_max = 2.0\n"),
            "has both limit_min and limit_max",
        ),
        (
            format!("{HUB}{HOST_HUB}{STEPPER}[module.motor]\nfull_steps_per_unit = 0.0\n"),
            "full_steps_per_unit 0 must be finite and positive",
        ),
        (
            format!("{HUB}{HOST_HUB}{STEPPER}[module.io]\nanalog = [0.5, 1.5]\n"),
            "analog value 1.5 must be a fraction of full scale",
        ),
        (
            format!("{HUB}{HOST_HUB}{STEPPER}[module.io]\ndigital = [true, true, true, true, true]\n"),
            "digital lists 5 pins; a module has 4",
        ),
        // A stepper has the firmware's links: one USB, one UART or RS-485.
        (
            format!("{HUB}{STEPPER}[[link]]\na = \"host\"\nb = \"s\"\nkind = \"memory\"\n{HOST_HUB}"),
            "a \"memory\" link cannot reach stepper \"s\"",
        ),
        (
            format!("{HUB}{HOST_HUB}{STEPPER}{HUB_S}{HUB_S}"),
            "stepper \"s\" already has its uart/rs485 link (link 2)",
        ),
        // A dangling UART is a stepper's, and only while nothing joins it.
        (
            format!("{HUB}dangling_uart = true\n{HOST_HUB}"),
            "dangling_uart is for modules of type \"stepper\"",
        ),
        (
            format!("{HUB}{HOST_HUB}{STEPPER}dangling_uart = true\n{HUB_S}"),
            "stepper \"s\" has dangling_uart = true, so nothing may join its uart/rs485 link",
        ),
    ];
    for (text, reason) in cases {
        let error = parse_error(&text);
        assert!(error.contains(reason), "{error:?} should say {reason:?}");
    }
    // Nine links on one module: one more than a module has.
    let mut many = format!("{HUB}{HOST_HUB}");
    for i in 0..8 {
        many += &format!(
            "[[module]]\nname = \"m{i}\"\ntype = \"stepper\"\n[[link]]\na = \"hub\"\nb = \"m{i}\"\nkind = \"uart\"\n"
        );
    }
    let error = parse_error(&many);
    assert!(
        error.contains("module \"hub\" has 9 links; a simulated module has at most 8"),
        "{error}"
    );
    // Errors about one module or link name the line of its header, in a
    // file the file's path too.
    let text = format!(
        "{HUB}{HOST_HUB}{STEPPER}{HUB_S}[[link]]\na = \"s\"\nb = \"nowhere\"\nkind = \"uart\"\n"
    );
    let error = parse_error(&text);
    assert!(
        error
            .starts_with("topology, line 15: link 3 (s – nowhere): no module is named \"nowhere\""),
        "{error}"
    );
    let path = std::env::temp_dir().join(format!("osap-sim-bad-{}.toml", std::process::id()));
    std::fs::write(&path, format!("{HUB}{HOST_HUB}{STEPPER}{HUB_S}{HUB_S}")).unwrap();
    let error = SimSpec::load(&path).unwrap_err().to_string();
    let _ = std::fs::remove_file(&path);
    assert!(
        error.starts_with(&format!(
            "topology file {}, line 15: link 3 (hub – s)",
            path.display()
        )),
        "{error}"
    );
    // A missing file names itself.
    let error = SimSpec::load("no/such/topology.toml")
        .unwrap_err()
        .to_string();
    assert!(error.contains("no/such/topology.toml"), "{error}");
}

/// One stepper on USB whose UART is open with nothing wired to it: a lone
/// board plugged in.
const LONE: &str = r#"
name = "lone"
[[module]]
name = "motor"
type = "stepper"
dangling_uart = true
[[link]]
a = "host"
b = "motor"
kind = "usb"
"#;

#[tokio::test]
async fn a_lone_module_with_an_unwired_uart_scans_whole() {
    let host = host();
    let topology = SimSpec::parse(LONE).unwrap();
    assert!(topology.modules[0].dangling_uart);
    let machine = SimMachine::start(&host, &topology).await.unwrap();
    let motor = machine.route_to("motor").unwrap();
    // The UART is open, and nothing is heard on it.
    let nr = Netrunner::new(&host).await.unwrap();
    let uart = nr.link_info(&motor, 1).await.unwrap();
    assert_eq!(uart.type_name, "uart");
    assert!(uart.open && !uart.heard, "{uart:?}");
    let report = netrunner::scan(&host, &ScanOptions::default())
        .await
        .unwrap();
    assert!(report.failures.is_empty(), "{:?}", report.failures);
    let map = &report.map;
    assert_eq!(map.runtimes.len(), 2);
    assert_eq!(map.links.len(), 1);
    let links = &map.find("motor").unwrap().links;
    assert!(!links[0].no_neighbour(), "USB: the host");
    assert!(links[1].no_neighbour(), "{:?}", links[1]);
    assert!(
        map.tree().contains("    link 1 uart (no neighbour)\n"),
        "{}",
        map.tree()
    );
}

#[tokio::test]
async fn a_heard_module_that_stops_answering_is_a_failure() {
    let host = host();
    let topology = SimSpec::load(shipped("small-machine.toml"))
        .unwrap()
        .with_zero_latency(true);
    let machine = SimMachine::start(&host, &topology).await.unwrap();
    let h = machine.host_links()[0];
    let hub = route(&[h]);
    // Wait until the hub has heard y (its clock requests), then freeze y:
    // heard a moment ago, answering nothing now.
    let nr = Netrunner::new(&host).await.unwrap();
    let start = Instant::now();
    while !nr.link_info(&hub, 2).await.unwrap().heard {
        assert!(start.elapsed() < Duration::from_secs(5), "y never heard");
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    machine
        .inject(&osap_sim::machine::Fault::Freeze("y".into()))
        .await
        .unwrap();
    let report = netrunner::scan(&host, &ScanOptions::default())
        .await
        .unwrap();
    assert!(report.map.find("y").is_none());
    assert_eq!(report.failures.len(), 1, "{:?}", report.failures);
    assert_eq!(report.failures[0].route, vec![h, 2]);
    assert!(
        report.failures[0].error.contains("no reply"),
        "{:?}",
        report.failures
    );
    let to_y = &report.map.find("hub").unwrap().links[2];
    assert!(to_y.heard && !to_y.no_neighbour(), "{to_y:?}");
    assert!(!report.map.tree().contains("no neighbour"));
}

#[tokio::test]
async fn a_scan_without_a_dead_module_shows_its_link_down() {
    let host = host();
    let topology = SimSpec::load(shipped("small-machine.toml"))
        .unwrap()
        .with_zero_latency(true);
    let machine = SimMachine::start(&host, &topology).await.unwrap();
    machine.module("y").unwrap().kill().await.unwrap();
    let report = netrunner::scan(&host, &ScanOptions::default())
        .await
        .unwrap();
    let map = &report.map;
    assert_eq!(map.runtimes.len(), topology.modules.len()); // host + 4
    assert!(map.find("y").is_none());
    let hub = map.find("hub").unwrap();
    let open: Vec<bool> = hub.links.iter().map(|l| l.open).collect();
    assert_eq!(open, vec![true, true, false, true, true]);
}
