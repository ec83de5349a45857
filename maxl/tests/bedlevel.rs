//! Bed levelling: plane recovery and residuals, mesh interpolation and edge
//! clamping, bad input and not-ready errors, the PIPES wire API.

mod common;

use maxl::blocks::bedlevel::{
    BedError, BedMesh, BedMeshBlock, BedPlane, BedPlaneBlock, MeshGrid, Plane, Probe,
    FAIL_BAD_PARAMETER, FAIL_COLLINEAR, FAIL_NON_FINITE, FAIL_NOT_READY, FAIL_OUT_OF_GRID,
    FAIL_OVERFLOW, FAIL_TOO_FEW_POINTS, MAX_PROBES,
};
use pipes_core::class::PipesClass;
use pipes_core::function::CallError;
use pipes_core::Value;
use proptest::prelude::*;

fn tilted(x: f64, y: f64) -> f64 {
    0.002 * x - 0.0013 * y + 0.35
}

#[test]
fn fit_recovers_a_tilted_plane_exactly() {
    let mut bed = BedPlane::new();
    for (x, y) in [
        (10.0, 10.0),
        (200.0, 15.0),
        (190.0, 210.0),
        (20.0, 200.0),
        (105.0, 110.0),
    ] {
        bed.add_probe(Probe::new(x, y, tilted(x, y))).unwrap();
    }
    let fit = bed.fit().unwrap();
    assert!((fit.plane.a - 0.002).abs() < 1e-15, "{fit:?}");
    assert!((fit.plane.b + 0.0013).abs() < 1e-15, "{fit:?}");
    assert!((fit.plane.c - 0.35).abs() < 1e-13, "{fit:?}");
    assert!(fit.rms < 1e-14 && fit.max_residual < 1e-14, "{fit:?}");
    assert_eq!(fit.points, 5);
    let z = bed.apply(50.0, 60.0, 1.0).unwrap();
    assert!((z - (1.0 + tilted(50.0, 60.0))).abs() < 1e-13);
    assert!((bed.unapply(50.0, 60.0, z).unwrap() - 1.0).abs() < 1e-13);
}

#[test]
fn fit_far_from_the_origin_stays_exact() {
    // Centring keeps a bed at (10 km, −5 km) as well conditioned as one at 0.
    let probes: Vec<_> = [(0.0, 0.0), (300.0, 0.0), (0.0, 300.0), (300.0, 300.0)]
        .iter()
        .map(|&(x, y)| {
            let (x, y) = (x + 1e4, y - 5e3);
            Probe::new(x, y, 1e-4 * x + 3e-4 * y - 1.0)
        })
        .collect();
    let fit = Plane::fit(&probes).unwrap();
    assert!((fit.plane.a - 1e-4).abs() < 1e-15 && (fit.plane.b - 3e-4).abs() < 1e-15);
    assert!(fit.max_residual < 1e-12, "{fit:?}");
}

#[test]
fn fit_residuals_are_reported() {
    // Four corners of a square, two raised by 0.1 diagonally: the best plane
    // is flat at 0.05 and every residual is ±0.05.
    let probes = [
        Probe::new(0.0, 0.0, 0.1),
        Probe::new(1.0, 0.0, 0.0),
        Probe::new(0.0, 1.0, 0.0),
        Probe::new(1.0, 1.0, 0.1),
    ];
    let fit = Plane::fit(&probes).unwrap();
    assert!(fit.plane.a.abs() < 1e-15 && fit.plane.b.abs() < 1e-15);
    assert!((fit.plane.c - 0.05).abs() < 1e-15);
    assert!((fit.rms - 0.05).abs() < 1e-15 && (fit.max_residual - 0.05).abs() < 1e-15);
}

