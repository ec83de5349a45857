//! `osap scan` of a lone module whose UART is wired to nothing: the UART is
//! open (a UART cannot tell), nothing is heard on it and nothing answers, so
//! the scan marks it as having no neighbour and the map is whole (exit 0).

use osap_host::map::NetworkMap;
use std::process::Command;

/// One stepper on USB, its UART open onto nothing (`dangling_uart`).
const LONE: &str = r#"
name = "lone"

[[module]]
name = "motor"
type = "stepper"
dangling_uart = true

[[link]]
a = "host"
b = "motor"
kind = "usb"
"#;

#[test]
fn a_lone_module_with_an_unwired_uart_scans_whole() {
    let dir = std::env::temp_dir();
    let id = std::process::id();
    let topology = dir.join(format!("osap-cli-lone-{id}.toml"));
    let map_path = dir.join(format!("osap-cli-lone-map-{id}.json"));
    std::fs::write(&topology, LONE).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_osap"))
        .args(["scan", "--sim"])
        .arg(&topology)
        .arg("-o")
        .arg(&map_path)
        .output()
        .expect("osap runs");
    let _ = std::fs::remove_file(&topology);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(0), "{stdout}\n{stderr}");
    assert!(
        stdout.contains("\n    link 1 uart (no neighbour)\n"),
        "{stdout}"
    );
    assert!(
        stdout.contains("2 runtimes, 1 links (1 open link with no neighbour)"),
        "{stdout}"
    );
    assert!(!stderr.contains("partial"), "{stderr}");
    let map = NetworkMap::from_json(&std::fs::read_to_string(&map_path).unwrap()).unwrap();
    let _ = std::fs::remove_file(&map_path);
    let uart = &map.find("motor").unwrap().links[1];
    assert!(uart.open && !uart.heard, "{uart:?}");
}
