//! The OSAP runtime's loop, the same on every board: it runs in thread
//! mode below everything else.
//!
//! It polls the runtime over the board's links (a module on two links is a
//! hub, and the runtime forwards between them) and the module's ports, then
//! sleeps until a link has news ([`wake_runtime`]) or the earliest deadline
//! the poll reported comes due. After every poll it hands the module the
//! clock's time map and persists a name the network set. A board wraps
//! [`run`] in its own `#[embassy_executor::task]` (tasks cannot be generic).

use embassy_futures::select::select;
use embassy_futures::yield_now;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Instant, Timer};
use osap_core::link::LinkGateway;
use osap_core::netresponder::Level;
use osap_core::Runtime;
use osap_module::{ModuleHandle, ModulePorts};

use crate::link::{FirmwareLink, FramedGateway, MTU};
use crate::name_store::{NameFlash, NameStore};
use crate::serial::SerialTiming;
use crate::usb::UsbTiming;

/// Packet slots: enough for two links' quotas, the ports' and replies.
pub const SLOTS: usize = 16;
/// Port indices with quotas (port 0 included): every index the module's
/// ports take, or the functions past the last would never reply.
pub const PORTS: usize = osap_module::PORT_INDICES;

/// A module's runtime with `LINKS` link gateways.
pub type ModuleRuntime<const LINKS: usize> = Runtime<SLOTS, MTU, PORTS, LINKS>;

/// What a module on USB (link 0) and a UART (link 1) runs: a board hands
/// it to its runtime task, which passes its fields to [`run`] by reference
/// (moving them into another future would keep a second copy of the
/// gateways' frame buffers in the task).
pub struct ModuleParts<F: NameFlash + 'static, H: 'static> {
    /// The runtime.
    pub runtime: &'static mut ModuleRuntime<2>,
    /// The module's ports.
    pub ports: &'static mut ModulePorts<H>,
    /// Link 0.
    pub usb: FramedGateway<UsbTiming>,
    /// Link 1.
    pub uart: FramedGateway<SerialTiming>,
    /// Where the name is kept.
    pub names: NameStore<F>,
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
        Ok(rt) => rt.with_version(version, osap_core::netresponder::BuildKey::RustEmbedded),
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

/// Set by the link tasks when there is something for the runtime to do.
static WAKE: Signal<CriticalSectionRawMutex, ()> = Signal::new();

/// Wakes the runtime loop (from any priority).
pub fn wake_runtime() {
    WAKE.signal(());
}

/// Runs the runtime forever over `links` (link `i` is the runtime's link
/// `i`), serving `ports`, keeping the name in `names`.
pub async fn run<F: NameFlash, H: ModuleHandle, const LINKS: usize>(
    runtime: &mut ModuleRuntime<LINKS>,
    ports: &mut ModulePorts<H>,
    mut links: [&mut dyn FirmwareLink; LINKS],
    names: &mut NameStore<F>,
) -> ! {
    // Bad frames seen so far on each link, to log new ones.
    let mut rx_errors = [0u32; LINKS];
    loop {
        let now = Instant::now().as_micros();
        // Queued or running motion: the clock slews, never steps.
        let moving = ports.module().with(|m| !m.stepper.is_standing());
        runtime
            .clock_mut()
            .set_motion_active(moving.unwrap_or(false));
        let result = {
            let mut gateways = links.each_mut().map(|l| &mut **l as &mut dyn LinkGateway);
            runtime.poll(now, ports.ports(), &mut gateways)
        };
        ports.module().publish_time(runtime.time_map());

        if runtime.take_changes().name {
            let saved = names.save(runtime.identity().name.as_str());
            if saved.is_err() {
                runtime.log(Level::Error, format_args!("name not saved to flash"));
            }
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
                select(WAKE.wait(), Timer::at(Instant::from_micros(at))).await;
            }
            None => WAKE.wait().await,
        }
    }
}
