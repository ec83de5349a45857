use std::path::Path;

use chrono::TimeZone;

use super::*;
use crate::config::MachineFile;

fn host() -> HostBuild {
    HostBuild {
        program: "osap".into(),
        version: "0.1.0".into(),
        commit: Some("0123456789ab".into()),
    }
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("osap-runs-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn mill() -> (PathBuf, MachineFile) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/machines/mill.toml");
    let cfg = MachineFile::load(&path).unwrap();
    (path, cfg)
}

#[test]
fn sha256_matches_the_standard_vectors() {
    assert_eq!(
        sha256_hex(b""),
        "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855"
    );
    assert_eq!(
        sha256_hex(b"abc"),
        "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
    );
}

#[test]
fn folder_names_sort_by_time_and_never_collide() {
    let dir = temp_dir("names");
    let at = chrono::Local
        .with_ymd_and_hms(2026, 11, 29, 14, 35, 2)
        .single()
        .unwrap();
    let a = folder_name(&dir, "run", "my printer/2", None, at);
    assert_eq!(
        a.file_name().unwrap().to_string_lossy(),
        "osap-run-my_printer_2-20261129-143502"
    );
    std::fs::create_dir_all(&a).unwrap();
    let b = folder_name(&dir, "run", "my printer/2", None, at);
    assert_eq!(
        b.file_name().unwrap().to_string_lossy(),
        "osap-run-my_printer_2-20261129-143502-2"
    );
    let r = folder_name(&dir, "resonance", "plotter", Some("y"), at);
    assert_eq!(
        r.file_name().unwrap().to_string_lossy(),
        "osap-resonance-plotter-y-20261129-143502"
    );
}

#[test]
fn a_record_round_trips_and_restores_its_inputs_where_the_machine_file_finds_them() {
    let dir = temp_dir("roundtrip");
    let (path, cfg) = mill();
    let mut r = RunRecord::start("run", &path, &cfg, host()).unwrap();
    // The mill names its bed mesh: the copy comes along, as named.
    let mesh = r.machine_inputs["bed_mesh"].clone();
    assert_eq!(mesh.path, "mill-mesh.toml");
    assert_eq!(
        mesh.sha256,
        sha256_hex(&std::fs::read(cfg.bed_mesh_path().unwrap()).unwrap())
    );
    let job = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/jobs/part.gcode");
    r.job = Some(InputFile::read(&job).unwrap());
    r.line("planned duration      12.000 s");
    r.wall_line("machine mill ready after 0.31 s");
    r.figure("planned_s", 12.0);
    let data = dir.join("planned.csv");
    std::fs::write(&data, "t,x\n0,1\n").unwrap();
    r.add_files(&dir, std::slice::from_ref(&data)).unwrap();
    r.finish(Some(5_000_000), 0, "ok", None);
    r.write(&dir.join(RUN_FILE)).unwrap();

    let back = RunRecord::read(&dir).unwrap();
    assert_eq!(back, r);
    assert_eq!(back.files[0].path, "planned.csv");
    assert_eq!(back.files[0].bytes, 8);
    assert_eq!(
        back.steady_summary().collect::<Vec<_>>(),
        ["planned duration      12.000 s"]
    );
    assert!(back.machine.unchanged_on_disk().unwrap());

    let (machine, job_copy) = back.restore_inputs(&dir.join("inputs")).unwrap();
    let restored = MachineFile::load(&machine).unwrap();
    assert_eq!(restored.name, cfg.name);
    assert_eq!(
        std::fs::read_to_string(restored.bed_mesh_path().unwrap()).unwrap(),
        mesh.text
    );
    assert_eq!(
        std::fs::read(job_copy.unwrap()).unwrap(),
        std::fs::read(&job).unwrap()
    );
}

#[test]
fn runs_are_found_oldest_first_and_bad_records_are_named_not_skipped() {
    let dir = temp_dir("find");
    let (path, cfg) = mill();
    for (name, wall) in [
        ("b", "2026-11-29T10:00:00.000Z"),
        ("a", "2026-11-29T11:00:00.000Z"),
    ] {
        let mut r = RunRecord::start("run", &path, &cfg, host()).unwrap();
        r.started.wall = wall.into();
        r.write(&dir.join(name).join(RUN_FILE)).unwrap();
    }
    let mut beside = RunRecord::start("capture", &path, &cfg, host()).unwrap();
    beside.started.wall = "2026-11-29T12:00:00.000Z".into();
    beside.write(&dir.join("cap.parquet.run.json")).unwrap();
    std::fs::create_dir_all(dir.join("broken")).unwrap();
    std::fs::write(dir.join("broken").join(RUN_FILE), "{\"format\": 3}").unwrap();
    std::fs::create_dir_all(dir.join("not-a-run")).unwrap();

    let runs = find_runs(&dir).unwrap();
    assert_eq!(runs.len(), 4, "{runs:?}");
    assert!(runs[0].record.is_err(), "an unreadable record sorts first");
    let order: Vec<String> = runs[1..]
        .iter()
        .map(|r| r.record.as_ref().unwrap().started.wall.clone())
        .collect();
    assert_eq!(
        order,
        [
            "2026-11-29T10:00:00.000Z",
            "2026-11-29T11:00:00.000Z",
            "2026-11-29T12:00:00.000Z"
        ]
    );
    assert_eq!(
        record_path(&dir.join("cap.parquet")),
        dir.join("cap.parquet.run.json")
    );
}

#[test]
fn a_record_of_another_format_or_version_is_refused_by_name() {
    let dir = temp_dir("version");
    let (path, cfg) = mill();
    let mut r = RunRecord::start("run", &path, &cfg, host()).unwrap();
    r.version = RUN_VERSION + 1;
    r.write(&dir.join(RUN_FILE)).unwrap();
    let e = RunRecord::read(&dir).unwrap_err().to_string();
    assert!(e.contains("not an osap run record"), "{e}");
    assert!(e.contains(&format!("version {}", RUN_VERSION + 1)), "{e}");
}

#[test]
fn a_mesh_outside_the_machine_files_folder_is_not_restored_silently() {
    let dir = temp_dir("outside");
    let (path, cfg) = mill();
    let mut r = RunRecord::start("run", &path, &cfg, host()).unwrap();
    r.machine_inputs.get_mut("bed_mesh").unwrap().path = "../elsewhere/mesh.toml".into();
    let e = r.restore_inputs(&dir).unwrap_err().to_string();
    assert!(e.contains("outside its folder"), "{e}");
}
