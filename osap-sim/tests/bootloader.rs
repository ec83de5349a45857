//! A simulated module's UF2 bootloader: `enter_bootloader` (osap-module's,
//! called over the network) answers, then the module goes off the network
//! and its drive shows `INFO_UF2.TXT`; a UF2 of another family is refused
//! and counted, the module staying in its bootloader; a UF2 of its family
//! unmounts the drive and the module comes back, with the name it was
//! given before. A module without a bootloader refuses the call.

use osap_core::route::Route;
use osap_host::netrunner::Netrunner;
use osap_host::som::{FnRef, Manager};
use osap_host::{Host, HostConfig};
use osap_module::boot::BootError;
use osap_sim::machine::board::bootloader::INFO_FILE;
use osap_sim::machine::SimMachine;
use osap_sim::topology::{BootloaderSpec, Chip};
use osap_sim::topology::{LinkKind, LinkSpec, ModuleSpec, SimSpec, HOST};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use uf2_link::uf2::{self, RP2040_FAMILY_ID, SAMD51_FAMILY_ID};

fn image(family: u32, blocks: u32) -> Vec<u8> {
    let payload = [0x5Au8; uf2::PAYLOAD];
    (0..blocks)
        .flat_map(|i| uf2::block(0x1000_0000 + i * 256, &payload, i, blocks, family))
        .collect()
}

fn drive_dir(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("osap-sim-boot-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

async fn until(what: &str, timeout: Duration, mut f: impl FnMut() -> bool) {
    let deadline = Instant::now() + timeout;
    while !f() {
        assert!(Instant::now() < deadline, "timed out waiting: {what}");
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

fn topology(drive: Option<&Path>) -> SimSpec {
    let mut motor = ModuleSpec::new("motor", "stepper");
    if let Some(d) = drive {
        motor = motor.with_bootloader(BootloaderSpec::new(d, Chip::Rp2040));
    }
    SimSpec::new("boot")
        .with_module(motor)
        .with_link(LinkSpec::new(HOST, "motor", LinkKind::Usb))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_module_enters_its_bootloader_refuses_another_family_and_comes_back() {
    let dir = drive_dir("cycle");
    let host = Host::start(HostConfig::named("h")).unwrap();
    let sim = SimMachine::start(&host, &topology(Some(&dir)))
        .await
        .unwrap();
    let module = sim.module("motor").unwrap().clone();
    let route: Route = sim.route_to("motor").unwrap();
    let nr = Netrunner::new(&host).await.unwrap();
    assert_eq!(nr.set_name(&route, "x-axis").await.unwrap(), "x-axis");

    let mut m = Manager::new(&host).await.unwrap();
    m.refresh().await.unwrap();
    let enter = m
        .function(&FnRef::new("x-axis", "enter_bootloader"))
        .unwrap();
    assert!(enter.call(&[]).await.unwrap().is_empty(), "answered");
    // It answered first: the drive comes 100 ms later.
    until("the bootloader", Duration::from_secs(5), || {
        dir.join(INFO_FILE).is_file()
    })
    .await;
    let info = std::fs::read_to_string(dir.join(INFO_FILE)).unwrap();
    assert!(info.contains("Board-ID: RPI-RP2"), "{info}");
    assert!(module.in_bootloader() && !module.is_running());
    assert!(nr.name(&route).await.is_err(), "off the network");
    assert_eq!(module.boot_stats().entered, 1);

    // Another family's UF2: refused, still in the bootloader.
    std::fs::write(dir.join("samd.uf2"), image(SAMD51_FAMILY_ID, 3)).unwrap();
    until("the refusal", Duration::from_secs(5), || {
        module.boot_stats().rejected == 1
    })
    .await;
    let why = module.boot_stats().last_rejection.unwrap();
    assert!(why.contains("SAMD51") && why.contains("rp2040"), "{why}");
    assert!(!dir.join("samd.uf2").exists());
    assert!(dir.join(INFO_FILE).is_file() && module.in_bootloader());

    // Its own family: flashed, the drive unmounts, the module is back with
    // its name.
    std::fs::write(dir.join("fw.uf2"), image(RP2040_FAMILY_ID, 3)).unwrap();
    until("the module back", Duration::from_secs(10), || {
        module.is_running()
    })
    .await;
    assert!(!dir.join(INFO_FILE).exists() && !dir.join("fw.uf2").exists());
    let stats = module.boot_stats();
    assert_eq!((stats.entered, stats.flashed, stats.rejected), (1, 1, 1));
    assert!(!module.in_bootloader());
    let deadline = Instant::now() + Duration::from_secs(5);
    let name = loop {
        match nr.name(&route).await {
            Ok(n) => break n,
            Err(e) => assert!(Instant::now() < deadline, "not back: {e}"),
        }
    };
    assert_eq!(name, "x-axis", "the name is kept");
    sim.stop().await.unwrap();
    let _ = std::fs::remove_dir_all(&dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_module_without_a_bootloader_refuses() {
    let host = Host::start(HostConfig::named("h")).unwrap();
    let sim = SimMachine::start(&host, &topology(None)).await.unwrap();
    let mut m = Manager::new(&host).await.unwrap();
    m.refresh().await.unwrap();
    let e = m
        .function(&FnRef::new("motor", "enter_bootloader"))
        .unwrap()
        .call(&[])
        .await
        .unwrap_err()
        .to_string();
    assert!(
        e.contains(&format!(
            "Unsupported (code {})",
            BootError::Unsupported.code()
        )),
        "{e}"
    );
    tokio::time::sleep(Duration::from_millis(200)).await;
    assert!(sim.module("motor").unwrap().is_running());
    sim.stop().await.unwrap();
}

#[test]
fn a_bootloader_is_for_steppers_with_their_own_drive() {
    let text = |extra: &str| {
        format!(
            "[[module]]\nname = \"a\"\ntype = \"stepper\"\n[module.bootloader]\ndrive = \"/tmp/d\"\n\
             [[module]]\nname = \"b\"\ntype = \"stepper\"\n{extra}\n\
             [[link]]\na = \"host\"\nb = \"a\"\nkind = \"usb\"\n[[link]]\na = \"a\"\nb = \"b\"\nkind = \"uart\"\n"
        )
    };
    let t = SimSpec::parse(&text("")).unwrap();
    let boot = t.modules[0].bootloader.as_ref().unwrap();
    assert_eq!((boot.chip, boot.reboot_ms), (Chip::Rp2040, 300));
    let e = SimSpec::parse(&text("[module.bootloader]\ndrive = \"/tmp/d\""))
        .unwrap_err()
        .to_string();
    assert!(e.contains("give each module its own drive"), "{e}");
    let e = SimSpec::parse(&text(
        "[module.bootloader]\ndrive = \"/tmp/e\"\nchip = \"esp32\"",
    ))
    .unwrap_err()
    .to_string();
    assert!(e.contains("esp32"), "{e}");
}
