//! Recordings written, read back, analysed and plotted.

use super::plot::*;
use super::*;

/// A fresh directory under the system's temporary directory.
fn tmp(name: &str) -> PathBuf {
    let dir =
        std::env::temp_dir().join(format!("osap-machine-record-{name}-{}", std::process::id()));
    let _ = fs::remove_dir_all(&dir);
    dir
}

fn s(t: f64, pos: &[f64]) -> Sample {
    Sample {
        t,
        pos: pos.to_vec(),
    }
}

fn axes(names: &[&str]) -> Vec<String> {
    names.iter().map(|n| n.to_string()).collect()
}

/// A run at `v` units/s along x and y from 0.1 s to 0.6 s, still before
/// and after, sampled every `dt` from `t_from`.
fn ramp(v: f64, dt: f64, t_from: f64, n: usize, delay: f64, offset: [f64; 2]) -> Vec<Sample> {
    (0..n)
        .map(|k| {
            let t = t_from + k as f64 * dt;
            let x = v * ((t - delay).clamp(0.1, 0.6) - 0.1);
            s(t, &[x + offset[0], x + offset[1]])
        })
        .collect()
}

#[test]
fn vibration_and_stall_columns_round_trip_and_must_fit() {
    let mut rec = Recording {
        axes: axes(&["x", "y"]),
        planned: vec![s(0.0, &[0.0, 0.0]), s(0.002, &[0.1, 0.2])],
        executed: vec![s(0.0, &[0.0, 0.0]), s(0.001, &[0.05, 0.1])],
        unshaped: Vec::new(),
        vibration: vec![
            ("x".into(), vec![f64::NAN, 0.25]),
            ("y".into(), vec![0.0, 1e-3]),
        ],
        stalled: vec![("a".into(), vec![0.0, 1.0])],
        tools: vec![("laser".into(), vec![0.25, 0.5])],
        tool_readbacks: Vec::new(),
    };
    let dir = tmp("columns");
    rec.write_csv(&dir).unwrap();
    let text = fs::read_to_string(dir.join(EXECUTED_CSV)).unwrap();
    assert_eq!(
        text,
        "t,x,y,vibration_x,vibration_y,stalled_a,tool_laser\n0,0,0,NaN,0,0,0.25\n0.001,0.05,0.1,0.25,0.001,1,0.5\n"
    );
    let back = Recording::read_csv(&dir).unwrap();
    assert_eq!(back.axes, rec.axes);
    assert_eq!(back.executed, rec.executed);
    assert_eq!(back.stalled, rec.stalled);
    assert_eq!(back.tools, rec.tools);
    assert_eq!(back.vibration[1], rec.vibration[1]);
    assert_eq!(back.vibration[0].0, "x");
    assert_eq!(back.vibration[0].1[1], 0.25);
    assert_eq!(
        back.largest_vibration(),
        vec![("x".into(), 0.25), ("y".into(), 1e-3)]
    );
    // A column that does not fit the samples is refused, naming it.
    rec.stalled[0].1.pop();
    let e = rec.write_csv(&dir).unwrap_err().to_string();
    assert!(e.contains("stalled_a has 1 values for 2 samples"), "{e}");
    let _ = fs::remove_dir_all(&dir);
}

