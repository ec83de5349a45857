//! `osap_machine::halt`: a served plotter halted from another host with
//! nothing but the machine file, every module at once, its pen written to
//! its off duty; and a module that does not answer reported as such while
//! the others are halted.

use osap_host::{Host, HostConfig};
use osap_machine::config::MachineFile;
use osap_machine::halt::{halt, HaltFailure};
use osap_machine::network::{open_links, Entry, Link};
use osap_module::stepper::Mode;
use osap_sim::machine::{Fault, SimMachine};

fn plotter() -> MachineFile {
    MachineFile::load(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/machines/plotter.toml"
    ))
    .unwrap()
}

/// The plotter served by a host of its own over TCP, as `osap serve`
/// does, and a second host, which neither gives nor follows time,
/// connected to it: the halting host, and the machine's entry point.
async fn served(
    cfg: &MachineFile,
) -> (
    SimMachine,
    osap_host::link::stream::Listener,
    Host,
    Vec<osap_host::link::stream::LinkHandle>,
    Entry,
) {
    let server = Host::start(HostConfig::named("server")).unwrap();
    let sim = SimMachine::start(&server, &osap_machine::sim::spec(cfg).unwrap())
        .await
        .unwrap();
    let listener = osap_host::link::tcp::listen(&server, "127.0.0.1:0".parse().unwrap(), false)
        .await
        .unwrap();
    let links = [Link::Tcp(listener.socket_addr().unwrap().to_string())];
    let mut config = HostConfig::named("halting");
    config.time.root = false;
    let host = Host::start(config).unwrap();
    let handles = open_links(&host, &links).await.unwrap();
    let entry = Entry::of(&links, &handles);
    // The machine up: every module answers (this host, the server, the
    // hub and three modules), as a machine that was running would.
    let end = std::time::Instant::now() + std::time::Duration::from_secs(10);
    loop {
        let scan = osap_host::netrunner::scan_runtimes(&host, &Default::default(), |_| true)
            .await
            .unwrap();
        if scan.map.runtimes.len() == 6 && scan.failures.is_empty() {
            break;
        }
        assert!(std::time::Instant::now() < end, "{:?}", scan.failures);
    }
    (sim, listener, host, handles, entry)
}

fn mode(sim: &SimMachine, module: &str) -> Mode {
    sim.module(module)
        .unwrap()
        .module()
        .unwrap()
        .lock(|m| m.stepper.mode())
}

/// The latest duty written to PWM channel 0 of `module`, of 65 535.
fn pwm0(sim: &SimMachine, module: &str) -> Option<u16> {
    sim.module(module).unwrap().module().unwrap().lock(|m| {
        m.board()
            .pins()
            .pwm_writes()
            .iter()
            .rev()
            .find(|w| w.channel == 0)
            .map(|w| w.duty)
    })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_module_is_halted_and_the_pen_written_off() {
    let cfg = plotter();
    let (sim, _listener, host, _links, entry) = served(&cfg).await;
    assert_eq!(entry, Entry::Beyond(0));
    // The pen down, as mid-drawing.
    let z = sim.module("z").unwrap().module().unwrap();
    z.lock(|m| m.pwm_write(0, 0.075)).unwrap();
    for m in ["a", "b", "z"] {
        assert_ne!(mode(&sim, m), Mode::Halted);
    }

    let report = halt(&host, &cfg, entry).await.unwrap();
    assert!(report.all_confirmed(), "{report:#?}");
    let keys: Vec<&str> = report.modules.iter().map(|m| m.key.as_str()).collect();
    assert_eq!(keys, ["a", "b", "z"]);
    // z by route from the served machine's entry point, a and b by name.
    let z_halt = &report.modules[2];
    assert_eq!(z_halt.route.as_deref(), Some(&[0u8, 0, 3][..]));
    assert_eq!(z_halt.runtime.as_deref(), Some("z"));
    for m in ["a", "b", "z"] {
        assert_eq!(mode(&sim, m), Mode::Halted, "module {m}");
    }
    // The pen's off duty, as the module rounds it.
    assert_eq!(z_halt.tools.len(), 1);
    assert_eq!(z_halt.tools[0].tool, "pen");
    assert_eq!(pwm0(&sim, "z"), Some((0.05f32 * 65_535.0 + 0.5) as u16));
    // Each module's halt went out within 100 ms of its being found.
    for m in &report.modules {
        let (found, sent) = (m.found_after.unwrap(), m.sent_after.unwrap());
        assert!(
            sent - found < std::time::Duration::from_millis(100),
            "{}: found {found:?}, sent {sent:?}",
            m.key
        );
    }
    sim.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_silent_module_is_reported_and_the_others_are_halted() {
    let cfg = plotter();
    let (sim, _listener, host, _links, entry) = served(&cfg).await;
    sim.inject(&Fault::Freeze("z".into())).await.unwrap();
    let report = halt(&host, &cfg, entry).await.unwrap();
    assert!(!report.all_confirmed());
    let by_key = |k: &str| report.modules.iter().find(|m| m.key == k).unwrap();
    for m in ["a", "b"] {
        assert!(by_key(m).confirmed(), "{:#?}", by_key(m));
        assert_eq!(mode(&sim, m), Mode::Halted, "module {m}");
    }
    let z = by_key("z");
    assert!(matches!(z.halt, Err(HaltFailure::Host(_))), "{:?}", z.halt);
    assert!(z.halted_after.is_none());
    assert!(
        matches!(&z.tools[0].result, Err(HaltFailure::ModuleUnreached(k)) if k == "z"),
        "{:?}",
        z.tools[0].result
    );
    // Not halted: it never heard the halt.
    sim.inject(&Fault::Thaw("z".into())).await.unwrap();
    assert_ne!(mode(&sim, "z"), Mode::Halted);
    sim.stop().await.unwrap();
}
