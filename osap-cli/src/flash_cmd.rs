//! `osap flash FIRMWARE [--name NAME]`: a firmware update over the network.
//!
//! 1. Checks the UF2 (its family: RP2040 or SAMD51) before anything else.
//! 2. Scans, and picks the module: `--module NAME`, or the one runtime
//!    directly at the other end of the link given. Where its chip can be
//!    told (a module on a USB link of its own: the USB product id; a
//!    simulated module: its topology's `[module.bootloader] chip`), a UF2
//!    of another family is refused here, before anything is sent to it.
//! 3. Reads its firmware version and function-set id, then calls its
//!    `enter_bootloader` (osap-module's: it answers, then reboots).
//! 4. Waits for a UF2 boot drive of the family to appear
//!    (`uf2_link::drive::find_boot_drives`, which honours
//!    `OSAP_UF2_MOUNTS`), and copies the UF2 onto it.
//! 5. Waits for the module to answer at the same route again (a serial
//!    link reopens by itself when the device re-enumerates), reads the
//!    version and function-set id again and prints old -> new. A function
//!    set other than this build's (`osap_module::FUNCTION_SET_ID`) means
//!    proxies generated from this host will not bind: said, exit code 4.
//! 6. Renames it if `--name` is given.

use crate::{connect, Connect, Connection};
use osap_core::route::Route;
use osap_host::link::serial;
use osap_host::netrunner::{self, Netrunner, ScanOptions};
use osap_host::som::model::{SomArg, SomRuntime};
use osap_host::som::{FnRef, Manager, ManagerOptions, SomError};
use osap_module::functions::FunctionSetHasher;
use pipes_core::control::ControlError;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};
use uf2_link::drive::{self, BootDrive};
use uf2_link::uf2::{self, Uf2Info, RP2040_FAMILY_ID, SAMD51_FAMILY_ID};

/// Exit code when the module was flashed and came back, but presents a
/// function set other than this build's.
pub(crate) const FUNCTION_SET_DIFFERS: u8 = 4;

/// `osap flash`'s arguments.
#[derive(clap::Args)]
pub(crate) struct FlashArgs {
    #[command(flatten)]
    connect: Connect,
    /// The firmware: a UF2 file, or a firmware ELF with `<elf>.uf2` next to
    /// it (the firmware crates' linker writes it), e.g.
    /// firmware-rp2040/target/thumbv6m-none-eabi/release/firmware-rp2040.
    firmware: PathBuf,
    /// The module to flash, by name (default: the one runtime directly at
    /// the other end of the link given).
    #[arg(long, value_name = "NAME")]
    module: Option<String>,
    /// Rename the module to this once it is back (at most 31 bytes).
    #[arg(long, value_name = "NAME")]
    name: Option<String>,
    /// How long to wait for the boot drive, and then for the module to
    /// come back, seconds (each).
    #[arg(long = "timeout", value_name = "SECONDS", default_value_t = 15.0)]
    timeout_s: f64,
}

/// The firmware to write: its path, bytes and what they hold.
struct Firmware {
    path: PathBuf,
    bytes: Vec<u8>,
    info: Uf2Info,
}

/// What a scan says of the module.
struct Seen {
    name: String,
    type_name: String,
    version: String,
    route: Route,
    /// The function-set id of what it presents (`None`: a type this build
    /// does not know).
    function_set: Option<u32>,
    has_enter: bool,
}

