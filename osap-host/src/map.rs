//! The network map: what a scan found, serializable to JSON.
//!
//! A map lists the runtimes (each with its route from the scanning host,
//! the route's MTU, its links and ports) and the links between them. The
//! host that scanned is runtime 0 with an empty route. Routes are lists of
//! link indices, walked from the host. The JSON layout is the serde form of
//! these types (documented in `docs/network-map.md`); `version` changes when
//! it does.

use crate::error::JsonError;
use osap_core::route::Route;
use serde::{Deserialize, Serialize};

/// Layout version of [`NetworkMap`]. Fields added with a default (as
/// [`LinkRecord::heard`]) keep it: older maps still load, and older readers
/// skip fields they do not know.
pub const MAP_VERSION: u32 = 1;

fn yes() -> bool {
    true
}

/// Everything a scan found.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NetworkMap {
    /// Layout version ([`MAP_VERSION`]).
    pub version: u32,
    /// The runtimes; index 0 is the scanning host.
    pub runtimes: Vec<RuntimeRecord>,
    /// The links between runtimes, each once.
    pub links: Vec<LinkEdge>,
}

fn is_zero(v: &u32) -> bool {
    *v == 0
}

/// One runtime.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RuntimeRecord {
    /// Its name (unique names are the user's business; the map keeps what
    /// it finds).
    pub name: String,
    /// What kind of runtime it is (firmware or program type).
    pub type_name: String,
    /// Version, `major.minor.patch`.
    pub version: String,
    /// Build key: 1 osap-rs embedded, 2 osap-rs host, 3 osap-rs simulated.
    pub build: u8,
    /// The function-set id of the functions it was built with, as it
    /// reports it (0: none, or a runtime that does not say).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub function_set: u32,
    /// Largest packet it handles, bytes.
    pub packet_size: u16,
    /// Clock tier when scanned (0 root, 255 unsynchronised).
    pub tier: u8,
    /// Link indices from the host to it (empty: the host itself).
    pub route: Vec<u8>,
    /// Per hop of `route`: the drop address where the hop crosses a bus
    /// (`bus_forward`), `None` for a point-to-point link. Empty when no hop
    /// crosses a bus (and in maps written before buses).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub route_drops: Vec<Option<u8>>,
    /// Smallest MTU along the route (its own packet size included).
    pub route_mtu: u16,
    /// Its link gateways, by index.
    pub links: Vec<LinkRecord>,
    /// Its ports, by index (port 0 is the netresponder).
    pub ports: Vec<PortRecord>,
}

/// One link gateway of a runtime.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct LinkRecord {
    /// Link index.
    pub index: u8,
    /// Link type (`uart`, `usb_cdc`, `tcp`, ...).
    pub type_name: String,
    /// Instance name.
    pub name: String,
    /// Whether it was up.
    pub open: bool,
    /// Whether a neighbour was there: its runtime heard something on the
    /// link lately, the scan's request across it was answered, or the scan
    /// lists it as a failure. An open link with `heard` false has nothing
    /// at the other end (an unwired UART); a closed link has it false too.
    /// Runtimes that cannot tell, and maps written before this field, give
    /// `true`.
    #[serde(default = "yes")]
    pub heard: bool,
    /// Largest packet it carries.
    pub mtu: u16,
    /// For a bus link: this station's drop address and the drops it knows
    /// present. `None` for point-to-point links and in older maps.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bus: Option<BusRecord>,
}

/// What a bus link reported of its bus.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct BusRecord {
    /// The station's own drop address (0 = the head).
    pub drop: u8,
    /// The other stations it knows present (for the head its drops, for a
    /// drop the head, 0).
    pub present: Vec<u8>,
    /// Head: drops it heard before that missed their last turn (busy, hung
    /// or unplugged). A scan asks them as it asks present drops, so one
    /// that went quiet is found or listed as a failure, never dropped from
    /// the map unsaid. Empty for runtimes that cannot tell, and in older
    /// maps.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub silent: Vec<u8>,
}

impl BusRecord {
    /// Every other station a scan asks across this bus: the present ones,
    /// then the silent ones, ascending, each once.
    pub fn stations(&self) -> Vec<u8> {
        let mut all: Vec<u8> = self.present.iter().chain(&self.silent).copied().collect();
        all.sort_unstable();
        all.dedup();
        all
    }
}

