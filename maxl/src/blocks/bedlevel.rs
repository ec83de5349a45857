//! Bed levelling: a z correction from probed bed heights, applied in line
//! with z.
//!
//! A probe measures the bed surface's height `z` (machine coordinates) at
//! `(x, y)`. The correction at a point is that height, so
//! `apply(x, y, z) = z + correction(x, y)` puts the tool at `z` above the
//! bed surface rather than above the machine's z zero, and
//! `unapply(x, y, z) = z − correction(x, y)` reads a machine position back.
//!
//! Two models:
//!
//! - [`BedPlane`]: a least-squares plane `h = a·x + b·y + c` through three or
//!   more probes not all on one line, with the fit's residuals (RMS and
//!   largest) reported.
//! - [`BedMesh`]: heights probed on a regular grid, bilinear in each cell.
//!   Outside the grid the point is first clamped onto the grid's boundary,
//!   so the correction is held at the edge value rather than extrapolated.
//!
//! Both are PIPES classes ([`BedPlaneBlock`] as `BedPlane`, [`BedMeshBlock`]
//! as `BedMesh`). `apply(stamp, x, y, z) -> (stamp, x, y, z)` passes the
//! stamp and x, y through and corrects z; `unapply(x, y, z) -> (x, y, z)`
//! undoes it. A failing member or constructor returns
//! `CallError::Failed(code)` ([`BedError::code`]):
//!
//! | code | constant                  | meaning                                                 |
//! |------|---------------------------|---------------------------------------------------------|
//! | 1    | [`FAIL_NON_FINITE`]       | an input is NaN or infinite                             |
//! | 2    | [`FAIL_TOO_FEW_POINTS`]   | fewer than 3 probes to fit a plane                      |
//! | 3    | [`FAIL_COLLINEAR`]        | the probes lie on one line (or one point)               |
//! | 4    | [`FAIL_NOT_READY`]        | no plane fitted or set yet / mesh nodes still unprobed  |
//! | 5    | [`FAIL_BAD_PARAMETER`]    | the `BedMesh` constructor refused its grid              |
//! | 6    | [`FAIL_OVERFLOW`]         | the result does not fit a finite `f32`                  |
//! | 7    | [`FAIL_OUT_OF_GRID`]      | a probe index is outside the grid                        |
//! | 8    | [`FAIL_TOO_MANY_PROBES`]  | more than [`MAX_PROBES`] probes                          |
//!
//! `docs/kinematics.md` describes both models.

use core::fmt;

use nalgebra::{DMatrix, DVector};
use pipes_core::function::CallError;

/// Failure code: an input is NaN or infinite.
pub const FAIL_NON_FINITE: u8 = 1;
/// Failure code: fewer than 3 probes to fit a plane.
pub const FAIL_TOO_FEW_POINTS: u8 = 2;
/// Failure code: the probes are collinear (or coincident).
pub const FAIL_COLLINEAR: u8 = 3;
/// Failure code: no correction yet (no plane fitted or set, or mesh nodes
/// not all probed).
pub const FAIL_NOT_READY: u8 = 4;
/// Failure code: a parameter is invalid (the `BedMesh` constructor refused
/// its grid).
pub const FAIL_BAD_PARAMETER: u8 = 5;
/// Failure code: the result does not fit a finite value.
pub const FAIL_OVERFLOW: u8 = 6;
/// Failure code: a probe's grid index is outside the grid.
pub const FAIL_OUT_OF_GRID: u8 = 7;
/// Failure code: the probe list is full.
pub const FAIL_TOO_MANY_PROBES: u8 = 8;

/// The most probes a [`BedPlane`] holds.
pub const MAX_PROBES: usize = 4096;
/// The most nodes a [`BedMesh`] holds.
pub const MAX_MESH_NODES: usize = 65536;

/// Relative size, against the largest, under which the smaller singular
/// value of the centred probe positions counts as zero (collinear probes).
const COLLINEAR_RATIO: f64 = 1e-9;

