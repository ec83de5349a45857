//! How far the B-spline a module runs strays from the planned path at a
//! corner, as a function of control-point interval, corner angle and speed.
//!
//! For each case a two-segment path turning by the corner angle at the
//! origin is sampled at the stamps of the interval; the samples become
//! uniform cubic B-spline control points (the track convention: the point
//! stamped `T_i` is `P_i`), the spline is evaluated densely with
//! `maxl::eval_f64`, and the deviation is the Hausdorff distance between the
//! spline and the polyline near the corner (the spline's farthest point from
//! the polyline, or the corner's distance to the spline, whichever is
//! larger), worst over several phases of the corner against the stamp grid.
//!
//! Two ways through the corner:
//! - `planned`: the lookahead planner's profile (acceleration limit and
//!   junction deviation from the options), which slows for the corner;
//! - `full`: the worst case, the corner taken at full speed with no
//!   slowdown.
//!
//! ```text
//! cargo run -p osap-examples --release --bin corner_deviation -- --out docs/img
//! ```

use std::error::Error;
use std::fs;
use std::path::PathBuf;

use clap::Parser;
use maxl::blocks::planner::{Limits, Planner};
use maxl::{eval_f64, Interval};
use plotters::coord::Shift;
use plotters::prelude::*;

#[derive(Parser, Debug)]
#[command(about = "Spline deviation from the planned path at corners")]
struct Args {
    /// Directory for the SVG plots.
    #[arg(long, default_value = "examples-out")]
    out: PathBuf,
    /// Also write every case as CSV to this file.
    #[arg(long)]
    csv: Option<PathBuf>,
    /// Acceleration limit of the planned case (mm/s², both axes).
    #[arg(long, default_value_t = 3000.0)]
    accel: f64,
    /// Junction deviation of the planned case (mm).
    #[arg(long, default_value_t = 0.02)]
    junction_deviation: f64,
    /// Corner phases against the stamp grid to take the worst of.
    #[arg(long, default_value_t = 16)]
    phases: u32,
}

const INTERVALS: [u32; 7] = [256, 512, 1024, 2048, 4096, 8192, 16384];
const ANGLES: [f64; 7] = [15.0, 30.0, 45.0, 60.0, 90.0, 120.0, 165.0];
const SPEEDS: [f64; 6] = [10.0, 25.0, 50.0, 100.0, 200.0, 500.0];
/// Spline evaluations per interval.
const DENSE: u32 = 64;

#[derive(Clone, Copy, Debug, PartialEq)]
enum Mode {
    Planned,
    Full,
}

impl Mode {
    fn name(self) -> &'static str {
        match self {
            Mode::Planned => "planned",
            Mode::Full => "full",
        }
    }
}

/// One case's result.
struct Case {
    mode: Mode,
    angle: f64,
    speed: f64,
    interval: u32,
    /// Largest deviation (mm).
    dev: f64,
    /// Speed through the corner (mm/s).
    corner_speed: f64,
}

/// The corner: from (−L, 0) to the origin, then turning by `turn` radians.
struct Corner {
    leg: f64,
    dir_out: [f64; 2],
}

impl Corner {
    fn new(turn: f64, speed: f64, accel: f64) -> Self {
        Corner {
            // Long enough to reach full speed before and stop after.
            leg: 20.0f64.max(1.5 * speed * speed / accel + 5.0),
            dir_out: [turn.cos(), turn.sin()],
        }
    }

    fn start(&self) -> [f64; 2] {
        [-self.leg, 0.0]
    }

    fn end(&self) -> [f64; 2] {
        [self.leg * self.dir_out[0], self.leg * self.dir_out[1]]
    }

    /// Point at arc length `s` from the corner (negative before it).
    fn at(&self, s: f64) -> [f64; 2] {
        let s = s.clamp(-self.leg, self.leg);
        if s < 0.0 {
            [s, 0.0]
        } else {
            [s * self.dir_out[0], s * self.dir_out[1]]
        }
    }

