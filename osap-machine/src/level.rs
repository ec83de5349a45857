//! Bed levelling (`osap level`): probe a grid of points on the bed, fit
//! maxl's [`BedMesh`] to them, save it to the file the machine file names
//! (`bed_mesh`), and plot it.
//!
//! The machine file describes the probe (`[probe]`, [`Probe`]) and, for
//! simulation, the bed it touches (`[sim.bed]`, a [`BedSurface`]):
//!
//! ```toml
//! [probe]
//! module = "z"               # the module whose limit input the probe is on
//! offset = [0.0, 0.0, 0.0]   # probe tip relative to the tool tip (x, y, z)
//! grid = [5, 4]              # probe points along x and along y (each ≥ 2)
//! margin = 20.0              # outer points this far inside the x-y travel
//! start_z = -60.0            # each search starts at this z (above the bed)
//! search_depth = 20.0        # and gives up this far below it
//! search_speed = 2.0         # z speed while searching (units/s)
//! travel_speed = 40.0        # speed between points (units/s)
//!
//! [sim.bed]                  # simulation only: the bed the probe touches
//! z = -70.0                  # height at the middle of the x-y travel
//! tilt_x = 0.001             # slope along x (units per unit)
//! tilt_y = -0.0015           # slope along y
//! warp = 0.15                # dome height at the middle (negative: a dish)
//! # center = [150.0, 100.0]  # where the bed's middle is (default: the
//! # half = [150.0, 100.0]    # travel's middle, half the travel's size)
//! ```
//!
//! Each point: lift to `start_z`, move over the point, search down at
//! `search_speed` until the probe's module reports its input pressed. The
//! trigger's height is the machine z at the edge's own time stamp (from
//! the samples the motors were sent, as in homing), plus the probe's z
//! offset. The mesh holds the heights relative to their mean (printed and
//! written in the mesh file): after levelling, z = mean + h puts the tool
//! `h` above the bed everywhere.

use std::path::Path;

use maxl::blocks::bedlevel::{
    BedError, BedMesh, MeshGrid, MeshStats, Plane, PlaneFit, Probe as PlaneProbe,
};

use crate::machine::{Machine, MachineError};

pub use crate::config::Probe;
pub use maxl::bed::BedSurface;

/// One probed point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProbePoint {
    /// Grid column.
    pub ix: usize,
    /// Grid row.
    pub iy: usize,
    /// Where the probe tip touched, x.
    pub x: f64,
    /// Where the probe tip touched, y.
    pub y: f64,
    /// The bed's height there (machine z of the probe tip at the trigger).
    pub z: f64,
    /// The trigger's synchronized time (the module's stamp), µs.
    pub time: u64,
}

/// What levelling found.
#[derive(Debug, Clone)]
pub struct Levelled {
    /// Every probed point, in probing order.
    pub points: Vec<ProbePoint>,
    /// The mean probed height: the mesh's heights are relative to it.
    pub reference: f64,
    /// The mesh: heights relative to `reference`.
    pub mesh: BedMesh,
    /// Its statistics (min, max, mean 0, rms unflatness).
    pub stats: MeshStats,
    /// The least-squares plane through the points (the bed's tilt), with
    /// its residuals (what a plane alone would leave: the warp).
    pub plane: PlaneFit,
}

/// Probes the bed on the grid `[probe]` gives and fits a mesh. The machine
/// must be homed. Probing runs on a flat machine (any mesh in force is
/// dropped meanwhile); on success the machine follows the new mesh, on
/// failure the mesh it had. `progress` is called after each point with it
/// and the number of points.
pub async fn level(
    machine: &Machine,
    mut progress: impl FnMut(&ProbePoint, usize),
) -> Result<Levelled, MachineError> {
    let cfg = machine.config().clone();
    let probe = cfg.probe.clone().ok_or_else(|| {
        MachineError::Unsupported(
            "no [probe] section: describe the probe (module, grid, start_z, search_depth, speeds) to level the bed".into(),
        )
    })?;
    let grid = probe
        .grid(&cfg)
        .map_err(|e| MachineError::Unsupported(e.to_string()))?;
    let axes = machine.axes();
    if let Some((a, _)) = axes.iter().zip(machine.homed()).find(|(_, homed)| !homed) {
        return Err(MachineError::NotHomed(a.clone()));
    }
    let previous = machine.bed_mesh();
    machine.set_bed_mesh(None).await?;
    let result = probe_grid(machine, &probe, &grid, &mut progress).await;
    match result {
        Ok(levelled) => {
            machine.set_bed_mesh(Some(levelled.mesh.clone())).await?;
            Ok(levelled)
        }
        Err(e) => {
            // Best effort: the machine may have faulted.
            let _ = machine.set_bed_mesh(previous).await;
            Err(e)
        }
    }
}