#[test]
fn csv_round_trip() {
    let rec = Recording {
        axes: axes(&["x", "y"]),
        planned: vec![
            s(0.0, &[0.0, 0.0]),
            s(0.001, &[0.1, 1.0 / 3.0]),
            s(0.002, &[-2.5e-7, 1e6]),
        ],
        executed: vec![s(0.0005, &[0.05, f64::NAN])],
        unshaped: Vec::new(),
        vibration: Vec::new(),
        stalled: Vec::new(),
        tools: Vec::new(),
        tool_readbacks: Vec::new(),
    };
    let dir = tmp("csv");
    let files = rec.write_csv(&dir.join("out")).unwrap();
    assert_eq!(
        files,
        vec![dir.join("out/planned.csv"), dir.join("out/executed.csv")]
    );

    // By hand: the header, then t and the positions.
    let text = fs::read_to_string(&files[0]).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("t,x,y"));
    let rows: Vec<Vec<f64>> = lines
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), 3);
    assert_eq!(rows[1], vec![0.001, 0.1, 1.0 / 3.0]);
    assert_eq!(rows[2], vec![0.002, -2.5e-7, 1e6]);
    let text = fs::read_to_string(&files[1]).unwrap();
    assert_eq!(text, "t,x,y\n0.0005,0.05,NaN\n");

    // Through the reader (NaN != NaN, so compare the rest).
    let back = Recording::read_csv(&dir.join("out")).unwrap();
    assert_eq!(back.axes, rec.axes);
    assert_eq!(back.planned, rec.planned);
    assert_eq!(back.executed[0].t, 0.0005);
    assert_eq!(back.executed[0].pos[0], 0.05);
    assert!(back.executed[0].pos[1].is_nan());
    let _ = fs::remove_dir_all(&dir);
}

#[test]
fn csv_refuses_mismatched_samples_and_bad_names() {
    let dir = tmp("csv-bad");
    let mut rec = Recording {
        axes: axes(&["x", "y"]),
        planned: vec![s(0.0, &[0.0, 0.0])],
        executed: vec![s(0.0, &[0.0, 0.0]), s(0.001, &[1.0])],
        unshaped: Vec::new(),
        vibration: Vec::new(),
        stalled: Vec::new(),
        tools: Vec::new(),
        tool_readbacks: Vec::new(),
    };
    let e = rec.write_csv(&dir).unwrap_err();
    assert!(
        matches!(
            e,
            RecordError::Shape {
                index: 1,
                len: 1,
                axes: 2,
                ..
            }
        ),
        "{e:?}"
    );
    assert!(e.to_string().contains("executed.csv"), "{e}");
    assert!(!dir.join(PLANNED_CSV).exists(), "nothing written on error");

    rec.executed.pop();
    rec.axes[1] = "y,z".into();
    let e = rec.write_csv(&dir).unwrap_err();
    assert!(matches!(e, RecordError::AxisName { .. }), "{e:?}");
    assert!(e.to_string().contains("planned.csv"), "{e}");

    // A reader error names the file and line.
    fs::create_dir_all(&dir).unwrap();
    fs::write(dir.join(PLANNED_CSV), "t,x\n0,1\n0.1,oops\n").unwrap();
    let e = Recording::read_csv(&dir).unwrap_err();
    assert!(e.to_string().contains("planned.csv:3"), "{e}");
    fs::write(dir.join(PLANNED_CSV), "").unwrap();
    assert!(Recording::read_csv(&dir).is_err());
    let _ = fs::remove_dir_all(&dir);
}

#[test]
fn following_error_of_offset_and_delay() {
    // Planned every 1 ms; executed every 1 ms but 0.4 ms later, x off by
    // 0.05 and y 10 ms late at 20 units/s: 0.2 behind while moving.
    let planned = ramp(20.0, 0.001, 0.0, 801, 0.0, [0.0, 0.0]);
    let mut executed = ramp(20.0, 0.001, 0.0004, 900, 0.0, [0.05, 0.0]);
    let late = ramp(20.0, 0.001, 0.0004, 900, 0.010, [0.0, 0.0]);
    for (e, l) in executed.iter_mut().zip(&late) {
        e.pos[1] = l.pos[1];
    }
    let rec = Recording {
        axes: axes(&["x", "y"]),
        planned,
        executed,
        unshaped: Vec::new(),
        vibration: Vec::new(),
        stalled: Vec::new(),
        tools: Vec::new(),
        tool_readbacks: Vec::new(),
    };
    let fe = rec.following_error();
    assert_eq!(fe.len(), 2);
    assert_eq!(fe[0].0, "x");
    assert!((fe[0].1 - 0.05).abs() < 1e-9, "{fe:?}");
    assert_eq!(fe[1].0, "y");
    assert!((fe[1].1 - 0.2).abs() < 1e-9, "{fe:?}");

    assert!((rec.planned_duration() - 0.5).abs() < 1e-9);
    // Executed x moves after 0.0994 (its last still sample), y stops at 0.6104.
    assert!(
        (rec.executed_duration() - 0.511).abs() < 1e-9,
        "{}",
        rec.executed_duration()
    );
}

