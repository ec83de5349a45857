//! Finding each module of `[modules]` in a model of the network: by name,
//! or by route from the machine's entry point, checked to be a kind of
//! module the machine knows.

use std::collections::BTreeMap;

use osap_core::route::Route;
use osap_host::som::Som;
use pipes_core::function::FUNCTION_PORT_TYPE;

use super::kinds::{kind_of, Mismatch};
use super::{file_route, Entry};
use crate::config::MachineFile;

/// A module of the machine, found on the network.
#[derive(Debug, Clone)]
pub struct ModuleInfo {
    /// Its runtime name on the network.
    pub runtime: String,
    /// Its route from the host.
    pub route: Route,
    /// Its kind ([`super::KNOWN_KINDS`]): `stepper`.
    pub kind: &'static str,
}

/// Why a module of `[modules]` was not found, or is not a module the
/// machine can drive.
#[derive(Debug, Clone, thiserror::Error)]
#[non_exhaustive]
pub enum FindError {
    /// Nothing on the network matches the module's name or route.
    #[error("modules.{key}: no module {wanted} on the network (found: {found}); check the cables, `osap scan`, or the name set with `osap rename`")]
    NotFound {
        /// The key in `[modules]`.
        key: String,
        /// What was looked for: a name, or a route from the entry point.
        wanted: String,
        /// The runtimes that were found.
        found: String,
    },
    /// Several runtimes have the module's name.
    #[error(
        "modules.{key}: {count} modules are named {name:?}; rename them apart with `osap rename`"
    )]
    SameName {
        /// The key in `[modules]`.
        key: String,
        /// The name.
        name: String,
        /// How many runtimes have it.
        count: usize,
    },
    /// The module found by route shares its name with another runtime (the
    /// machine calls modules by name).
    #[error("modules.{key}: the module {wanted} is named {name:?} like another runtime; give it a name of its own with `osap rename`")]
    NameShared {
        /// The key in `[modules]`.
        key: String,
        /// Its route from the entry point.
        wanted: String,
        /// Its name.
        name: String,
    },
    /// The runtime found is not a kind of module the machine knows.
    #[error("modules.{key}: {runtime:?} ({wanted}, route {route}) is not a module this machine knows: {mismatch}")]
    UnknownKind {
        /// The key in `[modules]`.
        key: String,
        /// The runtime found.
        runtime: String,
        /// How it was looked for.
        wanted: String,
        /// Its route from the host.
        route: String,
        /// What it presents against the kind it comes closest to.
        mismatch: Box<Mismatch>,
    },
    /// Some of the module's functions did not answer when the model was
    /// read (a lossy or busy link): what it is cannot be told.
    #[error("modules.{key}: {unread} of the {listed} functions of {runtime:?} (route {route}) did not answer when read; check its link (`osap scan -v` shows its counters) and try again")]
    Unread {
        /// The key in `[modules]`.
        key: String,
        /// The runtime found.
        runtime: String,
        /// Its route from the host.
        route: String,
        /// How many function ports it lists.
        listed: usize,
        /// How many of them could not be read.
        unread: usize,
    },
    /// Nothing answers behind the link the machine is served over.
    #[error("nothing answers behind this host's link {0}, where the served machine should be; is `osap serve` running there?")]
    NoEntry(u8),
}

/// A module of `[modules]` placed on the network: its runtime's index in
/// the model and name, how it was looked for, and what else was found
/// (for messages).
struct Located {
    index: usize,
    name: String,
    wanted: String,
    found: String,
}

/// Where module `key` (`m`) is in `som`: by name, or by route from
/// `entry`; never the host itself, and never under a name another runtime
/// shares.
fn locate(
    som: &Som,
    entry: Entry,
    key: &str,
    m: &crate::config::ModuleRef,
) -> Result<Located, FindError> {
    let names: Vec<&str> = som
        .runtimes
        .iter()
        .map(|r| r.record.name.as_str())
        .collect();
    let found = names.iter().skip(1).copied().collect::<Vec<_>>().join(", ");
    let start = match entry {
        Entry::Host => 0,
        Entry::Beyond(link) => som.neighbour(0, link).ok_or(FindError::NoEntry(link))?.0,
    };
    let (index, wanted) = if let Some(name) = &m.name {
        let hits: Vec<usize> = (0..names.len()).filter(|i| names[*i] == name).collect();
        if hits.len() > 1 {
            return Err(FindError::SameName {
                key: key.into(),
                name: name.clone(),
                count: hits.len(),
            });
        }
        (hits.first().copied(), format!("named {name:?}"))
    } else {
        let route = file_route(m.route.as_deref().unwrap_or_default());
        (som.walk(start, &route), format!("at route {route:?}"))
    };
    // Never the host itself (a route back to it, or its name).
    let Some(index) = index.filter(|&i| i != 0) else {
        return Err(FindError::NotFound {
            key: key.into(),
            wanted,
            found,
        });
    };
    let name = names[index].to_string();
    if names.iter().filter(|n| **n == name).count() > 1 {
        return Err(FindError::NameShared {
            key: key.into(),
            wanted,
            name,
        });
    }
    Ok(Located {
        index,
        name,
        wanted,
        found,
    })
}