/// Flashes the module; see the module docs for the steps.
pub(crate) async fn flash(args: FlashArgs) -> Result<ExitCode, String> {
    if !(args.timeout_s.is_finite() && args.timeout_s > 0.0) {
        return Err(format!(
            "--timeout {} must be a positive number of seconds",
            args.timeout_s
        ));
    }
    let timeout = Duration::from_secs_f64(args.timeout_s);
    let fw = load_firmware(&args.firmware)?;
    let family = fw.info.family_id;
    println!("firmware: {} ({})", fw.path.display(), fw.info);

    let c = connect(&args.connect).await?;
    let options = ManagerOptions {
        scan: ScanOptions {
            timeout: c.timeout,
            ..ScanOptions::default()
        },
        timeout: c.timeout,
        ..ManagerOptions::default()
    };
    let mut manager = Manager::with_options(&c.host, options)
        .await
        .map_err(|e| e.to_string())?;
    let refresh = manager.refresh().await.map_err(|e| e.to_string())?;
    for f in &refresh.function_failures {
        eprintln!("warning: {f}");
    }
    let rt = target(manager.som().runtimes.as_slice(), args.module.as_deref())?;
    let before = seen(rt);
    if !before.has_enter {
        return Err(format!(
            "{} ({} {}) has no enter_bootloader function: its firmware predates `osap flash` \
             or is not osap-rs module firmware. Put it into its bootloader by hand (hold \
             BOOTSEL while plugging a Pico in; double-tap reset on a SAMD51 board) and copy \
             {} onto the drive that appears",
            before.name,
            before.type_name,
            before.version,
            fw.path.display()
        ));
    }
    match chip_of(&c, manager.som().runtimes.as_slice(), rt) {
        Some((chip, how)) if chip != family => {
            return Err(format!(
                "{} is {} ({how}) but {} is {} firmware: refused before anything was sent \
                 to the module. Build the firmware for its board (firmware-rp2040 for a \
                 Pico, firmware-samd51 for a SAMD51 board)",
                before.name,
                uf2::family_label(chip),
                fw.path.display(),
                uf2::family_label(family)
            ));
        }
        Some((_, how)) => println!("module: {} ({how})", before.name),
        None => println!(
            "module: {} (its chip cannot be told from here: the boot drive's family decides)",
            before.name
        ),
    }
    println!(
        "before: {} {}, function set {}",
        before.type_name,
        before.version,
        id_text(before.function_set)
    );

    // Drives already there are someone else's: the module's is the new one.
    let already = drives(family).await?;
    let enter = manager
        .function(&FnRef::new(before.name.as_str(), "enter_bootloader"))
        .map_err(|e| e.to_string())?
        .with_timeout(c.timeout.max(Duration::from_millis(500)));
    match enter.call(&[]).await {
        Ok(_) => println!("{}: rebooting into its bootloader", before.name),
        Err(e @ SomError::Remote { .. }) => {
            let why = match &e {
                SomError::Remote {
                    error: ControlError::CallFailed(_),
                    failure: Some(f),
                    ..
                } => f.to_string(),
                other => other.to_string(),
            };
            return Err(format!(
                "{} refused to enter its bootloader: {why}",
                before.name
            ));
        }
        // The answer may be lost while the module reboots anyway: look for
        // its drive all the same.
        Err(e) => {
            eprintln!("warning: no answer to enter_bootloader ({e}); looking for its drive anyway")
        }
    }

    let drive = wait_for_drive(family, &already, timeout).await?;
    println!("boot drive: {drive}");
    let written = {
        let (drive, bytes) = (drive.clone(), fw.bytes.clone());
        tokio::task::spawn_blocking(move || drive::write_uf2(&drive, &bytes))
            .await
            .map_err(|e| format!("copying the UF2 failed: {e}"))?
    }
    .map_err(|e| {
        format!(
            "cannot write {} onto {drive}: {e}; copy it there by hand, or unplug and replug \
             the module and run osap flash again",
            fw.path.display()
        )
    })?;
    println!(
        "wrote {} ({} blocks); waiting for {} to come back",
        written.display(),
        fw.info.block_count,
        before.name
    );

    wait_for_module(&c, &before.route, timeout).await?;
    let refresh = manager.refresh().await.map_err(|e| e.to_string())?;
    for f in &refresh.function_failures {
        eprintln!("warning: {f}");
    }
    let after = manager
        .som()
        .runtimes
        .iter()
        .find(|r| r.record.route() == before.route)
        .map(seen)
        .ok_or_else(|| {
            format!(
                "{} answered again but then a scan did not find it; run `osap scan` to see \
                 where it is",
                before.name
            )
        })?;
    println!(
        "after: {} {} -> {} {}, function set {} -> {}",
        before.type_name,
        before.version,
        after.type_name,
        after.version,
        id_text(before.function_set),
        id_text(after.function_set)
    );

    let mut name = after.name.clone();
    if let Some(new) = &args.name {
        name = netrunner::rename(&c.host, &after.route, new)
            .await
            .map_err(|e| format!("flashed, but renaming {} failed: {e}", after.name))?;
        println!("renamed {} to {name}", after.name);
    }

    let host_id = osap_module::FUNCTION_SET_ID;
    if after.function_set != Some(host_id) {
        eprintln!(
            "error: {name} now presents function set {} but this osap was built with {}: \
             proxies generated from this host (proxygen) will not bind to it. Flash firmware \
             built from the same tree as this osap, or regenerate the proxies from a scan of \
             it (`osap scan --som som.json`, then proxygen)",
            id_text(after.function_set),
            id_text(Some(host_id))
        );
        return Ok(ExitCode::from(FUNCTION_SET_DIFFERS));
    }
    println!("{name}: flashed; its function set matches this osap's");
    Ok(ExitCode::SUCCESS)
}

