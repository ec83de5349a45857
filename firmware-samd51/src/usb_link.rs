//! The USB link: a CDC-ACM device (a virtual serial port on the host)
//! carrying frames (WIRE.md §5), with osap-rs's USB ids and strings so a
//! host finds the module by them.
//!
//! atsamd-hal's `UsbBus` implements usb-device, which is polled: all four
//! USB interrupts run [`poll`], which services the device, stamps and
//! stores received packets, and sends a staged one. Two tasks on the link
//! executor bridge that to the runtime's [`LinkShared`]: one feeds stored
//! packets through the framer, the other stages frame bytes to send.
//!
//! The link is open while the device is configured and the host holds DTR
//! (has the port open). A received packet is stamped with the time the
//! interrupt that read it began: a full-speed bulk OUT transfer completes
//! within the 1 ms frame the host scheduled it in, and its transfer-complete
//! interrupt is as near to the wire as the device side can see. While the
//! packet store is full, packets are left in the endpoint (the host is
//! NAKed: flow control), and stamped when read.

use core::cell::RefCell;
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use atsamd_hal::pac::{interrupt, Interrupt, NVIC};
use atsamd_hal::usb::UsbBus;
use critical_section::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::Instant;
use osap_core::usb::{MANUFACTURER, PRODUCT_ID_SAMD51, VENDOR_ID};
use osap_firmware::link::{ChunkTime, Framer, LinkShared};
use osap_firmware::usb::PACKET;
use usb_device::bus::UsbBusAllocator;
use usb_device::device::{
    StringDescriptors, UsbDevice, UsbDeviceBuilder, UsbDeviceState, UsbVidPid,
};
use usb_device::UsbError;
use usbd_serial::CdcAcmClass;

use crate::board::FastPin;

/// NVIC priority of the USB interrupts.
pub(crate) const PRIORITY: u8 = 0x40;
/// Received packets stored for the receive task.
const RX_SLOTS: usize = 4;
/// The USB interrupt lines; each runs [`poll`].
const IRQS: [Interrupt; 4] = [
    Interrupt::USB_OTHER,
    Interrupt::USB_SOF_HSOF,
    Interrupt::USB_TRCPT0,
    Interrupt::USB_TRCPT1,
];

/// The device, its class, and the packet staged to send.
struct Device {
    device: UsbDevice<'static, UsbBus>,
    class: CdcAcmClass<'static, UsbBus>,
    /// Bytes staged to send (`Some(0)`: a zero-length packet).
    tx: Option<usize>,
    tx_buf: [u8; PACKET],
    open: bool,
}

/// Received packets with their stamps, oldest first.
struct RxSlots {
    data: [[u8; PACKET]; RX_SLOTS],
    len: [usize; RX_SLOTS],
    stamp: [u64; RX_SLOTS],
    head: usize,
    count: usize,
}

static DEVICE: Mutex<RefCell<Option<Device>>> = Mutex::new(RefCell::new(None));
static RX: Mutex<RefCell<RxSlots>> = Mutex::new(RefCell::new(RxSlots {
    data: [[0; PACKET]; RX_SLOTS],
    len: [0; RX_SLOTS],
    stamp: [0; RX_SLOTS],
    head: 0,
    count: 0,
}));
static RX_READY: Signal<CriticalSectionRawMutex, ()> = Signal::new();
static TX_FREE: Signal<CriticalSectionRawMutex, ()> = Signal::new();
/// Set when the link opens: the receive task starts on a clean frame.
static NEW_PEER: AtomicBool = AtomicBool::new(false);
/// The LED (packed [`FastPin`]), on while the link is open.
static LED: AtomicU32 = AtomicU32::new(FastPin::NONE);
/// The link's shared state, set once by [`init`].
static SHARED: Mutex<RefCell<Option<&'static LinkShared>>> = Mutex::new(RefCell::new(None));

/// The strings the device reports.
pub(crate) struct UsbStrings {
    /// "osap-rs " and the module type.
    pub product: &'static str,
    /// The chip's 128-bit serial number in hex.
    pub serial: &'static str,
}

/// Builds the device on `bus` and starts its interrupts.
pub(crate) fn init(
    bus: &'static UsbBusAllocator<UsbBus>,
    strings: UsbStrings,
    shared: &'static LinkShared,
    led: FastPin,
    nvic: &mut NVIC,
) {
    let class = CdcAcmClass::new(bus, PACKET as u16);
    let descriptors = StringDescriptors::default()
        .manufacturer(MANUFACTURER)
        .product(strings.product)
        .serial_number(strings.serial);
    let builder = UsbDeviceBuilder::new(bus, UsbVidPid(VENDOR_ID, PRODUCT_ID_SAMD51))
        .device_class(usbd_serial::USB_CLASS_CDC);
    // Both only fail on out-of-range values (more than 16 languages, a
    // packet size other than 8/16/32/64): fixed here.
    let Ok(builder) = builder.strings(&[descriptors]) else {
        panic!("USB strings rejected");
    };
    let Ok(builder) = builder.max_packet_size_0(64) else {
        panic!("USB control packet size rejected");
    };
    let Ok(builder) = builder.max_power(100) else {
        panic!("USB power rejected");
    };
    let device = builder.build();
    LED.store(led.pack(), Ordering::Relaxed);
    critical_section::with(|cs| {
        *SHARED.borrow_ref_mut(cs) = Some(shared);
        *DEVICE.borrow_ref_mut(cs) = Some(Device {
            device,
            class,
            tx: None,
            tx_buf: [0; PACKET],
            open: false,
        });
    });
    for irq in IRQS {
        // SAFETY: the handlers below are ready and the device is stored.
        unsafe {
            nvic.set_priority(irq, PRIORITY);
            NVIC::unmask(irq);
        }
    }
}

