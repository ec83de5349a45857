//! One simulated module: an osap-core runtime sized like firmware, in its
//! own tokio task, on a drifting clock.

use super::clock::DriftClock;
use osap_core::link::{LinkGateway, LinkInfo, LinkSendError, Received};
use osap_core::port::Port;
use osap_core::Micros;
use osap_host::clock::HostClock;
use osap_host::link::ChannelLink;
use std::sync::Arc;
use tokio::sync::{mpsc, Notify};

/// Packet slots of a simulated module's runtime.
pub const MODULE_SLOTS: usize = 32;
/// Packet size of a simulated module (as on an RP2040 or SAMD51).
pub const MODULE_MTU: usize = 256;
/// Port indices of a simulated module (port 0 included).
pub const MODULE_PORTS: usize = 16;
/// Link gateways of a simulated module.
pub const MODULE_LINKS: usize = 8;

/// The runtime a simulated module runs: sized like firmware.
pub type ModuleRuntime = osap_core::Runtime<MODULE_SLOTS, MODULE_MTU, MODULE_PORTS, MODULE_LINKS>;

/// A module's side of a link: a [`ChannelLink`] (whose receive stamps are on
/// the host's clock) whose stamps are turned into the module's local time.
pub(crate) struct ModuleLink {
    pub(crate) inner: ChannelLink,
    clock: DriftClock,
    host_clock: HostClock,
}

impl ModuleLink {
    pub(crate) fn new(inner: ChannelLink, clock: DriftClock, host_clock: HostClock) -> Self {
        ModuleLink {
            inner,
            clock,
            host_clock,
        }
    }
}

impl LinkGateway for ModuleLink {
    fn info(&self) -> LinkInfo<'_> {
        self.inner.info()
    }
    fn is_open(&self) -> bool {
        self.inner.is_open()
    }
    fn mtu(&self) -> u16 {
        self.inner.mtu()
    }
    fn clear_to_send(&self) -> bool {
        self.inner.clear_to_send()
    }
    fn send(&mut self, packet: &[u8]) -> Result<(), LinkSendError> {
        self.inner.send(packet)
    }
    fn transmit_time(&self, len: usize) -> Micros {
        self.inner.transmit_time(len)
    }
    fn queue_delay(&self) -> Micros {
        self.inner.queue_delay()
    }
    fn receive(&mut self, buf: &mut [u8]) -> Option<Received> {
        let mut rx = self.inner.receive(buf)?;
        rx.timestamp = rx
            .timestamp
            .map(|host_us| self.clock.local_us_at(self.host_clock.instant_at(host_us)));
        Some(rx)
    }
}

pub(crate) type ModuleFn = Box<dyn FnOnce(&mut ModuleRuntime, Micros) + Send>;

pub(crate) enum ModuleCommand {
    With(ModuleFn),
    Stop,
}

/// What a stopped module leaves behind for its restart: its link ends and
/// the name it had (the network may have renamed it; firmware keeps a new
/// name in flash).
pub(crate) struct Parked {
    pub(crate) links: Vec<ChannelLink>,
    pub(crate) name: String,
}

pub(crate) struct ModuleTask {
    pub(crate) runtime: Box<ModuleRuntime>,
    pub(crate) ports: Vec<Box<dyn Port + Send>>,
    pub(crate) links: Vec<ModuleLink>,
    pub(crate) commands: mpsc::UnboundedReceiver<ModuleCommand>,
    pub(crate) wake: Arc<Notify>,
    pub(crate) clock: DriftClock,
}

impl ModuleTask {
    /// Polls the runtime whenever a link has news, a command comes, or the
    /// runtime's `wake_at` (local time, turned into an instant on the
    /// module's clock) comes due; stops on [`ModuleCommand::Stop`] or when
    /// every handle is gone.
    pub(crate) async fn run(mut self) -> Parked {
        loop {
            loop {
                match self.commands.try_recv() {
                    Ok(ModuleCommand::With(f)) => self.with(f),
                    Ok(ModuleCommand::Stop) | Err(mpsc::error::TryRecvError::Disconnected) => {
                        return self.park()
                    }
                    Err(mpsc::error::TryRecvError::Empty) => break,
                }
            }
            let now = self.clock.now_us();
            let result = self.runtime.poll(now, &mut self.ports, &mut self.links);
            if result.more {
                tokio::task::yield_now().await;
                continue;
            }
            let wake = self.wake.clone();
            let notified = wake.notified();
            let deadline = result
                .wake_at
                .map(|t| tokio::time::Instant::from_std(self.clock.instant_at(t)));
            tokio::select! {
                command = self.commands.recv() => match command {
                    Some(ModuleCommand::With(f)) => self.with(f),
                    Some(ModuleCommand::Stop) | None => return self.park(),
                },
                _ = notified => {}
                _ = sleep_until(deadline) => {}
            }
        }
    }

    fn with(&mut self, f: ModuleFn) {
        let now = self.clock.now_us();
        f(&mut self.runtime, now);
    }

    fn park(self) -> Parked {
        Parked {
            name: self.runtime.identity().name.to_string(),
            links: self.links.into_iter().map(|l| l.inner).collect(),
        }
    }
}

async fn sleep_until(deadline: Option<tokio::time::Instant>) {
    match deadline {
        Some(t) => tokio::time::sleep_until(t).await,
        None => std::future::pending().await,
    }
}
