//! The scan: a breadth-first walk over runtimes (see the [module
//! docs](super)), in full or for runtimes only.

use super::{Netrunner, RuntimeInfo, ScanFailure, ScanOptions, ScanReport};
use crate::map::{LinkEdge, LinkEnd, LinkRecord, NetworkMap, RuntimeRecord, MAP_VERSION};
use crate::{Host, HostError};
use futures_util::future::join_all;
use osap_core::route::Route;
use std::collections::{HashMap, VecDeque};
use tokio::time::Instant;

/// A runtime found during a scan, with the route it was reached by.
struct Found {
    record: RuntimeRecord,
    route: Route,
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
    scan_as(host, options, true, progress, |_| true).await
}

/// A scan for runtimes, not their functions: it reads no ports (each
/// record's `ports` is empty; a module's are most of a full scan's
/// requests), asks each runtime its name, type and links at once, and
/// calls `found` with each runtime the moment it is described, nearest
/// first. It stops as soon as `found` returns false. For a caller that
/// looks for a few runtimes by name and must act on each at once (`osap
/// halt`): those found early need not wait for the rest.
pub async fn scan_runtimes(
    host: &Host,
    options: &ScanOptions,
    found: impl FnMut(&RuntimeRecord) -> bool,
) -> Result<ScanReport, HostError> {
    scan_as(host, options, false, |_, _| {}, found).await
}

