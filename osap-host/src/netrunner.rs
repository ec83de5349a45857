//! The netrunner: queries runtimes' netresponders and scans the network.
//!
//! A scan is a breadth-first walk over runtimes. It starts at the host's own
//! netresponder, asks each runtime for its links, and sends a runtime
//! information request out of every open link, building routes one hop at a
//! time. Each request carries a fresh scan id; a runtime answers with the id
//! it was sent before, so a runtime reached again through a loop gives
//! itself away, and which one it is, and the reply also names the link the
//! request came in on, so every link is mapped end to end. A runtime that
//! does not answer (after retries) is listed as a failure and the scan goes
//! on: the map is partial, never a hang.
//!
//! A link whose runtime heard nothing on it lately (link information's
//! `open` byte 2, e.g. a UART with nothing wired to it) is asked once,
//! without retries. If nothing answers, its runtime still heard nothing
//! there, and the link never carried a packet in (link counters), the link
//! is recorded as having no neighbour ([`LinkRecord::heard`] false), not as
//! a failure. If the runtime heard something meanwhile (a late reply, a
//! neighbour waking), the request is retried as on any link; if the link
//! carried packets before, its neighbour went silent: a failure.

use crate::error::{NotSynchronised, ReplyProblem};
use crate::map::{
    BusRecord, LinkEdge, LinkEnd, LinkRecord, NetworkMap, PortRecord, RuntimeRecord, MAP_VERSION,
};
use crate::port::{Datagram, PortHandle};
use crate::{Host, HostError};
use futures_util::future::join_all;
use osap_core::clock::{ClockStatus, SyncState, TimeConfig};
use osap_core::codec::{Reader, Writer};
use osap_core::counters::LinkCounters;
use osap_core::netresponder::{key, Status, LINK_CLOSED, LINK_KIND_BUS, LINK_UNHEARD};
use osap_core::route::Route;
use std::collections::{HashMap, VecDeque};
use std::time::Duration;
use tokio::time::Instant;

/// How a scan behaves.
#[derive(Debug, Clone)]
pub struct ScanOptions {
    /// How long to wait for each reply.
    pub timeout: Duration,
    /// How many times to retry a request that got no reply (the first
    /// request across a link where nothing was heard is sent once).
    pub retries: u8,
    /// Stop after this many runtimes (a guard against runaway networks).
    pub max_runtimes: usize,
}

impl Default for ScanOptions {
    fn default() -> Self {
        ScanOptions {
            timeout: Duration::from_millis(200),
            retries: 2,
            max_runtimes: 1024,
        }
    }
}

/// A request during a scan that got no usable answer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ScanFailure {
    /// Route to where it was sent.
    pub route: Vec<u8>,
    /// What was asked and what went wrong.
    pub error: String,
}

/// The outcome of a scan: the map and what could not be mapped.
#[derive(Debug, Clone)]
pub struct ScanReport {
    /// What was found.
    pub map: NetworkMap,
    /// What did not answer or answered badly.
    pub failures: Vec<ScanFailure>,
    /// How long the scan took.
    pub elapsed: Duration,
}

/// Runtime information as answered by a netresponder.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RuntimeInfo {
    /// The scan id it held before this request.
    pub previous_scan_id: u32,
    /// Version.
    pub version: [u8; 3],
    /// Build key.
    pub build: u8,
    /// Largest packet it handles.
    pub packet_size: u16,
    /// Number of ports (port 0 included).
    pub port_count: u16,
    /// Number of link gateways.
    pub link_count: u8,
    /// Clock tier.
    pub tier: u8,
    /// The link the request came in on (255: from a local port).
    pub arrival_link: u8,
}

/// What [`Netrunner::wait_synchronised`] waits for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SyncGoal {
    /// The largest offset estimate accepted (default 100 µs).
    pub max_offset: Duration,
    /// How long the clock must stay within it without a hard jump
    /// (default 1 s).
    pub quiet: Duration,
    /// When to give up (default 30 s).
    pub timeout: Duration,
}

impl Default for SyncGoal {
    fn default() -> Self {
        SyncGoal {
            max_offset: Duration::from_micros(100),
            quiet: Duration::from_secs(1),
            timeout: Duration::from_secs(30),
        }
    }
}

/// Asks netresponders questions, through one host port.
pub struct Netrunner {
    port: PortHandle,
    /// Per-request timeout.
    pub timeout: Duration,
    /// Retries per request.
    pub retries: u8,
}

impl std::fmt::Debug for Netrunner {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Netrunner")
            .field("port", &self.port)
            .field("timeout", &self.timeout)
            .field("retries", &self.retries)
            .finish()
    }
}

