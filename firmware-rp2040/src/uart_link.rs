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
//! `Serial::chunk_time` in osap-firmware); the runtime's clock sync is as
//! good as this stamp.

use embassy_rp::gpio::Output;
use embassy_rp::uart::{BufferedUartRx, BufferedUartTx};
use embassy_time::{Instant, Timer};
use embedded_io_async::{Read, ReadReady, Write};

use osap_firmware::link::{Framer, LinkShared};
use osap_firmware::serial::{RxTrigger, Serial, SerialTiming};

/// Line rate, bits per second. 1 Mbaud suits RS-485 runs of a few metres;
/// the RP2040's UART and common transceivers (e.g. THVD1450, MAX3485 at
/// 10 Mbit/s) manage up to 3 Mbaud on short runs. Change it here: the
/// other end must match.
pub(crate) const BAUD: u32 = 1_000_000;

/// The line's timing at [`BAUD`].
const LINE: Serial = Serial {
    baud: BAUD,
    rx: RxTrigger::RP2040,
};

/// Time the transceiver's driver needs after DE rises before the first
/// start bit: 2 µs at 125 MHz (slow parts such as the MAX485 take up to
/// about 2 µs; fast ones tens of ns).
const DRIVER_ENABLE_CYCLES: u32 = 250;

/// Bytes the receive task takes in one go.
const RX_CHUNK: usize = 256;
/// Bytes the transmit task hands the UART in one go.
const TX_CHUNK: usize = 128;

/// The UART link's timing, shared by its gateway and its transmit task.
pub(crate) static UART_TIMING: SerialTiming = SerialTiming::new(LINE);

/// Receives frames from UART0 and hands their packets to the runtime.
#[embassy_executor::task]
pub async fn uart_rx_task(mut rx: BufferedUartRx, shared: &'static LinkShared) {
    let mut framer = Framer::new();
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
        let time = LINE.chunk_time(len, read_us);
        shared.receive_chunk(&mut framer, &buf[..len], time).await;
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
        let mut done_at = osap_core::Instant::ZERO;
        // Keep the driver on while more frames follow.
        while n > 0 {
            done_at = timing.queue(osap_firmware::local_now(), n);
            // BufferedUartTx only fails on a closed UART; nothing to do.
            let _ = tx.write_all(&buf[..n]).await;
            n = shared.try_take_tx(&mut buf);
        }
        // The ring buffer is empty once flush returns; the FIFO and shift
        // register still hold up to 33 bytes. Sleep until they should be
        // out, then wait out the last stop bit exactly.
        let _ = tx.flush().await;
        Timer::at(Instant::from_micros(done_at.as_micros())).await;
        while tx.busy() {}
        driver_enable.set_low();
    }
}