#[test]
fn fit_refuses_too_few_collinear_and_non_finite_probes() {
    let p = |x, y| Probe::new(x, y, 0.1);
    assert_eq!(Plane::fit(&[]), Err(BedError::TooFewPoints(0)));
    assert_eq!(
        Plane::fit(&[p(0.0, 0.0), p(1.0, 1.0)]),
        Err(BedError::TooFewPoints(2))
    );
    assert_eq!(
        Plane::fit(&[p(0.0, 0.0), p(1.0, 1.0), p(2.0, 2.0), p(-5.0, -5.0)]),
        Err(BedError::Collinear)
    );
    assert_eq!(
        Plane::fit(&[p(3.0, 4.0), p(3.0, 4.0), p(3.0, 4.0)]),
        Err(BedError::Collinear)
    );
    assert_eq!(
        Plane::fit(&[p(0.0, 0.0), p(1.0, 0.0), Probe::new(0.0, 1.0, f64::NAN)]),
        Err(BedError::NonFinite)
    );
    // Finite but so large that centring overflows: an error, not a hang.
    assert_eq!(
        Plane::fit(&[p(-1.7e308, 0.0), p(1.7e308, 1.0), p(1.7e308, -1.0)]),
        Err(BedError::Overflow)
    );
    let mut bed = BedPlane::new();
    assert_eq!(
        bed.add_probe(Probe::new(f64::INFINITY, 0.0, 0.0)),
        Err(BedError::NonFinite)
    );
    assert_eq!(bed.apply(0.0, 0.0, 0.0), Err(BedError::NotFitted));
    for i in 0..MAX_PROBES {
        bed.add_probe(Probe::new(i as f64, (i % 7) as f64, 0.0))
            .unwrap();
    }
    assert_eq!(
        bed.add_probe(Probe::new(0.0, 0.0, 0.0)),
        Err(BedError::TooManyProbes)
    );
}

#[test]
fn a_failed_fit_keeps_the_previous_plane() {
    let mut bed = BedPlane::new();
    bed.set_plane(Plane::new(0.0, 0.0, 0.2).unwrap());
    bed.add_probe(Probe::new(0.0, 0.0, 1.0)).unwrap();
    assert_eq!(bed.fit(), Err(BedError::TooFewPoints(1)));
    assert_eq!(bed.apply(5.0, 5.0, 1.0), Ok(1.2));
    assert_eq!(bed.apply(5.0, f64::NAN, 1.0), Err(BedError::NonFinite));
    assert_eq!(bed.apply(5.0, 5.0, f64::NAN), Err(BedError::NonFinite));
}

fn mesh_3x2() -> BedMesh {
    // Columns at x = 10, 20, 30; rows at y = 0, 5.
    let mut m = BedMesh::new(MeshGrid::new(10.0, 0.0, 10.0, 5.0, 3, 2).unwrap());
    let heights = [[0.0, 0.2, 0.1], [0.4, 0.0, -0.3]];
    for (iy, row) in heights.iter().enumerate() {
        for (ix, z) in row.iter().enumerate() {
            m.set_probe(ix, iy, *z).unwrap();
        }
    }
    m
}

#[test]
fn mesh_reproduces_nodes_and_interpolates_bilinearly() {
    let m = mesh_3x2();
    let heights = [[0.0, 0.2, 0.1], [0.4, 0.0, -0.3]];
    for (iy, row) in heights.iter().enumerate() {
        for (ix, z) in row.iter().enumerate() {
            let (x, y) = m.grid().node(ix, iy);
            assert_eq!(m.correction(x, y), Ok(*z), "node ({ix}, {iy})");
        }
    }
    // Cell centre: mean of the four corners.
    let c = m.correction(15.0, 2.5).unwrap();
    assert!((c - (0.0 + 0.2 + 0.4 + 0.0) / 4.0).abs() < 1e-15);
    // Along an edge: linear between two nodes.
    let c = m.correction(27.5, 0.0).unwrap();
    assert!((c - (0.25 * 0.2 + 0.75 * 0.1)).abs() < 1e-15);
    // A general point in the second cell, by the bilinear formula.
    let (fx, fy) = (0.3, 0.6);
    let want = (1.0 - fy) * ((1.0 - fx) * 0.2 + fx * 0.1) + fy * ((1.0 - fx) * 0.0 + fx * -0.3);
    let c = m.correction(23.0, 3.0).unwrap();
    assert!((c - want).abs() < 1e-15, "{c} vs {want}");
    assert!((m.apply(23.0, 3.0, 2.0).unwrap() - (2.0 + want)).abs() < 1e-15);
    assert!((m.unapply(23.0, 3.0, 2.0 + want).unwrap() - 2.0).abs() < 1e-15);
    let s = m.stats().unwrap();
    assert_eq!((s.min, s.max), (-0.3, 0.4));
    assert!((s.mean - 0.4 / 6.0).abs() < 1e-15);
}

