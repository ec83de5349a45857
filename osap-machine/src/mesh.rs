//! Bed mesh files: a grid of measured bed heights that the machine adds to
//! z wherever the tool is, so a job follows a bed that is not flat.
//!
//! ```toml
//! # Heights (z, machine units) measured at each node of a regular grid:
//! # node (ix, iy) sits at (x0 + ix·dx, y0 + iy·dy).
//! x0 = 20.0
//! y0 = 20.0
//! dx = 130.0
//! dy = 80.0
//! z = [
//!   [0.00, 0.05, 0.12],   # row iy = 0, columns ix = 0, 1, 2
//!   [0.02, 0.08, 0.15],   # row iy = 1
//! ]
//! ```
//!
//! Between nodes the correction is bilinear; beyond the grid, the edge's
//! (maxl's [`BedMesh`]).

use std::path::Path;

use maxl::blocks::bedlevel::{BedMesh, MeshGrid};
use serde::Deserialize;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct MeshFile {
    x0: f64,
    y0: f64,
    dx: f64,
    dy: f64,
    z: Vec<Vec<f64>>,
}

/// Reads a bed mesh file; the error names the file and what is wrong.
pub fn load(path: &Path) -> Result<BedMesh, String> {
    let text =
        std::fs::read_to_string(path).map_err(|e| format!("bed mesh {}: {e}", path.display()))?;
    parse(&text).map_err(|e| format!("bed mesh {}: {e}", path.display()))
}

/// Reads a bed mesh from text.
pub fn parse(text: &str) -> Result<BedMesh, String> {
    let f: MeshFile = toml::from_str(text).map_err(|e| e.message().to_string())?;
    let ny = f.z.len();
    let nx = f.z.first().map_or(0, Vec::len);
    if let Some((iy, row)) = f.z.iter().enumerate().find(|(_, r)| r.len() != nx) {
        return Err(format!(
            "z row {iy} has {} heights, row 0 has {nx}: every row needs one per column",
            row.len()
        ));
    }
    let grid = MeshGrid::new(f.x0, f.y0, f.dx, f.dy, nx, ny).map_err(|e| e.to_string())?;
    let mut mesh = BedMesh::new(grid);
    for (iy, row) in f.z.iter().enumerate() {
        for (ix, z) in row.iter().enumerate() {
            mesh.set_probe(ix, iy, *z)
                .map_err(|e| format!("z[{iy}][{ix}] = {z}: {e}"))?;
        }
    }
    Ok(mesh)
}

/// The mesh as a mesh file's text, `header` (lines) as comments on top.
/// Unprobed nodes are written as 0.
pub fn to_toml(mesh: &BedMesh, header: &str) -> String {
    let g = mesh.grid();
    let mut s = String::new();
    for line in header.lines() {
        s.push_str(&format!("# {line}\n"));
    }
    s.push_str(&format!(
        "x0 = {:?}\ny0 = {:?}\ndx = {:?}\ndy = {:?}\nz = [\n",
        g.x0, g.y0, g.dx, g.dy
    ));
    for iy in 0..g.ny {
        let row: Vec<String> = (0..g.nx)
            .map(|ix| format!("{:.5}", mesh.probe(ix, iy).unwrap_or(0.0)))
            .collect();
        s.push_str(&format!(
            "  [{}],   # y = {:.3}\n",
            row.join(", "),
            g.node(0, iy).1
        ));
    }
    s.push_str("]\n");
    s
}

/// Writes the mesh to `path` ([`to_toml`]); the error names the file.
pub fn save(path: &Path, mesh: &BedMesh, header: &str) -> Result<(), String> {
    std::fs::write(path, to_toml(mesh, header))
        .map_err(|e| format!("writing bed mesh {}: {e}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_a_grid_and_interpolates() {
        let m = parse("x0 = 0.0\ny0 = 0.0\ndx = 10.0\ndy = 10.0\nz = [[0.0, 1.0], [2.0, 3.0]]\n")
            .unwrap();
        assert_eq!(m.correction(5.0, 5.0).unwrap(), 1.5);
        assert_eq!(m.correction(0.0, 10.0).unwrap(), 2.0);
    }

    #[test]
    fn bad_meshes_say_why() {
        let e = parse("x0 = 0.0\ny0 = 0.0\ndx = 10.0\ndy = 10.0\nz = [[0.0, 1.0], [2.0]]\n")
            .unwrap_err();
        assert!(e.contains("row 1"), "{e}");
        let e = parse("x0 = 0.0\ny0 = 0.0\ndx = -1.0\ndy = 10.0\nz = [[0.0, 1.0], [2.0, 3.0]]\n")
            .unwrap_err();
        assert!(e.contains("spacing"), "{e}");
        let e = parse("x0 = 0.0\ny0 = 0.0\ndx = 1.0\ndy = 10.0\nz = [[0.0, 1.0], [2.0, \"a\"]]\n")
            .unwrap_err();
        assert!(!e.is_empty());
        let e = parse("x0 = 0.0\n").unwrap_err();
        assert!(e.contains("missing"), "{e}");
    }
}