/// The fields of a netresponder's reply to query `asked`, after its key
/// and status bytes, or why there are none.
fn reply_fields<'a>(route: &Route, asked: u8, reply: &'a [u8]) -> Result<&'a [u8], HostError> {
    let [answered, status, fields @ ..] = reply else {
        return Err(HostError::malformed(route, "reply", ReplyProblem::TooShort));
    };
    if *answered != asked {
        let answered = *answered;
        return Err(HostError::malformed(
            route,
            "reply",
            ReplyProblem::WrongQuery { asked, answered },
        ));
    }
    match Status::from_u8(*status) {
        Some(Status::Ok) => Ok(fields),
        Some(s) => Err(HostError::Remote {
            route: route.to_string(),
            status: s,
        }),
        None => Err(HostError::malformed(
            route,
            "reply",
            ReplyProblem::UnknownStatus(*status),
        )),
    }
}

fn unwritable(what: &'static str) -> impl Fn(osap_core::codec::CodecError) -> HostError {
    move |problem| HostError::Request { what, problem }
}

impl Netrunner {
    /// Opens a port on `host` for querying.
    pub async fn new(host: &Host) -> Result<Netrunner, HostError> {
        Ok(Netrunner {
            port: host.open_port("netrunner").await?,
            timeout: ScanOptions::default().timeout,
            retries: ScanOptions::default().retries,
        })
    }

    /// Sends one query to the netresponder at the end of `route` and
    /// returns the reply's fields (after key and status), retrying on
    /// timeouts.
    pub async fn query(&self, route: &Route, body: &[u8]) -> Result<Vec<u8>, HostError> {
        self.query_tries(route, body, self.retries).await
    }

    /// [`query`](Self::query) with `retries` retries.
    async fn query_tries(
        &self,
        route: &Route,
        body: &[u8],
        retries: u8,
    ) -> Result<Vec<u8>, HostError> {
        let mut attempt = 0;
        let reply: Datagram = loop {
            match self.port.request(route, 0, body, self.timeout).await {
                Ok(r) => break r,
                Err(HostError::Timeout { .. }) if attempt < retries => attempt += 1,
                Err(e) => return Err(e),
            }
        };
        reply_fields(route, body[0], &reply.body).map(<[u8]>::to_vec)
    }

    /// Runtime information, sending `scan_id`.
    pub async fn runtime_info(
        &self,
        route: &Route,
        scan_id: u32,
    ) -> Result<RuntimeInfo, HostError> {
        self.runtime_info_tries(route, scan_id, self.retries).await
    }

    /// [`runtime_info`](Self::runtime_info) with `retries` retries.
    async fn runtime_info_tries(
        &self,
        route: &Route,
        scan_id: u32,
        retries: u8,
    ) -> Result<RuntimeInfo, HostError> {
        let mut body = vec![key::RUNTIME_INFO];
        body.extend_from_slice(&scan_id.to_le_bytes());
        let f = self.query_tries(route, &body, retries).await?;
        let mut r = Reader::new(&f);
        let m = |e| HostError::malformed(route, "runtime information", e);
        Ok(RuntimeInfo {
            previous_scan_id: r.u32().map_err(m)?,
            version: r.array().map_err(m)?,
            build: r.u8().map_err(m)?,
            packet_size: r.u16().map_err(m)?,
            port_count: r.u16().map_err(m)?,
            link_count: r.u8().map_err(m)?,
            tier: r.u8().map_err(m)?,
            // Older netresponders end here.
            arrival_link: r.u8().unwrap_or(255),
        })
    }

    async fn string(&self, route: &Route, k: u8) -> Result<String, HostError> {
        let f = self.query(route, &[k]).await?;
        Reader::new(&f)
            .str8()
            .map(str::to_string)
            .map_err(|e| HostError::malformed(route, "name", e))
    }

    /// The runtime's type name.
    pub async fn type_name(&self, route: &Route) -> Result<String, HostError> {
        self.string(route, key::TYPE_NAME).await
    }

    /// The runtime's name.
    pub async fn name(&self, route: &Route) -> Result<String, HostError> {
        self.string(route, key::NAME).await
    }

    /// Renames the runtime; returns the name as stored.
    pub async fn set_name(&self, route: &Route, name: &str) -> Result<String, HostError> {
        let mut body = [0u8; 64];
        let mut w = Writer::new(&mut body);
        w.u8(key::SET_NAME).map_err(unwritable("name"))?;
        w.str8(name).map_err(unwritable("name"))?;
        let n = w.len();
        let f = self.query(route, &body[..n]).await?;
        Reader::new(&f)
            .str8()
            .map(str::to_string)
            .map_err(|e| HostError::malformed(route, "name", e))
    }