#[test]
fn mesh_clamps_outside_the_grid() {
    let m = mesh_3x2();
    // Left of the grid: the left edge's value at the same y.
    assert_eq!(m.correction(-100.0, 0.0), m.correction(10.0, 0.0));
    assert_eq!(m.correction(0.0, 2.5), m.correction(10.0, 2.5));
    // Beyond a corner: that corner's height.
    assert_eq!(m.correction(1e6, 1e6), Ok(-0.3));
    assert_eq!(m.correction(-1e6, -1e6), Ok(0.0));
    // Above the top edge between nodes: the top edge, linear in x.
    let c = m.correction(25.0, 50.0).unwrap();
    assert!((c - (0.0 - 0.3) / 2.0).abs() < 1e-15);
}

#[test]
fn mesh_refuses_incomplete_bad_and_out_of_grid_input() {
    let grid = MeshGrid::new(0.0, 0.0, 10.0, 10.0, 2, 2).unwrap();
    let mut m = BedMesh::new(grid);
    assert_eq!(m.correction(0.0, 0.0), Err(BedError::MeshIncomplete(4)));
    assert_eq!(m.set_probe(0, 0, 0.1), Ok(3));
    assert_eq!(
        m.set_probe(0, 0, 0.2),
        Ok(3),
        "re-probing a node replaces it"
    );
    assert_eq!(
        m.set_probe(2, 0, 0.1),
        Err(BedError::OutOfGrid { ix: 2, iy: 0 })
    );
    assert_eq!(m.set_probe(0, 1, f64::NAN), Err(BedError::NonFinite));
    assert_eq!(m.apply(0.0, 0.0, 0.0), Err(BedError::MeshIncomplete(3)));
    assert_eq!(m.stats(), Err(BedError::MeshIncomplete(3)));
    for (ix, iy) in [(1, 0), (0, 1), (1, 1)] {
        m.set_probe(ix, iy, 0.0).unwrap();
    }
    assert_eq!(m.probe(0, 0), Some(0.2));
    assert_eq!(m.apply(0.0, 0.0, 1.0), Ok(1.2));
    assert_eq!(m.apply(f64::NAN, 0.0, 1.0), Err(BedError::NonFinite));
    assert_eq!(m.apply(0.0, 0.0, f64::INFINITY), Err(BedError::NonFinite));
    m.clear();
    assert_eq!(m.apply(0.0, 0.0, 1.0), Err(BedError::MeshIncomplete(4)));
    // Heights whose mean overflows: stats refuse instead of reporting ∞.
    for (ix, iy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
        m.set_probe(ix, iy, 1.5e308).unwrap();
    }
    assert_eq!(m.stats(), Err(BedError::Overflow));
    for bad in [
        MeshGrid::new(f64::NAN, 0.0, 1.0, 1.0, 2, 2),
        MeshGrid::new(0.0, 0.0, 0.0, 1.0, 2, 2),
        MeshGrid::new(0.0, 0.0, 1.0, -1.0, 2, 2),
        MeshGrid::new(0.0, 0.0, 1.0, 1.0, 1, 5),
        MeshGrid::new(0.0, 0.0, 1.0, 1.0, 65535, 65535),
        MeshGrid::new(0.0, 0.0, 1e308, 1.0, 3, 2),
    ] {
        assert!(matches!(bad, Err(BedError::BadParameter(_))), "{bad:?}");
    }
}

/// The failure code a wire member's error reports.
fn code<T>(r: Result<T, BedError>) -> Result<T, u8> {
    r.map_err(|e| match CallError::from(e) {
        CallError::Failed(c) => c.code(),
        other => panic!("not a failure code: {other:?}"),
    })
}

#[test]
fn wire_signatures() {
    common::assert_wire_api::<BedPlaneBlock>(
        "BedPlane",
        "BedPlane() -> ()",
        &[
            "BedPlane.add_probe(x: f32, y: f32, z: f32) -> (count: u32)",
            "BedPlane.clear() -> ()",
            "BedPlane.fit() -> (rms: f32, max_residual: f32)",
            "BedPlane.plane() -> (a: f32, b: f32, c: f32)",
            "BedPlane.set_plane(a: f32, b: f32, c: f32) -> ()",
            "BedPlane.apply(stamp: u64, x: f32, y: f32, z: f32) -> (stamp: u64, x: f32, y: f32, z: f32)",
            "BedPlane.unapply(x: f32, y: f32, z: f32) -> (x: f32, y: f32, z: f32)",
        ]
    );
    common::assert_wire_api::<BedMeshBlock>(
        "BedMesh",
        "BedMesh(x0: f32, y0: f32, dx: f32, dy: f32, nx: u16, ny: u16) -> ()",
        &[
            "BedMesh.set_probe(ix: u16, iy: u16, z: f32) -> (missing: u32)",
            "BedMesh.clear() -> ()",
            "BedMesh.stats() -> (min: f32, max: f32, mean: f32, rms: f32)",
            "BedMesh.apply(stamp: u64, x: f32, y: f32, z: f32) -> (stamp: u64, x: f32, y: f32, z: f32)",
            "BedMesh.unapply(x: f32, y: f32, z: f32) -> (x: f32, y: f32, z: f32)",
        ]
    );
}

