//! Size probe: the smallest useful osap-core module firmware.
//!
//! One runtime (`Runtime<8, 128, 4, 2>`: 8 slots of 128 bytes), one UART-like
//! link gateway that frames packets with COBS + CRC-16, and the netresponder
//! on port 0; no user ports. `scripts/size-report.sh` builds it for
//! thumbv6m-none-eabi and thumbv7em-none-eabihf and reports its flash
//! footprint (goal: under 16 KiB of `.text` on thumbv6m).
//!
//! The probe is measured, never run. Its "peripherals" are plain addresses in
//! the Cortex-M peripheral region, read and written with volatile accesses,
//! so that nothing the runtime does can be proven dead and optimised away:
//! received bytes come from a data register, sent frames go to it, and `now`
//! comes from a free-running microsecond counter.

#![no_std]
#![no_main]

use core::ptr::{read_volatile, write_volatile};
use cortex_m_rt::entry;
use osap_core::framing::{encode_frame, max_frame_len, FrameDecoder};
use osap_core::link::{LinkGateway, LinkInfo, LinkSendError, Received};
use osap_core::netresponder::BuildKey;
use osap_core::port::{Delivery, Port, PortInfo, PortTx};
use osap_core::{Instant, Runtime};
use panic_halt as _;

/// Packet slot size and link MTU.
const MTU: usize = 128;
/// Largest frame of an MTU-sized packet, delimiter included.
const FRAME: usize = max_frame_len(MTU);

/// A made-up UART and timer. The addresses only need to be opaque to the
/// compiler; no real part is implied.
mod reg {
    /// Data register: reading pops a received byte, writing sends one.
    pub const UART_DATA: *mut u32 = 0x4000_0000 as *mut u32;
    /// Status register, see `RX_READY` and `TX_FULL`.
    pub const UART_STATUS: *const u32 = 0x4000_0004 as *const u32;
    /// Free-running microsecond counter.
    pub const TIMER_US: *const u32 = 0x4000_1000 as *const u32;

    /// A received byte is waiting in `UART_DATA`.
    pub const RX_READY: u32 = 1 << 0;
    /// The transmit FIFO is full.
    pub const TX_FULL: u32 = 1 << 1;
}

fn uart_status() -> u32 {
    // SAFETY: a device register address; reading it has no side effects the
    // program relies on (and the probe is never run).
    unsafe { read_volatile(reg::UART_STATUS) }
}

/// A byte-stream link: COBS + CRC-16 frames over the fake UART.
struct UartLink {
    decoder: FrameDecoder<FRAME>,
    tx: [u8; FRAME],
}

impl UartLink {
    const fn new() -> Self {
        UartLink {
            decoder: FrameDecoder::new(),
            tx: [0; FRAME],
        }
    }
}

impl LinkGateway for UartLink {
    fn info(&self) -> LinkInfo<'_> {
        LinkInfo {
            type_name: "uart",
            name: "",
        }
    }

    fn is_open(&self) -> bool {
        true
    }

    fn mtu(&self) -> u16 {
        MTU as u16
    }

    fn clear_to_send(&self) -> bool {
        uart_status() & reg::TX_FULL == 0
    }

    fn send(&mut self, packet: &[u8]) -> Result<(), LinkSendError> {
        let n = encode_frame(packet, &mut self.tx).map_err(|_| LinkSendError)?;
        for &byte in &self.tx[..n] {
            while uart_status() & reg::TX_FULL != 0 {}
            // SAFETY: a device register address (see `reg`).
            unsafe { write_volatile(reg::UART_DATA, u32::from(byte)) };
        }
        Ok(())
    }

    fn receive(&mut self, buf: &mut [u8]) -> Option<Received> {
        while uart_status() & reg::RX_READY != 0 {
            // SAFETY: a device register address (see `reg`).
            let byte = unsafe { read_volatile(reg::UART_DATA) } as u8;
            let mut input: &[u8] = &[byte];
            // Bad frames are counted by the decoder and skipped.
            if let Some(Ok(packet)) = self.decoder.decode(&mut input) {
                let len = packet.len();
                if let Some(dst) = buf.get_mut(..len) {
                    dst.copy_from_slice(packet);
                }
                return Some(Received {
                    len,
                    timestamp: None,
                });
            }
        }
        None
    }
}

/// The probe has no ports of its own: the netresponder is built in.
struct NoPort;

impl Port for NoPort {
    fn info(&self, _offset: u16) -> PortInfo<'_> {
        PortInfo {
            type_name: "",
            name: "",
        }
    }

    fn on_packet(&mut self, _delivery: Delivery<'_>, _tx: &mut PortTx<'_>) {}
}

/// Extends the 32-bit hardware counter to 64-bit microseconds.
struct Clock {
    last: u32,
    high: u64,
}

impl Clock {
    fn now(&mut self) -> Instant {
        // SAFETY: a device register address (see `reg`).
        let t = unsafe { read_volatile(reg::TIMER_US) };
        if t < self.last {
            self.high += 1 << 32;
        }
        self.last = t;
        Instant::from_micros(self.high | u64::from(t))
    }
}

#[entry]
fn main() -> ! {
    let Ok(rt) = Runtime::<8, MTU, 4, 2>::new("size_probe", "probe") else {
        #[allow(clippy::empty_loop)]
        loop {}
    };
    let mut rt = rt.with_version([0, 1, 0], BuildKey::RustEmbedded);
    let mut links = [UartLink::new()];
    let mut ports: [NoPort; 0] = [];
    let mut clock = Clock { last: 0, high: 0 };
    loop {
        let now = clock.now();
        rt.poll(now, &mut ports, &mut links);
    }
}