impl LinkRecord {
    /// Open, but with nothing at the other end.
    pub fn no_neighbour(&self) -> bool {
        self.open && !self.heard
    }
}

/// The link indices of `route`'s hops, from the host (a bus hop gives
/// its bus link; its drop is in [`route_drops`]).
pub fn route_hops(route: &Route) -> Vec<u8> {
    route
        .hops()
        .filter_map(|h| match h {
            osap_core::Instruction::LinkForward(l) => Some(l),
            osap_core::Instruction::BusForward { bus, .. } => Some(bus),
            _ => None,
        })
        .collect()
}

/// Per hop of `route`, the drop where it crosses a bus; empty if no hop
/// does (the form of [`RuntimeRecord::route_drops`]).
pub fn route_drops(route: &Route) -> Vec<Option<u8>> {
    let drops: Vec<Option<u8>> = route
        .hops()
        .map(|h| match h {
            osap_core::Instruction::BusForward { drop, .. } => Some(drop),
            _ => None,
        })
        .collect();
    if drops.iter().any(Option::is_some) {
        drops
    } else {
        Vec::new()
    }
}

/// The key of the request gate a runtime's requests share, from its route
/// (`hops` link indices, `drops` as in [`RuntimeRecord::route_drops`]):
/// the first bus the route crosses (1, then the hops up to and including
/// that bus's), or, behind no bus, the runtime itself (0, then its hops).
///
/// A bus carries a few requests at a time (a drop's replies queue for the
/// bus's turns, and too many at once outwait their timeouts), so every
/// request that crosses one bus must take a turn of one gate. The first
/// bus, not the last: a request from a drop back across its bus to the
/// head crosses that bus twice and must share the gate of the requests to
/// the drops; keyed by the last bus, it had a gate of its own, and a bus
/// of eight drops carried twelve requests at once, two of which outwaited
/// their timeouts (`cargo test -p osap-sim --test bus`).
pub fn gate_key(hops: &[u8], drops: &[Option<u8>]) -> Vec<u8> {
    match drops.iter().position(Option::is_some) {
        Some(first_bus) if first_bus < hops.len() => [&[1], &hops[..=first_bus]].concat(),
        _ => [&[0], hops].concat(),
    }
}

/// One port of a runtime.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct PortRecord {
    /// Port index.
    pub index: u16,
    /// Port type (`netresponder`, `pipes_function`, ...).
    pub type_name: String,
    /// Instance name.
    pub name: String,
}

/// One end of a link: a runtime (index in [`NetworkMap::runtimes`]) and
/// its link index.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct LinkEnd {
    /// Runtime index in the map.
    pub runtime: usize,
    /// Link index on that runtime.
    pub link: u8,
}

/// A link between two runtimes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct LinkEdge {
    /// The end nearer the host (found first).
    pub a: LinkEnd,
    /// The far end.
    pub b: LinkEnd,
}

/// What a runtime was built as, by what it reports: runtimes with the same
/// identity present the same ports and the same built functions, so what
/// was read of one holds for the others and for later runs. Only a
/// runtime that reports a function-set id has one.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct BuildIdentity {
    /// Its type name.
    pub type_name: String,
    /// Its version, `major.minor.patch`.
    pub version: String,
    /// Its build key.
    pub build: u8,
    /// The function-set id it reports (never 0).
    pub function_set: u32,
    /// How many ports it has (port 0 included).
    pub port_count: u16,
}

impl BuildIdentity {
    /// The identity of a runtime that reports these, or `None` if it
    /// reports no function-set id (it cannot be told from another build).
    pub fn new(
        type_name: &str,
        version: &str,
        build: u8,
        function_set: u32,
        port_count: u16,
    ) -> Option<BuildIdentity> {
        (function_set != 0 && !type_name.is_empty()).then(|| BuildIdentity {
            type_name: type_name.into(),
            version: version.into(),
            build,
            function_set,
            port_count,
        })
    }
}

impl RuntimeRecord {
    /// What it was built as ([`BuildIdentity`]), if it says.
    pub fn build_identity(&self) -> Option<BuildIdentity> {
        BuildIdentity::new(
            &self.type_name,
            &self.version,
            self.build,
            self.function_set,
            u16::try_from(self.ports.len()).ok()?,
        )
    }

