//! The scan: a breadth-first walk over runtimes (see the [module
//! docs](super)), in full or for runtimes only.

use super::{Netrunner, RuntimeInfo, ScanFailure, ScanOptions, ScanReport};
use crate::map::{
    gate_key, route_drops, route_hops as hops_of, BuildIdentity, LinkEdge, LinkEnd, LinkRecord,
    NetworkMap, PortRecord, RuntimeRecord, MAP_VERSION,
};
use crate::{Host, HostError};
use futures_util::future::join_all;
use futures_util::stream::{self, StreamExt};
use osap_core::bus::HEAD;
use osap_core::route::Route;
use std::collections::HashMap;
use tokio::sync::Semaphore;
use tokio::time::Instant;

/// Requests one runtime is sent at once during a scan: as many as a
/// microcontroller's link holds, so none waits in a full queue or is lost.
const AT_ONCE: usize = osap_core::stack::DEFAULT_LINK_QUOTA as usize;

/// A link of a runtime found at the last level, to be asked across.
struct Target {
    /// The runtime it leaves (index in the scan's list) and its route.
    parent: usize,
    here: Route,
    link: LinkRecord,
    /// Route to the neighbour, and its MTU so far.
    route: Route,
    mtu: u16,
    /// Across a bus: the drop asked, and whether its head missed it on its
    /// last turn (heard before, silent since).
    drop: Option<(u8, bool)>,
}

/// A runtime found during a scan, with the route it was reached by.
struct Found {
    record: RuntimeRecord,
    route: Route,
    /// The way back: the link it was reached on and, across a bus, the
    /// drop of the station it was reached from. Not asked again: that
    /// station is known, and the link's edge was mapped from its end.
    back: Option<Way>,
}

/// One way out of a runtime: a link and, on a bus, the drop across it.
type Way = (u8, Option<u8>);

/// The ways out of the runtime `found` across `link`, but its way back: a
/// point-to-point link leads to one neighbour, a bus head's link to each
/// drop it knows (present or silent), a drop's to its head.
fn ways_out(found: &Found, link: &LinkRecord) -> Vec<(Way, bool)> {
    let ways: Vec<(Way, bool)> = match &link.bus {
        None => vec![((link.index, None), false)],
        Some(bus) => bus
            .stations()
            .into_iter()
            .map(|d| ((link.index, Some(d)), bus.silent.contains(&d)))
            .collect(),
    };
    // Asking the way back only meets the station it came from again, and
    // costs requests where they are dearest: every drop of a level asking
    // its head at once put twice the requests on the bus (each crosses it
    // twice each way), which outwaited their timeouts.
    ways.into_iter()
        .filter(|(way, _)| found.back != Some(*way))
        .collect()
}

/// Scans the network reachable from `host`.
pub async fn scan(host: &Host, options: &ScanOptions) -> Result<ScanReport, HostError> {
    scan_with_progress(host, options, |_, _| {}).await
}

/// [`scan`], calling `progress(found, queued)` as runtimes are found.
pub async fn scan_with_progress(
    host: &Host,
    options: &ScanOptions,
    progress: impl FnMut(usize, usize),
) -> Result<ScanReport, HostError> {
    scan_as(host, options, Ports::Read(None), progress, |_| true).await
}

/// Ports already known, by the build of the runtimes that have them.
pub type KnownPorts = HashMap<BuildIdentity, Vec<PortRecord>>;

/// [`scan`], taking the ports of each runtime whose [`BuildIdentity`] is
/// in `known` from there instead of asking it for them (most of a full
/// scan's requests are a module's ports). The rest of every runtime
/// (name, links) is read as always.
pub async fn scan_known(
    host: &Host,
    options: &ScanOptions,
    known: &KnownPorts,
) -> Result<ScanReport, HostError> {
    scan_as(host, options, Ports::Read(Some(known)), |_, _| {}, |_| true).await
}

/// Whether a scan reads ports, and which it knows already.
#[derive(Clone, Copy)]
enum Ports<'a> {
    /// None read.
    Skip,
    /// Every runtime's read, but for those whose build is known.
    Read(Option<&'a KnownPorts>),
}

