//! osap-rs module firmware for the Raspberry Pi Pico (RP2040).
//!
//! One OSAP runtime with two links, USB CDC-ACM ([`usb_link`]) and UART /
//! RS-485 ([`uart_link`]), serving the module's PIPES functions from
//! osap-module (a stepper axis that follows MAXL motion in synchronized
//! time, and an I/O set). Work runs at three priorities:
//!
//! | where                         | what                                  |
//! |-------------------------------|---------------------------------------|
//! | edge executor, `SWI_IRQ_2`, P0 | digital pins' rising edges ([`edges`]) |
//! | step executor, `SWI_IRQ_1`, P1 | PIO step words, limit switch ([`steps`]) |
//! | link executor, `SWI_IRQ_0`, P2 | USB and UART I/O, time stamps         |
//! | thread mode                   | the OSAP runtime ([`runtime_task`])   |
//!
//! Peripheral interrupts stay at embassy-rp's default, the highest
//! priority; their handlers only move bytes and wake tasks.
//!
//! Panics reset the chip (`panic-reset`): a module that trips over a bug
//! comes back and rejoins the network, and a reset returns every pin to an
//! input, so the stepper driver's pulled-up EN disables the motor.
//! (`panic-halt` would leave the driver powered and the module silent.)
#![no_std]
#![no_main]

mod board;
mod edges;
mod name_store;
mod rate_store;
mod runtime_task;
mod steps;
mod uart_link;
mod usb_link;

use embassy_executor::{InterruptExecutor, Spawner};
use embassy_rp::adc::{self, Adc};
use embassy_rp::flash::Flash;
use embassy_rp::gpio::{Flex, Input, Level, Output, Pull};
use embassy_rp::interrupt;
use embassy_rp::interrupt::{InterruptExt, Priority};
use embassy_rp::peripherals::{PIN_10, PIN_11, PIN_12, PIN_13, PIO0, UART0, USB};
use embassy_rp::pio::{self, Pio};
use embassy_rp::pwm::Pwm;
use embassy_rp::uart::{self, BufferedUart};
use embassy_rp::{bind_interrupts, usb};
use osap_firmware::hot_start::RateKeeper;
use osap_firmware::link::{FramedGateway, LinkShared};
use osap_firmware::name_store::NameStore;
use osap_firmware::usb::USB_TIMING;
use osap_module::board::Parts;
use osap_module::{ModuleCell, ModulePorts};
use panic_reset as _;
use static_cell::StaticCell;

use board::{IoPins, StepperPins};
use name_store::NameSector;
use osap_firmware::runtime::{module_ports, module_runtime, uart_in_stored_role, ModuleParts};
use runtime_task::ModuleRuntime;
use usb_link::UsbStrings;

/// The module type: the runtime's type name, the USB product string's
/// tail and the prefix of a fresh module's name.
pub const MODULE_TYPE: &str = "stepper";

/// Firmware version reported to scans.
const VERSION: [u8; 3] = [0, 1, 0];

/// The module's function set (see `osap_module::FUNCTION_SET_ID`), kept in
/// its own ELF section so a script can check that every firmware presents
/// the same functions.
#[used]
#[link_section = ".osap_function_set"]
static FUNCTION_SET: [u8; 4] = osap_module::FUNCTION_SET_ID.to_le_bytes();

/// The module's board: its stepper driver, its I/O pins and the local clock.
pub type ModuleBoard = Parts<&'static mut StepperPins, &'static mut IoPins>;

/// The module (its logic and its board), shared by the runtime task and
/// the step interrupt.
pub static MODULE: ModuleCell<ModuleBoard> = ModuleCell::new();

/// How the module's ports reach it.
pub type Module = &'static ModuleCell<ModuleBoard>;

