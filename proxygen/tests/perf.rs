//! Generating proxies for 64 device types with 20 functions each takes
//! well under a second (the number is recorded in `docs/proxygen.md`).

use osap_host::som::model::{SomArg, SomFunction, SomInputMode, SomOutputMode};
use osap_host::som::Som;
use std::time::{Duration, Instant};

fn arg(name: &str, ty: &str) -> SomArg {
    SomArg {
        name: name.into(),
        type_name: ty.into(),
    }
}

#[test]
fn sixty_four_devices_of_twenty_functions() {
    let base = Som::from_json(include_str!("data/small-machine.som.json")).unwrap();
    let template = base.runtimes[2].clone();
    let mut som = Som::empty();
    som.runtimes.push(base.runtimes[0].clone());
    for d in 0..64 {
        let mut r = template.clone();
        r.record.name = format!("dev{d}");
        r.record.type_name = format!("type_{d}");
        r.functions = (0..20u16)
            .map(|f| SomFunction {
                name: format!("function_{f}"),
                summary: String::new(),
                port: 1 + f * 3,
                pipe_ports: vec![2 + f * 3, 3 + f * 3],
                inputs: vec![
                    arg("time", "u64"),
                    arg("position", "f32"),
                    arg("label", "utf8"),
                ],
                outputs: vec![arg("time", "u64"), arg("values", "arry_f32")],
                input_mode: SomInputMode::OnAnyFresh,
                output_mode: SomOutputMode::Always,
                pipe_slots: 2,
                pipes: Vec::new(),
            })
            .collect();
        som.runtimes.push(r);
    }
    let start = Instant::now();
    let files = proxygen::generate(&som, &proxygen::Options::default()).unwrap();
    let took = start.elapsed();
    assert_eq!(files.len(), 65);
    let bytes: usize = files.iter().map(|f| f.contents.len()).sum();
    println!(
        "64 device types x 20 functions: {} files, {bytes} bytes in {took:?}",
        files.len()
    );
    assert!(took < Duration::from_secs(1), "took {took:?}");
}
