//! Captures at 1 kHz from every module of the simulated plotter while it
//! draws a job, in virtual time: every sample the modules take arrives,
//! and loss, if any, is counted, never silent.
//!
//! `every_module_at_1_khz_beside_a_job_loses_nothing` runs one drawing
//! (about 12 s of machine time). The ignored `long_capture` runs the
//! 10-minute hatch of docs/performance.md (`CAPTURE_ROWS` rows, 101 by
//! default: 11 minutes) and prints the figures there:
//!
//! ```text
//! cargo test -p osap-machine --test capture_rate -- --ignored long_capture --nocapture
//! ```

use osap_machine::capture::{CaptureFile, RecordOptions};
use osap_machine::config::MachineFile;
use osap_machine::sim::SimOptions;
use osap_machine::svg::SvgOptions;
use osap_machine::{job, Machine};
use osap_sim::machine::virtual_runtime;
use std::path::PathBuf;

/// Every motor and sensor of the plotter: both belt motors' positions and
/// accelerometers, and what the pen module's outputs drive.
const SOURCES: [&str; 5] = [
    "a.get_position",
    "a.analog_read(0)",
    "b.get_position",
    "b.analog_read(0)",
    "z.level_read",
];

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn out(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("osap-capture-rate-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

/// What a capture beside the drawing gave.
struct Run {
    file: CaptureFile,
    /// Machine time the capture ran, s.
    seconds: f64,
    /// Wall-clock time, s.
    wall: f64,
}

fn plotter() -> MachineFile {
    MachineFile::load(root().join("examples/machines/plotter.toml")).unwrap()
}

/// `examples/jobs/drawing.svg` at 120 mm/s.
fn drawing(cfg: &MachineFile) -> job::Program {
    let text = std::fs::read_to_string(root().join("examples/jobs/drawing.svg")).unwrap();
    let drawing = osap_machine::svg::read(&text, &SvgOptions::default()).unwrap();
    job::from_svg(cfg, &drawing, 120.0).unwrap()
}

/// The hatch of docs/performance.md's 10-minute job: `rows` rows 1.3 mm
/// apart of 1 mm chords over 180 mm at 30 mm/s, the pen up between rows.
fn hatch(cfg: &MachineFile, rows: usize) -> job::Program {
    let mut g = String::from("G21 G90\nF1800\n");
    for r in 0..rows {
        let y = 10.0 + r as f64 * 1.3;
        let x_at = |k: usize| {
            let x = 10.0 + k as f64;
            if r % 2 == 0 {
                x
            } else {
                200.0 - x
            }
        };
        g.push_str(&format!("M5\nG0 X{:.3} Y{y:.3}\nM3\n", x_at(0)));
        for k in 1..=180 {
            g.push_str(&format!("G1 X{:.3}\n", x_at(k)));
        }
    }
    g.push_str("M5\nG0 X10 Y10\nM2\n");
    let gcode = osap_machine::gcode::read(&g).unwrap();
    let start = osap_machine::machine::drive::start_position(cfg);
    job::from_gcode(cfg, &gcode, &start).unwrap()
}

/// Records `SOURCES` every `period_us` while the simulated plotter runs
/// `program` once.
async fn capture_beside(
    cfg: &MachineFile,
    program: &job::Program,
    period_us: u32,
    name: &str,
) -> Run {
    let m = Machine::simulate_with(cfg, SimOptions::VIRTUAL)
        .await
        .unwrap();
    m.home().await.unwrap();
    let wall = std::time::Instant::now();
    let recorder = m
        .record(&SOURCES, RecordOptions::new(out(name)).period_us(period_us))
        .await
        .unwrap();
    let t0 = m.now_us().await.unwrap();
    m.run_program(program, |_| {}).await.unwrap();
    let t1 = m.now_us().await.unwrap();
    recorder.check().unwrap();
    let file = recorder.finish().await.unwrap();
    let wall = wall.elapsed().as_secs_f64();
    m.stop().await.unwrap();
    Run {
        file,
        seconds: (t1 - t0) as f64 * 1e-6,
        wall,
    }
}

/// Prints what a run recorded, per series: rows, the rows its span at
/// `period_us` should hold, and the counters.
fn report(run: &Run, period_us: u32) {
    let f = &run.file;
    println!(
        "{:.1} s of machine time in {:.1} s wall: {} rows; received {}, dropped {}, stale {}, lost at the modules {}, taken by the modules {}",
        run.seconds,
        run.wall,
        f.rows,
        f.stats.received,
        f.stats.dropped,
        f.stats.stale,
        f.stats.lost_at_source,
        f.stats.taken_at_source
    );
    for s in &f.series {
        let span = s.stats.last_us.unwrap_or(0) - s.stats.first_us.unwrap_or(0);
        let expected = span / u64::from(period_us) + 1;
        println!(
            "  {:28} {:8} rows, {:8} expected over {:.3} s",
            s.info.name,
            s.stats.rows,
            expected,
            span as f64 * 1e-6
        );
    }
}

#[test]
fn every_module_at_1_khz_beside_a_job_loses_nothing() {
    virtual_runtime().unwrap().block_on(async {
        let cfg = plotter();
        let run = capture_beside(&cfg, &drawing(&cfg), 1_000, "short.parquet").await;
        report(&run, 1_000);
        let f = &run.file;
        assert_eq!(f.stats.lost_at_source, 0, "{:?}", f.stats);
        assert_eq!((f.stats.dropped, f.stats.stale), (0, 0), "{:?}", f.stats);
        // Every sample a module took is in the file: per source, the rows
        // of its first series.
        let firsts = [
            "a.get_position.position",
            "a.analog_read(0).value",
            "b.get_position.position",
            "b.analog_read(0).value",
            "z.level_read.pwm0",
        ];
        let rows: u64 = f
            .series
            .iter()
            .filter(|s| firsts.contains(&s.info.name.as_str()))
            .map(|s| s.stats.rows)
            .sum();
        assert_eq!(rows, f.stats.taken_at_source, "{:?}", f.stats);
        for s in &f.series {
            // And the modules took one every period: in virtual time their
            // loops turn on tokio's 1 ms tick, so a timer that falls due
            // just after a tick fires at the next, and now and then one
            // fires a whole period late and skips it (none here, 13 of
            // 643 000 on one module over the 10-minute hatch): at most 1
            // in 1 000. Before blocks, more than half were missing.
            let span = s.stats.last_us.unwrap() - s.stats.first_us.unwrap();
            let expected = (span as f64 / 1_000.0).round() as u64 + 1;
            assert!(
                s.stats.rows <= expected + 1 && s.stats.rows * 1_000 >= expected * 999,
                "{}: {:?}",
                s.info.name,
                s.stats
            );
            assert!(run.seconds > 10.0 && span as f64 * 1e-6 > run.seconds - 0.05);
        }
    });
}

#[test]
#[ignore = "minutes of machine time: run by hand for docs/performance.md"]
fn long_capture() {
    let rows: usize = std::env::var("CAPTURE_ROWS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(101);
    let period_us: u32 = std::env::var("CAPTURE_PERIOD_US")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1_000);
    virtual_runtime().unwrap().block_on(async {
        let cfg = plotter();
        let run = capture_beside(&cfg, &hatch(&cfg, rows), period_us, "long.parquet").await;
        report(&run, period_us);
    });
}