/// The routes of the modules of `cfg`'s `[modules]` that `som` places
/// (a model with or without functions: only its runtimes and links are
/// read), by key; those it does not place are left out. What a caller
/// can start on before the functions are read ([`find_modules`] checks
/// them).
pub fn module_routes(cfg: &MachineFile, som: &Som, entry: Entry) -> BTreeMap<String, Route> {
    cfg.modules
        .iter()
        .filter_map(|(key, m)| {
            let at = locate(som, entry, key, m).ok()?;
            let route = som.path(0, at.index)?.route()?;
            Some((key.clone(), route))
        })
        .collect()
}

/// Finds every module of `cfg`'s `[modules]` in `som` (a model this host
/// built: runtime 0 is the host), by name or by route from `entry`, and
/// checks each presents a known function set ([`super::kind_of`]).
pub fn find_modules(
    cfg: &MachineFile,
    som: &Som,
    entry: Entry,
) -> Result<BTreeMap<String, ModuleInfo>, FindError> {
    let mut out = BTreeMap::new();
    for (key, m) in &cfg.modules {
        let Located {
            index,
            name,
            wanted,
            found,
        } = locate(som, entry, key, m)?;
        let not_found = || FindError::NotFound {
            key: key.clone(),
            wanted: wanted.clone(),
            found: found.clone(),
        };
        let path = som.path(0, index).ok_or_else(not_found)?;
        let route = path.route().ok_or_else(not_found)?;
        let route_text = path
            .links
            .iter()
            .map(u8::to_string)
            .collect::<Vec<_>>()
            .join(",");
        let rt = &som.runtimes[index];
        let listed = rt
            .record
            .ports
            .iter()
            .filter(|p| p.type_name == FUNCTION_PORT_TYPE)
            .count();
        if listed > rt.functions.len() {
            return Err(FindError::Unread {
                key: key.clone(),
                runtime: name,
                route: route_text,
                listed,
                unread: listed - rt.functions.len(),
            });
        }
        let kind = kind_of(rt).map_err(|mismatch| FindError::UnknownKind {
            key: key.clone(),
            runtime: name.clone(),
            wanted: wanted.clone(),
            route: route_text,
            mismatch,
        })?;
        out.insert(
            key.clone(),
            ModuleInfo {
                runtime: name,
                route,
                kind: kind.name,
            },
        );
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use osap_host::map::{LinkEdge, LinkEnd, LinkRecord, NetworkMap, RuntimeRecord};
    use osap_host::som::model::{SomArg, SomFunction, SomInputMode, SomOutputMode};
    use osap_module::functions::SIGNATURES;

    fn record(name: &str, links: u8) -> RuntimeRecord {
        RuntimeRecord {
            name: name.into(),
            type_name: "t".into(),
            version: "0.1.0".into(),
            build: 3,
            function_set: 0,
            packet_size: 256,
            tier: 1,
            route: Vec::new(),
            route_drops: Vec::new(),
            route_mtu: 256,
            links: (0..links)
                .map(|index| LinkRecord {
                    index,
                    open: true,
                    heard: true,
                    mtu: 256,
                    type_name: "uart".into(),
                    name: String::new(),
                    bus: None,
                })
                .collect(),
            ports: Vec::new(),
        }
    }

    fn edge(a: usize, la: u8, b: usize, lb: u8) -> LinkEdge {
        LinkEdge {
            a: LinkEnd {
                runtime: a,
                link: la,
            },
            b: LinkEnd {
                runtime: b,
                link: lb,
            },
        }
    }

    /// The plotter served: host -0- sim-host -0- hub -1,2,3- a, b, z
    /// (each module's link 0 to the hub). `z_functions`: z's functions.
    fn served_plotter(z_functions: Vec<SomFunction>) -> Som {
        let map = NetworkMap {
            version: osap_host::map::MAP_VERSION,
            runtimes: vec![
                record("machine", 1),
                record("sim-host", 2),
                record("hub", 4),
                record("a", 2),
                record("b", 2),
                record("z", 2),
            ],
            links: vec![
                edge(0, 0, 1, 1),
                edge(1, 0, 2, 0),
                edge(2, 1, 3, 0),
                edge(2, 2, 4, 0),
                edge(2, 3, 5, 0),
            ],
        };
        let mut som = Som::from_map(&map);
        for r in &mut som.runtimes[3..5] {
            r.functions = stepper();
        }
        som.runtimes[5].functions = z_functions;
        som
    }

    fn stepper() -> Vec<SomFunction> {
        SIGNATURES
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let args = |a: &[pipes_core::signature::Arg]| {
                    a.iter()
                        .map(|a| SomArg {
                            name: a.name.into(),
                            type_name: a.ty.name().into(),
                        })
                        .collect()
                };
                SomFunction {
                    name: s.name.into(),
                    summary: String::new(),
                    port: 1 + 3 * i as u16,
                    pipe_ports: Vec::new(),
                    inputs: args(s.inputs),
                    outputs: args(s.outputs),
                    input_mode: SomInputMode::OnAnyFresh,
                    output_mode: SomOutputMode::Always,
                    pipe_slots: 2,
                    pipes: Vec::new(),
                }
            })
            .collect()
    }

    fn plotter() -> MachineFile {
        MachineFile::load(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../examples/machines/plotter.toml"
        ))
        .unwrap()
    }

    #[test]
    fn routes_count_from_the_machine_entry_point() {
        let som = served_plotter(stepper());
        let cfg = plotter();
        // Served: the file's z = [0, 3] starts beyond the TCP link.
        let found = find_modules(&cfg, &som, Entry::Beyond(0)).unwrap();
        assert_eq!(found["z"].runtime, "z");
        assert_eq!(
            found["z"].route.as_bytes(),
            Route::through_links(&[0, 0, 3]).unwrap().as_bytes()
        );
        assert_eq!(found["a"].runtime, "a");
        assert_eq!(found["z"].kind, "stepper");
        // From the host itself, [0, 3] leads nowhere on a served machine:
        // the error the issue reproduced.
        let e = find_modules(&cfg, &som, Entry::Host).unwrap_err();
        assert!(
            matches!(&e, FindError::NotFound { key, .. } if key == "z"),
            "{e}"
        );
        assert_eq!(
            e.to_string(),
            "modules.z: no module at route [0, 3] on the network (found: sim-host, hub, a, b, z); \
             check the cables, `osap scan`, or the name set with `osap rename`"
        );
        // A link with nothing behind it.
        assert!(matches!(
            find_modules(&cfg, &som, Entry::Beyond(5)),
            Err(FindError::NoEntry(5))
        ));
    }

    #[test]
    fn a_module_whose_functions_did_not_all_answer_is_not_judged() {
        // z lists the stepper set's function ports, but one did not answer
        // the model's read.
        let mut som = served_plotter(stepper());
        som.runtimes[5].record.ports = stepper()
            .iter()
            .map(|f| osap_host::map::PortRecord {
                index: f.port,
                type_name: FUNCTION_PORT_TYPE.into(),
                name: f.name.clone(),
            })
            .collect();
        som.runtimes[5]
            .functions
            .retain(|f| f.name != "get_counters");
        let e = find_modules(&plotter(), &som, Entry::Beyond(0)).unwrap_err();
        assert!(
            matches!(&e, FindError::Unread { key, unread: 1, .. } if key == "z"),
            "{e}"
        );
        assert!(e.to_string().contains("did not answer when read"), "{e}");
    }

    #[test]
    fn a_module_of_no_known_kind_is_refused_by_name() {
        let mut z = stepper();
        z.retain(|f| f.name != "pwm_write");
        let e = find_modules(&plotter(), &served_plotter(z), Entry::Beyond(0)).unwrap_err();
        let text = e.to_string();
        assert!(
            matches!(&e, FindError::UnknownKind { key, .. } if key == "z"),
            "{text}"
        );
        assert!(
            text.starts_with(
                "modules.z: \"z\" (at route [0, 3], route 0,0,3) is not a module this machine knows: expected the stepper function set"
            ),
            "{text}"
        );
        assert!(text.contains("missing: pwm_write"), "{text}");
        // A hub named as a module.
        let mut cfg = plotter();
        cfg.modules.get_mut("z").unwrap().route = Some(vec![0]);
        let e = find_modules(&cfg, &served_plotter(stepper()), Entry::Beyond(0)).unwrap_err();
        assert!(e.to_string().contains("\"hub\""), "{e}");
        assert!(e.to_string().contains("found no functions"), "{e}");
    }
}