/// Reads the firmware: a UF2 file as it is, an ELF through the `<elf>.uf2`
/// next to it; checks it ([`uf2::inspect`]) and that it is for a chip
/// osap-rs firmware exists for.
fn load_firmware(path: &Path) -> Result<Firmware, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let (path, bytes) = if bytes.starts_with(b"\x7fELF") {
        let uf2_path = uf2_link::uf2_path(path, None);
        let bytes = std::fs::read(&uf2_path).map_err(|e| {
            format!(
                "{} is an ELF, and its UF2 {} cannot be read ({e}): build the firmware with \
                 its crate (e.g. cd firmware-rp2040 && cargo build --release), whose linker \
                 writes the UF2 next to the ELF, or give the UF2 file",
                path.display(),
                uf2_path.display()
            )
        })?;
        (uf2_path, bytes)
    } else {
        (path.to_path_buf(), bytes)
    };
    let info = uf2::inspect(&bytes).map_err(|e| {
        format!(
            "{} is not a valid UF2 file: {e}; give the .uf2 the firmware build wrote",
            path.display()
        )
    })?;
    if ![RP2040_FAMILY_ID, SAMD51_FAMILY_ID].contains(&info.family_id) {
        return Err(format!(
            "{} is for UF2 family {}: osap-rs firmware runs on RP2040 and SAMD51 boards only",
            path.display(),
            uf2::family_label(info.family_id)
        ));
    }
    Ok(Firmware { path, bytes, info })
}

/// The module to flash: `--module NAME`, or the one runtime directly at
/// the other end of a link of this host.
fn target<'a>(runtimes: &'a [SomRuntime], module: Option<&str>) -> Result<&'a SomRuntime, String> {
    let names = |rts: &[&SomRuntime]| {
        rts.iter()
            .map(|r| r.record.name.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    };
    let modules: Vec<&SomRuntime> = runtimes
        .iter()
        .filter(|r| !r.record.route.is_empty())
        .collect();
    if let Some(name) = module {
        let found: Vec<&SomRuntime> = modules
            .iter()
            .copied()
            .filter(|r| r.record.name == name)
            .collect();
        return match found.as_slice() {
            [one] => Ok(one),
            [] => Err(format!(
                "no runtime named {name} (found: {}); `osap scan` lists them",
                names(&modules)
            )),
            _ => Err(format!(
                "{} runtimes are named {name}: rename them apart first (`osap rename ROUTE NAME`)",
                found.len()
            )),
        };
    }
    let near: Vec<&SomRuntime> = modules
        .iter()
        .copied()
        .filter(|r| r.record.route.len() == 1)
        .collect();
    match near.as_slice() {
        [one] if one.functions.iter().any(|f| f.name == "enter_bootloader") => Ok(one),
        [one] => Err(format!(
            "{} ({}) is at the other end of the link, and it is not a module that can be \
             flashed (no enter_bootloader function): name the module with --module NAME \
             (found: {})",
            one.record.name,
            one.record.type_name,
            names(&modules)
        )),
        [] => Err(
            "nothing answered at the other end of the link: check the module is \
                   plugged in and powered, then `osap scan`"
                .into(),
        ),
        _ => Err(format!(
            "several runtimes are directly on this host's links ({}): pick one with \
             --module NAME, or give one link (--port PATH)",
            names(&near)
        )),
    }
}