/// A scan for runtimes, not their functions: it reads no ports (each
/// record's `ports` is empty; a module's are most of a full scan's
/// requests), and calls `found` with each runtime as soon as its level
/// is described, nearest first. It stops as soon as `found` returns false. For a caller that
/// looks for a few runtimes by name and must act on each at once (`osap
/// halt`): those found early need not wait for the rest.
pub async fn scan_runtimes(
    host: &Host,
    options: &ScanOptions,
    found: impl FnMut(&RuntimeRecord) -> bool,
) -> Result<ScanReport, HostError> {
    scan_as(host, options, Ports::Skip, |_, _| {}, found).await
}

/// The scan, level by level (a level's runtimes asked at once, each
/// across up to [`AT_ONCE`] links at a time), with every runtime's ports
/// (a reply-full at a time, or taken from those known) or none.
async fn scan_as(
    host: &Host,
    options: &ScanOptions,
    read_ports: Ports<'_>,
    mut progress: impl FnMut(usize, usize),
    mut each: impl FnMut(&RuntimeRecord) -> bool,
) -> Result<ScanReport, HostError> {
    let start = Instant::now();
    let mut runner = Netrunner::new(host).await?;
    runner.timeout = options.timeout;
    runner.retries = options.retries;
    // Ids of this scan start at a value unlikely to match a previous scan.
    let base = (host.clock().now().as_micros() as u32) | 1;
    let mut next_id = base;
    // Every id sent, and the runtime it was sent to.
    let mut sent_to: HashMap<u32, usize> = HashMap::new();
    let mut found: Vec<Found> = Vec::new();
    let mut links: Vec<LinkEdge> = Vec::new();
    let mut failures = Vec::new();

    // The host itself.
    let local = Route::local();
    let info = runner.runtime_info(&local, next_id).await?;
    sent_to.insert(next_id, 0);
    next_id = next_id.wrapping_add(1);
    let gates = Gates::default();
    let (record, failed) = describe(
        &runner,
        &local,
        &info,
        info.packet_size,
        read_ports,
        &gates.of(&local),
    )
    .await;
    failures.extend(failed);
    let mut more = each(&record);
    found.push(Found {
        record,
        route: local,
        back: None,
    });
    progress(1, 1);

    // Level by level: every runtime of a level is asked across its links
    // at once, so independent branches (hubs, buses) are walked side by
    // side, not one after another.
    let mut level: Vec<usize> = vec![0];
    while more && !level.is_empty() {
        let mut targets: Vec<Target> = Vec::new();
        for &i in &level {
            let here = found[i].route;
            for link in found[i].record.links.iter().filter(|l| l.open) {
                for ((_, drop), silent) in ways_out(&found[i], link) {
                    let hop = match drop {
                        None => osap_core::Instruction::LinkForward(link.index),
                        Some(drop) => osap_core::Instruction::BusForward {
                            bus: link.index,
                            drop,
                        },
                    };
                    let Ok(route) = here.with_hop(hop) else {
                        failures.push(failure(
                            &here,
                            format!("route through link {} is too long", link.index),
                        ));
                        continue;
                    };
                    let mtu = here.mtu().min(link.mtu);
                    targets.push(Target {
                        parent: i,
                        here,
                        link: link.clone(),
                        route: route.with_mtu(mtu),
                        mtu,
                        drop: drop.map(|d| (d, silent)),
                    });
                }
            }
        }
        level.clear();
        let ids: Vec<u32> = targets
            .iter()
            .map(|_| {
                let id = next_id;
                next_id = next_id.wrapping_add(1);
                id
            })
            .collect();
        // Each runtime is asked across as many of its links at once as a
        // microcontroller's link holds; different runtimes all at once.
        let mut probe_gates: HashMap<usize, Semaphore> = HashMap::new();
        for t in &targets {
            probe_gates
                .entry(t.parent)
                .or_insert_with(|| Semaphore::new(AT_ONCE));
        }
        // A probe across a bus also takes a turn of that bus's gate.
        let bus_gates: Vec<_> = targets.iter().map(|t| gates.of(&t.route)).collect();
        let replies = join_all(
            targets
                .iter()
                .zip(&ids)
                .zip(&bus_gates)
                .map(|((t, id), bus)| {
                    let (runner, gate) = (&runner, &probe_gates[&t.parent]);
                    async move {
                        let _turn = gate.acquire().await;
                        let _bus_turn = bus.acquire().await;
                        probe(runner, &t.here, &t.route, &t.link, *id).await
                    }
                }),
        )
        .await;
        let mut answered: Vec<Option<RuntimeInfo>> = Vec::new();
        for (t, reply) in targets.iter().zip(replies) {
            let record = &mut found[t.parent].record;
            answered.push(match reply {
                Probe::Answered(info) => {
                    // Whatever its runtime heard lately, a neighbour is there.
                    set_heard(record, t.link.index, true);
                    Some(info)
                }
                Probe::NoNeighbour => {
                    set_heard(record, t.link.index, false);
                    None
                }
                Probe::Failed(error) => {
                    // Listed as a failure, so not as a link with no neighbour.
                    set_heard(record, t.link.index, true);
                    // A drop is named by its bus and address: its route's
                    // link indices are those of every drop of its bus.
                    let error = match t.drop {
                        Some((drop, silent)) => format!(
                            "drop {drop} on bus link {} did not answer{}: {error}",
                            t.link.index,
                            if silent {
                                " (its head heard it before, not on its last turn)"
                            } else {
                                ""
                            }
                        ),
                        None => error,
                    };
                    failures.push(failure(&t.route, error));
                    None
                }
            });
        }
        // Probes of one level that reached the same runtime: each reply
        // names the id that runtime held before, another of the level's.
        let first_of = |k: usize| -> usize {
            let mut at = k;
            for _ in 0..targets.len() {
                let Some(info) = &answered[at] else { break };
                match ids.iter().position(|id| *id == info.previous_scan_id) {
                    Some(j) if answered[j].is_some() && j != at => at = j,
                    _ => break,
                }
            }
            at
        };
        // The runtimes new to this scan, described (all at once).
        let mut new: Vec<usize> = Vec::new();
        for (k, info) in answered.iter().enumerate() {
            let Some(info) = info else { continue };
            // Reached before by this scan: by an earlier level, or by a
            // probe of this one (even one whose reply was lost).
            let ours = sent_to.contains_key(&info.previous_scan_id)
                || ids.contains(&info.previous_scan_id);
            if first_of(k) != k || ours {
                continue;
            }
            if found.len() + new.len() >= options.max_runtimes {
                failures.push(failure(
                    &targets[k].route,
                    format!("stopped at {} runtimes", options.max_runtimes),
                ));
                continue;
            }
            new.push(k);
        }
        let runner = &runner;
        // Runtimes behind one bus share its few requests at a time (a
        // drop's replies queue for the bus's turns; too many at once
        // would outwait their timeouts).
        let described_gates: Vec<_> = new.iter().map(|&k| gates.of(&targets[k].route)).collect();
        let described = join_all(new.iter().zip(&described_gates).filter_map(|(&k, gate)| {
            let info = answered[k].as_ref()?;
            let t = &targets[k];
            let mtu = t.mtu.min(info.packet_size);
            let route = t.route.with_mtu(mtu);
            Some(async move {
                let (record, failed) = describe(runner, &route, info, mtu, read_ports, gate).await;
                (k, route, record, failed)
            })
        }))
        .await;
        let mut far_of: HashMap<usize, usize> = HashMap::new();
        for (k, route, record, failed) in described {
            failures.extend(failed);
            if more {
                more = each(&record);
            }
            let t = &targets[k];
            // Back on the link it came in on; across a bus, to the drop
            // of the station that asked.
            let back = answered[k]
                .as_ref()
                .map(|info| (info.arrival_link, t.link.bus.as_ref().map(|b| b.drop)));
            found.push(Found {
                record,
                route,
                back,
            });
            level.push(found.len() - 1);
            progress(found.len(), level.len());
            far_of.insert(k, found.len() - 1);
        }
        for (k, info) in answered.iter().enumerate() {
            let Some(info) = info else { continue };
            let first = first_of(k);
            let far = match far_of.get(&first) {
                Some(&far) => far,
                // Seen before in this scan: a loop, or the way back.
                None => match answered[first]
                    .as_ref()
                    .and_then(|f| sent_to.get(&f.previous_scan_id))
                {
                    Some(&known) => known,
                    // Past the runtime limit.
                    None => continue,
                },
            };
            sent_to.insert(ids[k], far);
            let a = LinkEnd {
                runtime: targets[k].parent,
                link: targets[k].link.index,
            };
            let b = LinkEnd {
                runtime: far,
                link: info.arrival_link,
            };
            // Each link is met from both ends; keep it once.
            if !links
                .iter()
                .any(|e| (e.a == b && e.b == a) || (e.a == a && e.b == b))
            {
                links.push(LinkEdge { a, b });
            }
        }
    }
    Ok(ScanReport {
        map: NetworkMap {
            version: MAP_VERSION,
            runtimes: found.into_iter().map(|f| f.record).collect(),
            links,
        },
        failures,
        elapsed: start.elapsed(),
    })
}

