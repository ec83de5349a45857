//! The spec as a graph: each node's links in gateway order, and the path
//! from the host to every module.

use super::{LinkKind, ModuleKind, SimSpec, HOST};
use std::collections::VecDeque;

/// One end of a link, as a node of the machine's graph.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(crate) enum Node {
    Host,
    Module(usize),
}

/// A link seen from one of its ends: the node at the other end, and the
/// link's index among this end's link gateways.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Hop {
    pub(crate) peer: Node,
    pub(crate) index: usize,
    /// Across a bus: the peer's drop address.
    pub(crate) drop: Option<u8>,
}

/// Which firmware link a link of `kind` is on a `stepper`.
pub(crate) fn firmware_link(kind: LinkKind) -> Option<usize> {
    match kind {
        LinkKind::Usb => Some(0),
        LinkKind::Uart | LinkKind::Rs485 => Some(1),
        LinkKind::Memory => None,
    }
}

impl SimSpec {
    /// The node named `name` (`host` or a module).
    pub(crate) fn node(&self, name: &str) -> Option<Node> {
        if name == HOST {
            Some(Node::Host)
        } else {
            self.module_index(name).map(Node::Module)
        }
    }

    /// Each node's links in order: index 0 is the host, module `i` is
    /// `i + 1`. Links naming an unknown end are left out.
    pub(crate) fn adjacency(&self) -> Vec<Vec<Hop>> {
        let slot = |n: Node| match n {
            Node::Host => 0,
            Node::Module(i) => i + 1,
        };
        let mut adj: Vec<Vec<Hop>> = vec![Vec::new(); self.modules.len() + 1];
        let index_at = |n: Node, adj: &Vec<Vec<Hop>>, kind: LinkKind| match n {
            Node::Module(m) if self.modules[m].kind() == Some(ModuleKind::Stepper) => {
                firmware_link(kind).unwrap_or(adj[slot(n)].len())
            }
            _ => adj[slot(n)].len(),
        };
        for l in &self.links {
            let (Some(a), Some(b)) = (self.node(&l.a), self.node(&l.b)) else {
                continue;
            };
            let index = index_at(a, &adj, l.kind);
            adj[slot(a)].push(Hop {
                peer: b,
                index,
                drop: None,
            });
            if a != b {
                let index = index_at(b, &adj, l.kind);
                adj[slot(b)].push(Hop {
                    peer: a,
                    index,
                    drop: None,
                });
            }
        }
        // A bus is one link index at each station, with a hop to every
        // other station on it.
        for bus in &self.buses {
            let stations: Vec<(Node, u8, usize)> = bus
                .stations()
                .filter_map(|(name, drop)| {
                    let n = self.node(name)?;
                    Some((n, drop, index_at(n, &adj, LinkKind::Rs485)))
                })
                .collect();
            for &(n, _, index) in &stations {
                for &(peer, drop, _) in &stations {
                    if peer != n {
                        adj[slot(n)].push(Hop {
                            peer,
                            index,
                            drop: Some(drop),
                        });
                    }
                }
            }
        }
        adj
    }

    /// For each module, the shortest way there from the host (fewest hops;
    /// among equals, the one through earlier-listed links): at each node on
    /// the way, the [`PathHop`] taken. `None` for modules the host cannot
    /// reach.
    pub(crate) fn paths(&self) -> Vec<Option<Vec<PathHop>>> {
        let adj = self.adjacency();
        // For each node: the node before it and the hop taken from there.
        let mut from: Vec<Option<(usize, PathHop)>> = vec![None; adj.len()];
        let mut seen = vec![false; adj.len()];
        seen[0] = true;
        let mut queue = VecDeque::from([0usize]);
        while let Some(n) = queue.pop_front() {
            for hop in &adj[n] {
                let Node::Module(m) = hop.peer else { continue };
                if !seen[m + 1] {
                    seen[m + 1] = true;
                    from[m + 1] = Some((n, (hop.index, hop.drop)));
                    queue.push_back(m + 1);
                }
            }
        }
        (1..adj.len())
            .map(|target| {
                if !seen[target] {
                    return None;
                }
                let mut hops = Vec::new();
                let mut n = target;
                while let Some((prev, k)) = from[n] {
                    hops.push(k);
                    n = prev;
                }
                hops.reverse();
                Some(hops)
            })
            .collect()
    }
}

/// One hop of a path from the host: the index of the link taken among
/// that node's link gateways (for the host, its position among the host's
/// links), and the drop addressed if that link is a bus.
pub(crate) type PathHop = (usize, Option<u8>);
