//! Golden comparison shared by the tests.

use proxygen::GeneratedFile;
use std::path::{Path, PathBuf};

/// `proxygen/tests/<rel>`.
pub(crate) fn tests_dir(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests")
        .join(rel)
}

/// Whether `PROXYGEN_BLESS=1`: rewrite expected output instead of comparing.
pub(crate) fn bless() -> bool {
    std::env::var("PROXYGEN_BLESS").is_ok_and(|v| v == "1")
}

/// Compares `files` with the files under `dir`, byte for byte (every
/// expected file must be generated and no other); with `PROXYGEN_BLESS=1`
/// rewrites `dir` instead.
pub(crate) fn golden(dir: &Path, files: &[GeneratedFile]) {
    if bless() {
        let _ = std::fs::remove_dir_all(dir);
        proxygen::write(dir, files).unwrap();
        return;
    }
    let mut expected = Vec::new();
    walk(dir, dir, &mut expected);
    expected.sort();
    let mut got: Vec<String> = files.iter().map(|f| f.path.display().to_string()).collect();
    got.sort();
    assert_eq!(got, expected, "files generated vs in {}", dir.display());
    for f in files {
        let path = dir.join(&f.path);
        let want = std::fs::read_to_string(&path).unwrap();
        if want != f.contents {
            let line = want
                .lines()
                .zip(f.contents.lines())
                .position(|(a, b)| a != b)
                .map_or(want.lines().count().min(f.contents.lines().count()), |l| l);
            panic!(
                "{} differs from the generator's output at line {}: run with PROXYGEN_BLESS=1 to accept\n  expected: {:?}\n  got:      {:?}",
                path.display(),
                line + 1,
                want.lines().nth(line),
                f.contents.lines().nth(line)
            );
        }
    }
}

fn walk(root: &Path, dir: &Path, out: &mut Vec<String>) {
    let entries = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e} (PROXYGEN_BLESS=1 writes it)", dir.display()));
    for e in entries {
        let path = e.unwrap().path();
        if path.is_dir() {
            walk(root, &path, out);
        } else {
            out.push(path.strip_prefix(root).unwrap().display().to_string());
        }
    }
}
