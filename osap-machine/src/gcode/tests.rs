//! The reader's tests, on programs as CAM tools and slicers write them.

use super::*;

fn actions(text: &str) -> Vec<Action> {
    read(text)
        .unwrap()
        .steps
        .into_iter()
        .map(|s| s.action)
        .collect()
}

#[test]
fn lines_units_modes_and_feed() {
    let a = actions("G21 G90\nG0 X10 Y5\nG1 X20 F600\nY15\nG91 X-5\nG20 G1 X1 F60\n");
    assert_eq!(
        a[0],
        Action::Rapid {
            to: [10.0, 5.0, 0.0]
        }
    );
    assert_eq!(
        a[1],
        Action::Line {
            to: [20.0, 5.0, 0.0],
            feed: 10.0
        }
    );
    assert_eq!(
        a[2],
        Action::Line {
            to: [20.0, 15.0, 0.0],
            feed: 10.0
        }
    );
    assert_eq!(
        a[3],
        Action::Line {
            to: [15.0, 15.0, 0.0],
            feed: 10.0
        }
    );
    let Action::Line { to, feed } = a[4] else {
        panic!("{:?}", a[4])
    };
    assert!((to[0] - 40.4).abs() < 1e-4, "{to:?}");
    assert!((feed - 25.4).abs() < 1e-9);
}

#[test]
fn g92_offsets_later_moves() {
    let a = actions("G0 X10\nG92 X0\nG0 X5\n");
    assert_eq!(
        a[1],
        Action::Rapid {
            to: [15.0, 0.0, 0.0]
        }
    );
}

#[test]
fn arcs_from_ij_and_r_agree() {
    let ij = actions("G1 F60\nG0 X10 Y0\nG3 X0 Y10 I-10 J0\n");
    let r = actions("G1 F60\nG0 X10 Y0\nG3 X0 Y10 R10\n");
    let (Action::Arc { center: c1, .. }, Action::Arc { center: c2, .. }) = (ij[1], r[1]) else {
        panic!("{ij:?} {r:?}")
    };
    assert!(
        (c1[0] - c2[0]).abs() < 1e-9 && (c1[1] - c2[1]).abs() < 1e-9,
        "{c1:?} {c2:?}"
    );
    assert!(c1[0].abs() < 1e-9 && c1[1].abs() < 1e-9);
}

#[test]
fn bad_blocks_name_their_line() {
    let e = read("G0 X1\n\nG1 X2\n").unwrap_err();
    assert_eq!(e.to_string().split(':').next(), Some("line 3"));
    assert!(e.to_string().contains("give F"), "{e}");
    let e = read("G1 F100\nG2 X10 Y0\n").unwrap_err();
    assert!(e.to_string().starts_with("line 2"), "{e}");
    let e = read("G1 F100\nG2 X10 Y0 I3 J0\n").unwrap_err();
    assert!(e.to_string().contains("fix I, J"), "{e}");
    let e = read("G18\n").unwrap_err();
    assert!(e.to_string().contains("only XY"), "{e}");
    let e = read("X5\n").unwrap_err();
    assert!(e.to_string().contains("motion mode"), "{e}");
}

#[test]
fn unsupported_words_warn_once_with_their_first_line() {
    let job =
        read("M117 Printing; (1/3) [x]\n(comment) G0 X1 ; note\nM117 again\nT2\nG0 X2\nT2\nM300\n")
            .unwrap();
    let lines: Vec<usize> = job.warnings.iter().map(|w| w.line).collect();
    assert_eq!(lines, vec![1, 4, 7], "{:?}", job.warnings);
    assert!(job.warnings[0].message.starts_with("M117 is not supported"));
    assert_eq!(job.steps.len(), 2);
}

fn read_marlin(text: &str) -> Job {
    read_with(text, &marlin()).unwrap()
}

/// `E` of each extruding move, in order.
fn e_of(job: &Job) -> Vec<f64> {
    job.steps
        .iter()
        .filter_map(|s| match s.action {
            Action::Extrude { e, .. } => Some(e),
            _ => None,
        })
        .collect()
}