    /// Distance from `p` to the polyline.
    fn distance(&self, p: [f64; 2]) -> f64 {
        let seg = |a: [f64; 2], b: [f64; 2]| {
            let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
            let t =
                (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / (dx * dx + dy * dy)).clamp(0.0, 1.0);
            (p[0] - a[0] - t * dx).hypot(p[1] - a[1] - t * dy)
        };
        seg(self.start(), [0.0, 0.0]).min(seg([0.0, 0.0], self.end()))
    }
}

/// Control points (one per stamp) and the corner time (µs).
struct Samples {
    points: Vec<[f64; 2]>,
    corner_us: f64,
    corner_speed: f64,
}

/// The planner's path sampled at every stamp, the path starting at
/// `start_us` (not on the grid, to set the corner's phase).
fn planned(
    c: &Corner,
    speed: f64,
    args: &Args,
    iv: u32,
    start_us: u64,
) -> Result<Samples, Box<dyn Error>> {
    let limits = Limits::new([1e4; 2], [args.accel; 2], args.junction_deviation)?;
    let mut p = Planner::<2>::new(limits)?;
    p.set_position(c.start())?;
    p.line([0.0, 0.0], speed)?;
    p.line(c.end(), speed)?;
    p.start(start_us)?;
    let plan = p.plan();
    let corner_us = plan.segments[0].end_us();
    let corner_speed = plan.segments[0].profile.exit;
    let mut points = Vec::new();
    let mut t = 0u64;
    loop {
        points.push(p.sample(t)?);
        if p.is_idle() && t > start_us {
            break;
        }
        t += iv as u64;
    }
    // Rest at the end for the last segments' lookahead.
    let last = points[points.len() - 1];
    points.extend([last; 3]);
    Ok(Samples {
        points,
        corner_us,
        corner_speed,
    })
}

/// Constant speed through the corner, reaching it at `corner_us`.
fn full_speed(c: &Corner, speed: f64, iv: u32, corner_us: f64) -> Samples {
    let n = ((corner_us + c.leg / speed * 1e6) / iv as f64).ceil() as usize + 4;
    let points = (0..n)
        .map(|k| c.at(speed * (k as f64 * iv as f64 - corner_us) * 1e-6))
        .collect();
    Samples {
        points,
        corner_us,
        corner_speed: speed,
    }
}

/// Hausdorff distance between the spline and the polyline near the corner:
/// the larger of the spline's farthest point from the polyline and the
/// corner's distance to the spline (the part of the corner cut off, which
/// at sharp turns is the larger: there a cutting spline can pass close to
/// the other leg).
fn deviation(c: &Corner, s: &Samples, iv: Interval) -> f64 {
    let dt = iv.micros() as f64;
    let ic = (s.corner_us / dt) as usize;
    let mut worst = 0.0f64;
    let mut to_corner = f64::INFINITY;
    // Only segments whose 4 points straddle the corner leave the polyline:
    // those within ±2 intervals of it. ±4 leaves margin.
    for i in ic.saturating_sub(4).max(1)..(ic + 5).min(s.points.len() - 2) {
        let q = &s.points[i - 1..i + 3];
        let px = [q[0][0], q[1][0], q[2][0], q[3][0]];
        let py = [q[0][1], q[1][1], q[2][1], q[3][1]];
        for j in 0..DENSE {
            let du = j * iv.micros() / DENSE;
            let x = eval_f64(&px, du, iv).pos;
            let y = eval_f64(&py, du, iv).pos;
            worst = worst.max(c.distance([x, y]));
            to_corner = to_corner.min(x.hypot(y));
        }
    }
    worst.max(to_corner)
}

fn run_case(
    args: &Args,
    mode: Mode,
    angle: f64,
    speed: f64,
    us: u32,
) -> Result<Case, Box<dyn Error>> {
    let iv = Interval::from_micros(us).map_err(|e| format!("interval {}", e.0))?;
    let c = Corner::new(angle.to_radians(), speed, args.accel);
    let mut dev = 0.0f64;
    let mut corner_speed = 0.0;
    for k in 0..args.phases.max(1) {
        let phase = us as f64 * k as f64 / args.phases.max(1) as f64;
        let s = match mode {
            Mode::Planned => planned(&c, speed, args, us, 10 * us as u64 + phase as u64)?,
            Mode::Full => full_speed(
                &c,
                speed,
                us,
                10.0 * us as f64 + c.leg / speed * 1e6 + phase,
            ),
        };
        corner_speed = s.corner_speed;
        dev = dev.max(deviation(&c, &s, iv));
    }
    Ok(Case {
        mode,
        angle,
        speed,
        interval: us,
        dev,
        corner_speed,
    })
}

