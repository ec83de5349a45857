//! The host runtime: an osap-core runtime driven by a tokio task.
//!
//! The task polls the runtime, then sleeps until one of three things: a
//! command from a [`Host`] handle, a wake-up from a link or port (a packet
//! arrived, room to send), or the deadline the poll returned. There is no
//! periodic tick.

use crate::clock::{HostClock, Pace};
use crate::error::ConfigError;
use crate::link::{self, ChannelLink, LinkConfig, LinkIo};
use crate::port::{HostPort, PortHandle, PortShared};
use crate::{HostError, HostRuntime};
use osap_core::clock::{ClockStatus, TimeConfig, Trust};
use osap_core::link::{LinkGateway, LinkInfo, LinkSendError, Received};
use osap_core::netresponder::BuildKey;
use osap_core::port::{Delivery, Port, PortInfo, PortTx};
use osap_core::runtime::RuntimeConfig;
use osap_core::{Duration, Instant, SystemInstant};
use std::sync::Arc;
use tokio::sync::{mpsc, oneshot, Notify};

/// How a host runtime is set up.
#[derive(Debug, Clone)]
pub struct HostConfig {
    /// Runtime type name reported to scans.
    pub type_name: String,
    /// Runtime name reported to scans.
    pub name: String,
    /// Quotas and per-poll budget of the core runtime. Hosts hold more than
    /// microcontrollers: 8 packets per port and 16 per link by default.
    pub runtime: RuntimeConfig,
    /// Clock sync; the host is the root (tier 0) by default.
    pub time: TimeConfig,
    /// The links whose neighbours the host's clock may follow, and whose
    /// remote writes of its time configuration and rate it takes (default:
    /// none). A host that attaches to a machine served by another sets this
    /// for that one link ([`Host::trust_time_link`]) and `time.root` to
    /// false; a root with no trusted link cannot be demoted remotely.
    pub trust: Trust,
    /// How fast the host's clock runs: real time by default. Slower only
    /// against emulated modules that keep a slower steady pace (see
    /// [`Pace`]).
    pub pace: Pace,
}

impl HostConfig {
    /// The default configuration with the runtime named `name`.
    pub fn named(name: impl Into<String>) -> Self {
        HostConfig {
            name: name.into(),
            ..HostConfig::default()
        }
    }
}

impl Default for HostConfig {
    fn default() -> Self {
        HostConfig {
            type_name: "osap_host".into(),
            name: "host".into(),
            runtime: RuntimeConfig {
                port_quota: 8,
                link_quota: 16,
                system_quota: 16,
                reply_ttl_us: 50_000,
                max_packets_per_poll: 256,
            },
            time: TimeConfig {
                root: true,
                ..TimeConfig::default()
            },
            trust: Trust::NONE,
            pace: Pace::REAL_TIME,
        }
    }
}

type RuntimeFn = Box<dyn FnOnce(&mut HostRuntime, Instant) + Send>;

enum Command {
    AttachLink(ChannelLink, oneshot::Sender<Result<u8, HostError>>),
    DetachLink(u8, Option<oneshot::Sender<bool>>),
    OpenPort(Arc<PortShared>, oneshot::Sender<Result<u16, HostError>>),
    ClosePort(u16),
    AttachPort(
        Box<dyn Port + Send>,
        oneshot::Sender<Result<u16, HostError>>,
    ),
    DetachPort(u16, oneshot::Sender<Option<Box<dyn Port + Send>>>),
    With(RuntimeFn),
}

/// Port indices a host runtime hands out (1..=255; port 0 is the
/// netresponder).
const MAX_PORT_INDICES: usize = 255;

/// One entry of the runtime's port list: a [`HostPort`] behind a
/// [`PortHandle`], a port object attached with [`Host::attach_port`], or the
/// place an attached object held before it was detached (which keeps its
/// indices so the ports after it do not move).
enum PortSlot {
    Handle(HostPort),
    Object(Box<dyn Port + Send>),
    Detached(u16),
}