#[test]
fn absolute_and_relative_extrusion_and_g92_e() {
    // PrusaSlicer's default: M83, relative E.
    let j = read_marlin("M83\nG1 X10 E0.5 F1200\nG1 X20 E0.5\nG1 E-0.8 F2100\nG1 E0.8\n");
    let e = e_of(&j);
    for (got, want) in e.iter().zip([0.5, 1.0, 0.2, 1.0]) {
        // Words are read as f32 (the parser's), so 0.8 is 0.800000012.
        assert!((got - want).abs() < 1e-6, "{e:?}");
    }
    // Cura's: M82, absolute E with G92 E0 resets.
    let j = read_marlin("M82\nG92 E0\nG1 X10 E0.5 F1200\nG1 X20 E1.0\nG92 E0\nG1 X30 E0.5\n");
    assert_eq!(e_of(&j), [0.5, 1.0, 1.5]);
    // G91 makes E relative too, until M82.
    let j = read_marlin("G91\nG1 X1 E0.1 F600\nG1 X1 E0.1\nM82\nG1 X1 E5\n");
    assert_eq!(e_of(&j), [0.1, 0.2, 5.0]);
    // A move of E alone keeps x, y, z and carries the feed.
    let Action::Extrude { to, e, feed } = j.steps[0].action else {
        panic!("{:?}", j.steps[0])
    };
    assert_eq!((to, e, feed), ([1.0, 0.0, 0.0], 0.1, 10.0));
    let e = read_with("G2 X1 Y1 I1 E0.2 F600\n", &ReadOptions::default()).unwrap_err();
    assert!(e.to_string().contains("arc fitting"), "{e}");
}

#[test]
fn slicer_codes_become_actions() {
    let j = read_marlin(concat!(
        "M140 S60\nM104 S210 T0\nM190 S60\nM109 R215\nG28\nG28 Z\nG29\n",
        ";LAYER_CHANGE\n;Z:0.2\nM106 S127.5\nG10\nG11\nM107\nM204 P1500 T3000\n",
        "M201 X5000 Y4000\nM203 X200 Y300\nM205 X8 Y8\nM73 P50 R3\n;LAYER:1\nM84\nM104 S0\n"
    ));
    let a: Vec<Action> = j.steps.iter().map(|s| s.action).collect();
    use super::HeaterRole::{Bed, Hotend};
    let heat = |heater, celsius, wait| Action::Heater {
        heater,
        celsius,
        wait,
    };
    assert_eq!(
        a,
        [
            heat(Bed, 60.0, false),
            heat(Hotend, 210.0, false),
            heat(Bed, 60.0, true),
            heat(Hotend, 215.0, true),
            Action::Home { axes: [false; 3] },
            Action::Home {
                axes: [false, false, true]
            },
            Action::BedMesh,
            Action::Layer { number: 1 },
            Action::Fan { duty: 0.5 },
            Action::Retract { retract: true },
            Action::Retract { retract: false },
            Action::Fan { duty: 0.0 },
            Action::Limits {
                velocity: None,
                acceleration: Some(1500.0),
                text: "M204"
            },
            Action::Limits {
                velocity: None,
                acceleration: Some(4000.0),
                text: "M201"
            },
            Action::Limits {
                velocity: Some(200.0),
                acceleration: None,
                text: "M203"
            },
            Action::Progress { percent: 50.0 },
            Action::Layer { number: 2 },
            Action::MotorsOff,
            heat(Hotend, 0.0, false),
        ]
    );
    // M205 is said once; nothing else is unknown.
    assert_eq!(j.warnings.len(), 1, "{:?}", j.warnings);
    assert!(j.warnings[0].message.starts_with("M205"));
    // A second extruder and a wait without a target are refused.
    let e = read_with("M104 S200 T1\n", &ReadOptions::default()).unwrap_err();
    assert!(e.to_string().contains("second extruder"), "{e}");
    let e = read_with("M109\n", &ReadOptions::default()).unwrap_err();
    assert!(e.to_string().contains("needs S"), "{e}");
    // In rs274ngc, G10 L2 is a work offset (refused), not a retraction.
    let e = read("G10 L2 P1 X0\n").unwrap_err();
    assert!(e.to_string().contains("G10 L"), "{e}");
}

