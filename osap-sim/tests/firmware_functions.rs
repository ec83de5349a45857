//! Simulated modules present exactly the module firmware's functions: a
//! scan of every module of every shipped topology finds, on each
//! `stepper`, the names, argument names and types and output names of
//! osap-module's function set, in port order, and so the same
//! `FUNCTION_SET_ID` every firmware image embeds. A proxy generated from a
//! simulated scan therefore binds on hardware.

use osap_host::som::Manager;
use osap_host::{Host, HostConfig};
use osap_module::functions::{function_set_id, SIGNATURES};
use osap_module::FUNCTION_SET_ID;
use osap_sim::machine::SimMachine;
use osap_sim::topology::{ModuleKind, SimSpec};
use pipes_core::signature::{Arg, Signature};
use pipes_core::Type;
use std::path::PathBuf;

fn shipped() -> Vec<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("topologies");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .expect("the topologies folder")
        .map(|e| e.expect("a folder entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    files.sort();
    files
}

/// A scanned argument list as a signature's (leaked: a test's lifetime).
fn args(scanned: &[osap_host::som::model::SomArg]) -> &'static [Arg] {
    let args: Vec<Arg> = scanned
        .iter()
        .map(|a| {
            let ty: Type = a
                .ty()
                .unwrap_or_else(|| panic!("unknown type {:?}", a.type_name));
            Arg::new(Box::leak(a.name.clone().into_boxed_str()), ty)
        })
        .collect();
    Box::leak(args.into_boxed_slice())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_simulated_stepper_presents_the_firmware_function_set() {
    let files = shipped();
    assert!(files.len() >= 4, "{files:?}");
    let mut steppers = 0;
    for file in files {
        let topology = SimSpec::load(&file)
            .unwrap_or_else(|e| panic!("{}: {e}", file.display()))
            .with_zero_latency(true);
        let host = Host::start(HostConfig::named("h")).unwrap();
        let sim = SimMachine::start(&host, &topology).await.unwrap();
        let mut m = Manager::new(&host).await.unwrap();
        let report = m.refresh().await.unwrap();
        assert!(
            report.scan_failures.is_empty() && report.function_failures.is_empty(),
            "{}: {report:?}",
            file.display()
        );
        for spec in &topology.modules {
            let what = format!("{} in {}", spec.name, file.display());
            let rt = m
                .som()
                .runtimes
                .iter()
                .find(|r| r.record.name == spec.name)
                .unwrap_or_else(|| panic!("{what}: not found by the scan"));
            assert_eq!(rt.record.type_name, spec.type_name, "{what}");
            match spec.kind() {
                Some(ModuleKind::Hub) => assert!(rt.functions.is_empty(), "{what}"),
                Some(ModuleKind::Stepper) => {
                    steppers += 1;
                    let scanned: Vec<&'static Signature> = rt
                        .functions
                        .iter()
                        .map(|f| {
                            &*Box::leak(Box::new(Signature {
                                name: Box::leak(f.name.clone().into_boxed_str()),
                                inputs: args(&f.inputs),
                                outputs: args(&f.outputs),
                            }))
                        })
                        .collect();
                    assert_eq!(scanned.len(), SIGNATURES.len(), "{what}");
                    for (got, want) in scanned.iter().zip(SIGNATURES) {
                        assert_eq!(**got, *want, "{what}");
                    }
                    assert_eq!(function_set_id(&scanned), FUNCTION_SET_ID, "{what}");
                }
                None => panic!("{what}: unknown type"),
            }
        }
        sim.stop().await.unwrap();
    }
    assert!(steppers >= 6, "only {steppers} steppers scanned");
}

#[test]
fn bad_topologies_are_refused_with_file_line_and_fix() {
    let dir = std::env::temp_dir().join(format!("osap-bad-topology-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let cases = [
        (
            "[[module]]\nname = \"x\"\ntype = \"axis\"\n\n[[link]]\na = \"host\"\nb = \"x\"\nkind = \"usb\"\n",
            "line 1",
            "unknown type \"axis\"",
        ),
        (
            "[[module]]\nname = \"x\"\ntype = \"stepper\"\n\n[[module]]\nname = \"x\"\ntype = \"hub\"\n",
            "line 5",
            "give each module its own name",
        ),
        (
            "[[module]]\nname = \"x\"\ntype = \"stepper\"\n\n[[link]]\na = \"host\"\nb = \"y\"\nkind = \"usb\"\n",
            "line 5",
            "no module is named \"y\"",
        ),
        (
            "[[module]]\nname = \"x\"\ntype = \"stepper\"\n[[module]]\nname = \"hub\"\ntype = \"hub\"\n[[link]]\na = \"host\"\nb = \"hub\"\nkind = \"usb\"\n[[link]]\na = \"hub\"\nb = \"x\"\nkind = \"uart\"\n[[link]]\na = \"x\"\nb = \"hub\"\nkind = \"rs485\"\n",
            "line 15",
            "already has its uart/rs485 link",
        ),
        (
            "[[module]]\nname = \"x\"\ntype = \"stepper\"\n[[link]]\na = \"host\"\nb = \"x\"\nkind = \"memory\"\n",
            "line 4",
            "the module firmware has a usb link (its link 0)",
        ),
        ("[[module]\nname = 1\n", "TOML parse error", "line 1"),
    ];
    for (i, (text, line, fix)) in cases.iter().enumerate() {
        let path = dir.join(format!("bad-{i}.toml"));
        std::fs::write(&path, text).unwrap();
        let e = SimSpec::load(&path).unwrap_err().to_string();
        assert!(e.contains(&*path.to_string_lossy()), "case {i}: {e}");
        assert!(e.contains(line), "case {i}: {e}");
        assert!(e.contains(fix), "case {i}: {e}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
