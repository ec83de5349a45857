//! The OSAP runtime's task: osap-firmware's runtime loop over this board's
//! two links (USB is link 0, UART link 1), its name sector and its clock
//! rate sector.

use osap_firmware::runtime::ModuleParts;

use crate::name_store::NameSector;
use crate::rate_store::RateSector;

/// The module's runtime: the module's links (USB and UART).
pub(crate) type ModuleRuntime = osap_firmware::runtime::ModuleRuntime<{ osap_module::sizes::LINKS }>;

/// Runs the runtime forever.
#[embassy_executor::task]
pub async fn runtime_task(mut parts: ModuleParts<NameSector, crate::Module, RateSector>) {
    osap_firmware::runtime::run(
        parts.runtime,
        parts.ports,
        [&mut parts.usb, &mut parts.uart],
        &mut parts.names,
        &mut parts.rates,
    )
    .await
}
