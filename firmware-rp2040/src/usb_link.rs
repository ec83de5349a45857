//! The USB link: a CDC-ACM device (a virtual serial port on the host)
//! carrying frames (WIRE.md §5), with osap-rs's USB ids and strings so a
//! host finds the module by them.
//!
//! The link is open while the host holds the port open (DTR set). Received
//! packets are stamped with the completion time of the USB packet their
//! frame started in: a full-speed bulk OUT transfer completes within the
//! 1 ms frame the host scheduled it in, and that is as near to the wire as
//! the device side can see.

use embassy_executor::Spawner;
use embassy_futures::select::{select, Either};
use embassy_rp::peripherals::USB;
use embassy_rp::usb::Driver;
use embassy_rp::Peri;
use embassy_time::Instant;
use embassy_usb::class::cdc_acm::{CdcAcmClass, ControlChanged, Receiver, Sender, State};
use embassy_usb::driver::EndpointError;
use embassy_usb::{Builder, UsbDevice};
use osap_core::usb::{MANUFACTURER, PRODUCT_ID_RP2040, VENDOR_ID};
use osap_firmware::link::{ChunkTime, Framer, LinkShared};
use osap_firmware::usb::{product_string, serial_string, ProductString, SerialString, PACKET};
use static_cell::StaticCell;

use crate::{unwrap, Irqs};

/// The strings the device reports.
pub(crate) struct UsbStrings {
    /// "osap-rs " and the module type.
    pub product: &'static str,
    /// The board's unique flash id in hex.
    pub serial: &'static str,
}

impl UsbStrings {
    /// The strings of a module of type `module_type` on the board with
    /// flash id `unique_id`.
    pub(crate) fn new(module_type: &str, unique_id: &[u8; 8]) -> Self {
        static PRODUCT: StaticCell<ProductString> = StaticCell::new();
        static SERIAL: StaticCell<SerialString> = StaticCell::new();
        UsbStrings {
            product: PRODUCT.init(product_string(module_type)),
            serial: SERIAL.init(serial_string(unique_id)),
        }
    }
}

/// Sets up the USB device and starts its tasks on the current executor.
///
/// embassy-usb's device and class handles are not `Send`, so they cannot be
/// handed to a task on an interrupt executor from outside it; this task is
/// spawned there instead and builds them in place.
#[embassy_executor::task]
pub async fn usb_start_task(
    usb: Peri<'static, USB>,
    strings: UsbStrings,
    shared: &'static LinkShared,
) {
    // SAFETY: awaited inside a task of the embassy link executor, whose
    // context is the executor's own (what the function requires).
    let spawner = unsafe { Spawner::for_current_executor() }.await;

    let mut config = embassy_usb::Config::new(VENDOR_ID, PRODUCT_ID_RP2040);
    config.manufacturer = Some(MANUFACTURER);
    config.product = Some(strings.product);
    config.serial_number = Some(strings.serial);
    config.max_power = 100;
    config.max_packet_size_0 = 64;

    static CONFIG_DESC: StaticCell<[u8; 256]> = StaticCell::new();
    static BOS_DESC: StaticCell<[u8; 64]> = StaticCell::new();
    static CONTROL_BUF: StaticCell<[u8; 64]> = StaticCell::new();
    static CDC_STATE: StaticCell<State> = StaticCell::new();
    let mut builder = Builder::new(
        Driver::new(usb, Irqs),
        config,
        CONFIG_DESC.init([0; 256]),
        BOS_DESC.init([0; 64]),
        &mut [],
        CONTROL_BUF.init([0; 64]),
    );
    let class = CdcAcmClass::new(&mut builder, CDC_STATE.init(State::new()), PACKET as u16);
    let device = builder.build();
    let (sender, receiver, control) = class.split_with_control();

    spawner.spawn(unwrap(usb_device_task(device)));
    spawner.spawn(unwrap(usb_rx_task(receiver, control, shared)));
    spawner.spawn(unwrap(usb_tx_task(sender, shared)));
}

/// Runs the USB device: enumeration, control requests, suspend.
#[embassy_executor::task]
async fn usb_device_task(mut device: UsbDevice<'static, Driver<'static, USB>>) {
    device.run().await;
}

/// Receives frames from the host and hands their packets to the runtime;
/// keeps the link open while the device is configured and the host holds
/// DTR (has the port open).
#[embassy_executor::task]
async fn usb_rx_task(
    mut rx: Receiver<'static, Driver<'static, USB>>,
    control: ControlChanged<'static>,
    shared: &'static LinkShared,
) {
    let mut framer = Framer::new();
    let mut buf = [0u8; PACKET];
    loop {
        rx.wait_connection().await;
        framer.reset();
        shared.set_open(control.dtr());
        loop {
            match select(rx.read_packet(&mut buf), control.control_changed()).await {
                Either::First(Ok(n)) => {
                    let time = ChunkTime::Completed(Instant::now().as_micros());
                    shared.receive_chunk(&mut framer, &buf[..n], time).await;
                }
                // Unplugged, reset or deconfigured.
                Either::First(Err(EndpointError::Disabled)) => break,
                // Cannot happen: the buffer holds a full packet.
                Either::First(Err(EndpointError::BufferOverflow)) => {}
                // Line coding or DTR changed; only DTR matters here.
                Either::Second(()) => {
                    let dtr = control.dtr();
                    if dtr != shared.is_open() {
                        // A new peer starts with a clean frame.
                        framer.reset();
                        shared.set_open(dtr);
                    }
                }
            }
        }
        shared.set_open(false);
    }
}

/// Sends queued frames to the host in bulk packets.
#[embassy_executor::task]
async fn usb_tx_task(mut tx: Sender<'static, Driver<'static, USB>>, shared: &'static LinkShared) {
    let mut buf = [0u8; PACKET];
    loop {
        tx.wait_connection().await;
        loop {
            let n = shared.take_tx(&mut buf).await;
            if tx.write_packet(&buf[..n]).await.is_err() {
                break;
            }
            // A full packet does not end a transfer: without a short
            // packet after it the host's read can sit on it until more
            // data comes. Send a zero-length one if nothing follows.
            if n == PACKET && shared.tx_queued() == 0 && tx.write_packet(&[]).await.is_err() {
                break;
            }
        }
    }
}