#[test]
fn wire_plane_class() {
    let mut bed = BedPlaneBlock::construct(&[]).unwrap();
    assert_eq!(code(bed.apply(1, 0.0, 0.0, 0.0)), Err(FAIL_NOT_READY));
    assert_eq!(code(bed.unapply(0.0, 0.0, 0.0)), Err(FAIL_NOT_READY));
    assert_eq!(code(bed.plane()), Err(FAIL_NOT_READY));
    assert_eq!(code(bed.fit()), Err(FAIL_TOO_FEW_POINTS));
    assert_eq!(
        code(bed.add_probe(0.0, 0.0, f32::NAN)),
        Err(FAIL_NON_FINITE)
    );
    for (i, (x, y)) in [(0.0, 0.0), (1.0, 1.0), (2.0, 2.0)].into_iter().enumerate() {
        assert_eq!(bed.add_probe(x, y, 0.5), Ok(i as u32 + 1));
    }
    assert_eq!(code(bed.fit()), Err(FAIL_COLLINEAR));
    bed.clear();
    assert!(bed.0.probes().is_empty());
    for (x, y) in [(0.0f32, 0.0f32), (200.0, 0.0), (0.0, 200.0)] {
        bed.add_probe(x, y, 0.001 * x + 0.5).unwrap();
    }
    let (rms, max) = bed.fit().unwrap();
    assert!(rms < 1e-6 && max < 1e-6);
    let (a, b, c) = bed.plane().unwrap();
    assert!((a - 0.001).abs() < 1e-7 && b.abs() < 1e-7 && (c - 0.5).abs() < 1e-6);
    let (stamp, x, y, z) = bed.apply(4096, 100.0, 50.0, 2.0).unwrap();
    assert_eq!((stamp, x, y), (4096, 100.0, 50.0));
    assert!((z - 2.6).abs() < 1e-5, "{z}");
    let (_, _, back) = bed.unapply(100.0, 50.0, z).unwrap();
    assert!((back - 2.0).abs() < 1e-5);
    assert_eq!(
        code(bed.apply(0, f32::INFINITY, 0.0, 0.0)),
        Err(FAIL_NON_FINITE)
    );
    assert_eq!(
        code(bed.set_plane(f32::NAN, 0.0, 0.0)),
        Err(FAIL_NON_FINITE)
    );
    bed.set_plane(0.0, 0.0, -0.25).unwrap();
    assert_eq!(bed.apply(9, 1.0, 2.0, 1.0), Ok((9, 1.0, 2.0, 0.75)));
    // A correction beyond f32 range.
    bed.set_plane(0.0, 0.0, f32::MAX).unwrap();
    assert_eq!(code(bed.apply(0, 0.0, 0.0, f32::MAX)), Err(FAIL_OVERFLOW));
}

