//! `osap run` on the simulated printer: a slicer-style print extrudes what
//! its G-code says, nothing extrudes before the hotend holds its target,
//! heaters.csv logs every heater at 10 Hz, and a heater that faults stops
//! the print with exit 3, naming the heater.

use std::path::{Path, PathBuf};
use std::process::Command;

/// The example printer with an 80 W hotend cartridge (the example's is
/// 40 W) and its bed at the room's temperature kept (no M190 below), so
/// the heat-up takes about 35 s of machine time instead of 80.
fn printer(extra_sim: &str) -> String {
    let text = std::fs::read_to_string(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../examples/machines/printer.toml"),
    )
    .unwrap();
    let hot = text.replacen(
        "[sim.heaters.hotend]\npower_w = 40.0",
        &format!("[sim.heaters.hotend]\npower_w = 80.0{extra_sim}"),
        1,
    );
    assert_ne!(hot, text);
    hot
}

/// Two layers of a 10 mm square's two perimeters, as PrusaSlicer writes
/// them (M83, retractions), after a purge line. Returns the G-code and the
/// filament it extrudes, mm.
fn job() -> (String, f64) {
    let mut g = String::from(
        "M140 S60\nM104 S210\nG28\nM109 S210\nG21\nG90\nM83\nG92 E0\nG1 Z0.3 F600\nG1 X20 Y10 F9000\n",
    );
    let mut e_total = 0.0;
    let purge = 2.5;
    g += &format!("G1 X60 Y10 E{purge} F1500\nG1 E-0.8 F2100\n");
    e_total += purge - 0.8;
    // 0.45 × 0.2 mm lines of 1.75 mm filament: 0.03385 mm of e per mm.
    let per_mm = 0.03385;
    for layer in 0..2 {
        let z = 0.2 * f64::from(layer + 1);
        g += &format!(";LAYER_CHANGE\nG1 Z{z:.1} F600\n");
        for p in 0..2 {
            let d = 5.0 - 0.225 - 0.45 * f64::from(p);
            let (x0, y0) = (110.0 - d, 110.0 - d);
            g += &format!("G1 X{x0:.3} Y{y0:.3} F9000\nG1 E0.8 F2100\n");
            e_total += 0.8;
            for (x, y) in [
                (110.0 + d, y0),
                (110.0 + d, 110.0 + d),
                (x0, 110.0 + d),
                (x0, y0),
            ] {
                let e = 2.0 * d * per_mm;
                g += &format!("G1 X{x:.3} Y{y:.3} E{e:.5} F1800\n");
                e_total += e;
            }
            g += "G1 E-0.8 F2100\n";
            e_total -= 0.8;
        }
    }
    g += "G1 Z10 F600\nM104 S0\nM140 S0\nM84\n";
    (g, e_total)
}

/// Runs `osap run --sim --fast` in a fresh folder: exit code, stdout and
/// stderr, and the output folder.
fn run(name: &str, machine: &str, job: &str) -> (Option<i32>, String, PathBuf) {
    let dir = std::env::temp_dir().join(format!("osap-print-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("printer.toml"), machine).unwrap();
    std::fs::write(dir.join("job.gcode"), job).unwrap();
    let out = dir.join("out");
    let o = Command::new(env!("CARGO_BIN_EXE_osap"))
        .args(["run", "--sim", "--fast", "--out"])
        .arg(&out)
        .arg(dir.join("printer.toml"))
        .arg(dir.join("job.gcode"))
        .current_dir(&dir)
        .output()
        .unwrap();
    let text = format!(
        "{}\n{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    (o.status.code(), text, out)
}

/// A CSV's header and rows of numbers.
fn csv(path: &Path) -> (Vec<String>, Vec<Vec<f64>>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header = lines.next().unwrap().split(',').map(String::from).collect();
    let rows = lines
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    (header, rows)
}

#[test]
fn a_print_extrudes_what_its_gcode_says_and_only_once_the_hotend_is_hot() {
    let (gcode, e_job) = job();
    let (code, text, out) = run("ok", &printer(""), &gcode);
    assert_eq!(code, Some(0), "{text}");
    assert!(text.contains("faults: none"), "{text}");
    assert!(text.contains("waited on heaters"), "{text}");

    let (header, executed) = csv(&out.join("executed.csv"));
    // The motors with datasheet values (not the extruder's) get a stall
    // column each.
    assert_eq!(
        header,
        [
            "t",
            "x",
            "y",
            "z",
            "e",
            "stalled_a",
            "stalled_b",
            "stalled_z"
        ]
    );
    let e0 = executed[0][4];
    let e1 = executed.last().unwrap()[4];
    let extruded = e1 - e0;
    assert!(
        (extruded - e_job).abs() <= 0.005 * e_job,
        "extruded {extruded} mm, the job {e_job} mm"
    );
    assert!(
        text.contains(&format!("({e_job:.2} mm in the job)")),
        "{text}"
    );

    let (header, heaters) = csv(&out.join("heaters.csv"));
    assert_eq!(
        header,
        [
            "t",
            "bed",
            "bed_target",
            "bed_power",
            "hotend",
            "hotend_target",
            "hotend_power"
        ]
    );
    // At least 10 Hz on the synchronized clock.
    let gaps: Vec<f64> = heaters.windows(2).map(|w| w[1][0] - w[0][0]).collect();
    let worst = gaps.iter().cloned().fold(0.0, f64::max);
    assert!(worst <= 0.15, "a gap of {worst} s in heaters.csv");
    // The first extrusion (the purge line) comes after the hotend holds
    // 210 °C within the wait's window.
    let first = executed
        .iter()
        .find(|r| r[4] - e0 > 0.01)
        .map(|r| r[0])
        .unwrap();
    let before: Vec<&Vec<f64>> = heaters.iter().filter(|r| r[0] <= first).collect();
    let at = before.last().unwrap();
    assert!(
        at[4] >= 210.0 - 1.5,
        "e moved at {first} s with the hotend at {} °C",
        at[4]
    );
    assert!(
        before.iter().any(|r| r[4] < 100.0),
        "the hotend was never cold: the log missed the heat-up"
    );
}

#[test]
fn a_heater_fault_stops_the_print_naming_the_heater_and_exits_3() {
    let (gcode, _) = job();
    // The hotend's thermistor breaks 30 s in, while the print waits for it.
    let (code, text, out) = run("fault", &printer("\nsensor_fails_at_s = 30.0"), &gcode);
    assert_eq!(code, Some(3), "{text}");
    assert!(text.contains("heater hotend"), "{text}");
    assert!(text.contains("thermistor reads open"), "{text}");
    // Every heater went off: the module cut the hotend, the stop the bed.
    let (_, heaters) = csv(&out.join("heaters.csv"));
    let last = heaters.last().unwrap();
    assert_eq!((last[3], last[6]), (0.0, 0.0), "{last:?}");
}