impl PortSlot {
    fn port(&self) -> Option<&dyn Port> {
        match self {
            PortSlot::Handle(p) => Some(p),
            PortSlot::Object(p) => Some(p.as_ref()),
            PortSlot::Detached(_) => None,
        }
    }

    fn port_mut(&mut self) -> Option<&mut dyn Port> {
        match self {
            PortSlot::Handle(p) => Some(p),
            PortSlot::Object(p) => Some(p.as_mut()),
            PortSlot::Detached(_) => None,
        }
    }
}

impl Port for PortSlot {
    fn port_count(&self) -> u16 {
        match self {
            PortSlot::Detached(n) => *n,
            other => other.port().map_or(1, |p| p.port_count()),
        }
    }

    fn info(&self, offset: u16) -> PortInfo<'_> {
        match self.port() {
            Some(p) => p.info(offset),
            None => PortInfo {
                type_name: "vacant",
                name: "",
            },
        }
    }

    fn clear_to_receive(&self, offset: u16) -> bool {
        // A detached place takes (and discards) packets so they do not linger.
        self.port().is_none_or(|p| p.clear_to_receive(offset))
    }

    fn on_packet(&mut self, delivery: Delivery<'_>, tx: &mut PortTx<'_>) {
        if let Some(p) = self.port_mut() {
            p.on_packet(delivery, tx);
        }
    }

    fn poll(&mut self, tx: &mut PortTx<'_>) {
        if let Some(p) = self.port_mut() {
            p.poll(tx);
        }
    }

    fn wake_at(&self) -> Option<Instant> {
        self.port().and_then(|p| p.wake_at())
    }
}

/// Builds the host's runtime, boxed, on a short-lived thread with room for
/// it: the runtime holds its packet slots and per-link clock state inline
/// (a few hundred KiB), and an unoptimised build copies it through each
/// builder call, more than a 2 MiB thread stack (a test's, a tokio
/// worker's) holds.
fn build_runtime(config: HostConfig) -> Result<Box<HostRuntime>, HostError> {
    let build = move || -> Result<Box<HostRuntime>, HostError> {
        let mut runtime = Box::new(
            HostRuntime::new(&config.type_name, &config.name)
                .map_err(ConfigError::from)?
                .with_version(version(), BuildKey::RustHost)
                .with_config(config.runtime),
        );
        runtime
            .clock_mut()
            .set_config(config.time)
            .map_err(ConfigError::from)?;
        runtime.clock_mut().set_trust(config.trust);
        Ok(runtime)
    };
    std::thread::Builder::new()
        .name("osap-host-init".into())
        .stack_size(32 << 20)
        .spawn(build)
        .map_err(|source| HostError::Io {
            context: "starting the host runtime".into(),
            source,
        })?
        .join()
        .unwrap_or_else(|panic| std::panic::resume_unwind(panic))
}

/// A handle to a running host runtime. Cheap to clone; the runtime stops
/// when the last handle is dropped.
#[derive(Clone)]
pub struct Host {
    commands: mpsc::UnboundedSender<Command>,
    wake: Arc<Notify>,
    clock: HostClock,
}

impl std::fmt::Debug for Host {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Host")
            .field("clock", &self.clock)
            .field("running", &!self.commands.is_closed())
            .finish_non_exhaustive()
    }
}

impl Host {
    /// Starts a host runtime on the current tokio runtime.
    pub fn start(config: HostConfig) -> Result<Host, HostError> {
        let clock = HostClock::paced(config.pace);
        let runtime = build_runtime(config.clone())?;
        let (commands, rx) = mpsc::unbounded_channel();
        let wake = Arc::new(Notify::new());
        let task = RuntimeTask {
            runtime,
            ports: Vec::new(),
            links: Vec::new(),
            detached: 0,
            commands: rx,
            wake: wake.clone(),
            clock,
        };
        tokio::spawn(task.run());
        Ok(Host {
            commands,
            wake,
            clock,
        })
    }

