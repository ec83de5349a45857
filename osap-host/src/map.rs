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
}

impl LinkRecord {
    /// Open, but with nothing at the other end.
    pub fn no_neighbour(&self) -> bool {
        self.open && !self.heard
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
