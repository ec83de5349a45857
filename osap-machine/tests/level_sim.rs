//! Bed levelling on the simulated mill, in virtual time: the probe (a
//! switch on the z module's limit input) touches a tilted, warped
//! simulated bed (`[sim.bed]` in mill.toml); `level` probes the grid, fits
//! a mesh, and a following job keeps the tool at its height above the
//! real (simulated) bed.

use std::time::Duration;

use osap_machine::config::MachineFile;
use osap_machine::level;
use osap_machine::machine::SimOptions;
use osap_machine::sim::axis_form;
use osap_machine::{Machine, MachineError};
use osap_sim::machine::{virtual_runtime, TimeMode};

fn mill() -> MachineFile {
    let mut cfg = MachineFile::load(format!(
        "{}/../examples/machines/mill.toml",
        env!("CARGO_MANIFEST_DIR")
    ))
    .unwrap();
    // Start flat: the example's mesh is for another bed.
    cfg.bed_mesh = None;
    cfg
}

async fn start(cfg: &MachineFile) -> Machine {
    Machine::simulate_with(
        cfg,
        SimOptions {
            time: TimeMode::Virtual,
        },
    )
    .await
    .unwrap()
}

/// Where the simulated tool tip really is (x, y, z), from the motors'
/// steps, and the simulated bed's height under it.
fn tip_and_bed(m: &Machine, cfg: &MachineFile) -> ([f64; 3], f64) {
    let bed = cfg.sim.as_ref().unwrap().bed.as_ref().unwrap();
    let surface = bed.surface(cfg).unwrap();
    let mut p = [0.0; 3];
    for (k, axis) in ["x", "y", "z"].iter().enumerate() {
        let form = axis_form(cfg, axis).unwrap();
        p[k] = m
            .with_sim(|s| {
                form.value(|module| {
                    s.module(module)
                        .and_then(|sm| sm.module())
                        .map_or(f64::NAN, |sm| sm.lock(|mm| mm.board().motor().position()))
                })
            })
            .unwrap();
    }
    (p, surface.height(p[0], p[1]))
}

/// A job across the bed at `z`: a zigzag over the probed area. Returns the
/// lowest and highest tool height above the simulated bed, sampled every
/// millisecond (virtual time) while it runs.
async fn zigzag(m: &Machine, cfg: &MachineFile, z: f64) -> (f64, f64) {
    m.goto_now([30.0, 30.0, z], 20.0).await.unwrap();
    let moves = [
        [270.0, 30.0],
        [270.0, 70.0],
        [30.0, 70.0],
        [30.0, 110.0],
        [270.0, 110.0],
        [270.0, 150.0],
        [30.0, 150.0],
        [150.0, 100.0],
        [270.0, 170.0],
    ];
    for [x, y] in moves {
        m.goto_via_queue([x, y, z], 40.0).await.unwrap();
    }
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    let idle = m.idle();
    tokio::pin!(idle);
    loop {
        let (tip, bed) = tip_and_bed(m, cfg);
        lo = lo.min(tip[2] - bed);
        hi = hi.max(tip[2] - bed);
        tokio::select! {
            r = &mut idle => { r.unwrap(); break; }
            _ = tokio::time::sleep(Duration::from_millis(1)) => {}
        }
    }
    (lo, hi)
}

#[test]
fn after_levelling_the_tool_follows_the_bed_within_0_05_mm() {
    virtual_runtime().unwrap().block_on(async {
        let cfg = mill();
        let m = start(&cfg).await;
        m.home().await.unwrap();
        // Unlevelled, at 0.5 mm above the bed's middle: the tool height
        // follows the bed's tilt and warp.
        let bed = cfg.sim.as_ref().unwrap().bed.clone().unwrap();
        let (lo0, hi0) = zigzag(&m, &cfg, bed.z + bed.warp + 0.5).await;
        assert!(hi0 - lo0 > 0.3, "unlevelled: {lo0}..{hi0}");

        let mut seen = 0;
        let l = level::level(&m, |_, total| {
            seen += 1;
            assert_eq!(total, 20);
        })
        .await
        .unwrap();
        assert_eq!(seen, 20);
        // Each probed height is the simulated bed's under the probe, to
        // within a few z steps (80 × 4 per mm: 3.1 µm).
        let surface = bed.surface(&cfg).unwrap();
        let worst = l
            .points
            .iter()
            .map(|p| (p.z - surface.height(p.x, p.y)).abs())
            .fold(0.0, f64::max);
        assert!(worst < 0.02, "probe error {worst}");
        // The plane through the points is the bed's tilt.
        assert!((l.plane.plane.a - bed.tilt_x).abs() < 2e-4, "{:?}", l.plane);
        assert!((l.plane.plane.b - bed.tilt_y).abs() < 2e-4, "{:?}", l.plane);
        assert!(m.bed_mesh().is_some());

        // Levelled: 0.5 mm above the bed everywhere.
        let h = 0.5;
        let (lo, hi) = zigzag(&m, &cfg, l.reference + h).await;
        println!(
            "unlevelled height {lo0:.4}..{hi0:.4} mm; levelled {lo:.4}..{hi:.4} mm (target {h}); probe error {worst:.4} mm; plane a {:.5} b {:.5}",
            l.plane.plane.a, l.plane.plane.b
        );
        assert!(
            (lo - h).abs() <= 0.05 && (hi - h).abs() <= 0.05,
            "levelled height {lo}..{hi}, target {h}"
        );

        // Saved and read back, it is the same mesh.
        let dir = std::env::temp_dir().join(format!("osap-level-sim-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("mesh.toml");
        level::save(&l, &path).unwrap();
        let back = osap_machine::mesh::load(&path).unwrap();
        for p in &l.points {
            let a = back.correction(p.x, p.y).unwrap();
            let b = l.mesh.correction(p.x, p.y).unwrap();
            assert!((a - b).abs() < 1e-4, "{a} {b}");
        }
        level::plot(&l, &dir.join("mesh.svg")).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
    });
}

#[test]
fn a_probe_that_never_triggers_stops_at_its_search_limit() {
    virtual_runtime().unwrap().block_on(async {
        let mut cfg = mill();
        // The bed sits below the search: start_z - search_depth = -74.
        cfg.sim.as_mut().unwrap().bed.as_mut().unwrap().z = -78.0;
        let m = start(&cfg).await;
        m.home().await.unwrap();
        let e = level::level(&m, |_, _| {}).await.unwrap_err();
        let text = e.to_string();
        assert!(matches!(e, MachineError::Probe { .. }), "{text}");
        assert!(text.contains("point (0, 0)"), "{text}");
        assert!(text.contains("never triggered"), "{text}");
        assert!(text.contains("-74"), "{text}");
        // The axis stopped at the search's end, not past it.
        let z = m.position()[2];
        assert!((z - -74.0).abs() < 1e-6, "z {z}");
        assert!(m.bed_mesh().is_none());
    });
}
