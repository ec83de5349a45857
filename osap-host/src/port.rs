//! Async ports on a host runtime.
//!
//! A [`PortHandle`] is a port index in the host runtime with queues on
//! either side: sends wait (without blocking the runtime) until the port is
//! clear to send; received datagrams wait in an inbox; replies to requests
//! made through [`PortHandle::request`] go straight to the caller that is
//! waiting for them, matched by sequence number. Payloads that arrive in
//! segments (transport key 3, `osap_core::segment`) are reassembled first,
//! so a reply longer than the route's MTU reaches its caller whole.

use crate::runtime::Host;
use crate::HostError;
use osap_core::port::{Delivery, Port, PortInfo, PortTx, SendError};
use osap_core::route::Route;
use osap_core::segment::{self, ReassemblyStats};
use osap_core::transport::Transport;
use std::collections::{HashMap, VecDeque};
use std::sync::atomic::{AtomicBool, AtomicU16, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;
use tokio::sync::{oneshot, Notify};

/// Datagrams a port keeps before it stops accepting (the runtime then
/// holds further packets for it until their deadlines).
const INBOX_DEPTH: usize = 64;
/// Segmented datagrams a host port reassembles at once.
pub const SEGMENT_SLOTS: usize = 4;
/// Largest segmented datagram a host port takes, bytes: more than the
/// longest signature reply (name and 16 arguments of 255-byte names, 4.4 KB).
pub const SEGMENT_BYTES: usize = 8192;

/// A host port's reassembler (boxed: 32 KiB, made on the first segment).
type HostReassembler = segment::Reassembler<SEGMENT_SLOTS, SEGMENT_BYTES>;

/// Time to live given to sends unless the caller sets one, µs.
pub const DEFAULT_TTL_US: u16 = 50_000;

/// A packet received by a host port.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Datagram {
    /// The transport header it carried.
    pub transport: Transport,
    /// The body after the transport header.
    pub body: Vec<u8>,
    /// The way back to the sender.
    pub route: Route,
    /// The sender's port.
    pub source_port: u16,
    /// When it arrived, on the host clock.
    pub arrival: osap_core::Instant,
}

struct Outgoing {
    route: Route,
    dst: u16,
    ttl: u16,
    payload: Vec<u8>,
    done: oneshot::Sender<Result<(), SendError>>,
}

struct PortQueues {
    inbox: VecDeque<Datagram>,
    outbox: VecDeque<Outgoing>,
    pending: HashMap<u16, oneshot::Sender<Datagram>>,
    stray_replies: u64,
    segments: Option<Box<HostReassembler>>,
}

/// State shared by a port's runtime side and its handles.
pub(crate) struct PortShared {
    type_name: String,
    queues: Mutex<PortQueues>,
    inbox_ready: Notify,
    runtime: Arc<Notify>,
    next_seq: AtomicU16,
    closed: AtomicBool,
}

impl PortShared {
    pub(crate) fn new(type_name: &str, runtime: Arc<Notify>) -> Arc<Self> {
        Arc::new(PortShared {
            type_name: type_name.to_string(),
            queues: Mutex::new(PortQueues {
                inbox: VecDeque::new(),
                outbox: VecDeque::new(),
                pending: HashMap::new(),
                stray_replies: 0,
                segments: None,
            }),
            inbox_ready: Notify::new(),
            runtime,
            next_seq: AtomicU16::new(0),
            closed: AtomicBool::new(false),
        })
    }

    fn lock(&self) -> MutexGuard<'_, PortQueues> {
        self.queues.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// The runtime's side of a host port (one slot in its port list).
pub(crate) struct HostPort {
    shared: Option<Arc<PortShared>>,
}

impl HostPort {
    pub(crate) fn new(shared: Arc<PortShared>) -> Self {
        HostPort {
            shared: Some(shared),
        }
    }

    pub(crate) fn is_vacant(&self) -> bool {
        self.shared.is_none()
    }

    pub(crate) fn occupy(&mut self, shared: Arc<PortShared>) {
        self.shared = Some(shared);
    }

    pub(crate) fn vacate(&mut self) {
        if let Some(s) = self.shared.take() {
            // Fail whatever is still queued, so no caller waits forever.
            let mut q = s.lock();
            for out in q.outbox.drain(..) {
                let _ = out.done.send(Err(SendError::NoSuchPort));
            }
            q.pending.clear();
        }
    }
}

impl Port for HostPort {
    fn info(&self, _offset: u16) -> PortInfo<'_> {
        PortInfo {
            type_name: self.shared.as_ref().map_or("vacant", |s| &s.type_name),
            name: "",
        }
    }

    fn clear_to_receive(&self, _offset: u16) -> bool {
        // A vacant slot takes (and discards) packets so they do not linger.
        self.shared
            .as_ref()
            .is_none_or(|s| s.lock().inbox.len() < INBOX_DEPTH)
    }

    fn on_packet(&mut self, d: Delivery<'_>, _tx: &mut PortTx<'_>) {
        let Some(shared) = &self.shared else {
            return;
        };
        let mut q = shared.lock();
        let whole;
        let payload = if segment::is_segment(d.payload) {
            let r = q.segments.get_or_insert_with(Box::default);
            // Refusals and duplicates are counted by the reassembler.
            match r.on_segment(d.arrival, &d.reply_route, d.source_port, d.payload) {
                Ok(Some(p)) => {
                    whole = p.to_vec();
                    &whole[..]
                }
                Ok(None) | Err(_) => return,
            }
        } else {
            d.payload
        };
        let Ok((transport, body)) = Transport::decode(payload) else {
            return;
        };
        let datagram = Datagram {
            transport,
            body: body.to_vec(),
            route: d.reply_route,
            source_port: d.source_port,
            arrival: d.arrival,
        };
        if let Transport::Reply(seq) = transport {
            match q.pending.remove(&seq) {
                Some(waiter) => {
                    let _ = waiter.send(datagram);
                }
                None => q.stray_replies += 1,
            }
            return;
        }
        q.inbox.push_back(datagram);
        drop(q);
        shared.inbox_ready.notify_one();
    }

