//! Graphs as files: a graph wired on one simulated `small-machine.toml`
//! (pipes between module functions, modes), saved, applied to a fresh one
//! of the same network, reproduces exactly; applying twice changes nothing;
//! a graph that does not match the network is refused, naming each
//! mismatch.

use osap_host::som::graph::{Graph, GraphChange, GraphError};
use osap_host::som::{FnRef, Manager, PipeOptions};
use osap_sim::machine::SimMachine;
use osap_sim::topology::SimSpec;
use pipes_core::control::{InputMode, OutputMode};
use pipes_core::pipe::PipeDelivery;

mod common;
use common::{host, refresh, shipped};

async fn network() -> (osap_host::Host, SimMachine, Manager) {
    let h = host("h");
    let topology = SimSpec::load(shipped("small-machine.toml")).unwrap();
    let machine = SimMachine::start(&h, &topology).await.unwrap();
    let mut m = Manager::new(&h).await.unwrap();
    refresh(&mut m).await;
    (h, machine, m)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_saved_graph_applies_exactly_and_once() {
    let (_h, machine, mut m) = network().await;
    let get_pos = FnRef::new("x", "get_position");
    let read_limit = FnRef::new("x", "read_limit");
    m.connect(
        &get_pos,
        &FnRef::new("y", "set_scale"),
        &[1],
        &[0],
        PipeOptions::default(),
    )
    .await
    .unwrap();
    let acked = PipeOptions {
        delivery: PipeDelivery::Acked,
        ttl_us: 20_000,
        slot: Some(1),
        ..PipeOptions::default()
    };
    m.connect(
        &read_limit,
        &FnRef::new("z", "set_interval"),
        &[2],
        &[0],
        acked,
    )
    .await
    .unwrap();
    m.set_input_mode(&get_pos, InputMode::OnTimer(50_000))
        .await
        .unwrap();
    m.set_output_mode(&get_pos, OutputMode::OnChange)
        .await
        .unwrap();
    m.set_input_mode(&FnRef::new("y", "set_scale"), InputMode::OnAllFresh)
        .await
        .unwrap();
    refresh(&mut m).await;
    let saved = Graph::from_som(m.som());
    assert_eq!(saved.pipes.len(), 2, "{saved:#?}");
    assert_eq!(saved.functions.len(), 4, "{saved:#?}");
    let text = serde_json::to_string_pretty(&saved).unwrap();
    drop(m);
    machine.stop().await.unwrap();

    // A fresh network of the same modules: applied, it reads back the same.
    let (_h2, machine2, mut fresh) = network().await;
    let graph: Graph = serde_json::from_str(&text).unwrap();
    let dry = graph.changes(fresh.som()).unwrap();
    assert_eq!(dry.len(), 5, "{dry:#?}");
    assert_eq!(
        dry.iter()
            .filter(|c| matches!(c, GraphChange::Pipe(_)))
            .count(),
        2
    );
    let applied = graph.apply(&mut fresh).await.unwrap();
    assert_eq!(applied, dry);
    refresh(&mut fresh).await;
    assert_eq!(Graph::from_som(fresh.som()), saved);
    // Again: nothing to do.
    assert!(graph.changes(fresh.som()).unwrap().is_empty());
    assert!(graph.apply(&mut fresh).await.unwrap().is_empty());

    // A graph that does not match: every mismatch named.
    let mut wrong = graph.clone();
    let extra = wrong.functions[0].outputs[0].clone();
    wrong.functions[0].inputs.push(extra);
    wrong.functions[1].runtime = "lathe".into();
    match wrong.changes(fresh.som()) {
        Err(GraphError::Mismatch(m)) => {
            assert_eq!(m.len(), 3, "{m:?}");
            assert!(m.iter().any(|x| x.contains("signature")), "{m:?}");
            assert!(m.iter().any(|x| x.contains("no runtime lathe")), "{m:?}");
        }
        other => panic!("{other:?}"),
    }
    let mut future = graph.clone();
    future.version = osap_host::som::graph::GRAPH_VERSION + 1;
    assert!(matches!(
        future.changes(fresh.som()),
        Err(GraphError::Format { .. })
    ));
    machine2.stop().await.unwrap();
}