async fn probe_grid(
    machine: &Machine,
    probe: &Probe,
    grid: &MeshGrid,
    progress: &mut impl FnMut(&ProbePoint, usize),
) -> Result<Levelled, MachineError> {
    let [ox, oy, oz] = probe.offset;
    let total = grid.nx * grid.ny;
    let mut points = Vec::with_capacity(total);
    for iy in 0..grid.ny {
        // Serpentine: the next point is always a neighbour.
        for j in 0..grid.nx {
            let ix = if iy % 2 == 0 { j } else { grid.nx - 1 - j };
            let (px, py) = grid.node(ix, iy);
            let name = format!("point ({ix}, {iy}) at x = {px:.2}, y = {py:.2}");
            let here = machine.position();
            // Up first, then across: never drag the tip over the bed.
            if here[2] < probe.start_z {
                machine
                    .goto_now([here[0], here[1], probe.start_z], probe.travel_speed)
                    .await?;
            }
            machine
                .goto_now([px - ox, py - oy, probe.start_z], probe.travel_speed)
                .await?;
            if machine.switch_pressed(&probe.module) {
                return Err(MachineError::Probe {
                    point: name,
                    reason: format!(
                        "the probe on module {} reads pressed at the start height z = {}; raise [probe] start_z above the bed, or check the probe's wiring",
                        probe.module, probe.start_z
                    ),
                });
            }
            let Some((time, at)) = machine
                .probe_down(&probe.module, probe.search_depth, probe.search_speed)
                .await?
            else {
                return Err(MachineError::Probe {
                    point: name,
                    reason: format!(
                        "the probe on module {} never triggered: z searched {} down from {} to {} and stopped there; lower [probe] start_z or search deeper (search_depth), and check the probe's wiring",
                        probe.module,
                        probe.search_depth,
                        probe.start_z,
                        probe.start_z - probe.search_depth
                    ),
                });
            };
            let point = ProbePoint {
                ix,
                iy,
                x: at[0] + ox,
                y: at[1] + oy,
                z: at[2] + oz,
                time,
            };
            points.push(point);
            progress(&point, total);
        }
    }
    let here = machine.position();
    machine
        .goto_now([here[0], here[1], probe.start_z], probe.travel_speed)
        .await?;
    fit(grid, &points).map_err(|e| MachineError::Unsupported(e.to_string()))
}

/// Why levelling could not fit or plot its mesh.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum LevelError {
    /// No points were probed.
    #[error("no probe points")]
    NoPoints,
    /// A point the mesh refused (off the grid, or not finite).
    #[error("point ({ix}, {iy}): {cause}")]
    Point {
        /// Its column.
        ix: usize,
        /// Its row.
        iy: usize,
        /// Why.
        cause: BedError,
    },
    /// The mesh's statistics (a node left unprobed).
    #[error("the mesh: {0}")]
    Mesh(BedError),
    /// The plane through the points (too few, or all in a line).
    #[error("the plane through the points: {0}")]
    Plane(BedError),
    /// Drawing the plot failed.
    #[error("plotting {path}: {message}")]
    Plot {
        /// The plot's path.
        path: String,
        /// The plotting library's message.
        message: String,
    },
}

/// Fits the mesh to probed points on `grid` (one per node): heights
/// relative to their mean, and the plane through them.
pub fn fit(grid: &MeshGrid, points: &[ProbePoint]) -> Result<Levelled, LevelError> {
    if points.is_empty() {
        return Err(LevelError::NoPoints);
    }
    let reference = points.iter().map(|p| p.z).sum::<f64>() / points.len() as f64;
    let mut mesh = BedMesh::new(*grid);
    for p in points {
        mesh.set_probe(p.ix, p.iy, p.z - reference)
            .map_err(|cause| LevelError::Point {
                ix: p.ix,
                iy: p.iy,
                cause,
            })?;
    }
    let stats = mesh.stats().map_err(LevelError::Mesh)?;
    let probes: Vec<PlaneProbe> = points
        .iter()
        .map(|p| PlaneProbe::new(p.x, p.y, p.z))
        .collect();
    let plane = Plane::fit(&probes).map_err(LevelError::Plane)?;
    Ok(Levelled {
        points: points.to_vec(),
        reference,
        mesh,
        stats,
        plane,
    })
}

