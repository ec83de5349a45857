//! What the page draws once: the runtimes, their links and functions, the
//! pipes between them and the machine's axes, from the network's model.

use osap_host::som::model::Som;
use serde_json::{json, Value};

use super::Source;

/// One runtime as the poller reads it.
#[derive(Debug, Clone)]
pub(crate) struct RuntimeInfo {
    pub name: String,
    pub route: Vec<u8>,
    pub route_mtu: u16,
    pub links: Vec<u8>,
    /// Whether it has a `get_fault` function (a module).
    pub has_fault: bool,
}

/// The page's static description, and the poller's list.
#[derive(Debug, Clone)]
pub(crate) struct Info {
    pub json: Value,
    pub runtimes: Vec<RuntimeInfo>,
}

impl Info {
    /// Runtimes on the map.
    pub(super) fn runtimes_len(&self) -> usize {
        self.runtimes.len()
    }
}

/// Reads the model (the machine's, or the plain network's).
pub(crate) async fn build(source: &Source) -> Info {
    let som = match source.manager() {
        Some(m) => m.lock().await.som().clone(),
        None => Som::empty(),
    };
    let machine = source.machine.as_ref().map(|m| {
        let cfg = m.config();
        let modules: serde_json::Map<String, Value> = m
            .modules()
            .iter()
            .map(|(k, v)| (k.clone(), json!(v.runtime)))
            .collect();
        json!({ "name": cfg.name, "axes": m.axes(), "modules": modules })
    });
    from_som(&som, &source.title, machine)
}

/// The description of `som`.
pub(crate) fn from_som(som: &Som, title: &str, machine: Option<Value>) -> Info {
    let parent = |route: &[u8]| -> Value {
        match route.split_last() {
            None => Value::Null,
            Some((_, up)) => som
                .runtimes
                .iter()
                .position(|r| r.record.route == up)
                .map_or(Value::Null, |i| json!(i)),
        }
    };
    let peer = |runtime: usize, link: u8| -> Value {
        som.links
            .iter()
            .find_map(|e| {
                if e.a.runtime == runtime && e.a.link == link {
                    Some(e.b.runtime)
                } else if e.b.runtime == runtime && e.b.link == link {
                    Some(e.a.runtime)
                } else {
                    None
                }
            })
            .map_or(Value::Null, |i| json!(i))
    };
    let mut runtimes = Vec::new();
    let mut list = Vec::new();
    for (id, r) in som.runtimes.iter().enumerate() {
        let links: Vec<Value> = r
            .record
            .links
            .iter()
            .map(|l| {
                json!({
                    "index": l.index,
                    "kind": l.type_name,
                    "name": l.name,
                    "open": l.open,
                    // False: open with nothing at the other end.
                    "heard": l.heard,
                    "peer": peer(id, l.index),
                    "capacity_bytes_per_s": Value::Null,
                })
            })
            .collect();
        let functions: Vec<Value> = r
            .functions
            .iter()
            .map(|f| {
                let pipes: Vec<Value> = som
                    .pipes
                    .iter()
                    .filter(|p| {
                        p.source.runtime == id && p.source.function.as_deref() == Some(&f.name)
                    })
                    .map(|p| {
                        let (to_runtime, to_function) = match &p.destination {
                            Some(d) => (
                                json!(d.runtime),
                                d.function
                                    .clone()
                                    .unwrap_or_else(|| format!("{} port {}", d.runtime_name, d.port)),
                            ),
                            None => (Value::Null, "(not on the map)".to_string()),
                        };
                        json!({ "slot": p.slot, "to_runtime": to_runtime, "to_function": to_function })
                    })
                    .collect();
                let args = |a: &[osap_host::som::model::SomArg]| -> Vec<Value> {
                    a.iter()
                        .map(|a| json!({ "name": a.name, "type": a.type_name }))
                        .collect()
                };
                json!({
                    "name": f.name,
                    "port": f.port,
                    "inputs": args(&f.inputs),
                    "outputs": args(&f.outputs),
                    "pipes": pipes,
                })
            })
            .collect();
        runtimes.push(json!({
            "id": id,
            "name": r.record.name,
            "type": r.record.type_name,
            "route": r.record.route,
            "parent": parent(&r.record.route),
            "links": links,
            "functions": functions,
        }));
        list.push(RuntimeInfo {
            name: r.record.name.clone(),
            route: r.record.route.clone(),
            route_mtu: r.record.route_mtu,
            links: r.record.links.iter().map(|l| l.index).collect(),
            has_fault: r.functions.iter().any(|f| f.name == "get_fault"),
        });
    }
    let edges: Vec<Value> = som
        .links
        .iter()
        .map(|e| {
            let kind = som
                .runtimes
                .get(e.a.runtime)
                .and_then(|r| r.record.links.iter().find(|l| l.index == e.a.link))
                .map_or("?", |l| l.type_name.as_str());
            json!({
                "from": e.a.runtime,
                "from_link": e.a.link,
                "to": e.b.runtime,
                "to_link": e.b.link,
                "kind": kind,
            })
        })
        .collect();
    Info {
        json: json!({
            "title": title,
            "runtimes": runtimes,
            "edges": edges,
            "machine": machine.unwrap_or(Value::Null),
        }),
        runtimes: list,
    }
}
