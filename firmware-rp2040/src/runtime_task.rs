//! The OSAP runtime's task, in thread mode below everything else.
//!
//! It polls the runtime over both links (USB is link 0, UART link 1: a Pico
//! on both is a hub, and the runtime forwards between them) and the
//! module's ports, then sleeps until a link has news ([`wake_runtime`]) or
//! the earliest deadline the poll reported comes due. After every poll it
//! hands the module the clock's time map and persists a name the network
//! set.

use embassy_futures::select::select;
use embassy_futures::yield_now;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Instant, Timer};
use osap_core::link::LinkGateway;
use osap_core::netresponder::Level;
use osap_core::Runtime;
use osap_firmware_logic::name_store::NameStore;
use osap_module::ModulePorts;

use crate::link::{FramedGateway, MTU};
use crate::name_store::NameSector;
use crate::uart_link::UartTiming;
use crate::usb_link::UsbTiming;

/// Packet slots: enough for both links' quotas, the ports' and replies.
pub const SLOTS: usize = 16;
/// Port indices with quotas (port 0 included): every index the module's
/// ports take, or the functions past the last would never reply.
pub const PORTS: usize = osap_module::PORT_INDICES;
/// Link gateways: USB and UART.
pub const LINKS: usize = 2;

/// The module's runtime.
pub type ModuleRuntime = Runtime<SLOTS, MTU, PORTS, LINKS>;

/// Set by the link tasks when there is something for the runtime to do.
static WAKE: Signal<CriticalSectionRawMutex, ()> = Signal::new();

/// Wakes the runtime task (from any priority).
pub fn wake_runtime() {
    WAKE.signal(());
}

/// What the runtime task owns.
pub struct RuntimeParts {
    /// The runtime.
    pub runtime: &'static mut ModuleRuntime,
    /// The module's ports.
    pub ports: &'static mut ModulePorts,
    /// Link 0.
    pub usb: FramedGateway<UsbTiming>,
    /// Link 1.
    pub uart: FramedGateway<UartTiming>,
    /// Where the name is kept.
    pub names: NameStore<NameSector>,
}

/// Runs the runtime forever.
#[embassy_executor::task]
pub async fn runtime_task(parts: RuntimeParts) {
    let RuntimeParts {
        runtime,
        ports,
        mut usb,
        mut uart,
        mut names,
    } = parts;
    // Bad frames seen so far on each link, to log new ones.
    let mut rx_errors = [0u32; LINKS];
    loop {
        let now = Instant::now().as_micros();
        let result = {
            let mut links: [&mut dyn LinkGateway; LINKS] = [&mut usb, &mut uart];
            runtime.poll(now, ports.ports(), &mut links)
        };
        osap_module::publish_time(runtime.time_map());

        if runtime.take_changes().name {
            let saved = names.save(runtime.identity().name.as_str());
            if saved.is_err() {
                runtime.log(Level::Error, format_args!("name not saved to flash"));
            }
        }

        for (seen, (name, shared)) in rx_errors.iter_mut().zip([
            (usb.info().type_name, usb.shared()),
            (uart.info().type_name, uart.shared()),
        ]) {
            let now_errors = shared.rx_errors();
            if now_errors != *seen {
                let new = now_errors.wrapping_sub(*seen);
                *seen = now_errors;
                // Readable over the network in the runtime's debug log.
                runtime.log(
                    Level::Warn,
                    format_args!("{name}: {new} bad frame(s) dropped, {now_errors} since boot"),
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
