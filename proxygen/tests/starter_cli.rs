//! `proxygen --starter`: a starter is written once; a second run refuses
//! to overwrite what the user may have edited, naming the files, and
//! `--force` overwrites.

use std::path::PathBuf;
use std::process::Command;

fn proxygen(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_proxygen"))
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn a_starter_is_not_written_over_edits_without_force() {
    let som = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/small-machine.som.json");
    let dir = std::env::temp_dir().join(format!("proxygen-starter-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let (som, out) = (som.to_str().unwrap(), dir.to_str().unwrap());
    let o = proxygen(&["--som", som, "--starter", out]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let main = dir.join("src/main.rs");
    std::fs::write(&main, "// my script\n").unwrap();

    let o = proxygen(&["--som", som, "--starter", out]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(stderr.contains("src/main.rs"), "{stderr}");
    assert!(stderr.contains("--force"), "{stderr}");
    assert_eq!(std::fs::read_to_string(&main).unwrap(), "// my script\n");

    let o = proxygen(&["--som", som, "--starter", out, "--force"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = std::fs::read_to_string(&main).unwrap();
    assert!(
        text.contains("--tcp"),
        "the starter takes osap's link options"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