#[test]
fn spindle_dwell_and_end() {
    let a = actions("M3 S12000\nG4 P1.5\nM5\nM30\nG0 X100\n");
    assert_eq!(
        a,
        vec![
            Action::ToolOn {
                speed: Some(12_000.0),
                dynamic: false,
            },
            Action::Dwell { seconds: 1.5 },
            Action::ToolOff,
            Action::End
        ]
    );
}

#[test]
fn travel_is_checked_over_arcs_before_motion() {
    // A half circle from (10, 0) to (-10, 0) through (0, 10): inside a
    // 20 mm high window only if the top of the arc is.
    let job = read("G0 X10 Y0\nG1 F600\nG3 X-10 Y0 I-10 J0\n").unwrap();
    job.check_travel([-20.0, -20.0, -1.0], [20.0, 20.0, 1.0])
        .unwrap();
    let e = job
        .check_travel([-20.0, -20.0, -1.0], [20.0, 9.0, 1.0])
        .unwrap_err();
    assert!(
        matches!(
            e,
            GcodeError::Travel {
                line: 3,
                axis: 'Y',
                ..
            }
        ),
        "{e}"
    );
    let e = read("G0 X300\n")
        .unwrap()
        .check_travel([0.0; 3], [200.0; 3])
        .unwrap_err();
    assert!(
        e.to_string().starts_with("line 1: X would reach 300.000"),
        "{e}"
    );
}

fn with(text: &str, options: &ReadOptions) -> Vec<Action> {
    read_with(text, options)
        .unwrap()
        .steps
        .into_iter()
        .map(|s| s.action)
        .collect()
}

fn marlin() -> ReadOptions {
    ReadOptions {
        dialect: Dialect::Marlin,
        ..ReadOptions::default()
    }
}

#[test]
fn a_comment_inside_a_block_keeps_the_words_after_it() {
    // From a LinuxCNC test program: a helical arc whose block carries a
    // comment between its G2 and its words. The start (2, -1) puts the end
    // on the circle around I0 J7.
    let a = actions("G21 G90\nG0 X2 Y-1\nG17 G2 (270 360) I0 J7 X9 Y6 Z13 F100000\n");
    assert_eq!(
        a[1],
        Action::Arc {
            to: [9.0, 6.0, 13.0],
            center: [2.0, 6.0],
            clockwise: true,
            feed: 100_000.0 / 60.0,
        }
    );
}

#[test]
fn helical_arcs_are_planned_as_helices() {
    // The planner's chords of the arc above: each on the circle, and z in
    // proportion to the angle swept (270° clockwise from the bottom).
    let a = actions("G0 X2 Y-1\nG17 G2 (270 360) I0 J7 X9 Y6 Z13 F100000\n");
    let Action::Arc {
        to,
        center,
        clockwise,
        ..
    } = a[1]
    else {
        panic!("{a:?}")
    };
    let arc = maxl::blocks::planner::Arc {
        end: to,
        plane: (0, 1),
        center,
        clockwise,
        chord_tolerance: 0.002,
    };
    let chords = arc.chords([2.0, -1.0, 0.0]).unwrap();
    assert!(chords.len() > 50, "{}", chords.len());
    let sweep = 1.5 * std::f64::consts::PI;
    let a0 = -std::f64::consts::FRAC_PI_2;
    for p in &chords {
        let r = (p[0] - 2.0).hypot(p[1] - 6.0);
        assert!((r - 7.0).abs() < 1e-9, "{p:?}");
        // Clockwise from a0: the angle swept so far.
        let swept = (a0 - (p[1] - 6.0).atan2(p[0] - 2.0)).rem_euclid(std::f64::consts::TAU);
        let swept = if swept < 1e-9 { sweep } else { swept };
        assert!((p[2] - 13.0 * swept / sweep).abs() < 1e-9, "{p:?} {swept}");
    }
    assert_eq!(*chords.last().unwrap(), [9.0, 6.0, 13.0]);
}

