//! Job planning throughput, segments per second: a long job of short chords
//! (as a flattened SVG drawing or G-code job gives) queued into a
//! `maxl` lookahead planner, alone and then sampled at 1 ms stamps until
//! the planner is idle, as a run records its planned positions.
//!
//! `cargo bench -p osap-machine --bench planning -- --warm-up-time 1 --measurement-time 3`
//!
//! Each job is planned with per-axis limits alone, and (`vector/`) with the
//! toolhead's vector limits on top, as a machine file sets them; then with
//! Klipper's minimum cruise ratio 0.5 (`vector+mcr/`), S-curves at
//! 100 000 mm/s³ (`scurve/`) and a speed-dependent acceleration model
//! (`motors/`). Two jobs
//! on a 200 × 150 mm sheet, 0.2 mm chords at 100 mm/s:
//! - `zigzag`: raster hatching, rows 1 mm apart (long collinear runs, a
//!   reversal at every row end);
//! - `spiral`: an elliptical spiral inward, 1 mm pitch (every junction a
//!   small turn, the turn growing toward the centre).

// criterion_main! writes an undocumented `main`.
#![allow(missing_docs)]

use criterion::{black_box, criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use maxl::blocks::planner::{AccelModel, Limits, Planner, VectorLimits, KLIPPER_MIN_CRUISE_RATIO};

/// Chord length, mm.
const CHORD: f64 = 0.2;
/// Sheet, mm.
const W: f64 = 200.0;
const H: f64 = 150.0;
/// Row spacing and spiral pitch, mm.
const PITCH: f64 = 1.0;
/// Feed, mm/s.
const FEED: f64 = 100.0;
/// Sample stamp interval, µs.
const STAMP_US: u64 = 1000;

/// Raster hatching: rows of `CHORD` chords, alternating direction.
fn zigzag() -> Vec<[f64; 2]> {
    let per_row = (W / CHORD).round() as usize;
    let rows = (H / PITCH).round() as usize + 1;
    let mut pts = Vec::with_capacity(rows * (per_row + 1));
    for r in 0..rows {
        let y = r as f64 * PITCH;
        for k in 0..=per_row {
            let x = k as f64 * CHORD;
            pts.push([if r % 2 == 0 { x } else { W - x }, y]);
        }
    }
    pts
}

/// An elliptical spiral from the sheet's edge inward, in chords of about
/// `CHORD`.
fn spiral() -> Vec<[f64; 2]> {
    let (cx, cy) = (W / 2.0, H / 2.0);
    let mut pts = Vec::new();
    let mut a = 0.0f64;
    loop {
        // The semi-axes shrink by one pitch per turn.
        let shrink = PITCH * a / std::f64::consts::TAU;
        let (rx, ry) = (cx - shrink, cy - shrink);
        if ry <= PITCH {
            break;
        }
        pts.push([cx + rx * a.cos(), cy + ry * a.sin()]);
        // Step the angle so the chord is about CHORD long.
        let speed = (rx * a.sin()).hypot(ry * a.cos()).max(PITCH);
        a += CHORD / speed;
    }
    pts
}

fn limits() -> Limits<2> {
    Limits::new([300.0, 300.0], [3000.0, 3000.0], 0.02).unwrap()
}

/// The toolhead's limits as a machine file sets them (the plotter's):
/// |v| ≤ 250 mm/s, |a| ≤ 2500 mm/s², both axes the toolhead's.
fn vector() -> VectorLimits {
    VectorLimits::new(250.0, 2500.0).unwrap().with_path_axes(2)
}

/// How a benchmark plans: the toolhead's vector limits, Klipper's minimum
/// cruise ratio on top, a jerk limit (S-curve), or a motor model.
#[derive(Clone, Copy, PartialEq)]
enum Mode {
    Vector,
    Cruise,
    Scurve,
    Motors,
}

/// A falling acceleration, as a stepper's torque falls with speed:
/// 6000 mm/s² at rest, 1500 at 300 mm/s.
#[derive(Debug)]
struct Falling;

impl AccelModel<2> for Falling {
    fn max_accel(&self, _: &[f64; 2], _: &[f64; 2], speed: f64) -> f64 {
        6000.0 * (1.0 - speed / 400.0).max(0.25)
    }
}

/// A planner at the job's first point holding the whole job, planning in
/// `mode`.
fn queued_with(path: &[[f64; 2]], mode: Mode) -> Planner<2> {
    let mut v = vector();
    let mut l = limits();
    match mode {
        Mode::Vector | Mode::Motors => {}
        Mode::Cruise => v = v.with_min_cruise_ratio(KLIPPER_MIN_CRUISE_RATIO).unwrap(),
        Mode::Scurve => l = l.with_max_jerk([100_000.0; 2]).unwrap(),
    }
    let mut p = Planner::with_vector_limits(l, v, path.len()).unwrap();
    if mode == Mode::Motors {
        p.set_accel_model(Some(std::sync::Arc::new(Falling)));
    }
    p.set_position(path[0]).unwrap();
    for q in &path[1..] {
        p.line(*q, FEED).unwrap();
    }
    p
}

/// A planner at the job's first point holding the whole job.
fn queued(path: &[[f64; 2]]) -> Planner<2> {
    let mut p = Planner::with_capacity(limits(), path.len()).unwrap();
    p.set_position(path[0]).unwrap();
    for q in &path[1..] {
        p.line(*q, FEED).unwrap();
    }
    p
}

/// Samples every `STAMP_US` until idle; returns the samples taken.
fn sample_all(p: &mut Planner<2>) -> u64 {
    let mut t = 0;
    let mut acc = 0.0;
    while !p.is_idle() {
        let q = p.sample(t).unwrap();
        acc += q[0] + q[1];
        t += STAMP_US;
    }
    black_box(acc);
    t / STAMP_US
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("planning");
    g.sample_size(10);
    for (name, path) in [("zigzag", zigzag()), ("spiral", spiral())] {
        // What one iteration plans: a chord to every point after the first.
        let mut p = queued(&path);
        let segments = p.stats().queued_total;
        let length: f64 = path
            .windows(2)
            .map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]))
            .sum();
        let samples = sample_all(&mut p);
        println!(
            "{name}: {segments} segments, {length:.0} mm, job {:.1} s planned, {samples} samples at {STAMP_US} µs",
            samples as f64 * STAMP_US as f64 * 1e-6
        );
        assert_eq!(segments as usize, path.len() - 1, "every chord queued");

        g.throughput(Throughput::Elements(segments));
        g.bench_with_input(BenchmarkId::new("queue", name), &path, |b, path| {
            b.iter(|| queued(path).stats().pending)
        });
        g.bench_with_input(BenchmarkId::new("queue+sample", name), &path, |b, path| {
            b.iter(|| sample_all(&mut queued(path)))
        });
        // As a machine plans: the toolhead's vector limits on top; and
        // with the minimum cruise ratio, S-curves, or a motor model.
        for (label, mode) in [
            ("vector", Mode::Vector),
            ("vector+mcr", Mode::Cruise),
            ("scurve", Mode::Scurve),
            ("motors", Mode::Motors),
        ] {
            g.bench_with_input(
                BenchmarkId::new(format!("{label}/queue"), name),
                &path,
                |b, path| b.iter(|| queued_with(path, mode).stats().pending),
            );
        }
        g.bench_with_input(
            BenchmarkId::new("vector/queue+sample", name),
            &path,
            |b, path| b.iter(|| sample_all(&mut queued_with(path, Mode::Vector))),
        );
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