/// Why a bed-levelling operation failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum BedError {
    /// An input is NaN or infinite.
    NonFinite,
    /// A plane needs at least 3 probes; this many were given.
    TooFewPoints(usize),
    /// The probes all lie on one line (or at one point): the tilt across
    /// that line is unknown.
    Collinear,
    /// No plane has been fitted or set yet.
    NotFitted,
    /// This many mesh nodes have not been probed yet.
    MeshIncomplete(usize),
    /// A parameter is invalid; the text names it and the rule.
    BadParameter(&'static str),
    /// The result is not finite (or, on the wire, does not fit an `f32`).
    Overflow,
    /// The grid index is outside the mesh.
    OutOfGrid {
        /// Column index given.
        ix: usize,
        /// Row index given.
        iy: usize,
    },
    /// The probe list already holds [`MAX_PROBES`] probes.
    TooManyProbes,
}

impl BedError {
    /// The PIPES failure code of this error (see the module docs).
    pub fn code(&self) -> u8 {
        match self {
            BedError::NonFinite => FAIL_NON_FINITE,
            BedError::TooFewPoints(_) => FAIL_TOO_FEW_POINTS,
            BedError::Collinear => FAIL_COLLINEAR,
            BedError::NotFitted | BedError::MeshIncomplete(_) => FAIL_NOT_READY,
            BedError::BadParameter(_) => FAIL_BAD_PARAMETER,
            BedError::Overflow => FAIL_OVERFLOW,
            BedError::OutOfGrid { .. } => FAIL_OUT_OF_GRID,
            BedError::TooManyProbes => FAIL_TOO_MANY_PROBES,
        }
    }
}

impl fmt::Display for BedError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BedError::NonFinite => f.write_str("an input is NaN or infinite"),
            BedError::TooFewPoints(n) => {
                write!(f, "a plane fit needs at least 3 probes, got {n}")
            }
            BedError::Collinear => {
                f.write_str("the probes lie on one line: probe at least three points not in line")
            }
            BedError::NotFitted => f.write_str("no bed plane has been fitted or set yet"),
            BedError::MeshIncomplete(n) => {
                write!(f, "{n} mesh node(s) have not been probed yet")
            }
            BedError::BadParameter(what) => write!(f, "invalid bed-levelling parameter: {what}"),
            BedError::Overflow => f.write_str("the result is not a finite number"),
            BedError::OutOfGrid { ix, iy } => {
                write!(f, "grid index ({ix}, {iy}) is outside the mesh")
            }
            BedError::TooManyProbes => write!(f, "at most {MAX_PROBES} probes are held"),
        }
    }
}

impl core::error::Error for BedError {}

impl From<BedError> for CallError {
    fn from(e: BedError) -> CallError {
        CallError::Failed(e.code().into())
    }
}

/// One probe: the bed surface's height `z` measured at `(x, y)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Probe {
    /// Probe x.
    pub x: f64,
    /// Probe y.
    pub y: f64,
    /// Measured bed height.
    pub z: f64,
}

impl Probe {
    /// A probe at `(x, y)` measuring height `z`.
    pub fn new(x: f64, y: f64, z: f64) -> Probe {
        Probe { x, y, z }
    }

    fn is_finite(&self) -> bool {
        self.x.is_finite() && self.y.is_finite() && self.z.is_finite()
    }
}

/// A plane `h(x, y) = a·x + b·y + c`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    /// Slope along x.
    pub a: f64,
    /// Slope along y.
    pub b: f64,
    /// Height at the origin.
    pub c: f64,
}

impl Plane {
    /// The plane with these coefficients (all finite).
    pub fn new(a: f64, b: f64, c: f64) -> Result<Plane, BedError> {
        if a.is_finite() && b.is_finite() && c.is_finite() {
            Ok(Plane { a, b, c })
        } else {
            Err(BedError::NonFinite)
        }
    }

    /// The plane's height at `(x, y)`.
    pub fn height(&self, x: f64, y: f64) -> f64 {
        self.a * x + self.b * y + self.c
    }