fn find(cases: &[Case], mode: Mode, angle: f64, speed: f64, us: u32) -> &Case {
    cases
        .iter()
        .find(|c| c.mode == mode && c.angle == angle && c.speed == speed && c.interval == us)
        .expect("every case was run")
}

/// Largest interval whose deviation stays under `limit` (mm) for every
/// interval up to it, worst over all angles.
fn recommended(cases: &[Case], mode: Mode, speed: f64, limit: f64) -> Option<u32> {
    let mut best = None;
    for us in INTERVALS {
        let worst = ANGLES
            .iter()
            .map(|&a| find(cases, mode, a, speed, us).dev)
            .fold(0.0, f64::max);
        if worst >= limit {
            break;
        }
        best = Some(us);
    }
    best
}

fn print_tables(args: &Args, cases: &[Case]) {
    println!(
        "Planned: accel {} mm/s², junction deviation {} mm. Deviation in µm, worst over {} phases.\n",
        args.accel, args.junction_deviation, args.phases
    );
    for mode in [Mode::Full, Mode::Planned] {
        println!("### {} — 90° corner\n", mode.name());
        print!("| speed (mm/s) | corner speed |");
        for us in INTERVALS {
            print!(" {us} µs |");
        }
        println!();
        println!("|---|---|{}", "---|".repeat(INTERVALS.len()));
        for v in SPEEDS {
            let cs = find(cases, mode, 90.0, v, 1024).corner_speed;
            print!("| {v} | {cs:.1} |");
            for us in INTERVALS {
                print!(" {:.3} |", find(cases, mode, 90.0, v, us).dev * 1e3);
            }
            println!();
        }
        println!();
    }
    println!("### deviation (µm) vs angle at 1024 µs, full speed\n");
    print!("| speed (mm/s) |");
    for a in ANGLES {
        print!(" {a}° |");
    }
    println!();
    println!("|---|{}", "---|".repeat(ANGLES.len()));
    for v in SPEEDS {
        print!("| {v} |");
        for a in ANGLES {
            print!(" {:.3} |", find(cases, Mode::Full, a, v, 1024).dev * 1e3);
        }
        println!();
    }
    println!();
    println!("### largest interval (µs) keeping the deviation under a bound, worst over angles\n");
    println!("| speed (mm/s) | full, 10 µm | full, 50 µm | planned, 10 µm | planned, 50 µm |");
    println!("|---|---|---|---|---|");
    let show = |o: Option<u32>| o.map_or("< 256".to_string(), |u| u.to_string());
    for v in SPEEDS {
        println!(
            "| {v} | {} | {} | {} | {} |",
            show(recommended(cases, Mode::Full, v, 0.010)),
            show(recommended(cases, Mode::Full, v, 0.050)),
            show(recommended(cases, Mode::Planned, v, 0.010)),
            show(recommended(cases, Mode::Planned, v, 0.050)),
        );
    }
}

fn plot(args: &Args, cases: &[Case]) -> Result<PathBuf, Box<dyn Error>> {
    fs::create_dir_all(&args.out)?;
    let path = args.out.join("corner-deviation.svg");
    let root = SVGBackend::new(&path, (1200, 900)).into_drawing_area();
    root.fill(&WHITE)?;
    let panels = root.split_evenly((2, 2));
    // Top: deviation vs interval at 90°, one line per speed.
    for (panel, mode) in panels.iter().take(2).zip([Mode::Full, Mode::Planned]) {
        let lines = SPEEDS.map(|v| {
            let dev = INTERVALS.map(|us| find(cases, mode, 90.0, v, us).dev);
            (format!("{v} mm/s"), dev)
        });
        deviation_panel(panel, &format!("{} speed, 90° corner", mode.name()), &lines)?;
    }
    // Bottom: deviation vs interval at 100 mm/s, one line per angle.
    for (panel, mode) in panels.iter().skip(2).zip([Mode::Full, Mode::Planned]) {
        let lines = ANGLES.map(|a| {
            let dev = INTERVALS.map(|us| find(cases, mode, a, 100.0, us).dev);
            (format!("turn {a}°"), dev)
        });
        deviation_panel(panel, &format!("{} speed, 100 mm/s", mode.name()), &lines)?;
    }
    root.present()?;
    Ok(path.clone())
}