    /// Sets link `index`'s bus role (module firmware keeps it in flash and
    /// applies it at once); returns the role as set. A runtime whose link
    /// cannot take a role refuses (`Status::Refused`). A role changed over
    /// the link itself cuts that link until the other end matches it: set
    /// roles over another link (USB) before wiring a bus.
    pub async fn set_bus(
        &self,
        route: &Route,
        index: u8,
        role: osap_core::bus::BusRole,
    ) -> Result<osap_core::bus::BusRole, HostError> {
        let [kind, param] = role.to_bytes();
        let f = self
            .query(route, &[key::SET_BUS, index, kind, param])
            .await?;
        match f.as_slice() {
            [i, k, p] if *i == index => osap_core::bus::BusRole::from_bytes([*k, *p])
                .map_err(|e| HostError::malformed(route, "bus role", e)),
            _ => Err(HostError::malformed(
                route,
                "bus role",
                ReplyProblem::Unexpected(f.clone()),
            )),
        }
    }

    /// Information on link `index`. `heard` is false for a closed link and
    /// for an open one its runtime heard nothing on lately (`open` byte
    /// [`LINK_UNHEARD`]); runtimes that only say open or closed give true
    /// for an open link.
    pub async fn link_info(&self, route: &Route, index: u8) -> Result<LinkRecord, HostError> {
        let f = self.query(route, &[key::LINK_INFO, index]).await?;
        let mut r = Reader::new(&f);
        let m = |e| HostError::malformed(route, "link information", e);
        let index = r.u8().map_err(m)?;
        let open = r.u8().map_err(m)?;
        let mut record = LinkRecord {
            index,
            open: open != LINK_CLOSED,
            heard: open != LINK_CLOSED && open != LINK_UNHEARD,
            mtu: r.u16().map_err(m)?,
            type_name: r.str8().map_err(m)?.to_string(),
            name: r.str8().map_err(m)?.to_string(),
            bus: None,
        };
        // A bus link follows with its address and the drops it knows.
        if r.u8().ok() == Some(LINK_KIND_BUS) {
            let drop = r.u8().map_err(m)?;
            let mut info = osap_core::link::BusInfo {
                drop,
                ..Default::default()
            };
            for word in info.present.iter_mut() {
                *word = r.u32().map_err(m)?;
            }
            record.bus = Some(BusRecord {
                drop,
                present: info.drops().filter(|&d| d != drop).collect(),
            });
        }
        Ok(record)
    }

    /// Information on port `index`.
    pub async fn port_info(&self, route: &Route, index: u16) -> Result<PortRecord, HostError> {
        let mut body = vec![key::PORT_INFO];
        body.extend_from_slice(&index.to_le_bytes());
        let f = self.query(route, &body).await?;
        let mut r = Reader::new(&f);
        let m = |e| HostError::malformed(route, "port information", e);
        Ok(PortRecord {
            index: r.u16().map_err(m)?,
            type_name: r.str8().map_err(m)?.to_string(),
            name: r.str8().map_err(m)?.to_string(),
        })
    }

    /// The time-controller configuration.
    pub async fn time_config(&self, route: &Route) -> Result<TimeConfig, HostError> {
        let f = self.query(route, &[key::GET_TIME_CONFIG]).await?;
        TimeConfig::decode(&f).map_err(|e| HostError::malformed(route, "time configuration", e))
    }

    /// Sets the time-controller configuration; returns it as applied.
    pub async fn set_time_config(
        &self,
        route: &Route,
        config: &TimeConfig,
    ) -> Result<TimeConfig, HostError> {
        let mut body = [0u8; 128];
        let mut w = Writer::new(&mut body);
        w.u8(key::SET_TIME_CONFIG)
            .map_err(unwritable("time configuration"))?;
        config
            .encode(&mut w)
            .map_err(unwritable("time configuration"))?;
        let n = w.len();
        let f = self.query(route, &body[..n]).await?;
        TimeConfig::decode(&f).map_err(|e| HostError::malformed(route, "time configuration", e))
    }

