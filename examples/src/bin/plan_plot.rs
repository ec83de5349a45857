//! Plots the planner's as-planned position, velocity and acceleration over
//! time for a square with one rounded corner, to SVG.
//!
//! ```text
//! cargo run -p osap-examples --release --bin plan_plot -- --out docs/img/plan.svg
//! ```

use std::error::Error;
use std::path::PathBuf;

use clap::Parser;
use maxl::blocks::planner::{Arc, Kin, Limits, Planner};
use plotters::prelude::*;

#[derive(Parser, Debug)]
#[command(about = "Plot the planner's profile for a square with a rounded corner")]
struct Args {
    /// The SVG to write.
    #[arg(long, default_value = "examples-out/plan.svg")]
    out: PathBuf,
    /// Side of the square (mm).
    #[arg(long, default_value_t = 40.0)]
    side: f64,
    /// Radius of the rounded corner (mm).
    #[arg(long, default_value_t = 8.0)]
    radius: f64,
    /// Feed rate (mm/s).
    #[arg(long, default_value_t = 150.0)]
    feed: f64,
    /// X speed and acceleration limits (mm/s, mm/s²).
    #[arg(long, num_args = 2, default_values_t = [300.0, 3000.0])]
    x: Vec<f64>,
    /// Y speed and acceleration limits (mm/s, mm/s²).
    #[arg(long, num_args = 2, default_values_t = [200.0, 1500.0])]
    y: Vec<f64>,
    /// Junction deviation (mm).
    #[arg(long, default_value_t = 0.05)]
    junction_deviation: f64,
    /// Sample interval (µs).
    #[arg(long, default_value_t = 1024)]
    step: u64,
}

/// One time plot: what it shows and the limits to draw.
struct Panel {
    name: &'static str,
    unit: &'static str,
    pick: fn(&Kin<2>) -> [f64; 2],
    lim: Option<[f64; 2]>,
}

impl Panel {
    fn new(
        name: &'static str,
        unit: &'static str,
        pick: fn(&Kin<2>) -> [f64; 2],
        lim: Option<[f64; 2]>,
    ) -> Self {
        Panel {
            name,
            unit,
            pick,
            lim,
        }
    }
}

fn main() -> std::process::ExitCode {
    osap_examples::init_logging();
    osap_examples::exit_code(run())
}

fn run() -> Result<(), Box<dyn Error>> {
    let a = Args::parse();
    if a.step == 0 {
        return Err("--step must be > 0".into());
    }
    let (s, r) = (a.side, a.radius);
    if !(r > 0.0 && r < s) {
        return Err("--radius must be in (0, side)".into());
    }
    let limits = Limits::new([a.x[0], a.y[0]], [a.x[1], a.y[1]], a.junction_deviation)?;
    let mut p = Planner::<2>::new(limits.clone())?;
    // Counter-clockwise square from the origin; the last corner is rounded.
    p.line([s, 0.0], a.feed)?;
    p.line([s, s], a.feed)?;
    p.line([r, s], a.feed)?;
    p.arc(
        &Arc {
            end: [0.0, s - r],
            plane: (0, 1),
            center: [r, s - r],
            clockwise: false,
            chord_tolerance: 0.005,
        },
        a.feed,
    )?;
    p.line([0.0, 0.0], a.feed)?;
    let stats = p.stats();
    let mut trace: Vec<(f64, Kin<2>)> = Vec::new();
    let mut t = 0;
    loop {
        let k = p.sample_kin(t)?;
        trace.push((t as f64 * 1e-6, k));
        if p.is_idle() {
            break;
        }
        t += a.step;
    }
    let t_end = trace.last().map_or(1.0, |x| x.0).max(1e-3);
    eprintln!(
        "{} segments, {:.3} s, {} samples",
        stats.pending,
        t_end,
        trace.len()
    );

    if let Some(dir) = a.out.parent() {
        std::fs::create_dir_all(dir)?;
    }
    let root = SVGBackend::new(&a.out, (1000, 1000)).into_drawing_area();
    root.fill(&WHITE)?;
    let (top, bottom) = root.split_vertically(330);
    let (path_area, pos_area) = top.split_horizontally(330);
    let (vel_area, acc_area) = bottom.split_vertically(335);

    let mut ch = ChartBuilder::on(&path_area)
        .caption("path (x, y)", ("sans-serif", 18))
        .margin(10)
        .x_label_area_size(30)
        .y_label_area_size(40)
        .build_cartesian_2d(-2.0..s + 2.0, -2.0..s + 2.0)?;
    ch.configure_mesh().draw()?;
    ch.draw_series(LineSeries::new(
        trace.iter().map(|(_, k)| (k.pos[0], k.pos[1])),
        BLUE.stroke_width(2),
    ))?;

    let vel_lim = Some([limits.max_vel[0], limits.max_vel[1]]);
    let acc_lim = Some([limits.max_acc[0], limits.max_acc[1]]);
    let panels = [
        (&pos_area, Panel::new("position", "mm", |k| k.pos, None)),
        (
            &vel_area,
            Panel::new("velocity", "mm/s", |k| k.vel, vel_lim),
        ),
        (
            &acc_area,
            Panel::new("acceleration", "mm/s²", |k| k.acc, acc_lim),
        ),
    ];
    for (
        area,
        Panel {
            name,
            unit,
            pick,
            lim,
        },
    ) in panels
    {
        let vals = trace.iter().flat_map(|(_, k)| pick(k));
        let (lo, hi) = vals.fold((0.0f64, 0.0f64), |(l, h), v| (l.min(v), h.max(v)));
        let pad = 0.1 * (hi - lo).max(1e-9);
        let mut ch = ChartBuilder::on(area)
            .caption(format!("{name} (dashed: limits)"), ("sans-serif", 18))
            .margin(10)
            .x_label_area_size(30)
            .y_label_area_size(60)
            .build_cartesian_2d(0.0..t_end, lo - pad..hi + pad)?;
        ch.configure_mesh().x_desc("time (s)").y_desc(unit).draw()?;
        for (axis, col) in [(0, RED), (1, BLUE)] {
            ch.draw_series(LineSeries::new(
                trace.iter().map(|(t, k)| (*t, pick(k)[axis])),
                col.stroke_width(2),
            ))?
            .label(["x", "y"][axis])
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 15, y)], col));
            if let Some(l) = lim {
                for sign in [-1.0, 1.0] {
                    let v = sign * l[axis];
                    if v > lo - pad && v < hi + pad {
                        ch.draw_series(DashedLineSeries::new(
                            [(0.0, v), (t_end, v)],
                            6,
                            4,
                            col.mix(0.5).into(),
                        ))?;
                    }
                }
            }
        }
        ch.configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()?;
    }
    root.present()?;
    eprintln!("wrote {}", a.out.display());
    Ok(())
}