#[test]
fn following_error_skips_what_it_cannot_use() {
    let rec = Recording {
        axes: axes(&["x", "y"]),
        planned: vec![
            s(0.0, &[0.0, 0.0]),
            s(1.0, &[1.0, f64::NAN]),
            s(f64::NAN, &[0.0, 0.0]),
        ],
        executed: vec![
            s(0.5, &[0.75, 0.0]),
            s(0.5, &[9.0]),
            s(2.0, &[9.0, 9.0]),
            s(f64::NAN, &[9.0, 9.0]),
        ],
        unshaped: Vec::new(),
        vibration: Vec::new(),
        stalled: Vec::new(),
        tools: Vec::new(),
        tool_readbacks: Vec::new(),
    };
    // x: 0.75 - 0.5; y: NaN planned, so nothing to compare.
    assert_eq!(rec.following_error(), vec![("x".to_string(), 0.25)]);

    // Planned out of order is sorted first.
    let mut r2 = rec.clone();
    r2.planned.reverse();
    assert_eq!(r2.following_error(), vec![("x".to_string(), 0.25)]);

    // One planned sample: only an executed sample at its time counts.
    let one = Recording {
        axes: axes(&["x"]),
        planned: vec![s(1.0, &[2.0])],
        executed: vec![s(1.0, &[2.5]), s(1.5, &[7.0])],
        unshaped: Vec::new(),
        vibration: Vec::new(),
        stalled: Vec::new(),
        tools: Vec::new(),
        tool_readbacks: Vec::new(),
    };
    assert_eq!(one.following_error(), vec![("x".to_string(), 0.5)]);
    assert_eq!(one.planned_duration(), 0.0);
    assert_eq!(one.executed_duration(), 0.5);
}

#[test]
fn resampling() {
    // Out of order, with a NaN to skip.
    let s = [
        (0.003, 30.0),
        (0.001, 10.0),
        (0.002, f64::NAN),
        (0.005, 50.0),
    ];
    let hold = resample_hold(&s, 0.0, 0.001, 7);
    assert_eq!(hold, vec![10.0, 10.0, 10.0, 30.0, 30.0, 50.0, 50.0]);
    let lin = resample_linear(&s, 0.0, 0.001, 7);
    let want = [10.0, 10.0, 20.0, 30.0, 40.0, 50.0, 50.0];
    for (a, b) in lin.iter().zip(want) {
        assert!((a - b).abs() < 1e-9, "{lin:?}");
    }
    // Between grid points of a finer grid, and equal times.
    let lin = resample_linear(&[(0.0, 0.0), (1.0, 1.0)], 0.25, 0.5, 2);
    assert_eq!(lin, vec![0.25, 0.75]);
    let dup = [(0.0, 1.0), (1.0, 2.0), (1.0, 3.0), (2.0, 3.0)];
    assert_eq!(resample_hold(&dup, 1.0, 1.0, 1), vec![3.0]);
    assert_eq!(resample_linear(&dup, 1.0, 1.0, 1), vec![3.0]);
    assert_eq!(resample_linear(&dup, 0.5, 1.0, 1), vec![1.5]);

    // Nothing usable, or no grid, or a non-finite grid.
    assert!(resample_hold(&[], 0.0, 0.001, 3).iter().all(|v| v.is_nan()));
    assert!(resample_linear(&[(f64::NAN, 1.0)], 0.0, 0.001, 3)
        .iter()
        .all(|v| v.is_nan()));
    assert!(resample_hold(&s, 0.0, 0.001, 0).is_empty());
    assert!(resample_linear(&s, f64::NAN, 0.001, 2)
        .iter()
        .all(|v| v.is_nan()));
    assert_eq!(resample_hold(&[(5.0, 2.0)], 0.0, 1.0, 3), vec![2.0; 3]);

    // Motors read at ~1 kHz, not aligned, onto a common 1 kHz grid.
    let motor: Vec<(f64, f64)> = (0..1000)
        .map(|k| {
            let t = 0.00037 + k as f64 * 0.00097;
            (t, 3.0 * t)
        })
        .collect();
    let on_grid = resample_linear(&motor, 0.001, 0.001, 900);
    for (k, v) in on_grid.iter().enumerate() {
        let t = 0.001 + k as f64 * 0.001;
        assert!((v - 3.0 * t).abs() < 1e-9);
    }
}