    /// The key of the request gate this runtime shares ([`gate_key`]).
    pub fn gate_key(&self) -> Vec<u8> {
        gate_key(&self.route, &self.route_drops)
    }

    /// The route to this runtime, with its MTU.
    pub fn route(&self) -> Route {
        // Routes in a map come from scans and are short; a hand-edited map
        // with an impossible route yields the local route.
        let mut route = Route::local();
        for (hop, drop) in self.path() {
            let ins = match drop {
                Some(drop) => osap_core::Instruction::BusForward { bus: hop, drop },
                None => osap_core::Instruction::LinkForward(hop),
            };
            match route.push(ins) {
                Ok(()) => {}
                Err(_) => return Route::default(),
            }
        }
        route.with_mtu(self.route_mtu)
    }

    /// The hops from the host: link index, and the drop where it is a bus.
    pub fn path(&self) -> Vec<(u8, Option<u8>)> {
        self.route
            .iter()
            .enumerate()
            .map(|(i, &l)| (l, self.route_drops.get(i).copied().flatten()))
            .collect()
    }
}

impl NetworkMap {
    /// The runtime with this name, if exactly one has it.
    pub fn find(&self, name: &str) -> Option<&RuntimeRecord> {
        let mut found = self.runtimes.iter().filter(|r| r.name == name);
        let first = found.next()?;
        found.next().is_none().then_some(first)
    }

    /// Names that more than one runtime has.
    pub fn duplicate_names(&self) -> Vec<&str> {
        let mut names: Vec<&str> = self.runtimes.iter().map(|r| r.name.as_str()).collect();
        names.sort_unstable();
        let mut dups: Vec<&str> = names
            .windows(2)
            .filter(|w| w[0] == w[1])
            .map(|w| w[0])
            .collect();
        dups.dedup();
        dups
    }