    fn poll(&mut self, tx: &mut PortTx<'_>) {
        let Some(shared) = &self.shared else {
            return;
        };
        let mut q = shared.lock();
        if let Some(r) = q.segments.as_mut() {
            r.expire(tx.now());
        }
        while tx.clear_to_send() {
            let Some(out) = q.outbox.pop_front() else {
                break;
            };
            let result = tx.send(&out.route, out.dst, out.ttl, &out.payload);
            let _ = out.done.send(result);
        }
    }
}

/// A host port, as seen by async code. Closing the handle (dropping it)
/// frees the port index.
pub struct PortHandle {
    host: Host,
    shared: Arc<PortShared>,
    index: u16,
    ttl: u16,
}

impl std::fmt::Debug for PortHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PortHandle")
            .field("index", &self.index)
            .field("ttl", &self.ttl)
            .finish_non_exhaustive()
    }
}

impl Drop for PortHandle {
    fn drop(&mut self) {
        self.shared.closed.store(true, Ordering::Relaxed);
        self.host.close_port(self.index);
    }
}

impl PortHandle {
    pub(crate) fn new(host: Host, shared: Arc<PortShared>, index: u16) -> Self {
        PortHandle {
            host,
            shared,
            index,
            ttl: DEFAULT_TTL_US,
        }
    }

    /// This port's index in the host runtime.
    pub fn index(&self) -> u16 {
        self.index
    }

    /// Sets the time to live of packets sent from now on, µs.
    pub fn set_ttl(&mut self, ttl_us: u16) {
        self.ttl = ttl_us;
    }

    /// Sends a payload (starting with its transport key) to port `dst` at
    /// the end of `route`; resolves once the runtime has taken it.
    pub async fn send_payload(
        &self,
        route: &Route,
        dst: u16,
        payload: Vec<u8>,
    ) -> Result<(), HostError> {
        let (done, rx) = oneshot::channel();
        self.shared.lock().outbox.push_back(Outgoing {
            route: *route,
            dst,
            ttl: self.ttl,
            payload,
            done,
        });
        self.host.wake();
        match rx.await {
            Ok(Ok(())) => Ok(()),
            Ok(Err(e)) => Err(HostError::Send(e)),
            Err(_) => Err(HostError::Stopped),
        }
    }

    /// Sends a raw datagram (transport key 0).
    pub async fn send(&self, route: &Route, dst: u16, body: &[u8]) -> Result<(), HostError> {
        let mut payload = Vec::with_capacity(body.len() + 1);
        payload.push(0);
        payload.extend_from_slice(body);
        self.send_payload(route, dst, payload).await
    }

    /// Sends a sequential request and waits up to `timeout` for its reply.
    pub async fn request(
        &self,
        route: &Route,
        dst: u16,
        body: &[u8],
        timeout: Duration,
    ) -> Result<Datagram, HostError> {
        let seq = self.shared.next_seq.fetch_add(1, Ordering::Relaxed);
        let (waiter, reply) = oneshot::channel();
        self.shared.lock().pending.insert(seq, waiter);
        let mut payload = vec![0u8; 3];
        Transport::Request(seq).encode(&mut payload);
        payload.extend_from_slice(body);
        let outcome = tokio::time::timeout(timeout, async {
            self.send_payload(route, dst, payload).await?;
            reply.await.map_err(|_| HostError::Stopped)
        })
        .await;
        match outcome {
            Ok(result) => result,
            Err(_) => {
                self.shared.lock().pending.remove(&seq);
                Err(HostError::Timeout {
                    timeout,
                    route: route.to_string(),
                    port: dst,
                })
            }
        }
    }

    /// Answers a request received on this port.
    pub async fn reply(&self, request: &Datagram, body: &[u8]) -> Result<(), HostError> {
        let Transport::Request(seq) = request.transport else {
            return Err(HostError::NotARequest);
        };
        let mut payload = vec![0u8; 3];
        Transport::Reply(seq).encode(&mut payload);
        payload.extend_from_slice(body);
        self.send_payload(&request.route, request.source_port, payload)
            .await
    }

    /// Waits for the next datagram that is not a reply to one of our
    /// requests.
    pub async fn recv(&self) -> Datagram {
        loop {
            let notified = self.shared.inbox_ready.notified();
            if let Some(d) = self.shared.lock().inbox.pop_front() {
                // Room in the inbox: packets held for this port may go now.
                self.shared.runtime.notify_one();
                return d;
            }
            notified.await;
        }
    }

    /// Replies that matched no waiting request (late, after a timeout).
    pub fn stray_replies(&self) -> u64 {
        self.shared.lock().stray_replies
    }

    /// What the port's reassembler of segmented datagrams counted (all
    /// zero until the first segment arrives).
    pub fn segment_stats(&self) -> ReassemblyStats {
        self.shared
            .lock()
            .segments
            .as_ref()
            .map_or_else(ReassemblyStats::default, |r| *r.stats())
    }
}
