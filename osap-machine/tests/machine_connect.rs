//! `Machine::connect` runs the same script as `Machine::simulate`: here
//! against modules served over TCP by another host (as `osap serve` does),
//! in real time.

use osap_host::{Host, HostConfig};
use osap_machine::config::MachineFile;
use osap_machine::machine::Link;
use osap_machine::network::FindError;
use osap_machine::{Machine, MachineError};
use osap_sim::machine::SimMachine;

/// The real-time machines of these tests run one at a time: two at once on
/// a 2-core machine starve each other's timers.
static REAL_TIME: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

fn mill() -> MachineFile {
    MachineFile::load(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/machines/mill.toml"
    ))
    .unwrap()
}

/// The script: the same for every constructor.
async fn square(m: &Machine) -> Result<Vec<f64>, MachineError> {
    m.set_position([100.0, 100.0, -10.0])?;
    let spindle = m.tool("spindle")?;
    spindle.set_rpm(6000.0).await?;
    for p in [
        [110.0, 100.0, -10.0],
        [110.0, 110.0, -10.0],
        [100.0, 110.0, -10.0],
        [100.0, 100.0, -10.0],
    ] {
        m.goto_via_queue(p, 20.0).await?;
    }
    m.idle().await?;
    spindle.off().await?;
    Ok(m.position())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_same_script_runs_on_connect() {
    let _one_at_a_time = REAL_TIME.lock().await;
    let cfg = mill();
    // Another host serves the simulated mill over TCP, as `osap serve`
    // does: it is the machine's clock root, and the connecting host
    // follows it.
    let server = Host::start(HostConfig {
        name: "server".into(),
        ..HostConfig::default()
    })
    .unwrap();
    let topology = osap_machine::sim::spec(&cfg).unwrap();
    let sim = SimMachine::start(&server, &topology).await.unwrap();
    let listener = osap_host::link::tcp::listen(&server, "127.0.0.1:0".parse().unwrap(), false)
        .await
        .unwrap();
    let addr = listener.socket_addr().unwrap().to_string();

    let m = Machine::connect(&cfg, &[Link::Tcp(addr)]).await.unwrap();
    // Found by name through the server: host → server → hub → module.
    assert_eq!(m.modules()["x"].runtime, "mill-x");
    assert_eq!(
        m.modules()["x"].route.hop_count(),
        3,
        "{:?}",
        m.modules()["x"].route
    );
    let at = square(&m).await.unwrap();
    assert_eq!(at, vec![100.0, 100.0, -10.0]);
    // The served modules moved: x's motor went 10 mm out and back.
    let x = sim.module("mill-x").unwrap().module().unwrap();
    let (up, down) = x.lock(|mm| {
        let (_, up, down, _) = mm.stepper.step_counts();
        (up, down)
    });
    // 10 mm at 40 full steps × 8 microsteps per mm, each way.
    assert_eq!((up, down), (3200, 3200));
    // The spindle's PWM was written on and off.
    let z = sim.module("mill-z").unwrap().module().unwrap();
    let duties: Vec<u16> = z.lock(|mm| {
        mm.board()
            .pins()
            .pwm_writes()
            .iter()
            .map(|w| w.duty)
            .collect()
    });
    assert!(
        duties.len() >= 2 && duties[duties.len() - 1] == 0,
        "{duties:?}"
    );
    m.stop().await.unwrap();
    drop(listener);
    sim.stop().await.unwrap();
}

#[tokio::test]
async fn connect_without_links_or_modules_says_why() {
    let cfg = mill();
    let e = Machine::connect(&cfg, &[]).await.err().unwrap();
    assert!(e.to_string().contains("no link"), "{e}");
    // A server with no modules behind it: the first missing module is named.
    let server = Host::start(HostConfig::named("empty")).unwrap();
    let listener = osap_host::link::tcp::listen(&server, "127.0.0.1:0".parse().unwrap(), false)
        .await
        .unwrap();
    let addr = listener.socket_addr().unwrap().to_string();
    let e = Machine::connect(&cfg, &[Link::Tcp(addr)])
        .await
        .err()
        .unwrap();
    assert!(
        matches!(&e, MachineError::Module(FindError::NotFound { key, .. }) if key == "x"),
        "{e}"
    );
    assert!(e.to_string().contains("mill-x"), "{e}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_keyed_server_takes_only_clients_with_its_key() {
    let _one_at_a_time = REAL_TIME.lock().await;
    use osap_host::link::noise::Key;
    use osap_host::link::stream::ListenOptions;
    let cfg = mill();
    let server = Host::start(HostConfig::named("server")).unwrap();
    let topology = osap_machine::sim::spec(&cfg).unwrap();
    let _sim = SimMachine::start(&server, &topology).await.unwrap();
    let key = Key::from_bytes([7; 32]);
    let listener = osap_host::link::tcp::listen_with(
        &server,
        "127.0.0.1:0".parse().unwrap(),
        ListenOptions {
            key: Some(key.clone()),
            ..ListenOptions::default()
        },
    )
    .await
    .unwrap();
    let addr = listener.socket_addr().unwrap().to_string();

    // The wrong key, or none: no machine.
    let wrong = Link::TcpKeyed {
        addr: addr.clone(),
        key: Key::from_bytes([8; 32]),
    };
    assert!(Machine::connect(&cfg, &[wrong]).await.is_err());
    assert!(Machine::connect(&cfg, &[Link::Tcp(addr.clone())])
        .await
        .is_err());

    // The right key: the same machine as over a plain loopback link.
    let m = Machine::connect(&cfg, &[Link::TcpKeyed { addr, key }])
        .await
        .unwrap();
    assert_eq!(m.modules()["x"].runtime, "mill-x");
    m.set_position([100.0, 100.0, -10.0]).unwrap();
    m.goto_now([101.0, 100.0, -10.0], 20.0).await.unwrap();
    m.stop().await.unwrap();
}