    /// The least-squares plane through `probes` (minimising the squared z
    /// residuals), with its residual statistics.
    ///
    /// Fails with fewer than 3 probes, non-finite probes, or probes on one
    /// line: positions are centred on their mean and the smaller singular
    /// value of the centred n×2 position matrix must exceed 1e-9 of the
    /// larger one. Coordinates so large that centring them overflows give
    /// [`BedError::Overflow`].
    pub fn fit(probes: &[Probe]) -> Result<PlaneFit, BedError> {
        if probes.len() < 3 {
            return Err(BedError::TooFewPoints(probes.len()));
        }
        if !probes.iter().all(Probe::is_finite) {
            return Err(BedError::NonFinite);
        }
        let n = probes.len() as f64;
        let mean = |f: fn(&Probe) -> f64| probes.iter().map(f).sum::<f64>() / n;
        let (mx, my, mz) = (mean(|p| p.x), mean(|p| p.y), mean(|p| p.z));
        // Centring decouples the constant term and keeps the positions well
        // scaled however far the bed is from the origin.
        let m = DMatrix::from_fn(probes.len(), 2, |i, j| {
            let p = &probes[i];
            if j == 0 {
                p.x - mx
            } else {
                p.y - my
            }
        });
        let dz = DVector::from_iterator(probes.len(), probes.iter().map(|p| p.z - mz));
        if !(m.iter().all(|v| v.is_finite()) && dz.iter().all(|v| v.is_finite())) {
            return Err(BedError::Overflow);
        }
        // Bounded iterations: a 2-column SVD converges in a handful, and an
        // unbounded one must never hang a controller.
        let svd = m
            .try_svd(true, true, f64::EPSILON, 10_000)
            .ok_or(BedError::Overflow)?;
        let (s_max, s_min) = (svd.singular_values.max(), svd.singular_values.min());
        if !(s_max.is_finite() && s_max > 0.0) || s_min <= COLLINEAR_RATIO * s_max {
            return Err(BedError::Collinear);
        }
        let ab = svd
            .solve(&dz, COLLINEAR_RATIO * s_max)
            .map_err(|_| BedError::Collinear)?;
        let (a, b) = (ab[0], ab[1]);
        let plane = Plane::new(a, b, mz - a * mx - b * my).map_err(|_| BedError::Overflow)?;
        let mut sq = 0.0;
        let mut max_residual: f64 = 0.0;
        for p in probes {
            let r = p.z - plane.height(p.x, p.y);
            sq += r * r;
            max_residual = max_residual.max(r.abs());
        }
        Ok(PlaneFit {
            plane,
            rms: finite((sq / n).sqrt())?,
            max_residual: finite(max_residual)?,
            points: probes.len(),
        })
    }
}

/// A fitted plane and how well it fits its probes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlaneFit {
    /// The plane.
    pub plane: Plane,
    /// Root mean square of the probes' z residuals.
    pub rms: f64,
    /// The largest absolute z residual.
    pub max_residual: f64,
    /// How many probes were fitted.
    pub points: usize,
}

/// A planar bed correction: collects probes, fits a plane, applies it.
///
/// The active plane changes only through [`fit`](BedPlane::fit) or
/// [`set_plane`](BedPlane::set_plane): adding or clearing probes leaves the
/// current correction in force until the next fit.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BedPlane {
    probes: Vec<Probe>,
    fit: Option<PlaneFit>,
    plane: Option<Plane>,
}

impl BedPlane {
    /// No probes and no plane: `apply` fails until a fit or `set_plane`.
    pub fn new() -> BedPlane {
        BedPlane::default()
    }

    /// Adds a probe; returns how many are held.
    pub fn add_probe(&mut self, probe: Probe) -> Result<usize, BedError> {
        if !probe.is_finite() {
            return Err(BedError::NonFinite);
        }
        if self.probes.len() >= MAX_PROBES {
            return Err(BedError::TooManyProbes);
        }
        self.probes.push(probe);
        Ok(self.probes.len())
    }

    /// The probes held.
    pub fn probes(&self) -> &[Probe] {
        &self.probes
    }

    /// Drops every probe (the active plane stays).
    pub fn clear_probes(&mut self) {
        self.probes.clear();
    }

    /// Fits a plane to the probes held and makes it the active correction.
    /// On failure the previous correction stays.
    pub fn fit(&mut self) -> Result<PlaneFit, BedError> {
        let fit = Plane::fit(&self.probes)?;
        self.fit = Some(fit);
        self.plane = Some(fit.plane);
        Ok(fit)
    }

    /// The last successful fit, if the active plane came from one.
    pub fn last_fit(&self) -> Option<PlaneFit> {
        self.fit
    }

