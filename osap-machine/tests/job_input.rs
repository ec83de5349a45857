//! No job input panics its reader: arbitrary text, G-code's own words in
//! any order, and SVG paths of any shape give a job or an error.

use osap_machine::gcode;
use proptest::prelude::*;

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn arbitrary_text_never_panics(text in "\\PC{0,200}") {
        if let Ok(job) = gcode::read(&text) {
            let _ = job.check_travel([-1e3; 3], [1e3; 3]);
        }
    }

    #[test]
    fn gcode_words_in_any_order_never_panic(
        text in "([GMTFSXYZIJRP][-]?[0-9]{1,4}(\\.[0-9]{1,3})?[ \\n;()]{0,2}){0,40}"
    ) {
        if let Ok(job) = gcode::read(&text) {
            for step in &job.steps {
                prop_assert!(step.line >= 1);
            }
            let _ = job.check_travel([-1e3; 3], [1e3; 3]);
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn arbitrary_svg_text_never_panics(text in "\\PC{0,200}") {
        let _ = osap_machine::svg::read(&text, &Default::default());
    }

    #[test]
    fn svg_paths_of_any_shape_never_panic(
        d in "([MLQCZHVmlqczhv]( ?-?[0-9]{1,3}(\\.[0-9])?){0,6} ?){0,12}"
    ) {
        let doc = format!(
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="10mm" height="10mm"><path d="{d}" stroke="black"/></svg>"#
        );
        if let Ok(drawing) = osap_machine::svg::read(&doc, &Default::default()) {
            for l in &drawing.polylines {
                prop_assert!(l.iter().all(|p| p[0].is_finite() && p[1].is_finite()));
            }
        }
    }
}