/// What the scan says of `rt`.
fn seen(rt: &SomRuntime) -> Seen {
    Seen {
        name: rt.record.name.clone(),
        type_name: rt.record.type_name.clone(),
        version: rt.record.version.clone(),
        route: rt.record.route(),
        function_set: function_set(rt),
        has_enter: rt
            .functions
            .iter()
            .any(|f| f.name == "enter_bootloader" && f.inputs.is_empty() && f.outputs.is_empty()),
    }
}

/// The function-set id of what `rt` presents, as every firmware embeds it
/// (`osap_module::functions::function_set_id` over its scanned signatures,
/// in port order); `None` if a type is unknown to this build.
fn function_set(rt: &SomRuntime) -> Option<u32> {
    fn keys(list: &[SomArg]) -> Option<Vec<(&str, u8)>> {
        list.iter()
            .map(|a| a.ty().map(|ty| (a.name.as_str(), ty.key())))
            .collect()
    }
    // Blocks made at run time are not what the firmware was built with.
    let mut id = FunctionSetHasher::new(rt.built_functions().count());
    for f in rt.built_functions() {
        let (inputs, outputs) = (keys(&f.inputs)?, keys(&f.outputs)?);
        id.function(&f.name, inputs.into_iter(), outputs.into_iter());
    }
    Some(id.finish())
}

/// `0xdde4505f`, or `unknown`.
fn id_text(id: Option<u32>) -> String {
    id.map_or_else(
        || "unknown (a type this osap does not know)".into(),
        |id| format!("{id:#010x}"),
    )
}

/// The module's chip (a UF2 family id), and how that is known, where it
/// can be: a simulated module's bootloader chip, or the USB product id of
/// the serial port the module is directly on.
fn chip_of(c: &Connection, runtimes: &[SomRuntime], rt: &SomRuntime) -> Option<(u32, String)> {
    if let Some(sim) = &c._sim {
        // Hops only: a scanned route also carries the path's MTU.
        let hops = Route::through_links(&rt.record.route).ok();
        let module = sim
            .modules()
            .iter()
            .find(|m| sim.route_to(m.name()) == hops)?;
        let boot = module.spec().bootloader.as_ref()?;
        return Some((
            boot.chip.family_id(),
            format!("simulated {} board", boot.chip.name()),
        ));
    }
    let [link] = rt.record.route.as_slice() else {
        return None;
    };
    let host = runtimes.iter().find(|r| r.record.route.is_empty())?;
    let path = &host.record.links.iter().find(|l| l.index == *link)?.name;
    let port = serial::available_ports()
        .ok()?
        .into_iter()
        .find(|p| &p.path == path)?;
    let family = match port.pid {
        osap_core::usb::PRODUCT_ID_RP2040 => RP2040_FAMILY_ID,
        osap_core::usb::PRODUCT_ID_SAMD51 => SAMD51_FAMILY_ID,
        _ => return None,
    };
    Some((
        family,
        format!("USB {:04x}:{:04x} on {path}", port.vid, port.pid),
    ))
}

/// The boot drives of `family` mounted now.
async fn drives(family: u32) -> Result<Vec<BootDrive>, String> {
    tokio::task::spawn_blocking(move || drive::find_boot_drives(family))
        .await
        .map_err(|e| format!("looking for boot drives failed: {e}"))?
        .map_err(|e| format!("looking for boot drives: {e}"))
}

