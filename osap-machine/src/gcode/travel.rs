//! The travel check: every point a job's moves reach, arcs over their
//! whole sweep, before anything moves.

use super::{Action, GcodeError, Job};

impl Job {
    /// Refuses the job if any move would take an axis outside `min..=max`
    /// (mm, per axis X, Y, Z), naming the first offending line. Arcs are
    /// checked over their whole sweep, not only their end points. The
    /// machine starts at the origin.
    pub fn check_travel(&self, min: [f64; 3], max: [f64; 3]) -> Result<(), GcodeError> {
        let mut pos = [0.0f64; 3];
        for step in &self.steps {
            let (to, extra) = match step.action {
                Action::Rapid { to } | Action::Line { to, .. } | Action::Extrude { to, .. } => {
                    (to, None)
                }
                Action::Arc {
                    to,
                    center,
                    clockwise,
                    ..
                } => (to, Some(arc_extremes(pos, to, center, clockwise))),
                _ => continue,
            };
            let mut points = vec![to];
            if let Some(e) = extra {
                points.extend(e);
            }
            for p in points {
                for (i, axis) in ['X', 'Y', 'Z'].into_iter().enumerate() {
                    let v = p[i];
                    if v < min[i] - 1e-9 || v > max[i] + 1e-9 {
                        return Err(GcodeError::Travel {
                            line: step.line,
                            axis,
                            value: v,
                            min: min[i],
                            max: max[i],
                        });
                    }
                }
            }
            pos = to;
        }
        Ok(())
    }
}

/// The points where an arc from `from` to `to` around `center` crosses the
/// axis directions (its extremes in X and Y), with Z interpolated.
fn arc_extremes(from: [f64; 3], to: [f64; 3], center: [f64; 2], clockwise: bool) -> Vec<[f64; 3]> {
    use std::f64::consts::{FRAC_PI_2, TAU};
    let r = (from[0] - center[0]).hypot(from[1] - center[1]);
    let a0 = (from[1] - center[1]).atan2(from[0] - center[0]);
    let a1 = (to[1] - center[1]).atan2(to[0] - center[0]);
    // The sweep, positive counter-clockwise; equal ends are a full circle.
    let mut sweep = if clockwise { a0 - a1 } else { a1 - a0 };
    sweep = sweep.rem_euclid(TAU);
    if sweep < 1e-12 {
        sweep = TAU;
    }
    let mut out = Vec::new();
    for k in 0..4 {
        let a = f64::from(k) * FRAC_PI_2;
        let along = if clockwise { a0 - a } else { a - a0 }.rem_euclid(TAU);
        if along <= sweep {
            let s = along / sweep;
            out.push([
                center[0] + r * a.cos(),
                center[1] + r * a.sin(),
                from[2] + (to[2] - from[2]) * s,
            ]);
        }
    }
    out
}
