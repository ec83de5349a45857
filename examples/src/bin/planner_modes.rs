//! One corner in each of the planner's three modes: trapezoid, S-curve
//! and motor model. A 40 mm move along x, a 90° corner, 40 mm along y, at
//! 400 mm/s, on a belt axis (40 mm per turn) whose NEMA 17 (0.45 N·m, 2 A,
//! 1.4 Ω, 3 mH, 54 g·cm²) on 12 V moves 1.5 kg; plots path speed and
//! acceleration over time, with the acceleration the motor allows at each
//! speed (margin 0.7) for the motor mode.
//!
//! ```text
//! cargo run -p osap-examples --release --bin planner_modes -- --out docs/img/planner-modes.svg
//! ```

use std::error::Error;
use std::path::PathBuf;
use std::sync::Arc;

use clap::Parser;
use maxl::blocks::planner::{AccelModel, Kin, Limits, Planner, VectorLimits};
use maxl::motor::StepperModel;
use plotters::prelude::*;

#[derive(Parser, Debug)]
#[command(about = "Plot one corner in each of the planner's modes")]
struct Args {
    /// The SVG to write.
    #[arg(long, default_value = "examples-out/planner-modes.svg")]
    out: PathBuf,
}

/// The belt axis: each of x and y on its own motor (cartesian).
#[derive(Debug)]
struct BeltAxis {
    motor: StepperModel,
    /// Radians per mm (40 mm per turn).
    kappa: f64,
    /// The moving mass, kg.
    mass: f64,
    margin: f64,
}

impl BeltAxis {
    fn accel_at(&self, speed: f64) -> f64 {
        let need = self.motor.rotor_inertia_kgm2 * self.kappa + self.mass / (1e6 * self.kappa);
        self.margin * self.motor.torque_at(self.kappa * speed) / need
    }
}

impl AccelModel<2> for BeltAxis {
    fn max_accel(&self, motion: &[f64; 2], accel: &[f64; 2], speed: f64) -> f64 {
        // Each axis's motor turns with its share of the motion.
        let mut best = f64::INFINITY;
        for k in 0..2 {
            if accel[k].abs() > 1e-12 {
                let a = self.accel_at(speed * motion[k].abs());
                best = best.min(a / accel[k].abs());
            }
        }
        best
    }
}

/// The plotted axis (see the module docs).
fn belt_axis() -> BeltAxis {
    BeltAxis {
        motor: StepperModel {
            holding_torque_nm: 0.45,
            rated_current_a: 2.0,
            resistance_ohm: 1.4,
            inductance_h: 3.0e-3,
            supply_v: 12.0,
            rotor_inertia_kgm2: 54e-7,
            steps_per_rev: 200.0,
        },
        kappa: std::f64::consts::TAU / 40.0,
        mass: 1.5,
        margin: 0.7,
    }
}

fn main() -> std::process::ExitCode {
    osap_examples::init_logging();
    osap_examples::exit_code(run())
}

fn trace(mut p: Planner<2>) -> Result<Vec<(f64, Kin<2>)>, Box<dyn Error>> {
    p.line([40.0, 0.0], 400.0)?;
    p.line([40.0, 40.0], 400.0)?;
    let mut out = Vec::new();
    let mut t = 0;
    loop {
        let k = p.sample_kin(t)?;
        out.push((t as f64 * 1e-6, k));
        if p.is_idle() {
            return Ok(out);
        }
        t += 250;
    }
}

fn run() -> Result<(), Box<dyn Error>> {
    let args = Args::parse();
    let axis = belt_axis();
    // The constant acceleration safe at the top speed, for the trapezoid
    // and S-curve.
    let constant = axis.accel_at(400.0);
    let jd = 0.02;
    let limits = Limits::new([400.0; 2], [constant; 2], jd)?;
    let vector = VectorLimits::new(400.0, f64::INFINITY)?;
    let trapezoid = trace(Planner::with_vector_limits(limits.clone(), vector, 64)?)?;
    let scurve = trace(Planner::with_vector_limits(
        limits.clone().with_max_jerk([constant * 25.0; 2])?,
        vector,
        64,
    )?)?;
    let mut motors =
        Planner::with_vector_limits(Limits::new([400.0; 2], [1e6; 2], jd)?, vector, 64)?;
    motors.set_accel_model(Some(Arc::new(belt_axis())));
    let motor_trace = trace(motors)?;
    let axis = belt_axis();
    let series = [
        ("trapezoid", &trapezoid, RED),
        ("S-curve (jerk 25 × a per s)", &scurve, BLUE),
        ("motor model", &motor_trace, GREEN),
    ];
    let t_end = series
        .iter()
        .map(|s| s.1.last().map_or(0.0, |x| x.0))
        .fold(0.0, f64::max);
    for (name, s, _) in &series {
        eprintln!("{name}: {:.1} ms", 1e3 * s.last().map_or(0.0, |x| x.0));
    }
    if let Some(dir) = args.out.parent() {
        std::fs::create_dir_all(dir)?;
    }
    let root = SVGBackend::new(&args.out, (900, 700)).into_drawing_area();
    root.fill(&WHITE)?;
    let (top, bottom) = root.split_vertically(350);
    let speed = |k: &Kin<2>| k.vel[0].hypot(k.vel[1]);
    let accel = |k: &Kin<2>| {
        // Along the path: the component of the acceleration on the velocity.
        let v = speed(k);
        if v > 1e-9 {
            (k.acc[0] * k.vel[0] + k.acc[1] * k.vel[1]) / v
        } else {
            k.acc[0].hypot(k.acc[1])
        }
    };
    let mut ch = ChartBuilder::on(&top)
        .caption(
            "one corner (40 mm along x, then y, at 400 mm/s): path speed",
            ("sans-serif", 18),
        )
        .margin(10)
        .x_label_area_size(30)
        .y_label_area_size(50)
        .build_cartesian_2d(0.0..t_end, 0.0..420.0)?;
    ch.configure_mesh()
        .x_desc("time (s)")
        .y_desc("mm/s")
        .draw()?;
    for (name, s, col) in &series {
        let col = *col;
        ch.draw_series(LineSeries::new(
            s.iter().map(|(t, k)| (*t, speed(k))),
            col.stroke_width(2),
        ))?
        .label(*name)
        .legend(move |(x, y)| PathElement::new([(x, y), (x + 15, y)], col));
    }
    ch.configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .position(SeriesLabelPosition::LowerRight)
        .draw()?;
    let a_max = axis.accel_at(0.0) * 1.1;
    let mut ch = ChartBuilder::on(&bottom)
        .caption(
            "acceleration along the path (dashed: what the motor model allows at that speed)",
            ("sans-serif", 18),
        )
        .margin(10)
        .x_label_area_size(30)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..t_end, -a_max..a_max)?;
    ch.configure_mesh()
        .x_desc("time (s)")
        .y_desc("mm/s²")
        .draw()?;
    for (_, s, col) in &series {
        ch.draw_series(LineSeries::new(
            s.iter().map(|(t, k)| (*t, accel(k))),
            col.stroke_width(2),
        ))?;
    }
    for sign in [-1.0, 1.0] {
        ch.draw_series(DashedLineSeries::new(
            motor_trace
                .iter()
                .map(|(t, k)| (*t, sign * axis.accel_at(speed(k)))),
            5,
            4,
            GREEN.mix(0.6).into(),
        ))?;
    }
    root.present()?;
    eprintln!("wrote {}", args.out.display());
    Ok(())
}