/// Where drives are looked for, for messages.
fn looked_in() -> String {
    match std::env::var_os(drive::MOUNTS_ENV) {
        Some(v) if !v.is_empty() => {
            format!("{}={}", drive::MOUNTS_ENV, v.to_string_lossy())
        }
        _ => format!(
            "the system's mounted drives ({} was not set)",
            drive::MOUNTS_ENV
        ),
    }
}

/// Waits for a boot drive of `family` that was not among `already`.
async fn wait_for_drive(
    family: u32,
    already: &[BootDrive],
    timeout: Duration,
) -> Result<BootDrive, String> {
    let deadline = Instant::now() + timeout;
    // A drive being mounted can show a half-written INFO_UF2.TXT for a
    // moment: an unreadable one is looked at again until the deadline.
    let mut last_error = None;
    loop {
        let found = match drives(family).await {
            Ok(found) => found,
            Err(e) => {
                if Instant::now() >= deadline {
                    return Err(e);
                }
                last_error = Some(e);
                tokio::time::sleep(Duration::from_millis(100)).await;
                continue;
            }
        };
        let new: Vec<BootDrive> = found
            .into_iter()
            .filter(|d| !already.iter().any(|a| a.path == d.path))
            .collect();
        match new.as_slice() {
            [one] => return Ok(one.clone()),
            [] => {}
            several => {
                return Err(format!(
                    "{} boot drives of {} appeared at once ({}): unplug the other boards, or \
                     set {} to the module's drive, and run osap flash again",
                    several.len(),
                    uf2::family_label(family),
                    several
                        .iter()
                        .map(|d| d.to_string())
                        .collect::<Vec<_>>()
                        .join(", "),
                    drive::MOUNTS_ENV
                ))
            }
        }
        if Instant::now() >= deadline {
            let mut message = no_drive_message(family, already, timeout).await;
            if let Some(e) = last_error {
                message.push_str(&format!(" (earlier, {e})"));
            }
            return Err(message);
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// Why no drive appeared, and what to do.
async fn no_drive_message(family: u32, already: &[BootDrive], timeout: Duration) -> String {
    let other = if family == RP2040_FAMILY_ID {
        SAMD51_FAMILY_ID
    } else {
        RP2040_FAMILY_ID
    };
    let mut msg = format!(
        "no UF2 boot drive of {} ({}) appeared within {:.0} s (looked in {}). If the \
         module rebooted into its bootloader, its drive may not be mounted: mount it, or \
         set {} to the directory it is mounted at. If it did not, put it into its \
         bootloader by hand (hold BOOTSEL while plugging a Pico in; double-tap reset on a \
         SAMD51 board) and run osap flash again; a slow automount needs a longer --timeout",
        uf2::family_label(family),
        drive::expected_board_id(family),
        timeout.as_secs_f64(),
        looked_in(),
        drive::MOUNTS_ENV
    );
    if !already.is_empty() {
        msg.push_str(&format!(
            ". Drives of that family that were there before and are not the module's: {}",
            already
                .iter()
                .map(|d| d.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ));
    }
    if let Ok(others) = drives(other).await {
        if !others.is_empty() {
            msg.push_str(&format!(
                ". A drive of {} is there ({}): is the module that chip? Then flash its \
                 firmware",
                uf2::family_label(other),
                others
                    .iter()
                    .map(|d| d.to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            ));
        }
    }
    msg
}

/// Waits for the runtime at `route` to answer again.
async fn wait_for_module(c: &Connection, route: &Route, timeout: Duration) -> Result<(), String> {
    let mut runner = Netrunner::new(&c.host).await.map_err(|e| e.to_string())?;
    runner.timeout = c.timeout;
    let deadline = Instant::now() + timeout;
    loop {
        if runner.name(route).await.is_ok() {
            return Ok(());
        }
        if Instant::now() >= deadline {
            return Err(format!(
                "the module did not come back within {:.0} s of the UF2 being written: if \
                 its drive is still there, the bootloader did not take the file (copy it \
                 again); otherwise it may run firmware that does not answer on this link. \
                 Unplug and replug it, then `osap scan`",
                timeout.as_secs_f64()
            ));
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
}