    /// Makes `plane` the active correction (for example one saved earlier).
    pub fn set_plane(&mut self, plane: Plane) {
        self.fit = None;
        self.plane = Some(plane);
    }

    /// The active plane.
    pub fn plane(&self) -> Result<Plane, BedError> {
        self.plane.ok_or(BedError::NotFitted)
    }

    /// The correction at `(x, y)`: the active plane's height there.
    pub fn correction(&self, x: f64, y: f64) -> Result<f64, BedError> {
        let plane = self.plane()?;
        if !(x.is_finite() && y.is_finite()) {
            return Err(BedError::NonFinite);
        }
        finite(plane.height(x, y))
    }

    /// `z + correction(x, y)`.
    pub fn apply(&self, x: f64, y: f64, z: f64) -> Result<f64, BedError> {
        self.shifted(x, y, z, 1.0)
    }

    /// `z − correction(x, y)`: the inverse of [`apply`](Self::apply).
    pub fn unapply(&self, x: f64, y: f64, z: f64) -> Result<f64, BedError> {
        self.shifted(x, y, z, -1.0)
    }
}

/// The regular grid a [`BedMesh`] is probed on: node `(ix, iy)` sits at
/// `(x0 + ix·dx, y0 + iy·dy)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshGrid {
    /// x of column 0.
    pub x0: f64,
    /// y of row 0.
    pub y0: f64,
    /// Column spacing (positive).
    pub dx: f64,
    /// Row spacing (positive).
    pub dy: f64,
    /// Number of columns (at least 2).
    pub nx: usize,
    /// Number of rows (at least 2).
    pub ny: usize,
}

impl MeshGrid {
    /// Checks the grid: finite origin, finite positive spacings, at least
    /// 2×2 and at most [`MAX_MESH_NODES`] nodes, a finite far corner.
    pub fn new(
        x0: f64,
        y0: f64,
        dx: f64,
        dy: f64,
        nx: usize,
        ny: usize,
    ) -> Result<MeshGrid, BedError> {
        if !(x0.is_finite() && y0.is_finite()) {
            return Err(BedError::BadParameter("the mesh origin must be finite"));
        }
        if !(dx.is_finite() && dx > 0.0 && dy.is_finite() && dy > 0.0) {
            return Err(BedError::BadParameter(
                "the mesh spacings must be finite and positive",
            ));
        }
        if nx < 2 || ny < 2 {
            return Err(BedError::BadParameter(
                "the mesh needs at least 2 nodes along each axis",
            ));
        }
        if nx.checked_mul(ny).is_none_or(|n| n > MAX_MESH_NODES) {
            return Err(BedError::BadParameter("the mesh has more than 65536 nodes"));
        }
        let far = (x0 + dx * (nx - 1) as f64, y0 + dy * (ny - 1) as f64);
        if !(far.0.is_finite() && far.1.is_finite()) {
            return Err(BedError::BadParameter("the mesh extent must be finite"));
        }
        Ok(MeshGrid {
            x0,
            y0,
            dx,
            dy,
            nx,
            ny,
        })
    }

    /// The position of node `(ix, iy)`.
    pub fn node(&self, ix: usize, iy: usize) -> (f64, f64) {
        (self.x0 + self.dx * ix as f64, self.y0 + self.dy * iy as f64)
    }

    /// Cell index and fraction along one axis, clamped onto the grid.
    fn locate(origin: f64, step: f64, n: usize, v: f64) -> (usize, f64) {
        let last = (n - 1) as f64;
        let u = ((v - origin) / step).clamp(0.0, last);
        // n ≥ 2, so the cell index stays below n − 1 and the fraction in [0, 1].
        let i = (u.floor() as usize).min(n - 2);
        (i, u - i as f64)
    }
}

/// Statistics of a complete mesh's probed heights.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshStats {
    /// Lowest probed height.
    pub min: f64,
    /// Highest probed height.
    pub max: f64,
    /// Mean probed height.
    pub mean: f64,
    /// RMS deviation of the heights from their mean (the bed's unflatness).
    pub rms: f64,
}