    /// The host's local clock.
    pub fn clock(&self) -> HostClock {
        self.clock
    }

    /// Makes a link's two halves on this host's clock and wake-up; attach
    /// the first with [`attach_link`](Self::attach_link) and give the second
    /// to the task that moves its bytes.
    pub fn make_link(&self, config: LinkConfig) -> (ChannelLink, LinkIo) {
        link::channel(config, self.wake.clone(), self.clock)
    }

    /// Adds a link gateway; returns its link index.
    pub async fn attach_link(&self, link: ChannelLink) -> Result<u8, HostError> {
        let (tx, rx) = oneshot::channel();
        self.send(Command::AttachLink(link, tx))?;
        rx.await.map_err(|_| HostError::Stopped)?
    }

    /// Detaches the link at `index` and frees its index for a later
    /// [`attach_link`](Self::attach_link). Until then the index is vacant:
    /// it reports closed, packets routed to it are dropped (counted as
    /// `link_closed` in the runtime's counters), and the clock has
    /// forgotten the neighbour that was there. Returns whether a link was
    /// attached there.
    pub async fn detach_link(&self, index: u8) -> Result<bool, HostError> {
        let (tx, rx) = oneshot::channel();
        self.send(Command::DetachLink(index, Some(tx)))?;
        rx.await.map_err(|_| HostError::Stopped)
    }

    /// [`detach_link`](Self::detach_link) without waiting (from a `Drop`).
    pub(crate) fn release_link(&self, index: u8) {
        let _ = self.send(Command::DetachLink(index, None));
    }

    /// Makes and attaches a link; returns its index and its I/O half.
    pub async fn add_link(&self, config: LinkConfig) -> Result<(u8, LinkIo), HostError> {
        let (link, io) = self.make_link(config);
        Ok((self.attach_link(link).await?, io))
    }

    /// Opens a port with the given type name; returns its handle.
    pub async fn open_port(&self, type_name: &str) -> Result<PortHandle, HostError> {
        let shared = PortShared::new(type_name, self.wake.clone());
        let (tx, rx) = oneshot::channel();
        self.send(Command::OpenPort(shared.clone(), tx))?;
        let index = rx.await.map_err(|_| HostError::Stopped)??;
        Ok(PortHandle::new(self.clone(), shared, index))
    }

    /// Attaches a port object (a PIPES function, say) to the runtime; it
    /// takes `port.port_count()` consecutive port indices, and the first is
    /// returned. Those indices stay its own, and no other port's index
    /// changes, until [`detach_port`](Self::detach_port). The object must
    /// keep its port count for as long as it is attached.
    ///
    /// The runtime polls the object whenever it polls (a packet, a command,
    /// a link's news, a deadline); it is not polled on a timer of its own.
    pub async fn attach_port(&self, port: Box<dyn Port + Send>) -> Result<u16, HostError> {
        let (tx, rx) = oneshot::channel();
        self.send(Command::AttachPort(port, tx))?;
        rx.await.map_err(|_| HostError::Stopped)?
    }

    /// Detaches the port object attached at `index` (the index
    /// [`attach_port`](Self::attach_port) returned) and gives it back; its
    /// indices stay reserved (packets to them are discarded), so no other
    /// port moves. `None` if no object was attached there.
    pub async fn detach_port(&self, index: u16) -> Result<Option<Box<dyn Port + Send>>, HostError> {
        let (tx, rx) = oneshot::channel();
        self.send(Command::DetachPort(index, tx))?;
        rx.await.map_err(|_| HostError::Stopped)
    }

    pub(crate) fn close_port(&self, index: u16) {
        let _ = self.commands.send(Command::ClosePort(index));
    }

