//! The UART / RS-485 link: UART0 on GP0 (TX) and GP1 (RX) as a
//! `BufferedUart`, with the transceiver's driver enable on GP6.
//!
//! Frames (WIRE.md §5) go out back-to-back in bursts; the driver is enabled
//! before a burst's first byte and released only after the last stop bit
//! has left the shift register (the UART's BUSY flag), so the bus is free
//! for the next module's reply at once and no byte is cut short.
//!
//! A received packet is stamped with the start of its first byte on the
//! wire, counted back from when its bytes reached the receive task (see
//! [`RxTimer`]); the runtime's clock sync is as good as this stamp.

use core::cell::Cell;

use critical_section::Mutex;
use embassy_rp::gpio::Output;
use embassy_rp::uart::{BufferedUartRx, BufferedUartTx};
use embassy_time::{Instant, Timer};
use embedded_io_async::{Read, ReadReady, Write};
use osap_core::framing::max_frame_len;
use osap_core::Micros;

use crate::link::{ChunkTime, LinkShared, Next, RxFramer, WireTiming};

/// Line rate, bits per second. 1 Mbaud suits RS-485 runs of a few metres;
/// the RP2040's UART and common transceivers (e.g. THVD1450, MAX3485 at
/// 10 Mbit/s) manage up to 3 Mbaud on short runs. Change it here: the
/// other end must match.
pub const BAUD: u32 = 1_000_000;

/// Bits on the wire per byte: start, 8 data, stop (8N1).
const BITS_PER_BYTE: u64 = 10;

/// The UART's receive interrupt fires when its FIFO holds 28 bytes (7/8,
/// as embassy-rp sets it) or after 32 idle bit times with bytes waiting.
const RX_FIFO_LEVEL: usize = 28;
/// Idle bit times before the receive timeout interrupt.
const RX_TIMEOUT_BITS: u64 = 32;

/// Time the transceiver's driver needs after DE rises before the first
/// start bit: 2 µs at 125 MHz (slow parts such as the MAX485 take up to
/// about 2 µs; fast ones tens of ns).
const DRIVER_ENABLE_CYCLES: u32 = 250;

/// Bytes the receive task takes in one go.
const RX_CHUNK: usize = 256;
/// Bytes the transmit task hands the UART in one go.
const TX_CHUNK: usize = 128;

/// Wire timing of the UART link at [`BAUD`].
pub struct UartTiming {
    /// When the transmitter will have sent everything handed to it so far
    /// (local µs), kept by the transmit task.
    wire_free_at: Mutex<Cell<Micros>>,
}

/// The UART link's timing, shared by its gateway and its transmit task.
pub static UART_TIMING: UartTiming = UartTiming {
    wire_free_at: Mutex::new(Cell::new(0)),
};

/// Wire time of one byte, ns.
const fn byte_ns() -> u64 {
    BITS_PER_BYTE * 1_000_000_000 / BAUD as u64
}

/// Wire time of `bytes` bytes, µs, rounded up.
const fn bytes_us(bytes: u64) -> Micros {
    (bytes * byte_ns()).div_ceil(1000)
}

impl UartTiming {
    fn wire_free_at(&self) -> Micros {
        critical_section::with(|cs| self.wire_free_at.borrow(cs).get())
    }

    /// Notes `bytes` handed to the transmitter at `now`; returns when they
    /// will all be out.
    fn queue(&self, now: Micros, bytes: usize) -> Micros {
        critical_section::with(|cs| {
            let cell = self.wire_free_at.borrow(cs);
            let end = cell.get().max(now) + bytes_us(bytes as u64);
            cell.set(end);
            end
        })
    }
}

impl WireTiming for UartTiming {
    fn transmit_time(&self, len: usize) -> Micros {
        bytes_us(max_frame_len(len) as u64)
    }

    fn queue_delay(&self, queued: usize) -> Micros {
        let now = Instant::now().as_micros();
        self.wire_free_at().saturating_sub(now) + bytes_us(queued as u64)
    }
}

/// Where the bytes of a chunk were on the wire.
struct RxTimer;

impl RxTimer {
    /// A chunk of `len` bytes read at local time `read_us`. A chunk shorter
    /// than the FIFO trigger level came with the receive timeout, 32 idle
    /// bit times after its last byte; a longer one came with the level
    /// trigger, right as its last byte landed. (Interrupt and task latency,
    /// a few µs on the link executor, is not taken off.)
    fn chunk(len: usize, read_us: Micros) -> ChunkTime {
        let byte_ns = byte_ns();
        let mut last_end_ns = read_us * 1000;
        if len < RX_FIFO_LEVEL {
            last_end_ns = last_end_ns.saturating_sub(RX_TIMEOUT_BITS * byte_ns / BITS_PER_BYTE);
        }
        ChunkTime::Streamed {
            last_end_ns,
            byte_ns,
        }
    }
}

/// Receives frames from UART0 and hands their packets to the runtime.
#[embassy_executor::task]
pub async fn uart_rx_task(mut rx: BufferedUartRx, shared: &'static LinkShared) {
    let mut framer = RxFramer::new();
    let mut buf = [0u8; RX_CHUNK];
    loop {
        let mut len = match rx.read(&mut buf).await {
            Ok(n) => n,
            Err(_) => {
                // Overrun, framing or parity error: the frame in progress
                // is damaged; resynchronise at the next delimiter.
                framer.reset();
                continue;
            }
        };
        let mut read_us = Instant::now().as_micros();
        // Take what else is already waiting (the ring buffer hands out
        // contiguous pieces), so the chunk's timing covers all of it.
        while len < buf.len() && rx.read_ready().unwrap_or(false) {
            match rx.read(&mut buf[len..]).await {
                Ok(n) => len += n,
                Err(_) => break,
            }
            read_us = Instant::now().as_micros();
        }
        let time = RxTimer::chunk(len, read_us);
        let mut rest = &buf[..len];
        loop {
            match framer.next(&mut rest, time, shared) {
                Next::Packet(packet, stamp) => shared.deliver(packet, stamp).await,
                Next::Skipped => {}
                Next::End => break,
            }
        }
    }
}

/// Sends queued frames on UART0, driving the RS-485 driver enable around
/// each burst.
#[embassy_executor::task]
pub async fn uart_tx_task(
    mut tx: BufferedUartTx,
    mut driver_enable: Output<'static>,
    shared: &'static LinkShared,
) {
    let timing = &UART_TIMING;
    let mut buf = [0u8; TX_CHUNK];
    loop {
        let mut n = shared.take_tx(&mut buf).await;
        driver_enable.set_high();
        cortex_m::asm::delay(DRIVER_ENABLE_CYCLES);
        let mut done_at = 0;
        // Keep the driver on while more frames follow.
        while n > 0 {
            done_at = timing.queue(Instant::now().as_micros(), n);
            // BufferedUartTx only fails on a closed UART; nothing to do.
            let _ = tx.write_all(&buf[..n]).await;
            n = shared.try_take_tx(&mut buf);
        }
        // The ring buffer is empty once flush returns; the FIFO and shift
        // register still hold up to 33 bytes. Sleep until they should be
        // out, then wait out the last stop bit exactly.
        let _ = tx.flush().await;
        Timer::at(Instant::from_micros(done_at)).await;
        while tx.busy() {}
        driver_enable.set_low();
    }
}