    /// As pretty JSON.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).unwrap_or_default()
    }

    /// From JSON, checking the layout version.
    ///
    /// Errors: [`JsonError::Json`] for text that is not a map's JSON,
    /// [`JsonError::Version`] for a map of another layout version.
    pub fn from_json(text: &str) -> Result<NetworkMap, JsonError> {
        let map: NetworkMap = serde_json::from_str(text)?;
        if map.version != MAP_VERSION {
            return Err(JsonError::Version {
                what: "network map",
                found: map.version,
                supported: MAP_VERSION,
            });
        }
        Ok(map)
    }

    /// The map as an indented tree from the host, following each runtime's
    /// route (loops appear as links back to runtimes already shown). Open
    /// links with nothing at the other end are listed under their runtime
    /// as `link 1 uart "uart0" (no neighbour)`.
    pub fn tree(&self) -> String {
        let mut out = String::new();
        let mut children: Vec<Vec<usize>> = vec![Vec::new(); self.runtimes.len()];
        let paths: Vec<Vec<(u8, Option<u8>)>> = self.runtimes.iter().map(|r| r.path()).collect();
        for (i, path) in paths.iter().enumerate().skip(1) {
            let parent = &path[..path.len().saturating_sub(1)];
            if let Some(p) = paths.iter().position(|x| x == parent) {
                children[p].push(i);
            }
        }
        fn line(
            map: &NetworkMap,
            i: usize,
            depth: usize,
            children: &[Vec<usize>],
            out: &mut String,
        ) {
            let r = &map.runtimes[i];
            let path = r.path();
            let via = match path.last() {
                Some((l, drop)) => {
                    let parent_path = &path[..path.len() - 1];
                    let kind = map
                        .runtimes
                        .iter()
                        .find(|x| x.path() == parent_path)
                        .and_then(|p| p.links.get(usize::from(*l)))
                        .map_or("?", |k| k.type_name.as_str());
                    match drop {
                        Some(d) => format!("via {kind} link {l} drop {d}: "),
                        None => format!("via {kind} link {l}: "),
                    }
                }
                None => String::new(),
            };
            let functions = r.ports.len().saturating_sub(1);
            out.push_str(&format!(
                "{}{via}{} ({} {}, tier {}, {} port{})\n",
                "  ".repeat(depth),
                r.name,
                r.type_name,
                r.version,
                if r.tier == 255 {
                    "-".to_string()
                } else {
                    r.tier.to_string()
                },
                functions,
                if functions == 1 { "" } else { "s" }
            ));
            for l in r.links.iter().filter(|l| l.no_neighbour()) {
                let name = if l.name.is_empty() {
                    String::new()
                } else {
                    format!(" {:?}", l.name)
                };
                out.push_str(&format!(
                    "{}link {} {}{name} (no neighbour)\n",
                    "  ".repeat(depth + 1),
                    l.index,
                    l.type_name
                ));
            }
            for &c in &children[i] {
                line(map, c, depth + 1, children, out);
            }
        }
        if !self.runtimes.is_empty() {
            line(self, 0, 0, &children, &mut out);
        }
        let tree_edges = self.runtimes.len().saturating_sub(1);
        if self.links.len() > tree_edges {
            let extra = self.links.len() - tree_edges;
            let verb = if extra == 1 {
                "link closes"
            } else {
                "links close"
            };
            out.push_str(&format!("{extra} {verb} a loop:\n"));
            for e in &self.links {
                let (a, b) = (&self.runtimes[e.a.runtime], &self.runtimes[e.b.runtime]);
                let on_tree = b.route.len() == a.route.len() + 1
                    && b.route[..a.route.len()] == a.route[..]
                    && b.route.last() == Some(&e.a.link);
                if !on_tree {
                    out.push_str(&format!(
                        "  {} link {} <-> {} link {}\n",
                        a.name, e.a.link, b.name, e.b.link
                    ));
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use osap_core::Instruction::{BusForward, LinkForward};

    fn route(hops: &[osap_core::Instruction]) -> Route {
        let mut r = Route::local();
        for &h in hops {
            r.push(h).unwrap();
        }
        r
    }

    fn key(r: &Route) -> Vec<u8> {
        gate_key(&route_hops(r), &route_drops(r))
    }

    #[test]
    fn a_gate_is_the_first_bus_a_route_crosses() {
        let to_head = route(&[LinkForward(0), LinkForward(2)]);
        let drop = |d| {
            route(&[
                LinkForward(0),
                LinkForward(2),
                BusForward { bus: 1, drop: d },
            ])
        };
        // Behind no bus: a gate of its own.
        assert_eq!(key(&to_head), [0, 0, 2]);
        // Every drop of one bus shares its bus's gate.
        assert_eq!(key(&drop(3)), [1, 0, 2, 1]);
        assert_eq!(key(&drop(3)), key(&drop(7)));
        // A probe from a drop back across the bus to its head crosses the
        // bus twice: it takes the same gate, not one of its own.
        let back = route(&[
            LinkForward(0),
            LinkForward(2),
            BusForward { bus: 1, drop: 3 },
            BusForward { bus: 0, drop: 0 },
        ]);
        assert_eq!(key(&back), key(&drop(3)));
        // Past a drop, on a point-to-point link or a second bus: still the
        // first bus's gate.
        let behind = route(&[
            LinkForward(0),
            BusForward { bus: 1, drop: 3 },
            LinkForward(4),
            BusForward { bus: 2, drop: 9 },
        ]);
        assert_eq!(key(&behind), [1, 0, 1]);
        // A record keys as its route does.
        let record = RuntimeRecord {
            name: "x".into(),
            type_name: "stepper".into(),
            version: "0.1.0".into(),
            build: 3,
            function_set: 0,
            packet_size: 128,
            tier: 255,
            route: route_hops(&behind),
            route_drops: route_drops(&behind),
            route_mtu: 128,
            links: Vec::new(),
            ports: Vec::new(),
        };
        assert_eq!(record.gate_key(), key(&behind));
        assert_eq!(record.route(), behind.with_mtu(128));
    }

    #[test]
    fn a_bus_asks_present_and_silent_stations_once_each() {
        let bus = BusRecord {
            drop: 0,
            present: vec![1, 4, 2],
            silent: vec![3, 2],
        };
        assert_eq!(bus.stations(), [1, 2, 3, 4]);
        // Maps written before `silent` read as none silent.
        let old: BusRecord = serde_json::from_str(r#"{"drop":0,"present":[1,2]}"#).unwrap();
        assert!(old.silent.is_empty());
        assert!(!serde_json::to_string(&old).unwrap().contains("silent"));
    }
}