/// A grid of probed bed heights, interpolated bilinearly.
///
/// Within a cell the correction is the bilinear blend of its four corner
/// heights; at a node it is that node's height exactly. A point outside the
/// grid is clamped onto the grid's boundary first (x and y separately), so
/// the correction beyond an edge is the edge's value: constant outward,
/// never extrapolated.
#[derive(Debug, Clone, PartialEq)]
pub struct BedMesh {
    grid: MeshGrid,
    // Row-major: node (ix, iy) at iy·nx + ix.
    z: Vec<f64>,
    set: Vec<bool>,
    missing: usize,
}

impl BedMesh {
    /// An unprobed mesh on `grid`.
    pub fn new(grid: MeshGrid) -> BedMesh {
        let n = grid.nx * grid.ny;
        BedMesh {
            grid,
            z: vec![0.0; n],
            set: vec![false; n],
            missing: n,
        }
    }

    /// The grid.
    pub fn grid(&self) -> &MeshGrid {
        &self.grid
    }

    /// Records the height probed at node `(ix, iy)` (again: replaces it);
    /// returns how many nodes are still unprobed.
    pub fn set_probe(&mut self, ix: usize, iy: usize, z: f64) -> Result<usize, BedError> {
        if ix >= self.grid.nx || iy >= self.grid.ny {
            return Err(BedError::OutOfGrid { ix, iy });
        }
        if !z.is_finite() {
            return Err(BedError::NonFinite);
        }
        let k = iy * self.grid.nx + ix;
        self.z[k] = z;
        if !self.set[k] {
            self.set[k] = true;
            self.missing -= 1;
        }
        Ok(self.missing)
    }

    /// The height probed at node `(ix, iy)`, if it has been.
    pub fn probe(&self, ix: usize, iy: usize) -> Option<f64> {
        if ix >= self.grid.nx || iy >= self.grid.ny {
            return None;
        }
        let k = iy * self.grid.nx + ix;
        self.set[k].then(|| self.z[k])
    }

    /// Forgets every probed height.
    pub fn clear(&mut self) {
        self.set.iter_mut().for_each(|s| *s = false);
        self.missing = self.set.len();
    }

    /// How many nodes are still unprobed.
    pub fn missing(&self) -> usize {
        self.missing
    }

    /// Whether every node has been probed.
    pub fn is_complete(&self) -> bool {
        self.missing == 0
    }

    fn ready(&self) -> Result<(), BedError> {
        if self.missing == 0 {
            Ok(())
        } else {
            Err(BedError::MeshIncomplete(self.missing))
        }
    }

    /// The correction at `(x, y)` (see the type docs for edges).
    pub fn correction(&self, x: f64, y: f64) -> Result<f64, BedError> {
        self.ready()?;
        if !(x.is_finite() && y.is_finite()) {
            return Err(BedError::NonFinite);
        }
        let g = &self.grid;
        let (i, fx) = MeshGrid::locate(g.x0, g.dx, g.nx, x);
        let (j, fy) = MeshGrid::locate(g.y0, g.dy, g.ny, y);
        let at = |ix: usize, iy: usize| self.z[iy * g.nx + ix];
        let lower = at(i, j) * (1.0 - fx) + at(i + 1, j) * fx;
        let upper = at(i, j + 1) * (1.0 - fx) + at(i + 1, j + 1) * fx;
        finite(lower * (1.0 - fy) + upper * fy)
    }

    /// `z + correction(x, y)`.
    pub fn apply(&self, x: f64, y: f64, z: f64) -> Result<f64, BedError> {
        self.shifted(x, y, z, 1.0)
    }

    /// `z − correction(x, y)`: the inverse of [`apply`](Self::apply).
    pub fn unapply(&self, x: f64, y: f64, z: f64) -> Result<f64, BedError> {
        self.shifted(x, y, z, -1.0)
    }

    /// Statistics of the probed heights (the mesh must be complete).
    pub fn stats(&self) -> Result<MeshStats, BedError> {
        self.ready()?;
        let n = self.z.len() as f64;
        let mean = self.z.iter().sum::<f64>() / n;
        let var = self.z.iter().map(|z| (z - mean).powi(2)).sum::<f64>() / n;
        let min = self.z.iter().copied().fold(f64::INFINITY, f64::min);
        let max = self.z.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        Ok(MeshStats {
            min,
            max,
            mean: finite(mean)?,
            rms: finite(var.sqrt())?,
        })
    }
}