// The interrupt bindings embassy-rp checks at compile time.
bind_interrupts!(
    /// The interrupts the links and the step output take.
    pub struct Irqs {
    USBCTRL_IRQ => usb::InterruptHandler<USB>;
    UART0_IRQ => uart::BufferedInterruptHandler<UART0>;
    PIO0_IRQ_0 => pio::InterruptHandler<PIO0>;
});

static EDGE_EXECUTOR: InterruptExecutor = InterruptExecutor::new();
static STEP_EXECUTOR: InterruptExecutor = InterruptExecutor::new();
static LINK_EXECUTOR: InterruptExecutor = InterruptExecutor::new();

#[interrupt]
unsafe fn SWI_IRQ_2() {
    // SAFETY: the executor was started on this interrupt in `main`.
    unsafe { EDGE_EXECUTOR.on_interrupt() }
}

#[interrupt]
unsafe fn SWI_IRQ_1() {
    // SAFETY: the executor was started on this interrupt in `main`.
    unsafe { STEP_EXECUTOR.on_interrupt() }
}

#[interrupt]
unsafe fn SWI_IRQ_0() {
    // SAFETY: the executor was started on this interrupt in `main`.
    unsafe { LINK_EXECUTOR.on_interrupt() }
}

static USB_SHARED: LinkShared = LinkShared::new();
static UART_SHARED: LinkShared = LinkShared::new();

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let p = embassy_rp::init(Default::default());

    // Board id and name, before any interrupt work starts (reading the id
    // briefly takes the flash out of execute-in-place mode).
    let mut flash = Flash::new_blocking(p.FLASH);
    let mut unique_id = [0u8; 8];
    // A failure leaves zeros: the module still runs, with a plain name.
    let _ = flash.blocking_unique_id(&mut unique_id);
    let mut names = NameStore::new(NameSector(flash));
    let name = names.load_or_default(MODULE_TYPE, &unique_id);
    // SAFETY: the name and rate drivers are both used only by the runtime
    // task, one at a time.
    let rates = RateKeeper::open(
        unsafe { rate_store::RateSector::steal() },
        Default::default(),
    );

    // The module's hardware.
    static STEPPER: StaticCell<StepperPins> = StaticCell::new();
    let stepper = STEPPER.init(StepperPins {
        // High: disabled until the module enables it.
        enable_n: Output::new(p.PIN_4, Level::High),
        ms: [
            Output::new(p.PIN_7, Level::Low),
            Output::new(p.PIN_8, Level::Low),
            Output::new(p.PIN_9, Level::Low),
        ],
    });
    // Second handles on the digital pins, only to await their edges
    // (edges::edge_task); made first, so the I/O set's own configuration
    // below (pull-downs) is what stays.
    // SAFETY: the watchers only arm the pins' edge interrupts and never
    // change their direction, pull or function; the I/O set owns those.
    let watchers = unsafe {
        [
            Flex::new(PIN_10::steal()),
            Flex::new(PIN_11::steal()),
            Flex::new(PIN_12::steal()),
            Flex::new(PIN_13::steal()),
        ]
    };
    static IO: StaticCell<IoPins> = StaticCell::new();
    let pwm_config = IoPins::pwm_start_config();
    let io = IO.init(IoPins {
        digital: [
            board::digital_input(Flex::new(p.PIN_10)),
            board::digital_input(Flex::new(p.PIN_11)),
            board::digital_input(Flex::new(p.PIN_12)),
            board::digital_input(Flex::new(p.PIN_13)),
        ],
        pwm: Pwm::new_output_ab(p.PWM_SLICE7, p.PIN_14, p.PIN_15, pwm_config.clone()),
        adc: Adc::new_blocking(p.ADC, adc::Config::default()),
        analog: [
            adc::Channel::new_pin(p.PIN_26, Pull::None),
            adc::Channel::new_pin(p.PIN_27, Pull::None),
            adc::Channel::new_pin(p.PIN_28, Pull::None),
        ],
        pwm_config,
    });
    MODULE.install(Parts {
        stepper,
        io: Some(io),
        clock: osap_firmware::local_now,
        bootloader: Some(board::reboot_to_usb_boot),
    });

    // The runtime and its ports.
    static RUNTIME: StaticCell<ModuleRuntime> = StaticCell::new();
    let runtime = RUNTIME.init(module_runtime(MODULE_TYPE, &name, VERSION));
    static PORTS: StaticCell<ModulePorts<Module>> = StaticCell::new();
    let ports = PORTS.init(module_ports(&MODULE));

    // Step generation on PIO0 state machine 0, and the limit switch.
    let Pio {
        mut common,
        mut sm0,
        ..
    } = Pio::new(p.PIO0, Irqs);
    let step_pin = common.make_pio_pin(p.PIN_2);
    let dir_pin = common.make_pio_pin(p.PIN_3);
    steps::configure(&mut common, &mut sm0, step_pin, dir_pin);
    let limit = Input::new(p.PIN_5, Pull::Up);

    // UART0 with its RS-485 driver enable.
    static UART_TX_BUF: StaticCell<[u8; 1024]> = StaticCell::new();
    static UART_RX_BUF: StaticCell<[u8; 1024]> = StaticCell::new();
    let mut uart_config = uart::Config::default();
    uart_config.baudrate = uart_link::BAUD;
    let uart = BufferedUart::new(
        p.UART0,
        p.PIN_0,
        p.PIN_1,
        Irqs,
        UART_TX_BUF.init([0; 1024]),
        UART_RX_BUF.init([0; 1024]),
        uart_config,
    );
    let (uart_tx, uart_rx) = uart.split();
    let driver_enable = Output::new(p.PIN_6, Level::Low);

    // The executors, highest first.
    interrupt::SWI_IRQ_2.set_priority(Priority::P0);
    let edge_spawner = EDGE_EXECUTOR.start(interrupt::SWI_IRQ_2);
    for (index, watch) in watchers.into_iter().enumerate() {
        edge_spawner.spawn(unwrap(edges::edge_task(index, watch)));
    }

    interrupt::SWI_IRQ_1.set_priority(Priority::P1);
    let step_spawner = STEP_EXECUTOR.start(interrupt::SWI_IRQ_1);
    step_spawner.spawn(unwrap(steps::step_task(sm0)));
    step_spawner.spawn(unwrap(steps::limit_task(limit)));

    interrupt::SWI_IRQ_0.set_priority(Priority::P2);
    let link_spawner = LINK_EXECUTOR.start(interrupt::SWI_IRQ_0);
    let strings = UsbStrings::new(MODULE_TYPE, &unique_id);
    link_spawner.spawn(unwrap(usb_link::usb_start_task(
        p.USB,
        strings,
        &USB_SHARED,
    )));
    link_spawner.spawn(unwrap(uart_link::uart_rx_task(uart_rx, &UART_SHARED)));
    link_spawner.spawn(unwrap(uart_link::uart_tx_task(
        uart_tx,
        driver_enable,
        &UART_SHARED,
    )));
    // A UART has no "connected": the link is up from the start.
    UART_SHARED.set_open(true);

    spawner.spawn(unwrap(runtime_task::runtime_task(ModuleParts {
        runtime,
        ports,
        usb: FramedGateway::new(&USB_SHARED, "usb_cdc", &USB_TIMING),
        // Point to point, or an RS-485 bus station, as the stored role says.
        uart: uart_in_stored_role(
            FramedGateway::new(&UART_SHARED, "uart", &uart_link::UART_TIMING),
            &mut names,
        ),
        names,
        rates,
    })));
}

/// Every task is spawned into a pool sized for its spawns (one task, or
/// one per digital pin), so spawning cannot fail.
pub(crate) fn unwrap<T>(r: Result<T, embassy_executor::SpawnError>) -> T {
    match r {
        Ok(t) => t,
        Err(_) => panic!("task spawned twice"),
    }
}