#[test]
fn expressions_parameters_and_o_words_are_refused_by_name() {
    let e = read("G21 G90\nG1 X0.5 Y[0.01*2] F100\n").unwrap_err();
    assert!(
        matches!(
            e,
            GcodeError::Unsupported {
                line: 2,
                feature: Unsupported::Expression,
                ..
            }
        ),
        "{e:?}"
    );
    assert_eq!(
        e.to_string().split(';').next(),
        Some("line 2: Y[0.01*2]: expressions ([...]) are not supported")
    );
    // LinuxCNC's subroutines (o-words with parameters inside).
    let sub = "G21\no100 sub\n  G1 X#1 F300\no100 endsub\no100 call [5]\nM2\n";
    let e = read(sub).unwrap_err();
    assert!(
        e.to_string()
            .starts_with("line 2: o100 sub: O-words (subroutines, loops) are not supported"),
        "{e}"
    );
    let e = read("G0 X#1\n").unwrap_err();
    assert!(
        e.to_string()
            .contains("X#1: parameters (#) are not supported"),
        "{e}"
    );
    // A loop condition is an O-word first.
    let e = read("O101 while [#1 LT 10]\n").unwrap_err();
    assert!(
        matches!(
            e,
            GcodeError::Unsupported {
                feature: Unsupported::OWord,
                ..
            }
        ),
        "{e}"
    );
    // Inside comments nothing counts; a bare program number is a name.
    let job = read("O1001 (PART [rev 2] #3)\nG0 X1 ; [done]\n").unwrap();
    assert_eq!(job.steps.len(), 1);
    let e = read("G0 X1 (not closed\n").unwrap_err();
    assert!(e.to_string().starts_with("line 1: a comment"), "{e}");
}

#[test]
fn g4_reads_by_dialect() {
    // Marlin (and Klipper, RepRapFirmware): P milliseconds, S seconds.
    let text = "G4 P250\nG4 S2\nG4\n";
    assert_eq!(
        with(text, &marlin()),
        [
            Action::Dwell { seconds: 0.25 },
            Action::Dwell { seconds: 2.0 },
            Action::Dwell { seconds: 0.0 }
        ]
    );
    // RS274/NGC (LinuxCNC, Grbl): P seconds.
    assert_eq!(actions("G4 P0.25\n"), [Action::Dwell { seconds: 0.25 }]);
    assert_eq!(actions("G4 P250\n"), [Action::Dwell { seconds: 250.0 }]);
    assert!(read("G4 S2\n")
        .unwrap_err()
        .to_string()
        .contains("G4 needs P"));
    assert_eq!(
        read_with("G0 X1\n", &marlin()).unwrap().dialect,
        Dialect::Marlin
    );
}

#[test]
fn work_offsets_place_the_program_and_g92_works_on_top() {
    let options = ReadOptions {
        work_offsets: [
            Some([20.0, 20.0, -60.0]),
            Some([150.0, 20.0, -60.0]),
            None,
            None,
            None,
            None,
        ],
        ..ReadOptions::default()
    };
    let a = with(
        "G21 G90\nG0 X10 Y5 Z1\nG55 G0 X10\nG54\nG0 X0\nG92 X0\nG0 X5\nG92.1\nG0 X5\nG53 G0 Z0\nG0 Z2\n",
        &options,
    );
    let to: Vec<[f64; 3]> = a
        .iter()
        .map(|a| match a {
            Action::Rapid { to } => *to,
            other => panic!("{other:?}"),
        })
        .collect();
    assert_eq!(
        to,
        [
            [30.0, 25.0, -59.0],  // G54 (the start)
            [160.0, 25.0, -59.0], // G55
            [20.0, 25.0, -59.0],  // G54 again
            [25.0, 25.0, -59.0],  // G92 X0 at x = 20: 5 more
            [25.0, 25.0, -59.0],  // G92.1: back to G54's x = 5
            [25.0, 25.0, 0.0],    // G53: machine z = 0, this block only
            [25.0, 25.0, -58.0],  // and G54 again
        ]
    );
    // G56 is not set: refused, naming the key to add.
    let e = read_with("G56 G0 X1\n", &options).unwrap_err();
    assert_eq!(e, GcodeError::NoWorkOffset { line: 1, code: 56 });
    assert!(e.to_string().contains("add G56 = [x, y, z]"), "{e}");
    // Without options G54 is the machine's zero, as before.
    assert_eq!(
        actions("G54 G0 X1\n"),
        [Action::Rapid {
            to: [1.0, 0.0, 0.0]
        }]
    );
    let e = read("G59.1\n").unwrap_err();
    assert!(e.to_string().contains("G54 to G59"), "{e}");
    let e = read("G10 L2 P1 X0 Y0 Z0\n").unwrap_err();
    assert!(e.to_string().contains("[work_offsets]"), "{e}");
}

