//! What every board's USB CDC-ACM link shares: the packet size, the wire
//! timing the runtime plans with, and the device strings a host finds a
//! module by (`osap scan` looks for [`osap_core::usb::VENDOR_ID`], a product
//! id of [`osap_core::usb::PRODUCT_IDS`] and the product prefix).

use core::fmt::Write as _;

use osap_core::framing::max_frame_len;
use osap_core::usb::PRODUCT_PREFIX;
use osap_core::Duration;

use crate::link::WireTiming;

/// Full-speed bulk packet size.
pub const PACKET: usize = 64;

/// USB full speed: 12 Mbit/s on the bus, so at least 2/3 µs per byte.
/// The host decides when it polls the bulk IN endpoint, so these are lower
/// bounds.
#[derive(Debug)]
pub struct UsbTiming;

/// The USB link's timing.
pub static USB_TIMING: UsbTiming = UsbTiming;

impl WireTiming for UsbTiming {
    fn transmit_time(&self, len: usize) -> Duration {
        Duration::from_micros((max_frame_len(len) as u64 * 2).div_ceil(3))
    }

    fn queue_delay(&self, queued: usize) -> Duration {
        Duration::from_micros((queued as u64 * 2).div_ceil(3))
    }
}

/// The product string: "osap-rs " and the module type.
pub type ProductString = heapless::String<48>;
/// The serial number: the board's unique id in hex (up to 16 bytes).
pub type SerialString = heapless::String<32>;

/// The product string of a module of type `module_type` (cut to fit).
pub fn product_string(module_type: &str) -> ProductString {
    let mut product = ProductString::new();
    let _ = product.push_str(PRODUCT_PREFIX);
    for c in module_type.chars() {
        if product.push(c).is_err() {
            break;
        }
    }
    product
}

/// The serial number of the board with unique id `unique_id`: upper-case
/// hex of its first 16 bytes.
pub fn serial_string(unique_id: &[u8]) -> SerialString {
    let mut serial = SerialString::new();
    for b in unique_id.iter().take(16) {
        // 16 bytes are 32 hex digits: it fits.
        let _ = write!(serial, "{b:02X}");
    }
    serial
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strings_carry_the_type_and_the_id() {
        assert_eq!(product_string("stepper").as_str(), "osap-rs stepper");
        assert_eq!(
            serial_string(&[0xe6, 0x61, 0x38, 0x52, 0x83, 0x0f, 0x2a, 0x2c]).as_str(),
            "E6613852830F2A2C"
        );
        // A SAMD51's 128-bit serial number fits whole.
        assert_eq!(serial_string(&[0xab; 16]).len(), 32);
        // An overlong type is cut, not dropped.
        let long = product_string(&"x".repeat(60));
        assert!(long.starts_with("osap-rs x") && long.len() == 48);
    }

    #[test]
    fn full_speed_timing() {
        // 64 bytes at 12 Mbit/s: at least 43 µs.
        assert_eq!(USB_TIMING.queue_delay(64), Duration::from_micros(43));
        assert!(USB_TIMING.transmit_time(100) >= Duration::from_micros(67));
    }
}
