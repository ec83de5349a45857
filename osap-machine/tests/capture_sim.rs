//! Captures beside a job on the simulated plotter, in virtual time: the
//! samples come back from the Parquet (and CSV) file in time order on the
//! synchronized clock, the motors' positions move when the plan does, and
//! bad sources are refused before anything is wired.

use osap_machine::capture::{CaptureError, Clock, RecordOptions};
use osap_machine::config::MachineFile;
use osap_machine::sim::SimOptions;
use osap_machine::Machine;
use osap_sim::machine::virtual_runtime;
use std::path::PathBuf;

fn plotter() -> MachineFile {
    MachineFile::load(format!(
        "{}/../examples/machines/plotter.toml",
        env!("CARGO_MANIFEST_DIR")
    ))
    .unwrap()
}

fn out(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("osap-capture-sim-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

async fn start() -> Machine {
    Machine::simulate_with(&plotter(), SimOptions::VIRTUAL)
        .await
        .unwrap()
}

/// Pipes of `function` on module `key`, as the manager's model lists them.
async fn pipes(m: &Machine, key: &str, function: &str) -> usize {
    let runtime = m.modules()[key].runtime.clone();
    let manager = m.manager().lock().await;
    let som = manager.som();
    let ri = som.runtime_index(&runtime).unwrap();
    som.function(ri, function).unwrap().pipes.len()
}

#[test]
fn a_capture_beside_a_job_is_synchronized_and_in_order() {
    virtual_runtime().unwrap().block_on(async {
        let m = start().await;
        m.home().await.unwrap();
        let path = out("job.parquet");
        let sources = [
            "z.analog_read(0)",
            "a.get_position",
            "b.get_position.position",
        ];
        let recorder = m
            .record(&sources, RecordOptions::new(&path).period_us(2_000))
            .await
            .unwrap();
        m.start_recording().await.unwrap();
        let t0 = m.now_us().await.unwrap();
        for p in [[60.0, 20.0], [60.0, 60.0], [20.0, 60.0], [20.0, 20.0]] {
            m.goto_via_queue(p, 80.0).await.unwrap();
        }
        m.idle().await.unwrap();
        // The machine's own recording ends while the capture goes on.
        let rec = m.take_recording(t0).await.unwrap();
        m.dwell(0.2).await.unwrap();
        let t1 = m.now_us().await.unwrap();
        recorder.check().unwrap();
        let file = recorder.finish().await.unwrap();
        assert_eq!(file.stats.dropped, 0, "{:?}", file.stats);
        let capture = file.read().unwrap();
        assert_eq!(capture.rows() as u64, file.rows);
        let names: Vec<&str> = capture.series.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "z.analog_read(0).value",
                "a.get_position.position",
                "b.get_position.position",
            ]
        );
        let job_s = (t1 - t0) as f64 * 1e-6;
        for s in &capture.series {
            let clock = if s.name.contains("get_steps") {
                Clock::Arrival
            } else {
                Clock::Source
            };
            assert_eq!(s.clock, Some(clock), "{}", s.name);
            // Strictly increasing, on the machine's clock, about 500 Hz
            // (motors a and b at the machine's own 1 kHz while it records).
            assert!(
                s.time_us.windows(2).all(|w| w[0] < w[1]),
                "{} is not in time order",
                s.name
            );
            let (first, last) = (s.time_us[0], *s.time_us.last().unwrap());
            assert!(
                first < t0 && last <= t1 + 100_000,
                "{}: {first}..{last} vs {t0}..{t1}",
                s.name
            );
            let inside = s.time_us.iter().filter(|t| (t0..t1).contains(*t)).count() as f64;
            assert!(
                inside > 0.9 * job_s * 500.0,
                "{}: {inside} samples in {job_s:.2} s",
                s.name
            );
        }
        // Module z's analog input reads what its simulated board holds.
        let analog = capture.get("z.analog_read(0).value").unwrap();
        assert!(analog.value.iter().all(|v| *v == 0.0));
        // The motors start moving when the plan does: both on one clock.
        let plan_start = rec
            .planned
            .windows(2)
            .find(|w| w[0].pos != w[1].pos)
            .map(|w| w[0].t)
            .unwrap();
        let a = capture.get("a.get_position.position").unwrap();
        let rest = a.value[0];
        let moved = a
            .time_us
            .iter()
            .zip(&a.value)
            .find(|(_, v)| (**v - rest).abs() > 0.02)
            .map(|(t, _)| (*t as f64 - t0 as f64) * 1e-6)
            .unwrap();
        assert!(
            (moved - plan_start).abs() < 0.01,
            "motor a moved at {moved:.4} s, the plan at {plan_start:.4} s"
        );
        // The capture's wiring is gone; the machine's own stays.
        assert_eq!(pipes(&m, "a", "get_position").await, 1);
        assert_eq!(pipes(&m, "z", "analog_read").await, 0);
        for key in ["a", "b", "z"] {
            assert_eq!(pipes(&m, key, "sample_block").await, 0, "{key}");
        }
        m.stop().await.unwrap();
    });
}