/// Saves the mesh to `path` (the format of [`crate::mesh`]), with a header
/// saying what it is relative to and `fitted_from`, the run record of the
/// probing (`osap level` writes `FILE.run.json`).
pub fn save(
    levelled: &Levelled,
    path: &Path,
    fitted_from: Option<&str>,
) -> Result<(), crate::mesh::MeshError> {
    let header = format!(
        "Bed mesh probed by `osap level`: {} points. Heights are relative to\n\
         the bed's mean probed height, machine z = {:.4}: after levelling, z =\n\
         {:.4} + h puts the tool h above the bed. Unflatness (rms) {:.4},\n\
         range {:.4} to {:.4}.",
        levelled.points.len(),
        levelled.reference,
        levelled.reference,
        levelled.stats.rms,
        levelled.stats.min,
        levelled.stats.max,
    );
    crate::mesh::save(path, &levelled.mesh, &header, fitted_from)
}

/// Plots the mesh as a heat map (SVG): the bilinear surface coloured by
/// height, the probe points marked, and a colour scale (feature `plot`).
#[cfg(feature = "plot")]
pub fn plot(levelled: &Levelled, path: &Path) -> Result<(), LevelError> {
    use plotters::prelude::*;
    let g = levelled.mesh.grid();
    let (x0, y0) = g.node(0, 0);
    let (x1, y1) = g.node(g.nx - 1, g.ny - 1);
    let (lo, hi) = (levelled.stats.min, levelled.stats.max);
    let span = (hi - lo).max(1e-9);
    let colour = |h: f64| {
        let t = ((h - lo) / span).clamp(0.0, 1.0);
        // Blue (low) through white to red (high).
        let (r, g, b) = if t < 0.5 {
            let u = t * 2.0;
            (u, u, 1.0)
        } else {
            let u = (1.0 - t) * 2.0;
            (1.0, u, u)
        };
        RGBColor((r * 255.0) as u8, (g * 255.0) as u8, (b * 255.0) as u8)
    };
    let err = |e: &dyn std::fmt::Display| LevelError::Plot {
        path: path.display().to_string(),
        message: e.to_string(),
    };
    let root = SVGBackend::new(path, (900, 620)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let (main, bar) = root.split_horizontally(780);
    let mut chart = ChartBuilder::on(&main)
        .caption(
            format!(
                "bed mesh: heights relative to z = {:.3} (range {:.3} .. {:.3})",
                levelled.reference, lo, hi
            ),
            ("sans-serif", 18),
        )
        .margin(10)
        .x_label_area_size(35)
        .y_label_area_size(50)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(|e| err(&e))?;
    chart
        .configure_mesh()
        .x_desc("x")
        .y_desc("y")
        .disable_mesh()
        .draw()
        .map_err(|e| err(&e))?;
    const CELLS: usize = 60;
    let (cw, ch) = ((x1 - x0) / CELLS as f64, (y1 - y0) / CELLS as f64);
    let mut cells = Vec::with_capacity(CELLS * CELLS);
    for i in 0..CELLS {
        for j in 0..CELLS {
            let (cx, cy) = (x0 + (i as f64 + 0.5) * cw, y0 + (j as f64 + 0.5) * ch);
            let h = levelled.mesh.correction(cx, cy).unwrap_or(0.0);
            cells.push(Rectangle::new(
                [
                    (x0 + i as f64 * cw, y0 + j as f64 * ch),
                    (x0 + (i + 1) as f64 * cw, y0 + (j + 1) as f64 * ch),
                ],
                colour(h).filled(),
            ));
        }
    }
    chart.draw_series(cells).map_err(|e| err(&e))?;
    chart
        .draw_series(
            levelled
                .points
                .iter()
                .map(|p| Circle::new((p.x, p.y), 4, BLACK.filled())),
        )
        .map_err(|e| err(&e))?;
    chart
        .draw_series(levelled.points.iter().map(|p| {
            Text::new(
                format!("{:+.3}", p.z - levelled.reference),
                (p.x, p.y),
                ("sans-serif", 12).into_font(),
            )
        }))
        .map_err(|e| err(&e))?;
    // The colour scale.
    let mut scale = ChartBuilder::on(&bar)
        .margin(10)
        .margin_top(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..1.0, lo..(lo + span))
        .map_err(|e| err(&e))?;
    scale
        .configure_mesh()
        .disable_x_axis()
        .disable_mesh()
        .y_label_style(("sans-serif", 13))
        .axis_desc_style(("sans-serif", 14))
        .y_desc("height")
        .draw()
        .map_err(|e| err(&e))?;
    const STEPS: usize = 50;
    scale
        .draw_series((0..STEPS).map(|k| {
            let a = lo + span * k as f64 / STEPS as f64;
            let b = lo + span * (k + 1) as f64 / STEPS as f64;
            Rectangle::new([(0.0, a), (1.0, b)], colour((a + b) / 2.0).filled())
        }))
        .map_err(|e| err(&e))?;
    root.present().map_err(|e| err(&e))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::MachineFile;

    fn mill() -> MachineFile {
        let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("../examples/machines/mill.toml");
        MachineFile::load(path).unwrap()
    }

    #[test]
    fn the_mill_probes_a_grid_inside_its_travel() {
        let cfg = mill();
        let p = cfg.probe.as_ref().unwrap();
        let g = p.grid(&cfg).unwrap();
        assert_eq!((g.nx, g.ny), (p.grid[0], p.grid[1]));
        let (x0, y0) = g.node(0, 0);
        let (x1, y1) = g.node(g.nx - 1, g.ny - 1);
        assert!((x0 - p.margin).abs() < 1e-9 && (x1 - (300.0 - p.margin)).abs() < 1e-9);
        assert!((y0 - p.margin).abs() < 1e-9 && (y1 - (200.0 - p.margin)).abs() < 1e-9);
    }

    #[test]
    fn bad_probes_and_beds_say_why() {
        let text = std::fs::read_to_string(
            std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
                .join("../examples/machines/mill.toml"),
        )
        .unwrap();
        let bad = |from: &str, to: &str| {
            assert!(text.contains(from), "{from}");
            let e = MachineFile::parse(&text.replacen(from, to, 1)).unwrap_err();
            e.to_string()
        };
        let e = bad("grid = [5, 4]", "grid = [1, 4]");
        assert!(e.contains("probe.grid[0]"), "{e}");
        let e = bad("search_depth = 7.0", "search_depth = 200.0");
        assert!(e.contains("probe.start_z"), "{e}");
        let e = bad(
            "module = \"z\"                 # the module whose limit",
            "module = \"w\"                 # the module whose limit",
        );
        assert!(e.contains("probe.module"), "{e}");
        let e = bad("tilt_x = 0.001", "tilt_x = 0.5");
        assert!(e.contains("sim.bed.tilt_x"), "{e}");
        let e = bad("margin = 20.0", "margin = 150.0");
        assert!(e.contains("margin"), "{e}");
        let e = bad("tilt_x = 0.001", "tilt_x = 0.001\nhalf = [0.0, 100.0]");
        assert!(e.contains("sim.bed.half[0]"), "{e}");
    }

    #[test]
    fn the_bed_lies_under_the_travel_unless_placed() {
        let text = std::fs::read_to_string(
            std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
                .join("../examples/machines/mill.toml"),
        )
        .unwrap();
        let bed = |text: &str| MachineFile::parse(text).unwrap().sim.unwrap().bed.unwrap();
        let cfg = MachineFile::parse(&text).unwrap();
        let (x, y) = (&cfg.axes["x"], &cfg.axes["y"]);
        let placed = bed(&text);
        assert_eq!(
            placed.center,
            [(x.min + x.max) / 2.0, (y.min + y.max) / 2.0]
        );
        assert_eq!(placed.half, [(x.max - x.min) / 2.0, (y.max - y.min) / 2.0]);
        // A bed placed by the file keeps its place; the rest still comes
        // from the travel.
        let own = bed(&text.replacen("tilt_x = 0.001", "tilt_x = 0.001\ncenter = [40.0, 30.0]", 1));
        assert_eq!(own.center, [40.0, 30.0]);
        assert_eq!(own.half, placed.half);
        assert!((own.height(40.0, 30.0) - (own.z + own.warp)).abs() < 1e-12);
    }

    #[test]
    fn a_fit_is_relative_to_the_mean_and_finds_the_tilt() {
        let g = MeshGrid::new(0.0, 0.0, 10.0, 10.0, 3, 2).unwrap();
        let mut points = Vec::new();
        for iy in 0..2 {
            for ix in 0..3 {
                let (x, y) = g.node(ix, iy);
                let z = -70.0 + 0.01 * x - 0.02 * y;
                points.push(ProbePoint {
                    ix,
                    iy,
                    x,
                    y,
                    z,
                    time: 0,
                });
            }
        }
        let l = fit(&g, &points).unwrap();
        assert!((l.reference - (-70.0 + 0.1 - 0.1)).abs() < 1e-9);
        assert!(l.stats.mean.abs() < 1e-9);
        assert!((l.plane.plane.a - 0.01).abs() < 1e-9);
        assert!((l.plane.plane.b + 0.02).abs() < 1e-9);
        assert!(l.plane.max_residual < 1e-9);
        let dir = std::env::temp_dir().join(format!("osap-level-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mesh = dir.join("mesh.toml");
        save(&l, &mesh, None).unwrap();
        let back = crate::mesh::load(&mesh).unwrap();
        assert!(
            (back.correction(20.0, 10.0).unwrap() - l.mesh.correction(20.0, 10.0).unwrap()).abs()
                < 1e-6
        );
        #[cfg(feature = "plot")]
        {
            plot(&l, &dir.join("mesh.svg")).unwrap();
            assert!(std::fs::read_to_string(dir.join("mesh.svg"))
                .unwrap()
                .contains("<svg"));
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
}