#[test]
fn wire_mesh_class() {
    let mut m = BedMeshBlock::construct(&[
        Value::F32(0.0),
        Value::F32(0.0),
        Value::F32(100.0),
        Value::F32(100.0),
        Value::U16(2),
        Value::U16(2),
    ])
    .unwrap();
    assert_eq!(
        m.0.grid(),
        &MeshGrid::new(0.0, 0.0, 100.0, 100.0, 2, 2).unwrap()
    );
    assert_eq!(code(m.apply(0, 0.0, 0.0, 0.0)), Err(FAIL_NOT_READY));
    assert_eq!(code(m.set_probe(2, 0, 0.0)), Err(FAIL_OUT_OF_GRID));
    assert_eq!(m.set_probe(0, 0, 0.1), Ok(3));
    assert_eq!(m.set_probe(1, 0, 0.3), Ok(2));
    assert_eq!(code(m.stats()), Err(FAIL_NOT_READY));
    assert_eq!(m.set_probe(0, 1, -0.1), Ok(1));
    assert_eq!(m.set_probe(1, 1, 0.1), Ok(0));
    let (s, x, y, z) = m.apply(77, 50.0, 50.0, 1.0).unwrap();
    assert_eq!((s, x, y), (77, 50.0, 50.0));
    assert!((z - 1.1).abs() < 1e-6, "{z}");
    let (_, _, back) = m.unapply(50.0, 50.0, z).unwrap();
    assert!((back - 1.0).abs() < 1e-6);
    let (min, max, mean, rms) = m.stats().unwrap();
    assert!((min + 0.1).abs() < 1e-7 && (max - 0.3).abs() < 1e-7);
    assert!((mean - 0.1).abs() < 1e-7 && (rms - 0.02f32.sqrt()).abs() < 1e-6);
    assert_eq!(code(m.apply(0, 0.0, f32::NAN, 0.0)), Err(FAIL_NON_FINITE));
    m.clear();
    assert_eq!(code(m.unapply(0.0, 0.0, 0.0)), Err(FAIL_NOT_READY));
    assert_eq!(m.0.missing(), 4);

    // An invalid grid: the constructor refuses it with code 5.
    let grid = |dx: f32, nx: u16| {
        BedMeshBlock::construct(&[
            Value::F32(0.0),
            Value::F32(0.0),
            Value::F32(dx),
            Value::F32(1.0),
            Value::U16(nx),
            Value::U16(2),
        ])
        .err()
    };
    let bad = Some(CallError::Failed(pipes_core::FailureCode::from_code(
        FAIL_BAD_PARAMETER,
    )));
    assert_eq!(grid(-1.0, 2), bad);
    assert_eq!(grid(1.0, 1), bad);
    assert_eq!(grid(f32::NAN, 2), bad);
    assert!(matches!(
        BedMeshBlock::new(0.0, 0.0, 1.0, 1.0, 300, 300),
        Err(BedError::BadParameter(_))
    ));
}

proptest! {
    #[test]
    fn plane_fit_recovers_random_planes(
        a in -0.01f64..0.01, b in -0.01f64..0.01, c in -2f64..2.0,
        pts in prop::collection::vec((-300f64..300.0, -300f64..300.0), 3..40),
    ) {
        let probes: Vec<_> = pts.iter().map(|&(x, y)| Probe::new(x, y, a * x + b * y + c)).collect();
        match Plane::fit(&probes) {
            Ok(fit) => {
                for p in &probes {
                    prop_assert!((fit.plane.height(p.x, p.y) - p.z).abs() < 1e-9);
                }
                prop_assert!(fit.max_residual < 1e-9);
            }
            // Random points can only fail by being (nearly) collinear.
            Err(e) => prop_assert_eq!(e, BedError::Collinear),
        }
    }

    #[test]
    fn mesh_is_bounded_by_its_cell_corners(x in -50f64..80.0, y in -20f64..30.0) {
        let m = mesh_3x2();
        let c = m.correction(x, y).unwrap();
        prop_assert!((-0.3..=0.4).contains(&c));
        let z = m.apply(x, y, 5.0).unwrap();
        prop_assert!((m.unapply(x, y, z).unwrap() - 5.0).abs() < 1e-12);
    }
}

proptest! {
    #[test]
    fn no_panics_or_hangs_on_any_probes(
        pts in prop::collection::vec(
            (prop::num::f64::ANY, prop::num::f64::ANY, prop::num::f64::ANY), 0..8),
        x in prop::num::f64::ANY, y in prop::num::f64::ANY, z in prop::num::f64::ANY,
    ) {
        let probes: Vec<_> = pts.iter().map(|&(x, y, z)| Probe::new(x, y, z)).collect();
        if let Ok(fit) = Plane::fit(&probes) {
            prop_assert!(fit.rms.is_finite() && fit.max_residual.is_finite());
            let mut bed = BedPlane::new();
            bed.set_plane(fit.plane);
            if let Ok(v) = bed.apply(x, y, z) {
                prop_assert!(v.is_finite());
            }
        }
        let m = mesh_3x2();
        if let Ok(v) = m.apply(x, y, z) {
            prop_assert!(v.is_finite());
        }
    }
}