#[test]
fn csv_captures_read_back_too() {
    virtual_runtime().unwrap().block_on(async {
        let m = start().await;
        let path = out("idle.csv");
        let recorder = m
            .record(
                &["b.get_status.queued", "z.analog_read"],
                RecordOptions::new(&path).period_us(1_000),
            )
            .await
            .unwrap();
        m.dwell(0.1).await.unwrap();
        let file = recorder.finish().await.unwrap();
        let capture = file.read().unwrap();
        let analog = capture.get("z.analog_read.value").unwrap();
        // 0.1 s at 1 kHz.
        assert!(analog.time_us.len() >= 90, "{}", analog.time_us.len());
        assert!(analog.time_us.windows(2).all(|w| w[0] < w[1]));
        // Status has no time output: b stamps each sample as it takes it
        // (in a block), at 1 kHz too (faster than the machine's own 20 Hz,
        // which comes back after).
        let queued = capture.get("b.get_status.queued").unwrap();
        assert_eq!(queued.clock, None, "a CSV file does not say");
        assert!(queued.time_us.len() >= 90, "{}", queued.time_us.len());
        m.stop().await.unwrap();
    });
}

#[test]
fn bad_sources_are_refused_before_anything_is_wired() {
    virtual_runtime().unwrap().block_on(async {
        let m = start().await;
        let path = out("bad.parquet");
        let refused = |sources: &'static [&'static str], options: RecordOptions| {
            let m = m.clone();
            async move {
                match m.record(sources, options).await {
                    Ok(_) => panic!("{sources:?} accepted"),
                    Err(e) => e,
                }
            }
        };
        let opts = || RecordOptions::new(&path);
        let e = refused(&["q.get_position"], opts()).await;
        assert!(matches!(e, CaptureError::UnknownModule { .. }), "{e}");
        assert!(e.to_string().contains("a, b, z"), "{e}");
        let e = refused(&["a.get_positoin"], opts()).await;
        assert!(matches!(e, CaptureError::UnknownFunction { .. }), "{e}");
        assert!(e.to_string().contains("get_position"), "{e}");
        let e = refused(&["a.get_position.speed"], opts()).await;
        assert!(e.to_string().contains("position: f32"), "{e}");
        let e = refused(&["a.halt"], opts()).await;
        assert!(e.to_string().contains("no output to record"), "{e}");
        let e = refused(&["z.analog_read(300)"], opts()).await;
        assert!(e.to_string().contains("out of range"), "{e}");
        let e = refused(&["z.analog_read(1, 2)"], opts()).await;
        assert!(e.to_string().contains("takes 1"), "{e}");
        let e = refused(&["z.analog_read", "z.analog_read(0)"], opts()).await;
        assert!(e.to_string().contains("sampled by another source"), "{e}");
        let e = refused(&["a.get_position"], RecordOptions::new(out("x.txt"))).await;
        assert!(e.to_string().contains(".parquet or .csv"), "{e}");
        let e = refused(&["a.get_position"], opts().period_us(10)).await;
        assert!(e.to_string().contains("at least 100"), "{e}");
        let e = refused(&[], opts()).await;
        assert!(e.to_string().contains("no source"), "{e}");
        let e = refused(
            &["a.get_position"],
            RecordOptions::new(out("no/such/dir/x.parquet")),
        )
        .await;
        assert!(matches!(e, CaptureError::Io { .. }), "{e}");
        // A good source beside a bad one: nothing was wired.
        let e = refused(&["a.get_position", "b.nope"], opts()).await;
        assert!(matches!(e, CaptureError::UnknownFunction { .. }), "{e}");
        assert_eq!(pipes(&m, "a", "get_position").await, 1);
        m.stop().await.unwrap();
    });
}