fn assert_svgs(files: &[PathBuf], names: &[&str]) {
    assert_eq!(files.len(), names.len());
    for (f, n) in files.iter().zip(names) {
        assert!(f.ends_with(n), "{f:?}");
        let text = fs::read_to_string(f).unwrap();
        assert!(text.starts_with("<svg"), "{f:?}");
        assert!(text.trim_end().ends_with("</svg>"), "{f:?}");
    }
}

#[test]
fn plots_written_and_small() {
    // A 20 s run at 1 kHz: 20 000 samples per series, a circle.
    let n = 20_000;
    let circle = |delay: f64, q: f64| -> Vec<Sample> {
        (0..n)
            .map(|k| {
                let t = k as f64 * 0.001;
                let a = 0.5 * (t - delay).max(0.0);
                let x = ((30.0 * a.cos()) / q).round() * q;
                let y = ((30.0 * a.sin()) / q).round() * q;
                s(t, &[x, y])
            })
            .collect()
    };
    let rec = Recording {
        axes: axes(&["x", "y"]),
        planned: circle(0.0, 1e-12),
        executed: circle(0.002, 0.0125),
        unshaped: Vec::new(),
        vibration: Vec::new(),
        stalled: Vec::new(),
        tools: Vec::new(),
        tool_readbacks: Vec::new(),
    };
    let dir = tmp("plot");
    let files = rec.plot(&dir).unwrap();
    assert_svgs(&files, &["path.svg", "speed.svg", "error.svg"]);
    for f in &files {
        let len = fs::metadata(f).unwrap().len();
        assert!(len > 1000 && len < 400_000, "{f:?}: {len} bytes");
    }
    // The executed speed, from 5 ms windows over 12.5 µm steps, stays
    // within √2 · 12.5 µm / 5 ms = 3.54 units/s of 15 (30 · 0.5), and
    // averages to it.
    let usable = rec.usable(&rec.executed);
    let v = speeds(&usable, SPEED_WINDOW_S);
    assert!(v[100..].iter().all(|(_, v)| (v - 15.0).abs() < 3.6));
    let mean = v[100..].iter().map(|(_, v)| v).sum::<f64>() / (v.len() - 100) as f64;
    assert!((mean - 15.0).abs() < 0.05, "{mean}");
    assert!(v.windows(2).all(|w| w[1].0 - w[0].0 > 0.0));

    // One axis: position against time.
    let one = Recording {
        axes: axes(&["z"]),
        planned: ramp(20.0, 0.001, 0.0, 700, 0.0, [0.0, 0.0])
            .into_iter()
            .map(|s| Sample {
                t: s.t,
                pos: vec![s.pos[0]],
            })
            .collect(),
        executed: vec![s(0.2, &[2.0])],
        unshaped: Vec::new(),
        vibration: Vec::new(),
        stalled: Vec::new(),
        tools: Vec::new(),
        tool_readbacks: Vec::new(),
    };
    assert_svgs(
        &one.plot(&dir.join("one")).unwrap(),
        &["path.svg", "speed.svg", "error.svg"],
    );
    let _ = fs::remove_dir_all(&dir);
}

