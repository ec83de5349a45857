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

use std::path::{Path, PathBuf};

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
    /// The run record of the probing that measured it (`osap level`).
    #[serde(default)]
    #[allow(dead_code)] // provenance for people and `osap runs`; the mesh does not use it
    fitted_from: Option<String>,
}

/// Why a bed mesh could not be read or written.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum MeshError {
    /// The text is not a bed mesh; the message says what is wrong.
    #[error("{0}")]
    Invalid(String),
    /// A mesh file that is not a bed mesh.
    #[error("bed mesh {}: {reason}", .path.display())]
    InFile {
        /// The file.
        path: PathBuf,
        /// What is wrong in it.
        reason: String,
    },
    /// Reading or writing the file failed.
    #[error("{} bed mesh {}: {source}", .action, .path.display())]
    Io {
        /// `reading` or `writing`.
        action: &'static str,
        /// The file.
        path: PathBuf,
        /// What the system said.
        #[source]
        source: std::io::Error,
    },
}

/// Reads a bed mesh file; the error names the file and what is wrong.
pub fn load(path: &Path) -> Result<BedMesh, MeshError> {
    let text = std::fs::read_to_string(path).map_err(|source| MeshError::Io {
        action: "reading",
        path: path.to_path_buf(),
        source,
    })?;
    parse(&text).map_err(|e| MeshError::InFile {
        path: path.to_path_buf(),
        reason: e.to_string(),
    })
}

/// Reads a bed mesh from text.
pub fn parse(text: &str) -> Result<BedMesh, MeshError> {
    parse_text(text).map_err(MeshError::Invalid)
}

fn parse_text(text: &str) -> Result<BedMesh, String> {
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

/// The mesh as a mesh file's text, `header` (lines) as comments on top,
/// and `fitted_from` (the run record of the probing) as its key.
/// Unprobed nodes are written as 0.
pub fn to_toml(mesh: &BedMesh, header: &str, fitted_from: Option<&str>) -> String {
    let g = mesh.grid();
    let mut s = String::new();
    for line in header.lines() {
        s.push_str(&format!("# {line}\n"));
    }
    if let Some(run) = fitted_from {
        s.push_str(&format!("fitted_from = {run:?}\n"));
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
pub fn save(
    path: &Path,
    mesh: &BedMesh,
    header: &str,
    fitted_from: Option<&str>,
) -> Result<(), MeshError> {
    std::fs::write(path, to_toml(mesh, header, fitted_from)).map_err(|source| MeshError::Io {
        action: "writing",
        path: path.to_path_buf(),
        source,
    })
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
    fn a_mesh_names_the_run_it_came_from_and_reads_back() {
        let m = parse("x0 = 0.0\ny0 = 0.0\ndx = 10.0\ndy = 10.0\nz = [[0.0, 1.0], [2.0, 3.0]]\n")
            .unwrap();
        let text = to_toml(&m, "probed", Some("runs/mesh.toml.run.json"));
        assert!(
            text.contains("fitted_from = \"runs/mesh.toml.run.json\"\n"),
            "{text}"
        );
        assert_eq!(parse(&text).unwrap().correction(5.0, 5.0).unwrap(), 1.5);
    }

    #[test]
    fn bad_meshes_say_why() {
        let e = parse("x0 = 0.0\ny0 = 0.0\ndx = 10.0\ndy = 10.0\nz = [[0.0, 1.0], [2.0]]\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("row 1"), "{e}");
        let e = parse("x0 = 0.0\ny0 = 0.0\ndx = -1.0\ndy = 10.0\nz = [[0.0, 1.0], [2.0, 3.0]]\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("spacing"), "{e}");
        let e = parse("x0 = 0.0\ny0 = 0.0\ndx = 1.0\ndy = 10.0\nz = [[0.0, 1.0], [2.0, \"a\"]]\n")
            .unwrap_err()
            .to_string();
        assert!(!e.is_empty());
        let e = parse("x0 = 0.0\n").unwrap_err().to_string();
        assert!(e.contains("missing"), "{e}");
    }
}
