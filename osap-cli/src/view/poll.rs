//! What the page sees change: every link's counters and load, every
//! runtime's clock, the machine's axes and state, and new faults; read
//! over the network each interval and sent to every open page.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

use osap_core::route::Route;
use osap_host::netrunner::Netrunner;
use osap_host::som::{self, FnRef};
use osap_machine::MachineEvent;
use serde_json::{json, Value};
use tokio::sync::broadcast;

use super::info::{Info, RuntimeInfo};
use super::Source;

/// Link counts at one reading.
#[derive(Debug, Clone, Copy)]
struct Reading {
    at: Instant,
    rx_bytes: u32,
    tx_bytes: u32,
}

/// Reads the network each interval and publishes a state message.
pub(crate) struct Poller {
    source: Arc<Source>,
    runner: Netrunner,
    runtimes: Vec<RuntimeInfo>,
    /// Per runtime, its route and link indices: what each reading asks.
    targets: Vec<(Route, Vec<u8>)>,
    last: BTreeMap<(usize, u8), Reading>,
    /// Per module runtime: the fault count last seen (plain networks).
    fault_counts: BTreeMap<usize, u32>,
    events: Option<broadcast::Receiver<MachineEvent>>,
}

impl Poller {
    pub(super) async fn new(source: &Arc<Source>, info: &Info) -> Result<Poller, String> {
        let runner = Netrunner::new(&source.host)
            .await
            .map_err(|e| e.to_string())?;
        Ok(Poller {
            source: source.clone(),
            runner,
            runtimes: info.runtimes.clone(),
            targets: info
                .runtimes
                .iter()
                .map(|r| (route_of(r), r.links.clone()))
                .collect(),
            last: BTreeMap::new(),
            fault_counts: BTreeMap::new(),
            events: source.machine.as_ref().map(|m| m.events()),
        })
    }