#[test]
fn empty_and_degenerate_recordings() {
    let dir = tmp("empty");
    let empty = Recording::default();
    assert_eq!(empty.following_error(), vec![]);
    assert_eq!(empty.planned_duration(), 0.0);
    assert_eq!(empty.executed_duration(), 0.0);
    let files = empty.write_csv(&dir).unwrap();
    assert_eq!(fs::read_to_string(&files[0]).unwrap(), "t\n");
    assert_eq!(Recording::read_csv(&dir).unwrap(), empty);
    assert_svgs(
        &empty.plot(&dir).unwrap(),
        &["path.svg", "speed.svg", "error.svg"],
    );

    // Axes but no samples, single samples, NaN and mismatched lengths.
    let odd = [
        Recording {
            axes: axes(&["x", "y"]),
            ..Recording::default()
        },
        Recording {
            axes: axes(&["x", "y"]),
            planned: vec![s(0.0, &[1.0, 2.0])],
            executed: vec![s(0.0, &[1.0, 2.0])],
            unshaped: Vec::new(),
            vibration: Vec::new(),
            stalled: Vec::new(),
            tools: Vec::new(),
            tool_readbacks: Vec::new(),
        },
        Recording {
            axes: axes(&["x", "y", "z"]),
            planned: vec![
                s(0.0, &[f64::NAN; 3]),
                s(f64::NAN, &[1.0; 3]),
                s(1.0, &[1.0]),
            ],
            executed: vec![s(0.5, &[]), s(0.5, &[f64::INFINITY, 0.0, f64::NAN])],
            unshaped: Vec::new(),
            vibration: Vec::new(),
            stalled: Vec::new(),
            tools: Vec::new(),
            tool_readbacks: Vec::new(),
        },
    ];
    for (i, rec) in odd.iter().enumerate() {
        let sub = dir.join(format!("odd{i}"));
        assert_svgs(
            &rec.plot(&sub).unwrap(),
            &["path.svg", "speed.svg", "error.svg"],
        );
        let _ = rec.following_error();
        assert_eq!(rec.planned_duration(), 0.0);
        assert_eq!(rec.executed_duration(), 0.0);
    }
    assert!(odd[2].write_csv(&dir.join("odd2")).is_err());
    assert_eq!(odd[1].following_error().len(), 2);
    let _ = fs::remove_dir_all(&dir);
}

#[test]
fn a_timeline_stacks_motion_and_streams() {
    let dir = std::env::temp_dir().join(format!("osap-timeline-{}", std::process::id()));
    let rec = Recording {
        axes: vec!["x".into()],
        planned: (0..100)
            .map(|i| Sample {
                t: i as f64 * 0.01,
                pos: vec![i as f64],
            })
            .collect(),
        executed: (0..100)
            .map(|i| Sample {
                t: i as f64 * 0.01,
                pos: vec![i as f64 - 0.1],
            })
            .collect(),
        unshaped: Vec::new(),
        vibration: Vec::new(),
        stalled: Vec::new(),
        tools: Vec::new(),
        tool_readbacks: Vec::new(),
    };
    let stream = Stream {
        name: "z.analog_read(0).value".into(),
        points: (0..500)
            .map(|i| (i as f64 * 0.002, (i as f64).sin()))
            .collect(),
    };
    let path = dir.join("timeline.svg");
    plot_timeline(&path, Some(&rec), std::slice::from_ref(&stream)).unwrap();
    let svg = std::fs::read_to_string(&path).unwrap();
    assert!(svg.contains("following error") && svg.contains("z.analog_read(0).value"));
    plot_timeline(&path, None, &[stream]).unwrap();
    assert!(plot_timeline(&path, None, &[]).is_err());
    std::fs::remove_dir_all(&dir).unwrap();
}