/// Services the device: enumeration and control requests, the link's
/// open state, received packets, the staged packet to send.
fn poll() {
    let now = Instant::now().as_micros();
    critical_section::with(|cs| {
        let mut device = DEVICE.borrow_ref_mut(cs);
        let Some(d) = device.as_mut() else {
            return;
        };
        let Some(shared) = *SHARED.borrow_ref(cs) else {
            return;
        };
        d.device.poll(&mut [&mut d.class]);

        let open = d.device.state() == UsbDeviceState::Configured && d.class.dtr();
        if open != d.open {
            d.open = open;
            // A new peer starts with a clean frame and nothing stale.
            let mut rx = RX.borrow_ref_mut(cs);
            rx.count = 0;
            d.tx = None;
            NEW_PEER.store(true, Ordering::Release);
            shared.set_open(open);
            FastPin::unpack(LED.load(Ordering::Relaxed)).set(open);
            TX_FREE.signal(());
        }

        let mut rx = RX.borrow_ref_mut(cs);
        while rx.count < RX_SLOTS {
            let slot = (rx.head + rx.count) % RX_SLOTS;
            match d.class.read_packet(&mut rx.data[slot]) {
                Ok(n) => {
                    rx.len[slot] = n;
                    rx.stamp[slot] = now;
                    rx.count += 1;
                    RX_READY.signal(());
                }
                Err(_) => break,
            }
        }

        if let Some(n) = d.tx {
            match d.class.write_packet(&d.tx_buf[..n]) {
                Ok(_) => {
                    d.tx = None;
                    TX_FREE.signal(());
                }
                // The previous packet is still in the endpoint; its
                // transfer-complete interrupt polls again.
                Err(UsbError::WouldBlock) => {}
                // Not configured: drop it.
                Err(_) => {
                    d.tx = None;
                    TX_FREE.signal(());
                }
            }
        }
    });
}

/// Hands the oldest stored packet to the runtime through `framer`.
async fn deliver_one(shared: &'static LinkShared, framer: &mut Framer) -> bool {
    let mut buf = [0u8; PACKET];
    let packet = critical_section::with(|cs| {
        let rx = RX.borrow_ref(cs);
        (rx.count > 0).then(|| {
            let n = rx.len[rx.head];
            buf[..n].copy_from_slice(&rx.data[rx.head][..n]);
            (n, rx.stamp[rx.head])
        })
    });
    let Some((n, stamp)) = packet else {
        return false;
    };
    if NEW_PEER.swap(false, Ordering::AcqRel) {
        framer.reset();
    }
    shared
        .receive_chunk(framer, &buf[..n], ChunkTime::Completed(stamp))
        .await;
    critical_section::with(|cs| {
        let mut rx = RX.borrow_ref_mut(cs);
        // A reset while delivering emptied the store: nothing to pop.
        if rx.count > 0 {
            rx.head = (rx.head + 1) % RX_SLOTS;
            rx.count -= 1;
        }
    });
    // Room again: read what the host may have been NAKed for.
    NVIC::pend(Interrupt::USB_OTHER);
    true
}

/// Feeds received packets to the runtime.
#[embassy_executor::task]
pub async fn usb_rx_task(shared: &'static LinkShared) {
    let mut framer = Framer::new();
    loop {
        RX_READY.wait().await;
        while deliver_one(shared, &mut framer).await {}
    }
}

/// Stages `data` (at most a packet) for the interrupt to send, once the
/// previous packet has gone.
async fn stage(data: &[u8]) {
    loop {
        let staged = critical_section::with(|cs| {
            let mut device = DEVICE.borrow_ref_mut(cs);
            let Some(d) = device.as_mut() else {
                return false;
            };
            if d.tx.is_some() {
                return false;
            }
            d.tx_buf[..data.len()].copy_from_slice(data);
            d.tx = Some(data.len());
            true
        });
        if staged {
            NVIC::pend(Interrupt::USB_OTHER);
            return;
        }
        TX_FREE.wait().await;
    }
}

/// Sends queued frames to the host in bulk packets.
#[embassy_executor::task]
pub async fn usb_tx_task(shared: &'static LinkShared) {
    let mut buf = [0u8; PACKET];
    loop {
        let n = shared.take_tx(&mut buf).await;
        stage(&buf[..n]).await;
        // A full packet does not end a transfer: without a short packet
        // after it the host's read can sit on it until more data comes.
        // Send a zero-length one if nothing follows.
        if n == PACKET && shared.tx_queued() == 0 {
            stage(&[]).await;
        }
    }
}

#[interrupt]
fn USB_OTHER() {
    poll();
}

#[interrupt]
fn USB_SOF_HSOF() {
    poll();
}

#[interrupt]
fn USB_TRCPT0() {
    poll();
}

#[interrupt]
fn USB_TRCPT1() {
    poll();
}