    /// Publishes a state every `interval` until the task is aborted. A
    /// reading that takes longer than the interval delays the next; the
    /// rates are per real elapsed time, so they stay right.
    pub(super) async fn run(
        mut self,
        interval: Duration,
        tx: broadcast::Sender<String>,
        latest: Arc<std::sync::Mutex<String>>,
    ) {
        let mut tick = tokio::time::interval(interval);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            tick.tick().await;
            let state = self.read().await.to_string();
            *latest.lock().unwrap_or_else(|e| e.into_inner()) = state.clone();
            // No page open: nothing to send to.
            let _ = tx.send(state);
        }
    }

    async fn read(&mut self) -> Value {
        let mut links = Vec::new();
        let mut runtimes = Vec::new();
        for id in 0..self.targets.len() {
            let (route, indices) = self.targets[id].clone();
            // The stack: slots held by what arrived on each link, summed.
            let (mut held, mut slots) = (0u32, None);
            for index in indices {
                if let Some((l, h, n)) = self.link(id, &route, index).await {
                    links.push(l);
                    held += u32::from(h);
                    slots = slots.or((n > 0).then_some(n));
                }
            }
            let mut clock = self.clock(id, &route).await;
            if let Some(n) = slots {
                clock["stack_used"] = json!(held);
                clock["stack_slots"] = json!(n);
            }
            runtimes.push(clock);
        }
        let faults = self.faults().await;
        let time_us = self
            .source
            .host
            .system_time()
            .await
            .map_or(0, |t| t.as_micros());
        let (axes, machine) = match &self.source.machine {
            Some(m) => {
                let names = m.axes();
                let position = m.position();
                let homed = m.homed();
                let axes: Vec<Value> = names
                    .iter()
                    .enumerate()
                    .map(|(i, a)| {
                        json!({
                            "name": a,
                            "position": position.get(i).copied().unwrap_or(f64::NAN),
                            "homed": homed.get(i).copied().unwrap_or(false),
                        })
                    })
                    .collect();
                (axes, json!({ "state": format!("{:?}", m.state()) }))
            }
            None => (Vec::new(), Value::Null),
        };
        json!({
            "type": "state",
            "time_us": time_us,
            "links": links,
            "runtimes": runtimes,
            "axes": axes,
            "motors": [],
            "machine": machine,
            "faults": faults,
        })
    }

    /// One link's counters and its rates since the last reading, with the
    /// stack slots its packets hold and the stack's size.
    async fn link(&mut self, id: usize, route: &Route, index: u8) -> Option<(Value, u16, u16)> {
        let c = self.runner.link_counters(route, index).await.ok()?;
        let now = Instant::now();
        let reading = Reading {
            at: now,
            rx_bytes: c.rx_bytes,
            tx_bytes: c.tx_bytes,
        };
        let (rx, tx) = match self.last.insert((id, index), reading) {
            Some(prev) => {
                let dt = now.duration_since(prev.at).as_secs_f64().max(1e-3);
                (
                    f64::from(c.rx_bytes.wrapping_sub(prev.rx_bytes)) / dt,
                    f64::from(c.tx_bytes.wrapping_sub(prev.tx_bytes)) / dt,
                )
            }
            None => (0.0, 0.0),
        };
        // Full duplex: each direction has the whole capacity.
        let load =
            (c.capacity_bytes_per_s > 0).then(|| rx.max(tx) / f64::from(c.capacity_bytes_per_s));
        let dropped = c.rx_dropped
            + c.expired
            + c.closed
            + c.send_errors
            + c.gateway
                .map_or(0, |g| g.frame_errors + g.rx_dropped + g.tx_dropped);
        let value = json!({
            "runtime": id,
            "index": index,
            "rx_bytes_per_s": rx,
            "tx_bytes_per_s": tx,
            "load": load,
            "capacity_bytes_per_s": (c.capacity_bytes_per_s > 0).then_some(c.capacity_bytes_per_s),
            "packets_in": c.received,
            "packets_out": c.sent,
            "dropped": dropped,
            "held": c.held,
            "slots": c.slots,
        });
        Some((value, c.held, c.slots))
    }

    /// One runtime's clock.
    async fn clock(&mut self, id: usize, route: &Route) -> Value {
        match self.runner.clock_status(route).await {
            Ok(s) => json!({
                "id": id,
                "tier": s.tier,
                "offset_us": s.offset_ns as f64 / 1e3,
                "settled": s.settled,
                "root": s.tier == 0,
                "error": Value::Null,
            }),
            Err(e) => json!({ "id": id, "error": e.to_string() }),
        }
    }

    /// Faults since the last reading: the machine's fault events, or on a
    /// plain network each module's `get_fault` count going up.
    async fn faults(&mut self) -> Vec<Value> {
        if let Some(rx) = &mut self.events {
            let mut out = Vec::new();
            loop {
                match rx.try_recv() {
                    Ok(MachineEvent::Fault {
                        module,
                        kind,
                        detail,
                        time,
                        reason,
                    }) => out.push(json!({
                        "time_us": time,
                        "module": module,
                        "kind": format!("{kind:?}"),
                        "detail": detail,
                        "reason": reason,
                    })),
                    Ok(_) => {}
                    Err(broadcast::error::TryRecvError::Lagged(_)) => {}
                    Err(_) => break,
                }
            }
            return out;
        }
        let Some(manager) = self.source.manager() else {
            return Vec::new();
        };
        let mut out = Vec::new();
        for (id, r) in self.runtimes.iter().enumerate() {
            if !r.has_fault {
                continue;
            }
            let handle = {
                let m = manager.lock().await;
                m.function(&FnRef::new(r.name.clone(), "get_fault".to_string()))
            };
            let Ok(handle) = handle else { continue };
            let Ok(v) = handle.call(&[]).await else {
                continue;
            };
            // (time: u64, code: u8, detail: u32, count: u32); anything else
            // is shown as what it is, never read as zeros.
            let [som::Value::U64(time), som::Value::U8(code), som::Value::U32(detail), som::Value::U32(count)] =
                v.as_slice()
            else {
                out.push(json!({
                    "module": r.name,
                    "kind": format!("unreadable get_fault reply {v:?}: update the module's firmware"),
                }));
                continue;
            };
            let (code, count) = (*code, *count);
            let seen = self.fault_counts.insert(id, count);
            if seen.is_some_and(|s| count > s) {
                out.push(json!({
                    "time_us": time,
                    "module": r.name,
                    "kind": osap_machine::FaultKind::from_code(code)
                        .map_or_else(|| format!("code {code}"), |k| format!("{k:?}")),
                    "detail": detail,
                    "count": count,
                }));
            }
        }
        out
    }
}

fn route_of(r: &RuntimeInfo) -> Route {
    Route::through_links(&r.route)
        .map(|x| x.with_mtu(r.route_mtu))
        .unwrap_or_default()
}