/// What a runtime-information request across a link came to.
enum Probe {
    Answered(RuntimeInfo),
    /// Nothing answered and nothing was heard there: no neighbour.
    NoNeighbour,
    /// Why it is a failure.
    Failed(String),
}

/// Sends runtime information request `id` across `link` of the runtime at
/// `here` (to `route`). A link where a neighbour was heard gets the usual
/// retries. One where nothing was heard gets one try; if that goes
/// unanswered its runtime is asked again whether it heard anything there
/// meanwhile (a late reply, a neighbour that just woke): if so the request
/// is retried as on any link. If not, the link has no neighbour, unless it
/// ever carried a packet in (its link counters): then a neighbour was there
/// and went silent (hung, or lost power behind a UART that stays open),
/// which is a failure.
async fn probe(
    runner: &Netrunner,
    here: &Route,
    route: &Route,
    link: &LinkRecord,
    id: u32,
) -> Probe {
    let answer = |r: Result<RuntimeInfo, HostError>| match r {
        Ok(info) => Probe::Answered(info),
        Err(e) => Probe::Failed(e.to_string()),
    };
    if link.heard {
        return answer(runner.runtime_info(route, id).await);
    }
    let unanswered = match runner.runtime_info_tries(route, id, 0).await {
        Err(e @ HostError::Timeout { .. }) => e,
        other => return answer(other),
    };
    match runner.link_info(here, link.index).await {
        Ok(now) if now.no_neighbour() => {
            // A runtime without link counters tells nothing more.
            match runner.link_counters(here, link.index).await {
                Ok(c) if c.received > 0 => Probe::Failed(format!(
                    "{unanswered} (nothing heard on link {} lately, but {} packets came in on it before: its neighbour went silent)",
                    link.index, c.received
                )),
                _ => Probe::NoNeighbour,
            }
        }
        Ok(now) if now.open => answer(runner.runtime_info(route, id).await),
        // Closed meanwhile, or its runtime stopped answering: a failure.
        _ => Probe::Failed(unanswered.to_string()),
    }
}

