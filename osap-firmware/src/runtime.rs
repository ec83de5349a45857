//! The OSAP runtime's loop, the same on every board: it runs in thread
//! mode below everything else.
//!
//! It polls the runtime over the board's links (a module on two links is a
//! hub, and the runtime forwards between them) and the module's ports, then
//! sleeps until a link has news ([`wake_runtime`]) or the earliest deadline
//! the poll reported comes due. After every poll it hands the module the
//! clock's time map, persists a name or bus role the network set once the
//! axis stands ([`crate::flash_writes`]), and runs the hot start policy
//! ([`crate::hot_start`]): the clock starts from the rate saved in flash
//! and its learned rate is saved, sparingly, also only while the axis
//! stands. A board wraps [`run`] in its own `#[embassy_executor::task]`
//! (tasks cannot be generic).

use embassy_futures::select::select;
use embassy_futures::yield_now;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Instant, Timer};
use osap_core::link::LinkGateway;
use osap_core::netresponder::Level;
use osap_core::Runtime;
use osap_module::{ModuleHandle, ModulePorts};

use crate::flash_writes::{PendingWrites, Written};
use crate::hot_start::{HotStartEvent, RateKeeper};
use crate::link::{FirmwareLink, FramedGateway, MTU};
use crate::name_store::{NameFlash, NameStore};
use crate::rate_store::RateFlash;
use crate::serial::SerialTiming;
use osap_core::bus::{BusRole, Switchable};

/// A board's UART link: framed, and a bus station when its role says so.
pub type UartLink = Switchable<FramedGateway<SerialTiming>, MTU>;

/// The UART link over `gateway`, in the bus role stored in `names`.
pub fn uart_in_stored_role<F: NameFlash>(
    gateway: FramedGateway<SerialTiming>,
    names: &mut NameStore<F>,
) -> UartLink {
    Switchable::new(gateway, names.load_bus())
}
use crate::usb::UsbTiming;

/// Packet slots ([`osap_module::sizes::SLOTS`]).
pub const SLOTS: usize = osap_module::sizes::SLOTS;
/// Port indices with quotas ([`osap_module::sizes::PORTS`]).
pub const PORTS: usize = osap_module::sizes::PORTS;
/// Link gateways of a board ([`osap_module::sizes::LINKS`]).
pub const LINKS: usize = osap_module::sizes::LINKS;

/// A module's runtime with `LINKS` link gateways.
pub type ModuleRuntime<const LINKS: usize> = Runtime<SLOTS, MTU, PORTS, LINKS>;

/// What a module on USB (link 0) and a UART (link 1) runs: a board hands
/// it to its runtime task, which passes its fields to [`run`] by reference
/// (moving them into another future would keep a second copy of the
/// gateways' frame buffers in the task).
pub struct ModuleParts<F: NameFlash + 'static, H: ModuleHandle + 'static, R: RateFlash + 'static> {
    /// The runtime.
    pub runtime: &'static mut ModuleRuntime<2>,
    /// The module's ports.
    pub ports: &'static mut ModulePorts<H>,
    /// Link 0.
    pub usb: FramedGateway<UsbTiming>,
    /// Link 1: point to point, or a station on an RS-485 bus, as its
    /// role says (kept in the name sector; see [`uart_in_stored_role`]).
    pub uart: UartLink,
    /// Where the name is kept.
    pub names: NameStore<F>,
    /// Where the learned clock rate is kept, and when it is used.
    pub rates: RateKeeper<R>,
}

impl<F: NameFlash, H: ModuleHandle, R: RateFlash> core::fmt::Debug for ModuleParts<F, H, R> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("ModuleParts")
            .field("runtime", &self.runtime)
            .finish_non_exhaustive()
    }
}

/// A module's runtime: of type `module_type`, named `name`, reporting
/// firmware `version` to scans.
///
/// # Panics
/// If `name` is longer than a runtime name may be (the name store never
/// returns one).
pub fn module_runtime<const LINKS: usize>(
    module_type: &str,
    name: &str,
    version: [u8; 3],
) -> ModuleRuntime<LINKS> {
    match ModuleRuntime::new(module_type, name) {
        Ok(rt) => rt
            .with_version(version, osap_core::netresponder::BuildKey::RustEmbedded)
            .with_function_set(osap_module::FUNCTION_SET_ID),
        Err(_) => panic!("module name too long"),
    }
}

/// The ports of the module `module` reaches (the firmware's `&'static`
/// [`osap_module::ModuleCell`]).
///
/// # Panics
/// If a function signature is rejected: osap-module's tests check every
/// one, so this is a build bug.
pub fn module_ports<H: ModuleHandle>(module: H) -> ModulePorts<H> {
    match ModulePorts::new(module) {
        Ok(ports) => ports,
        Err(_) => panic!("module function signature rejected"),
    }
}