/// One panel: max deviation (µm, log) against interval (µs, log2), one line
/// per `(label, deviation in mm at each of INTERVALS)`, with the bounds.
fn deviation_panel(
    area: &DrawingArea<SVGBackend<'_>, Shift>,
    caption: &str,
    lines: &[(String, [f64; INTERVALS.len()])],
) -> Result<(), Box<dyn Error>> {
    let colors = [
        RED,
        BLUE,
        GREEN,
        MAGENTA,
        CYAN,
        BLACK,
        RGBColor(255, 140, 0),
    ];
    let floor = 0.1; // µm, for the log axis
    let mut ch = ChartBuilder::on(area)
        .caption(caption, ("sans-serif", 20))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(8f64..14f64, (floor..1e4f64).log_scale())?;
    ch.configure_mesh()
        .x_labels(7)
        .x_label_formatter(&|x| format!("{}", 2f64.powf(*x).round()))
        .x_desc("interval (µs)")
        .y_desc("max deviation (µm)")
        .draw()?;
    for ((label, dev), col) in lines.iter().zip(colors) {
        let pts = INTERVALS
            .iter()
            .zip(dev)
            .map(|(&us, d)| ((us as f64).log2(), (d * 1e3).max(floor)));
        ch.draw_series(LineSeries::new(pts, col.stroke_width(2)))?
            .label(label)
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 15, y)], col));
    }
    bounds(&mut ch)?;
    ch.configure_series_labels()
        .position(SeriesLabelPosition::LowerRight)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}

/// Dashed lines at the 10 µm and 50 µm bounds.
fn bounds<DB: DrawingBackend>(
    ch: &mut ChartContext<
        '_,
        DB,
        Cartesian2d<plotters::coord::types::RangedCoordf64, LogCoord<f64>>,
    >,
) -> Result<(), Box<dyn Error>>
where
    DB::ErrorType: 'static,
{
    for lim in [10.0, 50.0] {
        ch.draw_series(DashedLineSeries::new(
            [(8.0, lim), (14.0, lim)],
            8,
            5,
            RGBColor(110, 110, 110).into(),
        ))
        .map_err(|e| e.to_string())?;
    }
    Ok(())
}

fn main() -> std::process::ExitCode {
    osap_examples::init_logging();
    osap_examples::exit_code(run())
}

fn run() -> Result<(), Box<dyn Error>> {
    let args = Args::parse();
    if !(args.accel.is_finite() && args.accel > 0.0) {
        return Err("--accel must be finite and > 0".into());
    }
    let mut cases = Vec::new();
    for mode in [Mode::Full, Mode::Planned] {
        for angle in ANGLES {
            for speed in SPEEDS {
                for us in INTERVALS {
                    cases.push(run_case(&args, mode, angle, speed, us)?);
                }
            }
        }
    }
    if let Some(csv) = &args.csv {
        let mut s = String::from(
            "mode,turn_deg,speed_mm_s,interval_us,corner_speed_mm_s,max_deviation_um\n",
        );
        for c in &cases {
            s += &format!(
                "{},{},{},{},{:.4},{:.6}\n",
                c.mode.name(),
                c.angle,
                c.speed,
                c.interval,
                c.corner_speed,
                c.dev * 1e3
            );
        }
        fs::write(csv, s)?;
    }
    print_tables(&args, &cases);
    let svg = plot(&args, &cases)?;
    eprintln!("wrote {}", svg.display());
    Ok(())
}