/// The scan: every runtime's ports read one by one (`read_ports`), or
/// none and the rest of a runtime's records asked at once.
async fn scan_as(
    host: &Host,
    options: &ScanOptions,
    read_ports: bool,
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
    let mut queue = VecDeque::new();

    // The host itself.
    let local = Route::local();
    let info = runner.runtime_info(&local, next_id).await?;
    sent_to.insert(next_id, 0);
    next_id = next_id.wrapping_add(1);
    let (record, failed) = describe(&runner, &local, &info, info.packet_size, read_ports).await;
    failures.extend(failed);
    let mut more = each(&record);
    found.push(Found {
        record,
        route: local,
    });
    queue.push_back(0);
    progress(1, queue.len());

    while let Some(i) = queue.pop_front().filter(|_| more) {
        let here = found[i].route;
        let link_list = found[i].record.links.clone();
        // A point-to-point link leads to one neighbour; a bus head's link
        // to each drop it knows, a drop's to its head.
        let mut targets = Vec::new();
        for link in link_list.iter().filter(|l| l.open) {
            let hops: Vec<osap_core::Instruction> = match &link.bus {
                None => vec![osap_core::Instruction::LinkForward(link.index)],
                Some(bus) => bus
                    .present
                    .iter()
                    .map(|&drop| osap_core::Instruction::BusForward {
                        bus: link.index,
                        drop,
                    })
                    .collect(),
            };
            for hop in hops {
                let Ok(route) = here.with_hop(hop) else {
                    failures.push(ScanFailure {
                        route: hops_of(&here),
                        error: format!("route through link {} is too long", link.index),
                    });
                    continue;
                };
                let mtu = here.mtu().min(link.mtu);
                targets.push((link, route.with_mtu(mtu), mtu));
            }
        }
        // A full scan asks across one link at a time; a scan for runtimes
        // across the links of a runtime at once, as many as a
        // microcontroller's link holds.
        let batch = if read_ports {
            1
        } else {
            usize::from(osap_core::stack::DEFAULT_LINK_QUOTA)
        };
        for chunk in targets.chunks(batch) {
            if !more {
                break;
            }
            let ids: Vec<u32> = chunk
                .iter()
                .map(|_| {
                    let id = next_id;
                    next_id = next_id.wrapping_add(1);
                    id
                })
                .collect();
            let replies = join_all(
                chunk
                    .iter()
                    .zip(&ids)
                    .map(|((link, route, _), id)| probe(&runner, &here, route, link, *id)),
            )
            .await;
            let mut answered: Vec<Option<RuntimeInfo>> = Vec::new();
            for ((link, route, _), reply) in chunk.iter().zip(replies) {
                answered.push(match reply {
                    Probe::Answered(info) => {
                        // Whatever its runtime heard lately, a neighbour is there.
                        set_heard(&mut found[i].record, link.index, true);
                        Some(info)
                    }
                    Probe::NoNeighbour => {
                        set_heard(&mut found[i].record, link.index, false);
                        None
                    }
                    Probe::Failed(error) => {
                        // Listed as a failure, so not as a link with no neighbour.
                        set_heard(&mut found[i].record, link.index, true);
                        failures.push(ScanFailure {
                            route: hops_of(route),
                            error,
                        });
                        None
                    }
                });
            }
            // Probes of one batch that reached the same runtime: each reply
            // names the id that runtime held before, another of the batch's.
            let first_of = |k: usize| -> usize {
                let mut at = k;
                for _ in 0..chunk.len() {
                    let Some(info) = &answered[at] else { break };
                    match ids.iter().position(|id| *id == info.previous_scan_id) {
                        Some(j) if answered[j].is_some() && j != at => at = j,
                        _ => break,
                    }
                }
                at
            };
            // The runtimes new to this scan, described (at once).
            let mut new: Vec<usize> = Vec::new();
            for (k, info) in answered.iter().enumerate() {
                let Some(info) = info else { continue };
                if first_of(k) != k || sent_to.contains_key(&info.previous_scan_id) {
                    continue;
                }
                if found.len() + new.len() >= options.max_runtimes {
                    failures.push(ScanFailure {
                        route: hops_of(&chunk[k].1),
                        error: format!("stopped at {} runtimes", options.max_runtimes),
                    });
                    continue;
                }
                new.push(k);
            }
            let runner = &runner;
            let described = join_all(new.iter().filter_map(|&k| {
                let info = answered[k].as_ref()?;
                let (_, route, mtu) = &chunk[k];
                let mtu = (*mtu).min(info.packet_size);
                let route = route.with_mtu(mtu);
                Some(async move {
                    let (record, failed) = describe(runner, &route, info, mtu, read_ports).await;
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
                found.push(Found { record, route });
                queue.push_back(found.len() - 1);
                progress(found.len(), queue.len());
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
                    runtime: i,
                    link: chunk[k].0.index,
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

fn hops_of(route: &Route) -> Vec<u8> {
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
/// does.
fn route_drops(route: &Route) -> Vec<Option<u8>> {
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

/// Asks a newly found runtime everything about itself (its ports only if
/// `read_ports`); what it fails to answer is recorded and left empty.
async fn describe(
    runner: &Netrunner,
    route: &Route,
    info: &RuntimeInfo,
    route_mtu: u16,
    read_ports: bool,
) -> (RuntimeRecord, Vec<ScanFailure>) {
    let mut failures = Vec::new();
    let mut fail = |what: &str, e: HostError| {
        failures.push(ScanFailure {
            route: hops_of(route),
            error: format!("{what}: {e}"),
        })
    };
    // Asked one after another in a full scan (as it always was), all at
    // once in a scan for runtimes.
    let (name, type_name, link_infos) = if read_ports {
        let name = runner.name(route).await;
        let type_name = runner.type_name(route).await;
        let mut links = Vec::new();
        for index in 0..info.link_count {
            links.push(runner.link_info(route, index).await);
        }
        (name, type_name, links)
    } else {
        // Name, type and the first two links at once, then the others as
        // many at a time: no more than a microcontroller's link holds.
        let at_once = usize::from(osap_core::stack::DEFAULT_LINK_QUOTA);
        let indices: Vec<u8> = (0..info.link_count).collect();
        let (name, type_name, mut links) = tokio::join!(
            runner.name(route),
            runner.type_name(route),
            join_all(
                indices
                    .iter()
                    .take(at_once - 2)
                    .map(|&index| runner.link_info(route, index))
            )
        );
        for chunk in indices[indices.len().min(at_once - 2)..].chunks(at_once) {
            links.extend(join_all(chunk.iter().map(|&index| runner.link_info(route, index))).await);
        }
        (name, type_name, links)
    };
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
    let mut ports = Vec::new();
    for index in (0..info.port_count).filter(|_| read_ports) {
        match runner.port_info(route, index).await {
            Ok(p) => ports.push(p),
            Err(e) => fail(&format!("port {index}"), e),
        }
    }
    let [a, b, c] = info.version;
    let record = RuntimeRecord {
        name,
        type_name,
        version: format!("{a}.{b}.{c}"),
        build: info.build,
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