fn set_heard(record: &mut RuntimeRecord, index: u8, heard: bool) {
    if let Some(l) = record.links.iter_mut().find(|l| l.index == index) {
        l.heard = heard;
    }
}

/// A failure of a request to `route`.
fn failure(route: &Route, error: String) -> ScanFailure {
    ScanFailure {
        route: hops_of(route),
        route_drops: route_drops(route),
        error,
    }
}

/// One gate of [`AT_ONCE`] requests for each bus a scan crosses first on
/// the way to a runtime, and one for each runtime behind no bus (keyed by
/// [`gate_key`], as the SOM manager's gates are).
#[derive(Default)]
struct Gates(std::sync::Mutex<HashMap<Vec<u8>, std::sync::Arc<Semaphore>>>);

impl Gates {
    /// The gate of the runtime at `route`.
    fn of(&self, route: &Route) -> std::sync::Arc<Semaphore> {
        let key = gate_key(&hops_of(route), &route_drops(route));
        let mut gates = self.0.lock().unwrap_or_else(|e| e.into_inner());
        gates
            .entry(key)
            .or_insert_with(|| std::sync::Arc::new(Semaphore::new(AT_ONCE)))
            .clone()
    }
}

/// `f`, once `gate` lets one more request go.
async fn gated<T>(gate: &Semaphore, f: impl std::future::Future<Output = T>) -> T {
    let _turn = gate.acquire().await;
    f.await
}

/// Reads the first `count` ports of the runtime at `route` a reply-full at
/// a time (port list); returns them and the indices left to ask one by
/// one: from where the list stopped (a runtime without the query, a reply
/// lost, or a record too long for one) to the end.
async fn list_ports(
    runner: &Netrunner,
    route: &Route,
    count: u16,
) -> (Vec<PortRecord>, std::ops::Range<u16>) {
    let mut ports: Vec<PortRecord> = Vec::new();
    let mut next = 0;
    while next < count {
        match runner.port_list(route, next).await {
            Ok(list) if !list.is_empty() => {
                let take = list.len().min(usize::from(count - next));
                next += take as u16;
                ports.extend(list.into_iter().take(take));
            }
            _ => break,
        }
    }
    (ports, next..count)
}

