//! A machine refuses a module of no kind it knows: a host runtime posing
//! as module z beside a served mill, found by name, is named as the wrong
//! module with what it lacks and what differs, before anything is set up.

use osap_host::link::memory;
use osap_host::som::{attach_function, HostFunction};
use osap_host::{Host, HostConfig};
use osap_machine::config::MachineFile;
use osap_machine::machine::Link;
use osap_machine::network::FindError;
use osap_machine::{Machine, MachineError};
use osap_sim::machine::SimMachine;
use pipes_core::{ScalarType, Type};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_runtime_posing_as_a_module_is_refused_by_name() {
    let mut cfg = MachineFile::load(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/machines/mill.toml"
    ))
    .unwrap();
    // The mill served by another host, and beside it a host runtime named
    // "impostor" with a `halt` and an `add_point` of its own, which the
    // machine file names as module z.
    let server = Host::start(HostConfig::named("server")).unwrap();
    let topology = osap_machine::sim::spec(&cfg).unwrap();
    let sim = SimMachine::start(&server, &topology).await.unwrap();
    cfg.modules.get_mut("z").unwrap().name = Some("impostor".into());
    let impostor = Host::start(HostConfig::named("impostor")).unwrap();
    for f in [
        HostFunction::new("halt", &[], &[], |_| Ok(Vec::new())).unwrap(),
        HostFunction::new(
            "add_point",
            &[
                ("time", Type::Scalar(ScalarType::U64)),
                ("position", Type::Scalar(ScalarType::F64)),
            ],
            &[],
            |_| Ok(Vec::new()),
        )
        .unwrap(),
    ] {
        attach_function(&impostor, f).await.unwrap();
    }
    memory::connect(&server, &impostor).await.unwrap();
    let listener = osap_host::link::tcp::listen(&server, "127.0.0.1:0".parse().unwrap(), false)
        .await
        .unwrap();
    let addr = listener.socket_addr().unwrap().to_string();

    let e = Machine::connect(&cfg, &[Link::Tcp(addr)])
        .await
        .expect_err("the impostor is refused");
    let text = e.to_string();
    let MachineError::Module(FindError::UnknownKind {
        key,
        runtime,
        mismatch,
        ..
    }) = &e
    else {
        panic!("{text}");
    };
    assert_eq!(
        (key.as_str(), runtime.as_str()),
        ("z", "impostor"),
        "{text}"
    );
    assert_eq!(mismatch.kind, "stepper");
    assert_eq!(mismatch.found_count, 2);
    assert_eq!(mismatch.expected_id, osap_module::FUNCTION_SET_ID, "{text}");
    assert!(mismatch.missing.iter().any(|f| f == "pwm_write"), "{text}");
    assert_eq!(
        mismatch.different,
        [(
            "add_point(time: u64, position: f64)".to_string(),
            "add_point(time: u64, position: f32)".to_string()
        )],
        "{text}"
    );
    assert!(
        text.starts_with("modules.z: \"impostor\" (named \"impostor\", route 0,"),
        "{text}"
    );
    assert!(
        text.contains("is not a module this machine knows"),
        "{text}"
    );
    drop(listener);
    sim.stop().await.unwrap();
}
