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
    fn unsupported_words_warn_with_their_line() {
        let job = read("G28\n(comment) G0 X1 ; note\nM106 S255\nT2\nG0 X2\n").unwrap();
        let lines: Vec<usize> = job.warnings.iter().map(|w| w.line).collect();
        assert_eq!(lines, vec![1, 3, 4], "{:?}", job.warnings);
        assert_eq!(job.steps.len(), 2);
    }

    #[test]
    fn spindle_dwell_and_end() {
        let a = actions("M3 S12000\nG4 P1.5\nM5\nM30\nG0 X100\n");
        assert_eq!(
            a,
            vec![
                Action::ToolOn {
                    speed: Some(12_000.0)
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