    /// Runs `f` on the runtime inside its task and returns its result.
    pub async fn with_runtime<R: Send + 'static>(
        &self,
        f: impl FnOnce(&mut HostRuntime, Instant) -> R + Send + 'static,
    ) -> Result<R, HostError> {
        let (tx, rx) = oneshot::channel();
        self.send(Command::With(Box::new(move |rt, now| {
            let _ = tx.send(f(rt, now));
        })))?;
        rx.await.map_err(|_| HostError::Stopped)
    }

    /// The host's synchronised system time now.
    pub async fn system_time(&self) -> Result<SystemInstant, HostError> {
        self.with_runtime(|rt, now| rt.system_time(now)).await
    }

    /// The host clock's sync status.
    pub async fn clock_status(&self) -> Result<ClockStatus, HostError> {
        self.with_runtime(|rt, _| rt.clock().status()).await
    }

    /// Trusts the neighbour on link `index` as a time source (and for
    /// remote clock writes): a host attached to a served machine follows
    /// the serving host this way. Exchanges on the link before this are
    /// counted as untrusted.
    pub async fn trust_time_link(&self, index: u8) -> Result<(), HostError> {
        self.with_runtime(move |rt, _| {
            let trust = rt.clock().trust().with_link(index);
            rt.clock_mut().set_trust(trust);
        })
        .await
    }

    /// Tells the host's clock whether motion planned in its time is under
    /// way: while it is, the clock slews offsets away (within
    /// `max_rate_ppm`) instead of stepping. A host that follows a served
    /// machine's clock and plans motion holds this on once synchronised,
    /// so its timeline never jumps.
    pub async fn set_motion_active(&self, active: bool) -> Result<(), HostError> {
        self.with_runtime(move |rt, _| rt.clock_mut().set_motion_active(active))
            .await
    }

    /// Withdraws the trust of [`trust_time_link`](Self::trust_time_link):
    /// the neighbour on link `index` is forgotten and no longer followed.
    pub async fn distrust_time_link(&self, index: u8) -> Result<(), HostError> {
        self.with_runtime(move |rt, _| {
            let trust = rt.clock().trust().without_link(index);
            rt.clock_mut().set_trust(trust);
        })
        .await
    }

    /// Wakes the runtime task (a port or link has news).
    pub(crate) fn wake(&self) {
        self.wake.notify_one();
    }

    fn send(&self, command: Command) -> Result<(), HostError> {
        self.commands
            .send(command)
            .map_err(|_| HostError::Stopped)?;
        self.wake.notify_one();
        Ok(())
    }
}

/// This crate's version as three bytes.
fn version() -> [u8; 3] {
    let part = |s: &str| s.parse::<u8>().unwrap_or(0);
    [
        part(env!("CARGO_PKG_VERSION_MAJOR")),
        part(env!("CARGO_PKG_VERSION_MINOR")),
        part(env!("CARGO_PKG_VERSION_PATCH")),
    ]
}

struct RuntimeTask {
    runtime: Box<HostRuntime>,
    ports: Vec<PortSlot>,
    links: Vec<LinkSlot>,
    /// Detachments so far, to order vacant link indices by age.
    detached: u64,
    commands: mpsc::UnboundedReceiver<Command>,
    wake: Arc<Notify>,
    clock: HostClock,
}

impl RuntimeTask {
    async fn run(mut self) {
        let mut commands = std::mem::replace(&mut self.commands, mpsc::unbounded_channel().1);
        let wake = self.wake.clone();
        crate::driver::drive(&mut self, &mut commands, &wake).await;
    }
}

impl crate::driver::Driven for RuntimeTask {
    type Command = Command;

    fn handle(&mut self, command: Command) -> std::ops::ControlFlow<()> {
        self.handle_command(command);
        std::ops::ControlFlow::Continue(())
    }

    fn poll(&mut self) -> crate::driver::PollOutcome {
        let now = self.clock.now();
        let result = self.runtime.poll(now, &mut self.ports, &mut self.links);
        crate::driver::PollOutcome {
            more: result.more,
            wake_at: result
                .wake_at
                .map(|t| tokio::time::Instant::from_std(self.clock.instant_at(t))),
        }
    }
}

