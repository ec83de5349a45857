//! Serial links: USB-CDC modules and UART/RS-485 adapters, framed per
//! `docs/protocol.md` §5.
//!
//! [`available_ports`] finds osap-rs firmware among the USB serial devices
//! by the ids in [`osap_core::usb`] (or by its product string), and
//! [`spawn_serial`] opens a port, found that way or named explicitly (a UART
//! adapter has no osap-rs ids), as a link of the host. A port that goes away
//! (cable pulled, device reset) marks the link closed and is reopened when
//! it comes back, even under another name if the USB device has a serial
//! number; the host keeps running throughout.
//!
//! Enumeration reads sysfs (`/sys/class/tty`) directly, so nothing beyond
//! the C library is needed on Linux (no libudev).

use super::stream::{link_error, LinkHandle, StreamLimits};
use super::LinkConfig;
use crate::runtime::Host;
use crate::HostError;
use osap_core::usb;
use std::io;
use std::path::Path;
use tokio_serial::{SerialPortBuilderExt, SerialPortType, SerialStream};

/// A serial link's handle: its index, state, and the task that keeps the
/// port open.
pub type SerialLink = LinkHandle;

/// The baud rate for UART links unless told otherwise. (USB-CDC devices
/// ignore it.)
pub const DEFAULT_BAUD: u32 = 115_200;

/// What a user who may not open a serial port should do about it.
#[cfg(target_os = "linux")]
const PERMISSION_FIX: &str = "add yourself to the group that owns it: \
    sudo usermod -aG {group} $USER, then log in again";
#[cfg(not(target_os = "linux"))]
const PERMISSION_FIX: &str = "give your user read and write access to it \
    (it belongs to the group {group})";

/// A USB serial device that may be an OSAP module.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SerialCandidate {
    /// The device path to open, e.g. `/dev/ttyACM0`.
    pub path: String,
    /// USB vendor id.
    pub vid: u16,
    /// USB product id.
    pub pid: u16,
    /// USB manufacturer string, if the device has one.
    pub manufacturer: Option<String>,
    /// USB product string, if the device has one.
    pub product: Option<String>,
    /// USB serial number, if the device has one. Used to find the device
    /// again if it comes back under another path.
    pub serial_number: Option<String>,
}

impl SerialCandidate {
    /// Whether the device presents osap-rs firmware's USB ids or product
    /// string.
    pub fn is_osap(&self) -> bool {
        usb::is_osap_device(self.vid, self.pid)
            || self
                .product
                .as_deref()
                .is_some_and(|p| p.starts_with(usb::PRODUCT_PREFIX))
    }
}

impl std::fmt::Display for SerialCandidate {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} ({:04x}:{:04x}", self.path, self.vid, self.pid)?;
        if let Some(p) = &self.product {
            write!(f, " {p}")?;
        }
        if let Some(s) = &self.serial_number {
            write!(f, " serial {s}")?;
        }
        f.write_str(")")
    }
}

/// Every serial port on the system: its path and, for USB ones, the device.
fn all_ports() -> Result<Vec<(String, Option<SerialCandidate>)>, HostError> {
    // The sysfs scan panics when there is no sysfs (some containers).
    if cfg!(target_os = "linux") && !Path::new("/sys/class/tty").is_dir() {
        return Ok(Vec::new());
    }
    let ports = tokio_serial::available_ports().map_err(|e| HostError::Io {
        context: "listing serial ports".into(),
        source: io::Error::other(e.description),
    })?;
    Ok(ports
        .into_iter()
        .map(|p| {
            let usb = match p.port_type {
                SerialPortType::UsbPort(u) => Some(SerialCandidate {
                    path: p.port_name.clone(),
                    vid: u.vid,
                    pid: u.pid,
                    manufacturer: u.manufacturer,
                    product: u.product,
                    serial_number: u.serial_number,
                }),
                _ => None,
            };
            (p.port_name, usb)
        })
        .collect())
}

/// The USB serial ports that are osap-rs firmware, by USB vendor and
/// product id ([`osap_core::usb::is_osap_device`]) or by a product string
/// starting with [`osap_core::usb::PRODUCT_PREFIX`]. An empty list is not an
/// error; see [`find_port`] for one that explains itself.
pub fn available_ports() -> Result<Vec<SerialCandidate>, HostError> {
    Ok(all_ports()?
        .into_iter()
        .filter_map(|(_, usb)| usb.filter(SerialCandidate::is_osap))
        .collect())
}

