//! osap-rs module firmware for SAMD51 boards: the Adafruit Metro M4
//! Express (feature `metro-m4`, the default) and Feather M4 Express
//! (`feather-m4`), both ATSAMD51J19.
//!
//! Board glue only: the module's logic is osap-module's, the links'
//! framing, the runtime loop and the name record are osap-firmware's, the
//! same code the RP2040 firmware runs. One OSAP runtime with two links,
//! USB CDC-ACM ([`usb_link`]) and UART / RS-485 ([`uart_link`]). Work runs
//! at these priorities (the SAMD51 has 3 priority bits; 0x00 is highest):
//!
//! | where | priority | what |
//! |-------|----------|------|
//! | TC0 interrupt | 0x00 | the 100 kHz step tick ([`steps`]), never masked |
//! | TC2, EIC interrupts | 0x20 | time driver ([`time_driver`]), limit switch, digital pins' edge counts ([`edges`]) |
//! | step executor, `PDEC_MC0` | 0x20 | the step task: refills the tick's words |
//! | USB, SERCOM interrupts | 0x40 | link I/O, receive time stamps |
//! | link executor, `PDEC_OTHER` | 0x60 | the links' tasks |
//! | thread mode | — | the OSAP runtime ([`runtime_task`]) |
//!
//! Critical sections mask 0x20 and below ([`cs`]), so only the step tick
//! runs through them.
//!
//! Panics reset the chip (`panic-reset`): a module that trips over a bug
//! comes back and rejoins the network, and a reset returns every pin to an
//! input, so the stepper driver's pulled-up EN disables the motor.
//!
//! Built and size-checked only: no SAMD51 board or emulator was at hand,
//! so none of this has run.
#![no_std]
#![no_main]

#[cfg(all(feature = "metro-m4", feature = "feather-m4"))]
compile_error!("choose one board: feature `metro-m4` or `feather-m4`, not both");
#[cfg(not(any(feature = "metro-m4", feature = "feather-m4")))]
compile_error!(
    "choose a board: `--features metro-m4` (the default) or `--no-default-features --features feather-m4`"
);

mod board;
mod clocks;
mod cs;
mod edges;
mod name_store;
mod rate_store;
mod runtime_task;
mod steps;
mod time_driver;
mod uart_link;
mod usb_link;

use atsamd_hal::clock::{ClockGenId, ClockSource};
use atsamd_hal::gpio::{DynAlternate, DynPin, Pins};
use atsamd_hal::nvm::Nvm;
use atsamd_hal::pac::{self, interrupt, Interrupt};
use atsamd_hal::sercom::uart::{self, BaudMode, Oversampling};
use atsamd_hal::time::Hertz;
use atsamd_hal::usb::UsbBus;
use embassy_executor::{InterruptExecutor, Spawner};
use osap_firmware::hot_start::RateKeeper;
use osap_firmware::link::{FramedGateway, LinkShared};
use osap_firmware::name_store::NameStore;
use osap_firmware::usb::{product_string, serial_string, ProductString, SerialString, USB_TIMING};
use osap_module::board::Parts;
use osap_module::{ModuleCell, ModulePorts};
use panic_reset as _;
use static_cell::StaticCell;
use usb_device::bus::UsbBusAllocator;

use board::{BoardUart, FastPin, IoPins, StepperPins};
use name_store::NameBlock;
use osap_firmware::runtime::{module_ports, module_runtime, uart_in_stored_role, ModuleParts};
use runtime_task::ModuleRuntime;

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

static STEP_EXECUTOR: InterruptExecutor = InterruptExecutor::new();
static LINK_EXECUTOR: InterruptExecutor = InterruptExecutor::new();

/// Step executor priority.
const STEP_EXECUTOR_PRIORITY: u8 = 0x20;
/// Link executor priority.
const LINK_EXECUTOR_PRIORITY: u8 = 0x60;

#[interrupt]
fn PDEC_MC0() {
    // SAFETY: the executor was started on this interrupt in `main`.
    unsafe { STEP_EXECUTOR.on_interrupt() }
}

#[interrupt]
fn PDEC_OTHER() {
    // SAFETY: the executor was started on this interrupt in `main`.
    unsafe { LINK_EXECUTOR.on_interrupt() }
}

static USB_SHARED: LinkShared = LinkShared::new();
static UART_SHARED: LinkShared = LinkShared::new();

