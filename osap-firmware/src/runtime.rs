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
use osap_module::ModulePorts;

use crate::link::{FirmwareLink, MTU};
use crate::name_store::{NameFlash, NameStore};

/// Packet slots: enough for two links' quotas, the ports' and replies.
pub const SLOTS: usize = 16;
/// Port indices with quotas (port 0 included): every index the module's
/// ports take, or the functions past the last would never reply.
pub const PORTS: usize = osap_module::PORT_INDICES;

/// A module's runtime with `LINKS` link gateways.
pub type ModuleRuntime<const LINKS: usize> = Runtime<SLOTS, MTU, PORTS, LINKS>;

/// Set by the link tasks when there is something for the runtime to do.
static WAKE: Signal<CriticalSectionRawMutex, ()> = Signal::new();

/// Wakes the runtime loop (from any priority).
pub fn wake_runtime() {
    WAKE.signal(());
}

/// Runs the runtime forever over `links` (link `i` is the runtime's link
/// `i`), serving `ports`, keeping the name in `names`.
pub async fn run<F: NameFlash, const LINKS: usize>(
    runtime: &mut ModuleRuntime<LINKS>,
    ports: &mut ModulePorts,
    mut links: [&mut dyn FirmwareLink; LINKS],
    names: &mut NameStore<F>,
) -> ! {
    // Bad frames seen so far on each link, to log new ones.
    let mut rx_errors = [0u32; LINKS];
    loop {
        let now = Instant::now().as_micros();
        let result = {
            let mut gateways = links.each_mut().map(|l| &mut **l as &mut dyn LinkGateway);
            runtime.poll(now, ports.ports(), &mut gateways)
        };
        osap_module::publish_time(runtime.time_map());

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
