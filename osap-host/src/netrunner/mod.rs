//! The netrunner: queries runtimes' netresponders and scans the network.
//!
//! A scan is a breadth-first walk over runtimes. It starts at the host's own
//! netresponder, asks each runtime for its links, and sends a runtime
//! information request out of every open link, building routes one hop at a
//! time. It walks level by level: the runtimes found at one distance are
//! all asked at once (each across a few links at a time, as many requests
//! as a microcontroller's link holds), so independent branches, hubs and
//! buses, are walked side by side. Each request carries a fresh scan id; a runtime answers with the id
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

mod scan;

use crate::error::{NotSynchronised, ReplyProblem};
use crate::map::{BusRecord, LinkRecord, NetworkMap, PortRecord};
use crate::port::{Datagram, PortHandle};
use crate::{Host, HostError};
use osap_core::clock::{ClockStatus, SyncState, TimeConfig};
use osap_core::codec::{Reader, Writer};
use osap_core::counters::LinkCounters;
use osap_core::netresponder::{key, Status, LINK_CLOSED, LINK_KIND_BUS, LINK_UNHEARD};
use osap_core::route::Route;
use std::time::Duration;
use tokio::time::Instant;

pub use scan::{scan, scan_known, scan_runtimes, scan_with_progress, KnownPorts};

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
    /// Route to where it was sent: link indices from the host.
    pub route: Vec<u8>,
    /// Per hop of `route`, the drop where it crosses a bus (as
    /// [`RuntimeRecord::route_drops`](crate::map::RuntimeRecord::route_drops);
    /// empty when no hop does): two drops of one bus have the same `route`.
    pub route_drops: Vec<Option<u8>>,
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
    /// The function-set id of the functions it was built with (0: none,
    /// or a runtime that does not say).
    pub function_set: u32,
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

/// How often [`Netrunner::wait_synchronised`] polls a clock for `goal`: a
/// twentieth of its quiet window, no more often than every 5 ms (a query
/// is a round trip through every hop) and at least every 50 ms.
fn poll_every(goal: SyncGoal) -> Duration {
    (goal.quiet / 20).clamp(Duration::from_millis(5), Duration::from_millis(50))
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
            // Older netresponders end here, or before the function set.
            arrival_link: r.u8().unwrap_or(255),
            function_set: r.u32().unwrap_or(0),
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
                silent: Vec::new(),
            });
        }
        Ok(record)
    }

    /// The stations bus link `index` has heard at least once (key
    /// [`key::BUS_KNOWN`]), ascending; `None` from a runtime that predates
    /// the query. A head drops a station from link information's present
    /// drops when it misses one turn, never from these.
    pub async fn bus_known(&self, route: &Route, index: u8) -> Result<Option<Vec<u8>>, HostError> {
        let f = match self.query(route, &[key::BUS_KNOWN, index]).await {
            Ok(f) => f,
            Err(HostError::Remote {
                status: Status::UnknownKey,
                ..
            }) => return Ok(None),
            Err(e) => return Err(e),
        };
        let mut r = Reader::new(&f);
        let m = |e| HostError::malformed(route, "bus stations heard", e);
        let answered = r.u8().map_err(m)?;
        if answered != index {
            return Err(HostError::malformed(
                route,
                "bus stations heard",
                ReplyProblem::Unexpected(f.clone()),
            ));
        }
        let mut info = osap_core::link::BusInfo::default();
        for word in info.known.iter_mut() {
            *word = r.u32().map_err(m)?;
        }
        Ok(Some((0..=254u8).filter(|&d| info.is_known(d)).collect()))
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

    /// Information on the ports from index `from` on, as many as one reply
    /// holds (none: `from` is past the last port, or its record does not
    /// fit a reply). A runtime without the query refuses it
    /// ([`Status::UnknownKey`]): ask [`port_info`](Self::port_info).
    pub async fn port_list(&self, route: &Route, from: u16) -> Result<Vec<PortRecord>, HostError> {
        let mut body = vec![key::PORT_LIST];
        body.extend_from_slice(&from.to_le_bytes());
        let f = self.query(route, &body).await?;
        let mut r = Reader::new(&f);
        let m = |e| HostError::malformed(route, "port list", e);
        let first = r.u16().map_err(m)?;
        if first != from {
            return Err(HostError::malformed(
                route,
                "port list",
                ReplyProblem::WrongIndex {
                    asked: from,
                    answered: first,
                },
            ));
        }
        let count = r.u8().map_err(m)?;
        (0..u16::from(count))
            .map(|k| {
                Ok(PortRecord {
                    index: from.saturating_add(k),
                    type_name: r.str8().map_err(m)?.to_string(),
                    name: r.str8().map_err(m)?.to_string(),
                })
            })
            .collect()
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
    /// would step the axis with it. Polls the clock status every
    /// twentieth of `goal.quiet` (5 to 50 ms), so the wait ends within 5 %
    /// of the quiet window's end; fails with [`HostError::NotSynchronised`] after `goal.timeout`.
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
            tokio::time::sleep(poll_every(goal)).await;
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