impl RuntimeTask {
    fn handle_command(&mut self, command: Command) {
        match command {
            Command::AttachLink(link, reply) => {
                let _ = reply.send(self.attach_link(link));
            }
            Command::DetachLink(index, reply) => {
                let detached = self.detach_link(index);
                if let Some(reply) = reply {
                    let _ = reply.send(detached);
                }
            }
            Command::OpenPort(shared, reply) => {
                // Port indices are positions: reuse a closed handle's slot
                // before growing, and never shift the others.
                let vacant = self
                    .ports
                    .iter()
                    .position(|p| matches!(p, PortSlot::Handle(h) if h.is_vacant()));
                let result = if let Some(i) = vacant {
                    if let Some(PortSlot::Handle(h)) = self.ports.get_mut(i) {
                        h.occupy(shared);
                    }
                    Ok(self.base_of(i))
                } else if self.used_indices() < MAX_PORT_INDICES {
                    self.ports.push(PortSlot::Handle(HostPort::new(shared)));
                    Ok(self.base_of(self.ports.len() - 1))
                } else {
                    Err(HostError::NoFreePort(MAX_PORT_INDICES))
                };
                let _ = reply.send(result);
            }
            Command::ClosePort(index) => {
                if let Some(PortSlot::Handle(p)) = self.slot_at(index) {
                    p.vacate();
                }
            }
            Command::AttachPort(port, reply) => {
                let count = usize::from(port.port_count());
                let result = if count == 0 || self.used_indices() + count > MAX_PORT_INDICES {
                    Err(HostError::NoFreePort(MAX_PORT_INDICES))
                } else {
                    self.ports.push(PortSlot::Object(port));
                    Ok(self.base_of(self.ports.len() - 1))
                };
                let _ = reply.send(result);
            }
            Command::DetachPort(index, reply) => {
                let i = (0..self.ports.len()).find(|i| self.base_of(*i) == index);
                let taken = match i.and_then(|i| self.ports.get_mut(i)) {
                    Some(slot @ PortSlot::Object(_)) => {
                        let count = slot.port_count();
                        match std::mem::replace(slot, PortSlot::Detached(count)) {
                            PortSlot::Object(p) => Some(p),
                            _ => None,
                        }
                    }
                    _ => None,
                };
                let _ = reply.send(taken);
            }
            Command::With(f) => {
                let now = self.clock.now();
                f(&mut self.runtime, now);
            }
        }
    }
}

impl RuntimeTask {
    /// Attaches `link` at a vacant index, or a new one. A vacancy left by
    /// a link of the same type and name comes first (a peer that
    /// reconnects keeps its index, so routes through it stay valid), then
    /// the one vacant longest (replies still on their way to the old
    /// neighbour have had the most time to expire).
    fn attach_link(&mut self, link: ChannelLink) -> Result<u8, HostError> {
        let max = 32usize; // the HostRuntime's LINKS
        let same = |slot: &LinkSlot| {
            let info = link.info();
            matches!(slot, LinkSlot::Vacant { type_name, name, .. }
                if type_name == info.type_name && name == info.name)
        };
        let vacancy = self.links.iter().position(same).or_else(|| {
            self.links
                .iter()
                .enumerate()
                .filter_map(|(i, s)| match s {
                    LinkSlot::Vacant { order, .. } => Some((*order, i)),
                    LinkSlot::Attached(_) => None,
                })
                .min()
                .map(|(_, i)| i)
        });
        if let Some((i, slot)) = vacancy.and_then(|i| Some((i, self.links.get_mut(i)?))) {
            *slot = LinkSlot::Attached(link);
            return Ok(i as u8);
        }
        if self.links.len() >= max {
            return Err(HostError::NoFreeLink(max));
        }
        self.links.push(LinkSlot::Attached(link));
        Ok((self.links.len() - 1) as u8)
    }