/// Runs the hot start policy after a poll at local time `now` and logs
/// what it did (readable over the network in the runtime's debug log).
fn hot_start<R: RateFlash, const LINKS: usize>(
    runtime: &mut ModuleRuntime<LINKS>,
    rates: &mut RateKeeper<R>,
    now: osap_core::Instant,
) {
    match rates.poll(now, runtime.clock_mut()) {
        Ok(None) => {}
        Ok(Some(HotStartEvent::Preset(ppb))) => runtime.log(
            Level::Info,
            format_args!("hot start: clock rate {ppb} ppb from flash"),
        ),
        Ok(Some(HotStartEvent::Declined(src))) => runtime.log(
            Level::Info,
            format_args!(
                "cold start: saved clock rate was learned on link {} at tier {}",
                src.link, src.tier
            ),
        ),
        Ok(Some(HotStartEvent::Saved(r))) => runtime.log(
            Level::Info,
            format_args!("clock rate {} ppb saved (record {})", r.rate_ppb, r.seq),
        ),
        Err(_) => runtime.log(Level::Error, format_args!("clock rate not saved to flash")),
    }
}

/// Puts link `index` in `role` (the network asked, netresponder key
/// `SET_BUS`) at once, and keeps the role for the flash once the axis
/// stands (see [`crate::flash_writes`]).
fn apply_bus_role<const LINKS: usize>(
    runtime: &mut ModuleRuntime<LINKS>,
    links: &mut [&mut dyn FirmwareLink; LINKS],
    pending: &mut PendingWrites,
    index: u8,
    role: BusRole,
) {
    let Some(link) = links.get_mut(usize::from(index)) else {
        return;
    };
    if !link.set_bus_role(role) {
        return;
    }
    let [kind, param] = role.to_bytes();
    runtime.log(
        Level::Info,
        format_args!("link {index}: bus role {kind}/{param}, saved to flash once the axis stands"),
    );
    pending.bus_changed(role);
}

/// Logs what [`PendingWrites::write_due`] wrote (readable over the
/// network in the runtime's debug log).
fn log_written<E, const LINKS: usize>(runtime: &mut ModuleRuntime<LINKS>, written: Written<E>) {
    match written.name {
        Some(Err(_)) => runtime.log(Level::Error, format_args!("name not saved to flash")),
        Some(Ok(true)) => runtime.log(Level::Info, format_args!("name saved to flash")),
        Some(Ok(false)) | None => {}
    }
    match written.bus {
        Some(Err(_)) => runtime.log(
            Level::Error,
            format_args!("bus role in force, not saved to flash"),
        ),
        Some(Ok(true)) => runtime.log(Level::Info, format_args!("bus role saved to flash")),
        Some(Ok(false)) | None => {}
    }
}

/// Set by the link tasks when there is something for the runtime to do.
static WAKE: Signal<CriticalSectionRawMutex, ()> = Signal::new();

/// Wakes the runtime loop (from any priority).
pub fn wake_runtime() {
    WAKE.signal(());
}

/// Runs the runtime forever over `links` (link `i` is the runtime's link
/// `i`), serving `ports`, keeping the name in `names` and the clock rate
/// in `rates`.
pub async fn run<F: NameFlash, H: ModuleHandle, R: RateFlash, const LINKS: usize>(
    runtime: &mut ModuleRuntime<LINKS>,
    ports: &mut ModulePorts<H>,
    mut links: [&mut dyn FirmwareLink; LINKS],
    names: &mut NameStore<F>,
    rates: &mut RateKeeper<R>,
) -> ! {
    // Bad frames seen so far on each link, to log new ones.
    let mut rx_errors = [0u32; LINKS];
    // A name or bus role set while the axis moves, for the flash.
    let mut pending = PendingWrites::new();
    loop {
        let now = crate::local_now();
        // Queued or running motion: the clock slews, never steps.
        let moving = ports.module().with(|m| !m.stepper.is_standing());
        runtime
            .clock_mut()
            .set_motion_active(moving.unwrap_or(false));
        let result = {
            let mut gateways = links.each_mut().map(|l| &mut **l as &mut dyn LinkGateway);
            runtime.poll(now, core::slice::from_mut(&mut *ports), &mut gateways)
        };
        ports.module().publish_time(runtime.time_map());
        // The poll may have queued motion: whether the axis stands now
        // decides every flash write below.
        let standing = ports
            .module()
            .with(|m| m.stepper.is_standing())
            .unwrap_or(true);
        runtime.clock_mut().set_motion_active(!standing);
        hot_start(runtime, rates, now);

        if runtime.take_changes().name {
            pending.name_changed(runtime.identity().name.as_str());
        }
        if let Some((index, role)) = runtime.take_bus_request() {
            apply_bus_role(runtime, &mut links, &mut pending, index, role);
        }
        if !pending.is_empty() {
            let written = pending.write_due(standing, names);
            log_written(runtime, written);
        }

        for (seen, link) in rx_errors.iter_mut().zip(links.iter()) {
            let now_errors = link.shared().rx_errors();
            if now_errors != *seen {
                let new = now_errors.wrapping_sub(*seen);
                *seen = now_errors;
                // Readable over the network in the runtime's debug log.
                runtime.log(
                    Level::Warn,
                    format_args!(
                        "{}: {new} bad frame(s) dropped, {now_errors} since boot",
                        link.info().type_name
                    ),
                );
            }
        }

        if result.more {
            // Budget ran out with work left: let other tasks in, then go on.
            yield_now().await;
            continue;
        }
        match result.wake_at {
            Some(at) => {
                select(WAKE.wait(), Timer::at(Instant::from_micros(at.as_micros()))).await;
            }
            None => WAKE.wait().await,
        }
    }
}
