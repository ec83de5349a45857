//! `osap heater-tune` on the simulated printer in virtual time: `--write`
//! puts new gains into (a copy of) the machine file, which keeps its
//! comments and loads; an unknown heater is refused with exit code 2,
//! naming the known ones.

use std::path::PathBuf;
use std::process::Command;

use osap_machine::config::MachineFile;

fn printer() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../examples/machines/printer.toml")
}

#[test]
fn heater_tune_writes_the_hotends_gains_keeping_the_files_comments() {
    let dir = std::env::temp_dir().join(format!("osap-heater-tune-cli-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let machine = dir.join("printer.toml");
    std::fs::copy(printer(), &machine).unwrap();
    let before = std::fs::read_to_string(&machine).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_osap"))
        .args([
            "heater-tune",
            "--sim",
            "--fast",
            "--heater",
            "hotend",
            "--write",
        ])
        .arg(&machine)
        .output()
        .unwrap();
    let (stdout, stderr) = (
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr),
    );
    assert!(o.status.success(), "{stdout}\n{stderr}");
    assert!(stdout.contains("wrote kp = "), "{stdout}");
    let after = std::fs::read_to_string(&machine).unwrap();
    // Every line but the three gains is as it was, comments included.
    let changed: Vec<(&str, &str)> = before
        .lines()
        .zip(after.lines())
        .filter(|(a, b)| a != b)
        .collect();
    assert_eq!(before.lines().count(), after.lines().count());
    assert_eq!(changed.len(), 3, "{changed:?}");
    for ((old, new), key) in changed.iter().zip(["kp = ", "ki = ", "kd = "]) {
        assert!(
            old.starts_with(key) && new.starts_with(key),
            "{old} -> {new}"
        );
    }
    assert!(after.contains("# The hotend: a 40 W cartridge"));
    let cfg = MachineFile::load(&machine).unwrap();
    cfg.validate().unwrap();
    let h = &cfg.heaters["hotend"];
    // The relay's gains for the simulated block (osap-machine's
    // heater_tune_sim gives the band), not the file's 21.5, 1.06, 109.
    assert!((60.0..78.0).contains(&h.kp), "{h:?}");
    assert!((14.0..25.0).contains(&h.ki), "{h:?}");
    assert!((45.0..80.0).contains(&h.kd), "{h:?}");
    // The bed is untouched.
    assert_eq!(
        (
            cfg.heaters["bed"].kp,
            cfg.heaters["bed"].ki,
            cfg.heaters["bed"].kd
        ),
        (54.0, 0.77, 948.0)
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn an_unknown_heater_is_refused_naming_the_known_ones() {
    let o = Command::new(env!("CARGO_BIN_EXE_osap"))
        .args(["heater-tune", "--sim", "--fast", "--heater", "chamber"])
        .arg(printer())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("\"chamber\"") && stderr.contains("bed, hotend"),
        "{stderr}"
    );
}