    /// Makes the link at `index` vacant; see [`Host::detach_link`].
    fn detach_link(&mut self, index: u8) -> bool {
        let Some(slot) = self.links.get_mut(usize::from(index)) else {
            return false;
        };
        let LinkSlot::Attached(link) = slot else {
            return false;
        };
        let info = link.info();
        let (type_name, name) = (info.type_name.to_string(), info.name.to_string());
        self.detached += 1;
        *slot = LinkSlot::Vacant {
            type_name,
            name,
            order: self.detached,
        };
        // Forget the neighbour now: the index may be attached again before
        // the next poll would have seen it closed. Its time trust goes
        // with it: whoever takes the index next is someone else.
        self.runtime.clock_mut().forget(usize::from(index));
        let trust = self.runtime.clock().trust().without_link(index);
        self.runtime.clock_mut().set_trust(trust);
        // And drop what is routed to it now, for the same reason.
        let _ = crate::driver::Driven::poll(self);
        true
    }

    /// The first port index of slot `i` (slots take consecutive indices
    /// from 1, each as many as its port count).
    fn base_of(&self, i: usize) -> u16 {
        let before: usize = self
            .ports
            .iter()
            .take(i)
            .map(|p| usize::from(p.port_count()))
            .sum();
        (1 + before) as u16
    }

    /// How many port indices the slots take.
    fn used_indices(&self) -> usize {
        self.ports.iter().map(|p| usize::from(p.port_count())).sum()
    }

    /// The slot whose first index is `index`.
    fn slot_at(&mut self, index: u16) -> Option<&mut PortSlot> {
        let i = (0..self.ports.len()).find(|i| self.base_of(*i) == index)?;
        self.ports.get_mut(i)
    }
}

/// One entry of the runtime's link table: an attached link, or the index
/// a detached one left, free for the next.
enum LinkSlot {
    Attached(ChannelLink),
    Vacant {
        /// Who held it last (a returning peer gets it back).
        type_name: String,
        name: String,
        /// When it was vacated, in detachments (lower: longer ago).
        order: u64,
    },
}

impl LinkGateway for LinkSlot {
    fn info(&self) -> LinkInfo<'_> {
        match self {
            LinkSlot::Attached(l) => l.info(),
            LinkSlot::Vacant { .. } => LinkInfo {
                type_name: "vacant",
                name: "",
            },
        }
    }

    fn is_open(&self) -> bool {
        match self {
            LinkSlot::Attached(l) => l.is_open(),
            LinkSlot::Vacant { .. } => false,
        }
    }

    fn mtu(&self) -> u16 {
        match self {
            LinkSlot::Attached(l) => l.mtu(),
            LinkSlot::Vacant { .. } => 0,
        }
    }

    fn clear_to_send(&self) -> bool {
        match self {
            LinkSlot::Attached(l) => l.clear_to_send(),
            LinkSlot::Vacant { .. } => false,
        }
    }

    fn send(&mut self, packet: &[u8]) -> Result<(), LinkSendError> {
        match self {
            LinkSlot::Attached(l) => l.send(packet),
            LinkSlot::Vacant { .. } => Err(LinkSendError),
        }
    }

    fn transmit_time(&self, len: usize) -> Duration {
        match self {
            LinkSlot::Attached(l) => l.transmit_time(len),
            LinkSlot::Vacant { .. } => Duration::ZERO,
        }
    }

    fn queue_delay(&self) -> Duration {
        match self {
            LinkSlot::Attached(l) => l.queue_delay(),
            LinkSlot::Vacant { .. } => Duration::ZERO,
        }
    }

    fn receive(&mut self, buf: &mut [u8]) -> Option<Received> {
        match self {
            LinkSlot::Attached(l) => l.receive(buf),
            LinkSlot::Vacant { .. } => None,
        }
    }

    fn poll(&mut self, now: Instant) {
        if let LinkSlot::Attached(l) = self {
            l.poll(now);
        }
    }

    fn counters(&self) -> Option<osap_core::counters::GatewayCounters> {
        match self {
            LinkSlot::Attached(l) => l.counters(),
            LinkSlot::Vacant { .. } => None,
        }
    }
}