/// Asks a newly found runtime everything about itself (its ports as
/// `read_ports` says: none, or read unless its build's are known); what it
/// fails to answer is recorded and left empty.
async fn describe(
    runner: &Netrunner,
    route: &Route,
    info: &RuntimeInfo,
    route_mtu: u16,
    read_ports: Ports<'_>,
    gate: &Semaphore,
) -> (RuntimeRecord, Vec<ScanFailure>) {
    let mut failures = Vec::new();
    let mut fail = |what: &str, e: HostError| failures.push(failure(route, format!("{what}: {e}")));
    // Name, type and the first links at once, then the other links and
    // the ports, as many at a time as a microcontroller's link holds.
    // (Owned indices, not borrowed: the scan's future stays spawnable.)
    let first = info.link_count.min(AT_ONCE as u8 - 2);
    let (name, type_name, mut link_infos) = tokio::join!(
        gated(gate, runner.name(route)),
        gated(gate, runner.type_name(route)),
        join_all((0..first).map(|index| gated(gate, runner.link_info(route, index))))
    );
    link_infos.extend(
        stream::iter(
            (first..info.link_count).map(|index| gated(gate, runner.link_info(route, index))),
        )
        .buffered(AT_ONCE)
        .collect::<Vec<_>>()
        .await,
    );
    let name = match name {
        Ok(n) => n,
        Err(e) => {
            fail("name", e);
            String::new()
        }
    };
    let type_name = match type_name {
        Ok(n) => n,
        Err(e) => {
            fail("type name", e);
            String::new()
        }
    };
    let mut links = Vec::new();
    for (index, l) in link_infos.into_iter().enumerate() {
        match l {
            Ok(l) => links.push(l),
            Err(e) => fail(&format!("link {index}"), e),
        }
    }
    // A head's present drops are those that answered their last turn: ask
    // it which it ever heard, so a drop that went quiet is asked too.
    let heads: Vec<usize> = (0..links.len())
        .filter(|&i| links[i].bus.as_ref().is_some_and(|b| b.drop == HEAD))
        .collect();
    let known = join_all(
        heads
            .iter()
            .map(|&i| gated(gate, runner.bus_known(route, links[i].index))),
    )
    .await;
    for (&i, known) in heads.iter().zip(known) {
        let link = &mut links[i];
        match (known, link.bus.as_mut()) {
            (Ok(Some(known)), Some(bus)) => {
                bus.silent = known
                    .into_iter()
                    .filter(|d| *d != bus.drop && !bus.present.contains(d))
                    .collect();
            }
            // A runtime that predates the query: its present drops alone.
            (Ok(None), _) | (_, None) => {}
            (Err(e), _) => fail(&format!("bus stations heard on link {}", link.index), e),
        }
    }
    let [a, b, c] = info.version;
    let version = format!("{a}.{b}.{c}");
    let identity = BuildIdentity::new(
        &type_name,
        &version,
        info.build,
        info.function_set,
        info.port_count,
    );
    let (port_count, known) = match read_ports {
        Ports::Skip => (0, None),
        Ports::Read(known) => {
            let known = identity.and_then(|id| known?.get(&id));
            (if known.is_some() { 0 } else { info.port_count }, known)
        }
    };
    let mut ports = known.cloned().unwrap_or_default();
    let (listed, rest) = gated(gate, list_ports(runner, route, port_count)).await;
    ports.extend(listed);
    let port_infos =
        stream::iter(rest.map(|index| async move {
            (index, gated(gate, runner.port_info(route, index)).await)
        }))
        .buffered(AT_ONCE)
        .collect::<Vec<_>>()
        .await;
    for (index, p) in port_infos {
        match p {
            Ok(p) => ports.push(p),
            Err(e) => fail(&format!("port {index}"), e),
        }
    }
    let record = RuntimeRecord {
        name,
        type_name,
        version,
        build: info.build,
        function_set: info.function_set,
        packet_size: info.packet_size,
        tier: info.tier,
        route: hops_of(route),
        route_drops: route_drops(route),
        route_mtu,
        links,
        ports,
    };
    (record, failures)
}