/// What the plane and the mesh share: a z correction over `(x, y)` that
/// may not be ready yet. `apply`/`unapply` and their wire members are
/// written once here, so both models fail in the same order with the same
/// codes.
trait Correction {
    /// `Ok` once the model can correct (plane active / mesh complete).
    fn check_ready(&self) -> Result<(), BedError>;

    /// The correction at `(x, y)`.
    fn correction_at(&self, x: f64, y: f64) -> Result<f64, BedError>;

    /// `z + sign · correction(x, y)`, `sign` ±1 (negating is exact, so
    /// `-1` gives `z − correction` to the bit).
    fn shifted(&self, x: f64, y: f64, z: f64, sign: f64) -> Result<f64, BedError> {
        let c = self.correction_at(x, y)?;
        if !z.is_finite() {
            return Err(BedError::NonFinite);
        }
        finite(z + sign * c)
    }

    /// The wire `apply`: readiness first (an unready model reports
    /// [`FAIL_NOT_READY`] whatever the inputs), then finite inputs.
    fn wire_apply(
        &self,
        stamp: u64,
        x: f32,
        y: f32,
        z: f32,
    ) -> Result<(u64, f32, f32, f32), BedError> {
        self.check_ready()?;
        inputs_finite(&[x, y, z])?;
        let z = self.shifted(x.into(), y.into(), z.into(), 1.0)?;
        Ok((stamp, x, y, to_f32(z)?))
    }

    /// The wire `unapply`, checked in the same order as
    /// [`wire_apply`](Self::wire_apply).
    fn wire_unapply(&self, x: f32, y: f32, z: f32) -> Result<(f32, f32, f32), BedError> {
        self.check_ready()?;
        inputs_finite(&[x, y, z])?;
        let z = self.shifted(x.into(), y.into(), z.into(), -1.0)?;
        Ok((x, y, to_f32(z)?))
    }
}

impl Correction for BedPlane {
    fn check_ready(&self) -> Result<(), BedError> {
        self.plane().map(|_| ())
    }

    fn correction_at(&self, x: f64, y: f64) -> Result<f64, BedError> {
        self.correction(x, y)
    }
}

impl Correction for BedMesh {
    fn check_ready(&self) -> Result<(), BedError> {
        self.ready()
    }

    fn correction_at(&self, x: f64, y: f64) -> Result<f64, BedError> {
        self.correction(x, y)
    }
}

fn finite(v: f64) -> Result<f64, BedError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(BedError::Overflow)
    }
}

/// An `f64` result as a finite `f32`, or [`BedError::Overflow`].
fn to_f32(v: f64) -> Result<f32, BedError> {
    let f = v as f32;
    if f.is_finite() {
        Ok(f)
    } else {
        Err(BedError::Overflow)
    }
}

/// Checks f32 inputs are finite before they reach the f64 models.
fn inputs_finite(v: &[f32]) -> Result<(), BedError> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(BedError::NonFinite)
    }
}

/// A [`BedPlane`] as the PIPES class `BedPlane` (see the module docs).
///
/// Its methods are the class's members, in `f32`; the plane correction
/// itself is the public field.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BedPlaneBlock(pub BedPlane);

#[pipes_core::class(name = "BedPlane")]
impl BedPlaneBlock {
    /// The constructor `BedPlane`: no probes, no plane.
    #[constructor]
    pub fn new() -> BedPlaneBlock {
        BedPlaneBlock(BedPlane::new())
    }

    /// `BedPlane.add_probe`: adds a probe; returns how many are held.
    #[outputs = "count"]
    pub fn add_probe(&mut self, x: f32, y: f32, z: f32) -> Result<u32, BedError> {
        let n = self.0.add_probe(Probe::new(x.into(), y.into(), z.into()))?;
        // At most MAX_PROBES, so it fits.
        Ok(u32::try_from(n).unwrap_or(u32::MAX))
    }

    /// `BedPlane.clear`: drops the probes (the plane stays).
    pub fn clear(&mut self) {
        self.0.clear_probes();
    }

    /// `BedPlane.fit`: fits and activates the plane; returns its residual
    /// RMS and largest residual.
    #[outputs = "rms, max_residual"]
    pub fn fit(&mut self) -> Result<(f32, f32), BedError> {
        let fit = self.0.fit()?;
        Ok((to_f32(fit.rms)?, to_f32(fit.max_residual)?))
    }

