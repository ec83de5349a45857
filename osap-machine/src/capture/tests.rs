//! Capture specs, resolution and the recorder's bookkeeping.

use super::source::resolve_function;
use super::*;

#[test]
fn sources_parse() {
    let s = SourceSpec::parse("z.analog_read(2).value").unwrap();
    assert_eq!(
        (
            s.module.as_str(),
            s.function.as_str(),
            s.args.clone(),
            s.output.as_deref()
        ),
        ("z", "analog_read", vec!["2".to_string()], Some("value"))
    );
    let s = SourceSpec::parse("a.get_position").unwrap();
    assert_eq!(s.output, None);
    assert!(s.args.is_empty());
    let s = SourceSpec::parse("a.get_steps.steps").unwrap();
    assert_eq!(s.output.as_deref(), Some("steps"));
    assert_eq!(s.prefix(), "a.get_steps");
    for bad in [
        "",
        "z",
        "z.",
        ".f",
        "z.f(1",
        "z.f(1)x",
        "z.f.o.p",
        "z.f(,)",
        "z.f(1).o.p",
    ] {
        let e = SourceSpec::parse(bad).unwrap_err();
        assert!(e.to_string().contains("MODULE.FUNCTION"), "{bad}: {e}");
    }
}

#[test]
fn holds_keep_the_fastest_timer_and_give_the_machine_its_own_back() {
    use crate::machine::holds::Holds;
    let h = Holds::default();
    let f = FnRef::new("a", "get_fault");
    assert_eq!(
        h.acquire(&f, 1, 10_000, InputMode::OnTimer(5_000)),
        InputMode::OnTimer(5_000)
    );
    assert_eq!(
        h.acquire(&f, 2, 1_000, InputMode::OnTimer(5_000)),
        InputMode::OnTimer(1_000)
    );
    assert_eq!(h.release(&f, 2), Some(InputMode::OnTimer(5_000)));
    assert_eq!(h.release(&f, 1), Some(InputMode::OnTimer(5_000)));
    assert_eq!(h.release(&f, 1), None);
    let p = FnRef::new("a", "get_position");
    assert_eq!(
        h.acquire(&p, 3, 2_000, InputMode::OnAnyFresh),
        InputMode::OnTimer(2_000)
    );
    // The machine starts and stops its own recording meanwhile.
    assert_eq!(
        h.machine_sets(&p, InputMode::OnTimer(1_000)),
        InputMode::OnTimer(1_000)
    );
    assert_eq!(
        h.machine_sets(&p, InputMode::OnAnyFresh),
        InputMode::OnTimer(2_000)
    );
    assert_eq!(h.release(&p, 3), Some(InputMode::OnAnyFresh));
    assert_eq!(
        h.machine_sets(&p, InputMode::OnAnyFresh),
        InputMode::OnAnyFresh
    );
}

fn function(outputs: &[(&str, &str)]) -> SomFunction {
    let arg = |(name, ty): &(&str, &str)| osap_host::som::model::SomArg {
        name: name.to_string(),
        type_name: ty.to_string(),
    };
    SomFunction {
        name: "f".into(),
        summary: String::new(),
        port: 1,
        pipe_ports: vec![2, 3],
        inputs: Vec::new(),
        outputs: outputs.iter().map(arg).collect(),
        input_mode: osap_host::som::model::SomInputMode::OnAnyFresh,
        output_mode: osap_host::som::model::SomOutputMode::Always,
        pipe_slots: 2,
        pipes: Vec::new(),
    }
}

#[test]
fn outputs_that_are_not_numbers_are_refused_naming_their_type() {
    let f = function(&[("time", "u64"), ("name", "utf8"), ("level", "f32")]);
    let spec = |t: &str| SourceSpec::parse(t).unwrap();
    let e = resolve_function(&spec("m.f.name"), "m".into(), &f).unwrap_err();
    assert!(matches!(e, CaptureError::NotNumeric { .. }), "{e}");
    assert!(e.to_string().contains("utf8, not a number"), "{e}");
    // Without .OUTPUT the numeric ones are taken, the time first.
    let r = resolve_function(&spec("m.f"), "m".into(), &f).unwrap();
    assert_eq!(r.outputs, [0, 2]);
    assert_eq!(r.series, ["m.f.level"]);
    assert!(r.stamped);
    // A function with only a string: refused, naming it.
    let only = function(&[("name", "utf8")]);
    let e = resolve_function(&spec("m.f"), "m".into(), &only).unwrap_err();
    assert!(e.to_string().contains("output \"name\" is a utf8"), "{e}");
}