    /// Waits until the clock of the runtime at `route` follows its time
    /// source closely enough to run motion on: synchronised (or the root),
    /// its offset estimate within `goal.max_offset`, and neither out of
    /// that bound nor hard-jumped for `goal.quiet`. Motion streams are keyed
    /// by synchronized time, and a clock that still steps while settling
    /// would step the axis with it. Polls the clock status every 50 ms;
    /// fails with [`HostError::NotSynchronised`] after `goal.timeout`.
    pub async fn wait_synchronised(
        &self,
        route: &Route,
        goal: SyncGoal,
    ) -> Result<ClockStatus, HostError> {
        let start = Instant::now();
        let mut quiet_since = start;
        let mut jumps = None;
        loop {
            let s = self.clock_status(route).await?;
            let following = matches!(s.state, SyncState::Synced | SyncState::Root);
            let close = s.offset_ns.unsigned_abs() <= goal.max_offset.as_nanos() as u64;
            if !(following && close) || jumps != Some(s.stats.jumps) {
                quiet_since = Instant::now();
                jumps = Some(s.stats.jumps);
            }
            if s.state == SyncState::Root || quiet_since.elapsed() >= goal.quiet {
                return Ok(s);
            }
            if start.elapsed() >= goal.timeout {
                return Err(HostError::NotSynchronised(Box::new(NotSynchronised {
                    route: *route,
                    waited: start.elapsed(),
                    last: s,
                })));
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }

    /// The clock's status (a runtime of the first layout reads as not
    /// settled, without the untrusted and deferred-step counts).
    pub async fn clock_status(&self, route: &Route) -> Result<ClockStatus, HostError> {
        let f = self.query(route, &[key::TIME_STATUS]).await?;
        ClockStatus::decode(&f).map_err(|e| HostError::malformed(route, "clock status", e))
    }

    /// The counters of link `link` of the runtime at `route`: what that
    /// runtime counted of the link's packets, and the link gateway's own
    /// frame, error, drop and disconnect counts (when it keeps them).
    pub async fn link_counters(&self, route: &Route, link: u8) -> Result<LinkCounters, HostError> {
        let f = self.query(route, &[key::LINK_COUNTERS, link]).await?;
        let mut r = Reader::new(&f);
        let m = |e| HostError::malformed(route, "link counters", e);
        let index = r.u8().map_err(m)?;
        if index != link {
            return Err(HostError::malformed(
                route,
                "link counters",
                ReplyProblem::WrongIndex {
                    asked: link.into(),
                    answered: index.into(),
                },
            ));
        }
        LinkCounters::decode(&mut r).map_err(m)
    }

    /// Round-trip times of `count` name queries to the runtime at `route`.
    pub async fn ping(&self, route: &Route, count: usize) -> Result<Vec<Duration>, HostError> {
        let mut times = Vec::with_capacity(count);
        for _ in 0..count {
            let start = Instant::now();
            self.port
                .request(route, 0, &[key::NAME], self.timeout)
                .await?;
            times.push(start.elapsed());
        }
        Ok(times)
    }
}

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

/// Renames the runtime at `route`; returns the name as stored.
pub async fn rename(host: &Host, route: &Route, name: &str) -> Result<String, HostError> {
    Netrunner::new(host).await?.set_name(route, name).await
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::MalformedReply;

    fn problem(e: HostError) -> ReplyProblem {
        match e {
            HostError::Malformed(m) => {
                let MalformedReply { what, problem, .. } = *m;
                assert_eq!(what, "reply");
                problem
            }
            other => panic!("not a malformed reply: {other:?}"),
        }
    }

    #[test]
    fn a_reply_is_checked_before_its_fields_are_read() {
        let route = Route::through_links(&[2]).unwrap();
        let ok = [key::NAME, Status::Ok as u8, 4, b'a'];
        assert_eq!(reply_fields(&route, key::NAME, &ok).unwrap(), &[4, b'a']);
        let e = reply_fields(&route, key::NAME, &[key::NAME]).unwrap_err();
        assert_eq!(problem(e), ReplyProblem::TooShort);
        let e = reply_fields(&route, key::NAME, &[key::TYPE_NAME, 0]).unwrap_err();
        assert!(e.to_string().contains("answers query"), "{e}");
        assert_eq!(
            problem(e),
            ReplyProblem::WrongQuery {
                asked: key::NAME,
                answered: key::TYPE_NAME
            }
        );
        let e = reply_fields(&route, key::NAME, &[key::NAME, 200]).unwrap_err();
        assert_eq!(problem(e), ReplyProblem::UnknownStatus(200));
        let refused = [key::NAME, Status::Malformed as u8];
        let e = reply_fields(&route, key::NAME, &refused).unwrap_err();
        assert!(
            matches!(
                e,
                HostError::Remote {
                    status: Status::Malformed,
                    ..
                }
            ),
            "{e:?}"
        );
    }

    #[test]
    fn a_malformed_reply_names_what_and_where() {
        let route = Route::through_links(&[1, 3]).unwrap();
        let e = HostError::malformed(
            &route,
            "clock status",
            osap_core::codec::CodecError::Truncated,
        );
        let text = e.to_string();
        assert!(text.starts_with("malformed clock status from "), "{text}");
        assert!(text.contains(&route.to_string()), "{text}");
        // Errors stay small: the report is boxed.
        assert!(std::mem::size_of::<HostError>() <= 64);
    }
}