/// The one osap-rs device plugged in. Fails with a message that says what
/// to do if there is none (listing the serial ports that are there) or
/// several.
pub fn find_port() -> Result<SerialCandidate, HostError> {
    let mut found = available_ports()?;
    match found.len() {
        1 => Ok(found.remove(0)),
        0 => {
            let others: Vec<String> = all_ports()?.into_iter().map(|(path, _)| path).collect();
            let present = if others.is_empty() {
                "there are no serial ports at all".to_string()
            } else {
                format!("serial ports present: {}", others.join(", "))
            };
            Err(link_error(
                "no osap-rs devices found".into(),
                io::ErrorKind::NotFound,
                format!(
                    "looked for USB vendor {:04x} products {:04x?} or a product string \
                     starting with {:?}; {present}. Is the module plugged in and powered? \
                     For a UART or RS-485 adapter, name its port explicitly (--port PATH).",
                    usb::VENDOR_ID,
                    usb::PRODUCT_IDS,
                    usb::PRODUCT_PREFIX
                ),
            ))
        }
        _ => Err(link_error(
            "several osap-rs devices found".into(),
            io::ErrorKind::InvalidInput,
            format!(
                "{}; choose one with --port PATH",
                found
                    .iter()
                    .map(ToString::to_string)
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        )),
    }
}

/// The USB device behind `path` (which may be a symlink such as
/// `/dev/serial/by-id/...`), if it is one.
fn usb_identity(path: &str) -> Option<SerialCandidate> {
    let real = std::fs::canonicalize(path).ok()?;
    all_ports().ok()?.into_iter().find_map(|(p, usb)| {
        let same = std::fs::canonicalize(&p).ok()? == real;
        usb.filter(|_| same)
    })
}

/// Opens `path` and explains a failure.
fn open(path: &str, baud: u32) -> Result<SerialStream, HostError> {
    tokio_serial::new(path, baud)
        .open_native_async()
        .map_err(|e| open_error(path, &e))
}

/// Turns a failure to open `path` into an error that says what to do.
fn open_error(path: &str, e: &tokio_serial::Error) -> HostError {
    use tokio_serial::ErrorKind as K;
    let (kind, message) = match e.kind {
        K::Io(io::ErrorKind::NotFound) => (io::ErrorKind::NotFound, not_found(path)),
        K::Io(io::ErrorKind::PermissionDenied) => (
            io::ErrorKind::PermissionDenied,
            permission_denied(&owning_group(path)),
        ),
        K::NoDevice => (
            io::ErrorKind::ResourceBusy,
            "it is in use by another program (a serial monitor, another osap host, \
             ModemManager); close that and try again"
                .to_string(),
        ),
        // ENOTTY, which nix describes in either of these ways.
        K::Unknown
            if e.description.contains("Inappropriate ioctl")
                || e.description.contains("typewriter") =>
        {
            (
                io::ErrorKind::InvalidInput,
                "it is not a serial port".to_string(),
            )
        }
        _ => (io::ErrorKind::Other, e.description.clone()),
    };
    link_error(format!("cannot open serial port {path}"), kind, message)
}

/// The explanation for a path that does not exist, naming the ports that do.
fn not_found(path: &str) -> String {
    let present: Vec<String> = all_ports()
        .unwrap_or_default()
        .into_iter()
        .map(|(p, usb)| match usb {
            Some(u) => u.to_string(),
            None => p,
        })
        .collect();
    let present = if present.is_empty() {
        "there are no serial ports".to_string()
    } else {
        format!("serial ports present: {}", present.join(", "))
    };
    format!("{path} does not exist: is the device plugged in, and is the path right? ({present})")
}

/// The explanation for a port the user may not open.
fn permission_denied(group: &str) -> String {
    format!(
        "permission denied; {}",
        PERMISSION_FIX.replace("{group}", group)
    )
}

/// The name of the group that owns `path` (the group to join to use it),
/// `dialout` if that cannot be found out.
fn owning_group(path: &str) -> String {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        let gid = std::fs::metadata(path).map(|m| m.gid()).ok();
        let groups = std::fs::read_to_string("/etc/group").unwrap_or_default();
        let name = gid.and_then(|gid| {
            groups.lines().find_map(|line| {
                let mut fields = line.split(':');
                let name = fields.next()?;
                let id = fields.nth(1)?.parse::<u32>().ok()?;
                (id == gid && !name.is_empty()).then(|| name.to_string())
            })
        });
        if let Some(name) = name {
            return name;
        }
    }
    let _ = path;
    "dialout".into()
}