/// A stream of a's analog input while the machine homes on a's switch:
/// homing finishes, the samples arrive in order on the synchronized clock,
/// and stopping the stream unwires it.
#[test]
fn a_stream_beside_homing_on_the_same_module() {
    virtual_runtime().unwrap().block_on(async {
        let m = start().await;
        let (stream, rows) = m
            .stream(&["a.analog_read(0)"], 10_000, 1 << 16)
            .await
            .unwrap();
        assert_eq!(stream.series().len(), 1);
        tokio::time::timeout(std::time::Duration::from_secs(60), m.home())
            .await
            .expect("homing hung beside the stream")
            .unwrap();
        let times: Vec<u64> = rows.try_iter().map(|r| r.time_us).collect();
        assert!(times.len() > 100, "{} samples", times.len());
        // Stamped by a's clock: 10 ms apart within its sync's corrections,
        // after the first sample (taken as the pipe opens). The simulated
        // module's loop turns on a 1 ms tick, so a sample whose timer falls
        // due just after a tick is taken (and stamped) at the next: a gap
        // may be one tick long or short, never more, and all but a few
        // are 10 ms to within 20 µs.
        let gaps: Vec<u64> = times
            .windows(2)
            .skip(1)
            .map(|w| (w[1] - w[0]).abs_diff(10_000))
            .collect();
        assert!(gaps.iter().all(|g| *g < 1_000 + 20), "{times:?}");
        let off_tick = gaps.iter().filter(|g| **g >= 20).count();
        assert!(
            off_tick * 50 <= gaps.len(),
            "{off_tick} of {} gaps off: {times:?}",
            gaps.len()
        );
        stream.stop().await;
        assert_eq!(pipes(&m, "a", "analog_read").await, 0);
        m.stop().await.unwrap();
    });
}

/// Two captures of one module, one after the other: the second's blocks
/// are its own (a new session), none of the first's counted or written,
/// none of its own lost.
#[test]
fn a_second_capture_of_a_module_starts_its_own_count() {
    virtual_runtime().unwrap().block_on(async {
        let m = start().await;
        for k in 0..2 {
            let path = out(&format!("again{k}.csv"));
            let recorder = m
                .record(
                    &["a.get_position", "a.analog_read(0)"],
                    RecordOptions::new(&path).period_us(1_000),
                )
                .await
                .unwrap();
            m.dwell(0.2).await.unwrap();
            let file = recorder.finish().await.unwrap();
            let s = file.stats;
            assert_eq!(
                (s.lost_at_source, s.stale, s.dropped),
                (0, 0, 0),
                "{k}: {s:?}"
            );
            // Every sample taken written: 0.2 s at 1 kHz and the round
            // trips that wire and unwire the capture (about 50 ms).
            assert_eq!(s.taken_at_source, s.received, "{k}: {s:?}");
            assert!((2 * 200..=2 * 300).contains(&s.received), "{k}: {s:?}");
            assert_eq!(pipes(&m, "a", "sample_block").await, 0);
        }
        m.stop().await.unwrap();
    });
}