/// A pin as a push-pull output at `high`, for [`FastPin`] writes.
fn output(mut pin: DynPin, high: bool) -> FastPin {
    let fast = FastPin::of(&pin);
    fast.set(high);
    pin.into_push_pull_output();
    fast.set(high);
    fast
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let (Some(mut p), Some(mut core)) = (pac::Peripherals::take(), pac::CorePeripherals::take())
    else {
        panic!("peripherals taken twice");
    };
    let mut clocks = clocks::init(
        p.gclk,
        &mut p.mclk,
        &mut p.osc32kctrl,
        &mut p.oscctrl,
        &mut p.nvmctrl,
    );
    time_driver::init(&mut p.mclk, &mut core.NVIC);

    // Generators for the HAL's peripherals: GCLK0 (120 MHz) for the SERCOM
    // and TCC0, GCLK2 (the DFLL's 48 MHz) for USB, GCLK4 (16 MHz) for the
    // EIC and the ADC.
    let gclk0 = clocks.gclk0();
    let (Some(_), Some(_)) = (
        clocks.configure_gclk_divider_and_source(ClockGenId::Gclk2, 1, ClockSource::Dfll, false),
        clocks.configure_gclk_divider_and_source(ClockGenId::Gclk4, 3, ClockSource::Dfll, false),
    ) else {
        panic!("clock generator in use");
    };
    let (Some(gclk2), Some(gclk4)) = (
        clocks.get_gclk(ClockGenId::Gclk2),
        clocks.get_gclk(ClockGenId::Gclk4),
    ) else {
        panic!("clock generator not configured");
    };

    // Board id and name.
    let unique_id = atsamd_hal::serial_number();
    let mut names = NameStore::new(NameBlock(Nvm::new(p.nvmctrl)));
    let name = names.load_or_default(MODULE_TYPE, &unique_id);
    // SAFETY: the name and rate drivers are both used only by the runtime
    // task, one at a time.
    let rates = RateKeeper::open(
        unsafe { rate_store::RateBlock::steal() },
        Default::default(),
    );

    let pins = board::take(Pins::new(p.port));

    // The module's hardware. EN high: disabled until the module enables it.
    static STEPPER: StaticCell<StepperPins> = StaticCell::new();
    let stepper = STEPPER.init(StepperPins {
        enable_n: output(pins.enable_n, true),
    });
    let [mut pwm0, mut pwm1] = pins.pwm;
    pwm0.into_alternate(DynAlternate::G);
    pwm1.into_alternate(DynAlternate::G);
    let Some(_) = clocks.tcc0_tcc1(&gclk0) else {
        panic!("TCC0 clock in use");
    };
    board::start_pwm(&mut p.mclk);
    let Some(_) = clocks.adc0(&gclk4) else {
        panic!("ADC0 clock in use");
    };
    let [(mut a0, ain0), (mut a1, ain1), (mut a2, ain2)] = pins.analog;
    for a in [&mut a0, &mut a1, &mut a2] {
        a.into_alternate(DynAlternate::B);
    }
    board::start_adc(&mut p.mclk);
    static IO: StaticCell<IoPins> = StaticCell::new();
    let mut digital = pins.digital;
    for d in &mut digital {
        // Nothing connected is driven until a script writes it. Inputs
        // through the EIC, which counts their rising edges (edges), with
        // the input buffer on so they read as plain inputs too.
        d.into_pull_down_interrupt();
        FastPin::of(d).enable_input();
    }
    let io = IO.init(IoPins {
        digital,
        analog: [ain0, ain1, ain2],
    });
    MODULE.install(Parts {
        stepper,
        io: Some(io),
        clock: osap_firmware::local_now,
        bootloader: Some(board::reboot_to_uf2),
    });

    // The runtime and its ports.
    static RUNTIME: StaticCell<ModuleRuntime> = StaticCell::new();
    let runtime = RUNTIME.init(module_runtime(MODULE_TYPE, &name, VERSION));
    static PORTS: StaticCell<ModulePorts<Module>> = StaticCell::new();
    let ports = PORTS.init(module_ports(&MODULE));

    // Step generation and the limit switch.
    let step = output(pins.step, false);
    let dir = output(pins.dir, false);
    steps::configure(&mut p.mclk, &mut core.NVIC, step, dir);
    let mut limit = pins.limit;
    limit.into_pull_up_interrupt();
    let Some(_) = clocks.eic(&gclk4) else {
        panic!("EIC clock in use");
    };
    start_eic(
        &mut p.mclk,
        &p.eic,
        pins.limit_channel,
        &board::DIGITAL_CHANNELS,
    );
    edges::start(&mut core.NVIC);
    steps::start_limit(
        &mut core.NVIC,
        steps::Limit {
            channel: pins.limit_channel,
            pin: FastPin::of(&limit),
        },
        board::LIMIT_IRQ,
    );

    // The UART with its RS-485 driver enable.
    let driver_enable = output(pins.driver_enable, false);
    #[cfg(feature = "metro-m4")]
    let (sercom, uart_clock) = (p.sercom3, clocks.sercom3_core(&gclk0));
    #[cfg(feature = "feather-m4")]
    let (sercom, uart_clock) = (p.sercom5, clocks.sercom5_core(&gclk0));
    let Some(uart_clock) = uart_clock else {
        panic!("SERCOM clock in use");
    };
    static UART: StaticCell<BoardUart> = StaticCell::new();
    UART.init(
        uart::Config::new(&p.mclk, sercom, pins.uart, uart_clock.freq())
            .baud(
                Hertz::from_raw(uart_link::BAUD),
                BaudMode::Fractional(Oversampling::Bits16),
            )
            .enable(),
    );
    uart_link::init(&mut core.NVIC);

    // USB.
    let led = output(pins.led, false);
    let Some(usb_clock) = clocks.usb(&gclk2) else {
        panic!("USB clock in use");
    };
    static USB_BUS: StaticCell<UsbBusAllocator<UsbBus>> = StaticCell::new();
    let bus = USB_BUS.init(UsbBusAllocator::new(UsbBus::new(
        &usb_clock,
        &mut p.mclk,
        pins.usb.0,
        pins.usb.1,
        p.usb,
    )));
    static PRODUCT: StaticCell<ProductString> = StaticCell::new();
    static SERIAL: StaticCell<SerialString> = StaticCell::new();
    let strings = usb_link::UsbStrings {
        product: PRODUCT.init(product_string(MODULE_TYPE)),
        serial: SERIAL.init(serial_string(&unique_id)),
    };
    usb_link::init(bus, strings, &USB_SHARED, led, &mut core.NVIC);

    // The executors, highest first.
    // SAFETY: priorities are set before the executors start.
    unsafe {
        core.NVIC
            .set_priority(Interrupt::PDEC_MC0, STEP_EXECUTOR_PRIORITY);
        core.NVIC
            .set_priority(Interrupt::PDEC_OTHER, LINK_EXECUTOR_PRIORITY);
    }
    let step_spawner = STEP_EXECUTOR.start(Interrupt::PDEC_MC0);
    step_spawner.spawn(unwrap(steps::step_task()));

    let link_spawner = LINK_EXECUTOR.start(Interrupt::PDEC_OTHER);
    link_spawner.spawn(unwrap(usb_link::usb_rx_task(&USB_SHARED)));
    link_spawner.spawn(unwrap(usb_link::usb_tx_task(&USB_SHARED)));
    link_spawner.spawn(unwrap(uart_link::uart_rx_task(&UART_SHARED)));
    link_spawner.spawn(unwrap(uart_link::uart_tx_task(driver_enable, &UART_SHARED)));
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

/// Enables the EIC with both-edge sensing on `both` (the limit switch) and
/// rising-edge sensing on `rising` (the digital pins' edge counting), and
/// their interrupts (the EIC's generic clock must be routed already).
fn start_eic(mclk: &mut pac::Mclk, eic: &pac::Eic, both: u8, rising: &[u8]) {
    mclk.apbamask().modify(|_, w| w.eic_().set_bit());
    eic.ctrla().write(|w| w.swrst().set_bit());
    while eic.syncbusy().read().swrst().bit_is_set() {}
    // SENSE is BOTH (3) or RISE (1) in the channel's 4-bit field; CONFIG
    // is writable only while the EIC is disabled.
    let senses = rising.iter().map(|&c| (c, 1u32)).chain([(both, 3u32)]);
    for (channel, sense) in senses.filter(|&(c, _)| c < 16) {
        let shift = 4 * u32::from(channel % 8);
        // SAFETY: only the channel's SENSE field changes.
        eic.config(usize::from(channel / 8))
            .modify(|r, w| unsafe { w.bits(r.bits() & !(0xF << shift) | sense << shift) });
        // SAFETY: write-one-to-clear and -set registers, this channel's bit.
        eic.intflag().write(|w| unsafe { w.bits(1 << channel) });
        eic.intenset().write(|w| unsafe { w.bits(1 << channel) });
    }
    eic.ctrla().modify(|_, w| w.enable().set_bit());
    while eic.syncbusy().read().enable().bit_is_set() {}
}

/// Every task is spawned once, into its own one-task pool, so spawning
/// cannot fail.
pub(crate) fn unwrap<T>(r: Result<T, embassy_executor::SpawnError>) -> T {
    match r {
        Ok(t) => t,
        Err(_) => panic!("task spawned twice"),
    }
}
