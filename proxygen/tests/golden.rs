//! Golden tests: fixed system object models → the generated files,
//! compared byte for byte with the checked-in expected output
//! (`PROXYGEN_BLESS=1 cargo test -p proxygen` rewrites it).

mod common;

use osap_host::som::Som;
use proxygen::{Options, StarterOptions};

fn som(name: &str) -> Som {
    let path = common::tests_dir("data").join(name);
    Som::from_json(&std::fs::read_to_string(&path).unwrap()).unwrap()
}

#[test]
fn small_machine() {
    let files = proxygen::generate(&som("small-machine.som.json"), &Options::default()).unwrap();
    common::golden(&common::tests_dir("generated_small_machine"), &files);
}

#[test]
fn odd_names_types_and_classes() {
    let files = proxygen::generate(&som("odd.som.json"), &Options::default()).unwrap();
    common::golden(&common::tests_dir("golden/odd"), &files);
}

#[test]
fn starter() {
    let files = proxygen::starter(
        &som("small-machine.som.json"),
        &StarterOptions {
            name: "my-machine".into(),
            osap_host: "../osap-rs/osap-host".into(),
            osap_sim: "../osap-rs/osap-sim".into(),
            proxies: Options::default(),
        },
    )
    .unwrap();
    let files: Vec<_> = files
        .into_iter()
        .filter(|f| !f.path.starts_with("src/proxies"))
        .collect();
    common::golden(&common::tests_dir("golden/starter"), &files);
}

#[test]
fn nothing_to_generate() {
    let mut som = som("small-machine.som.json");
    som.runtimes.iter_mut().for_each(|r| r.functions.clear());
    let e = proxygen::generate(&som, &Options::default()).unwrap_err();
    assert_eq!(
        e.to_string(),
        "no runtime in the system object model has functions or classes"
    );
}