    /// `BedPlane.plane`: the active plane's coefficients.
    #[outputs = "a, b, c"]
    pub fn plane(&self) -> Result<(f32, f32, f32), BedError> {
        let p = self.0.plane()?;
        Ok((to_f32(p.a)?, to_f32(p.b)?, to_f32(p.c)?))
    }

    /// `BedPlane.set_plane`: activates the plane with these coefficients.
    pub fn set_plane(&mut self, a: f32, b: f32, c: f32) -> Result<(), BedError> {
        self.0.set_plane(Plane::new(a.into(), b.into(), c.into())?);
        Ok(())
    }

    /// `BedPlane.apply`: z corrected; stamp, x and y passed through.
    #[outputs = "stamp, x, y, z"]
    pub fn apply(
        &self,
        stamp: u64,
        x: f32,
        y: f32,
        z: f32,
    ) -> Result<(u64, f32, f32, f32), BedError> {
        self.0.wire_apply(stamp, x, y, z)
    }

    /// `BedPlane.unapply`: a machine position read back to bed-relative z.
    #[outputs = "x, y, z"]
    pub fn unapply(&self, x: f32, y: f32, z: f32) -> Result<(f32, f32, f32), BedError> {
        self.0.wire_unapply(x, y, z)
    }
}

/// A [`BedMesh`] as the PIPES class `BedMesh` (see the module docs).
///
/// Its methods are the class's members, in `f32`; the mesh itself is the
/// public field.
#[derive(Debug, Clone, PartialEq)]
pub struct BedMeshBlock(pub BedMesh);

#[pipes_core::class(name = "BedMesh")]
impl BedMeshBlock {
    /// The constructor `BedMesh`: an unprobed mesh on the grid with origin
    /// `(x0, y0)`, spacings `dx`, `dy` and `nx × ny` nodes; refuses an
    /// invalid grid with [`BedError::BadParameter`] (code 5).
    #[constructor]
    pub fn new(
        x0: f32,
        y0: f32,
        dx: f32,
        dy: f32,
        nx: u16,
        ny: u16,
    ) -> Result<BedMeshBlock, BedError> {
        let grid = MeshGrid::new(
            x0.into(),
            y0.into(),
            dx.into(),
            dy.into(),
            nx.into(),
            ny.into(),
        )?;
        Ok(BedMeshBlock(BedMesh::new(grid)))
    }

    /// `BedMesh.set_probe`: records node `(ix, iy)`'s height; returns how
    /// many nodes are still unprobed.
    #[outputs = "missing"]
    pub fn set_probe(&mut self, ix: u16, iy: u16, z: f32) -> Result<u32, BedError> {
        let left = self.0.set_probe(ix.into(), iy.into(), z.into())?;
        // At most MAX_MESH_NODES, so it fits.
        Ok(u32::try_from(left).unwrap_or(u32::MAX))
    }

    /// `BedMesh.clear`: forgets every probed height.
    pub fn clear(&mut self) {
        self.0.clear();
    }

    /// `BedMesh.stats`: min, max, mean and RMS deviation of the heights.
    #[outputs = "min, max, mean, rms"]
    pub fn stats(&self) -> Result<(f32, f32, f32, f32), BedError> {
        let s = self.0.stats()?;
        Ok((
            to_f32(s.min)?,
            to_f32(s.max)?,
            to_f32(s.mean)?,
            to_f32(s.rms)?,
        ))
    }

    /// `BedMesh.apply`: z corrected; stamp, x and y passed through.
    #[outputs = "stamp, x, y, z"]
    pub fn apply(
        &self,
        stamp: u64,
        x: f32,
        y: f32,
        z: f32,
    ) -> Result<(u64, f32, f32, f32), BedError> {
        self.0.wire_apply(stamp, x, y, z)
    }

    /// `BedMesh.unapply`: a machine position read back to bed-relative z.
    #[outputs = "x, y, z"]
    pub fn unapply(&self, x: f32, y: f32, z: f32) -> Result<(f32, f32, f32), BedError> {
        self.0.wire_unapply(x, y, z)
    }
}
