//! The UART / RS-485 link: a SERCOM in USART mode (the board's labelled
//! RX/TX pins, see [`crate::board`]), with the transceiver's driver enable
//! on a GPIO.
//!
//! The SERCOM's interrupt moves bytes: each received byte is stamped as it
//! lands (the SAMD51's USART interrupts per byte, so the stamp is the end
//! of its stop bit, `RxTrigger::PER_BYTE`) and stored; bytes to send are
//! handed to DATA as it empties. Two tasks on the link executor bridge that
//! to the runtime's [`LinkShared`].
//!
//! Frames (WIRE.md §5) go out back-to-back in bursts; the driver is enabled
//! before a burst's first byte and released only after the last stop bit
//! has left the shift register (the USART's TXC flag), so the bus is free
//! for the next module's reply at once and no byte is cut short.

use core::cell::RefCell;

use atsamd_hal::pac::{self, NVIC};
use critical_section::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::Instant;
use osap_firmware::link::{Framer, LinkShared};
use osap_firmware::serial::{RxTrigger, Serial, SerialTiming};

use crate::board::{FastPin, UartSercom, UART_IRQS};

/// Line rate, bits per second. 1 Mbaud suits RS-485 runs of a few metres;
/// the SERCOM (120 MHz core clock, 16× oversampling) and common
/// transceivers (e.g. THVD1450, MAX3485 at 10 Mbit/s) manage up to
/// 3 Mbaud on short runs. Change it here: the other end must match.
pub(crate) const BAUD: u32 = 1_000_000;

/// The line's timing at [`BAUD`].
const LINE: Serial = Serial {
    baud: BAUD,
    rx: RxTrigger::PER_BYTE,
};

/// Time the transceiver's driver needs after DE rises before the first
/// start bit: 2 µs at 120 MHz.
const DRIVER_ENABLE_CYCLES: u32 = 240;
/// NVIC priority of the SERCOM interrupts.
pub(crate) const PRIORITY: u8 = 0x40;
/// Bytes stored between the interrupt and the receive task: 2.5 ms at
/// 1 Mbaud.
const RX_BYTES: usize = 256;
/// Bytes the transmit task hands the interrupt in one go.
const TX_CHUNK: usize = 128;

/// Received bytes and the stamp of the latest.
struct RxRing {
    buf: [u8; RX_BYTES],
    head: usize,
    len: usize,
    /// When the latest byte's stop bit ended, local µs.
    last_us: u64,
    /// A framing, parity or overrun error (or a full ring) since the last
    /// take: the frame in progress is damaged.
    error: bool,
}

/// Bytes being sent.
struct TxBuf {
    buf: [u8; TX_CHUNK],
    pos: usize,
    len: usize,
}

static RX: Mutex<RefCell<RxRing>> = Mutex::new(RefCell::new(RxRing {
    buf: [0; RX_BYTES],
    head: 0,
    len: 0,
    last_us: 0,
    error: false,
}));
static TX: Mutex<RefCell<TxBuf>> = Mutex::new(RefCell::new(TxBuf {
    buf: [0; TX_CHUNK],
    pos: 0,
    len: 0,
}));
static RX_READY: Signal<CriticalSectionRawMutex, ()> = Signal::new();
static TX_DRAINED: Signal<CriticalSectionRawMutex, ()> = Signal::new();
static TX_DONE: Signal<CriticalSectionRawMutex, ()> = Signal::new();

/// The USART's registers.
fn usart() -> &'static pac::sercom0::UsartInt {
    // SAFETY: the SERCOM belongs to this link after `init`; static MMIO.
    unsafe { (*UartSercom::ptr()).usart_int() }
}

/// The UART link's timing, shared by its gateway and its transmit task.
pub(crate) static UART_TIMING: SerialTiming = SerialTiming::new(LINE);

/// Enables the receive and error interrupts of the (HAL-configured and
/// enabled) USART and unmasks its four interrupt lines.
pub(crate) fn init(nvic: &mut NVIC) {
    let u = usart();
    u.intenset().write(|w| w.rxc().set_bit().error().set_bit());
    for irq in UART_IRQS {
        // SAFETY: the handlers (in `board`) call `on_interrupt`, ready now.
        unsafe {
            nvic.set_priority(irq, PRIORITY);
            NVIC::unmask(irq);
        }
    }
}

