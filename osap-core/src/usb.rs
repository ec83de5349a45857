//! USB identity of osap-rs firmware, in one place for the firmware that
//! presents it and for hosts that look for it.
//!
//! osap-rs modules enumerate as USB CDC-ACM devices with these ids and
//! strings. The vendor id is the pid.codes open-source vendor (0x1209); the
//! product ids are in its range for testing until the project registers its
//! own, so a host also accepts any device whose product string starts with
//! [`PRODUCT_PREFIX`].

/// USB vendor id of osap-rs firmware (pid.codes).
pub const VENDOR_ID: u16 = 0x1209;
/// Product id of osap-rs firmware on the RP2040.
pub const PRODUCT_ID_RP2040: u16 = 0x0001;
/// Product id of osap-rs firmware on the SAMD51.
pub const PRODUCT_ID_SAMD51: u16 = 0x0002;
/// Every product id osap-rs firmware uses.
pub const PRODUCT_IDS: [u16; 2] = [PRODUCT_ID_RP2040, PRODUCT_ID_SAMD51];
/// Manufacturer string of osap-rs firmware.
pub const MANUFACTURER: &str = "osap-rs";
/// Product strings start with this (then the module type).
pub const PRODUCT_PREFIX: &str = "osap-rs ";

/// Whether a USB device with these ids is osap-rs firmware.
pub fn is_osap_device(vendor_id: u16, product_id: u16) -> bool {
    vendor_id == VENDOR_ID && PRODUCT_IDS.contains(&product_id)
}