/// Reopens a lost port: at `path` if it is back, otherwise wherever the
/// same USB device (vendor, product and serial number) reappeared.
fn reopen(path: &str, baud: u32, usb: Option<&SerialCandidate>) -> Result<SerialStream, HostError> {
    if Path::new(path).exists() {
        return open(path, baud);
    }
    if let Some(id) = usb.filter(|u| u.serial_number.is_some()) {
        let back = all_ports()?.into_iter().find_map(|(_, found)| {
            found.filter(|f| {
                f.vid == id.vid && f.pid == id.pid && f.serial_number == id.serial_number
            })
        });
        if let Some(found) = back {
            tracing::info!("serial link {path}: the device is back as {}", found.path);
            return open(&found.path, baud);
        }
    }
    Err(link_error(
        format!("serial port {path}"),
        io::ErrorKind::NotFound,
        "the device is gone (unplugged, or resetting); waiting for it to come back".into(),
    ))
}

/// Opens the serial port at `path` and adds it to `host` as a link, then
/// keeps it open in a task: if the port goes away the link is marked closed
/// (the runtime drops what is routed over it meanwhile) and the task polls
/// for the device, with backoff from 100 ms to 2 s, and resumes the link
/// when it is back.
///
/// The link's type is `usb_cdc` for a USB device, with no wire speed (the
/// bus is fast and its latency is not a baud rate), and `uart` otherwise,
/// with `baud` at 10 bits per byte so the runtime counts wire time against
/// packets' time to live. Its name is `path`.
///
/// Fails, without adding a link, if the port cannot be opened now; the
/// error says why and what to do (a path that does not exist, permission
/// denied and how to get it, a port in use, a file that is not a serial
/// port). Whether the device at the other end speaks OSAP shows when it is
/// asked: see [`LinkHandle::probe`].
pub async fn spawn_serial(host: &Host, path: &str, baud: u32) -> Result<SerialLink, HostError> {
    let usb = usb_identity(path);
    let port = open(path, baud)?;
    let config = match &usb {
        Some(_) => LinkConfig::new("usb_cdc", path),
        None => LinkConfig {
            bits_per_second: baud,
            bits_per_byte: 10,
            ..LinkConfig::new("uart", path)
        },
    };
    match &usb {
        Some(u) => tracing::info!("serial link: opened {u}"),
        None => tracing::info!("serial link: opened {path} at {baud} baud"),
    }
    let (index, io) = host.add_link(config).await?;
    let path = path.to_string();
    Ok(LinkHandle::spawn_client(
        host,
        index,
        io,
        None,
        port,
        move || std::future::ready(reopen(&path, baud, usb.as_ref())),
        StreamLimits::NONE,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn permission_denied_says_how_to_fix_it() {
        let e = tokio_serial::Error::new(
            tokio_serial::ErrorKind::Io(io::ErrorKind::PermissionDenied),
            "Permission denied",
        );
        let text = open_error("/nonexistent/ttyACM9", &e).to_string();
        assert!(
            text.contains("cannot open serial port /nonexistent/ttyACM9"),
            "{text}"
        );
        #[cfg(target_os = "linux")]
        assert!(
            text.contains("sudo usermod -aG dialout $USER, then log in again"),
            "{text}"
        );
    }

    #[test]
    fn busy_and_not_a_tty_are_named() {
        let busy = tokio_serial::Error::new(tokio_serial::ErrorKind::NoDevice, "busy");
        assert!(open_error("/dev/x", &busy).to_string().contains("in use"));
        let notty = tokio_serial::Error::new(
            tokio_serial::ErrorKind::Unknown,
            "Inappropriate ioctl for device",
        );
        assert!(open_error("/dev/x", &notty)
            .to_string()
            .contains("not a serial port"));
        let notty = tokio_serial::Error::new(tokio_serial::ErrorKind::Unknown, "Not a typewriter");
        assert!(open_error("/dev/x", &notty)
            .to_string()
            .contains("not a serial port"));
    }

    #[test]
    fn osap_devices_are_recognised_by_ids_or_product() {
        let mut c = SerialCandidate {
            path: "/dev/ttyACM0".into(),
            vid: usb::VENDOR_ID,
            pid: usb::PRODUCT_ID_RP2040,
            manufacturer: None,
            product: None,
            serial_number: None,
        };
        assert!(c.is_osap());
        c.pid = 0x7777;
        assert!(!c.is_osap());
        c.product = Some(format!("{}stepper", usb::PRODUCT_PREFIX));
        assert!(c.is_osap());
        c.product = Some("CP2102 USB to UART".into());
        c.vid = 0x10c4;
        assert!(!c.is_osap());
    }
}