/// The SERCOM's interrupt, from all four of its lines.
pub(crate) fn on_interrupt() {
    let u = usart();
    let flags = u.intflag().read();
    let enabled = u.intenset().read();
    if flags.rxc().bit_is_set() {
        let now = Instant::now().as_micros();
        let status = u.status().read();
        let bad = status.ferr().bit_is_set()
            || status.perr().bit_is_set()
            || status.bufovf().bit_is_set();
        // Reading DATA clears RXC.
        let byte = u.data().read().data().bits() as u8;
        if bad {
            u.status()
                .write(|w| w.ferr().set_bit().perr().set_bit().bufovf().set_bit());
        }
        critical_section::with(|cs| {
            let mut rx = RX.borrow_ref_mut(cs);
            if bad || rx.len == RX_BYTES {
                rx.error = true;
            }
            if !bad && rx.len < RX_BYTES {
                let at = (rx.head + rx.len) % RX_BYTES;
                rx.buf[at] = byte;
                rx.len += 1;
                rx.last_us = now;
            }
        });
        RX_READY.signal(());
    }
    if flags.error().bit_is_set() {
        u.intflag().write(|w| w.error().set_bit());
        u.status()
            .write(|w| w.ferr().set_bit().perr().set_bit().bufovf().set_bit());
        critical_section::with(|cs| RX.borrow_ref_mut(cs).error = true);
        RX_READY.signal(());
    }
    if flags.dre().bit_is_set() && enabled.dre().bit_is_set() {
        critical_section::with(|cs| {
            let mut tx = TX.borrow_ref_mut(cs);
            if tx.pos < tx.len {
                // TXC then only comes after this byte (and any after it).
                u.intflag().write(|w| w.txc().set_bit());
                // SAFETY: any byte is valid data.
                u.data()
                    .write(|w| unsafe { w.data().bits(u32::from(tx.buf[tx.pos])) });
                tx.pos += 1;
            } else {
                u.intenclr().write(|w| w.dre().set_bit());
                TX_DRAINED.signal(());
            }
        });
    }
    if flags.txc().bit_is_set() && enabled.txc().bit_is_set() {
        u.intenclr().write(|w| w.txc().set_bit());
        TX_DONE.signal(());
    }
}

/// Receives frames and hands their packets to the runtime.
#[embassy_executor::task]
pub async fn uart_rx_task(shared: &'static LinkShared) {
    let mut framer = Framer::new();
    let mut buf = [0u8; RX_BYTES];
    loop {
        RX_READY.wait().await;
        loop {
            let (len, last_us, error) = critical_section::with(|cs| {
                let mut rx = RX.borrow_ref_mut(cs);
                let len = rx.len;
                for (i, b) in buf[..len].iter_mut().enumerate() {
                    *b = rx.buf[(rx.head + i) % RX_BYTES];
                }
                rx.head = (rx.head + len) % RX_BYTES;
                rx.len = 0;
                let error = core::mem::take(&mut rx.error);
                (len, rx.last_us, error)
            });
            if error {
                // The frame in progress is damaged; resynchronise at the
                // next delimiter.
                framer.reset();
            }
            if len == 0 {
                break;
            }
            let time = LINE.chunk_time(len, last_us);
            shared.receive_chunk(&mut framer, &buf[..len], time).await;
        }
    }
}

/// Sends queued frames, driving the RS-485 driver enable around each burst.
#[embassy_executor::task]
pub async fn uart_tx_task(driver_enable: FastPin, shared: &'static LinkShared) {
    let u = usart();
    let mut buf = [0u8; TX_CHUNK];
    loop {
        let mut n = shared.take_tx(&mut buf).await;
        driver_enable.set(true);
        cortex_m::asm::delay(DRIVER_ENABLE_CYCLES);
        // Keep the driver on while more frames follow.
        while n > 0 {
            UART_TIMING.queue(osap_firmware::local_now(), n);
            TX_DRAINED.reset();
            critical_section::with(|cs| {
                let mut tx = TX.borrow_ref_mut(cs);
                tx.buf[..n].copy_from_slice(&buf[..n]);
                tx.pos = 0;
                tx.len = n;
            });
            u.intenset().write(|w| w.dre().set_bit());
            TX_DRAINED.wait().await;
            n = shared.try_take_tx(&mut buf);
        }
        // DATA is empty; the shift register may still hold a byte. TXC
        // comes when its stop bit is out (or is already set).
        TX_DONE.reset();
        u.intenset().write(|w| w.txc().set_bit());
        TX_DONE.wait().await;
        driver_enable.set(false);
    }
}
