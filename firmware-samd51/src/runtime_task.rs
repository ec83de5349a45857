//! The OSAP runtime's task: osap-firmware's runtime loop over this board's
//! two links (USB is link 0, UART link 1) and its name block.

use osap_firmware::link::FramedGateway;
use osap_firmware::name_store::NameStore;
use osap_firmware::usb::UsbTiming;
use osap_module::ModulePorts;

use crate::name_store::NameBlock;
use crate::uart_link::UartTiming;

/// Link gateways: USB and UART.
pub const LINKS: usize = 2;

/// The module's runtime.
pub type ModuleRuntime = osap_firmware::runtime::ModuleRuntime<LINKS>;

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
    pub names: NameStore<NameBlock>,
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
    osap_firmware::runtime::run(runtime, ports, [&mut usb, &mut uart], &mut names).await
}