#[test]
fn a_linuxcnc_cam_file_in_inches_reads_with_modal_r_arcs_and_g64() {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/jobs/slot.ngc"
    ))
    .unwrap();
    let options = ReadOptions {
        work_offsets: [Some([20.0, 20.0, -60.0]), None, None, None, None, None],
        ..ReadOptions::default()
    };
    let job = read_with(&text, &options).unwrap();
    // The modes it sets (G17 G20 G40 G49 G54 G80 G90 G94, G64 P) are
    // this reader's own: nothing is skipped.
    assert!(job.warnings.is_empty(), "{:?}", job.warnings);
    let inch = 25.4;
    let at = |x: f64, y: f64, z: f64| [20.0 + x * inch, 20.0 + y * inch, -60.0 + z * inch];
    let a: Vec<Action> = job.steps.iter().map(|s| s.action).collect();
    assert_eq!(
        a[0],
        Action::ToolOn {
            speed: Some(10_000.0),
            dynamic: false,
        }
    );
    // z = +1 in above the work; x and y stay where the machine is.
    assert_eq!(
        a[1],
        Action::Rapid {
            to: [0.0, 0.0, at(0.0, 0.0, 1.0)[2]]
        }
    );
    assert_eq!(
        a[2],
        Action::Rapid {
            to: at(0.5, 0.375, 1.0)
        }
    );
    // The plunge keeps its F after the comment: 10 in/min.
    let Action::Line { to, feed } = a[4] else {
        panic!("{:?}", a[4])
    };
    assert!((feed - 10.0 * inch / 60.0).abs() < 1e-9, "{feed}");
    assert!((to[2] - at(0.0, 0.0, -0.025)[2]).abs() < 1e-6, "{to:?}");
    // Four R arcs per pass, two of them modal (no G3 on their line), each
    // a quarter circle of 0.375 in around the slot's round ends.
    let arcs: Vec<(usize, [f64; 2])> = job
        .steps
        .iter()
        .filter_map(|s| match s.action {
            Action::Arc {
                center, clockwise, ..
            } => {
                assert!(!clockwise);
                Some((s.line, center))
            }
            _ => None,
        })
        .collect();
    assert_eq!(arcs.len(), 8, "{arcs:?}");
    for (line, c) in &arcs {
        let want = if c[0] > 40.0 {
            at(1.25, 0.75, 0.0)
        } else {
            at(0.5, 0.75, 0.0)
        };
        assert!(
            (c[0] - want[0]).abs() < 1e-4 && (c[1] - want[1]).abs() < 1e-4,
            "line {line}: {c:?}"
        );
    }
    assert_eq!(a.last(), Some(&Action::End));
}

#[test]
fn m4_is_dynamic_and_an_s_while_on_changes_the_power_in_place() {
    let a = actions("M4 S800\nG1 X10 F600\nG1 X20 S400\nX30 S400\nS200\nM5\nS900\nG1 X40\n");
    assert_eq!(
        a,
        vec![
            Action::ToolOn {
                speed: Some(800.0),
                dynamic: true,
            },
            Action::Line {
                to: [10.0, 0.0, 0.0],
                feed: 10.0
            },
            Action::ToolOn {
                speed: Some(400.0),
                dynamic: true,
            },
            Action::Line {
                to: [20.0, 0.0, 0.0],
                feed: 10.0
            },
            // The same S again changes nothing.
            Action::Line {
                to: [30.0, 0.0, 0.0],
                feed: 10.0
            },
            Action::ToolOn {
                speed: Some(200.0),
                dynamic: true,
            },
            Action::ToolOff,
            // An S with the tool off only sets the next M3's speed.
            Action::Line {
                to: [40.0, 0.0, 0.0],
                feed: 10.0
            },
        ]
    );
}
