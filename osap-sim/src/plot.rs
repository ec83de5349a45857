//! SVG plots of clock error over time (plotters, no system fonts needed).
//!
//! One file, two panels: the whole run as |error| on a log scale (so cold
//! start offsets of seconds and steady-state errors of µs share a chart),
//! and a linear zoom on the signed error from a chosen time on. Series are
//! reduced to at most [`MAX_POINTS`] points by keeping, per bucket, the
//! sample of largest magnitude, so spikes survive the reduction.

use crate::error::SimError;
use crate::metrics::Metrics;
use plotters::prelude::*;
use std::path::Path;

/// Most points drawn per series and panel.
pub const MAX_POINTS: usize = 500;

/// Smallest |error| shown on the log scale, µs (zero errors sit on it).
const LOG_FLOOR_US: f64 = 0.1;

/// Reduces `(t, e)` to at most `max` points, keeping per bucket the point
/// of largest |e|.
fn reduce(times: &[f64], values: &[f64], max: usize) -> Vec<(f64, f64)> {
    let n = times.len().min(values.len());
    let per = n.div_ceil(max.max(1)).max(1);
    (0..n)
        .step_by(per)
        .filter_map(|start| {
            (start..(start + per).min(n))
                .max_by(|&a, &b| values[a].abs().total_cmp(&values[b].abs()))
                .map(|k| (times[k], values[k]))
        })
        .collect()
}

/// A µs axis label: plain up to 10⁴, then powers of ten.
fn format_us(v: f64) -> String {
    if v.abs() >= 1e4 {
        format!("{v:.0e}")
    } else if v.abs() >= 10.0 || v == 0.0 {
        format!("{v:.0}")
    } else {
        format!("{v:.1}")
    }
}

fn out_err<E: std::fmt::Debug>(path: &Path) -> impl Fn(E) -> SimError + '_ {
    move |e| SimError::Output(format!("{}: {e:?}", path.display()))
}

/// Writes the two-panel plot of `metrics` to `path`: every non-root node's
/// error against the root, in full (log |error|) and from `zoom_from_s` on
/// (signed, linear).
pub fn plot_errors(
    path: &Path,
    title: &str,
    metrics: &Metrics,
    zoom_from_s: f64,
) -> Result<(), SimError> {
    let err = out_err(path);
    let t_end = metrics.times_s.last().copied().unwrap_or(1.0).max(1e-3);
    let area = SVGBackend::new(path, (1100, 900)).into_drawing_area();
    area.fill(&WHITE).map_err(&err)?;
    let (upper, lower) = area.split_vertically(450);
    let followers: Vec<usize> = metrics.followers().collect();

    // Full run, log |error|.
    let peak = followers
        .iter()
        .flat_map(|&i| metrics.error_us[i].iter().map(|e| e.abs()))
        .fold(1.0, f64::max);
    let mut chart = ChartBuilder::on(&upper)
        .caption(format!("{title}: |error| vs root"), ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(36)
        .y_label_area_size(70)
        .build_cartesian_2d(0.0..t_end, (LOG_FLOOR_US..peak * 2.0).log_scale())
        .map_err(&err)?;
    chart
        .configure_mesh()
        .x_desc("time (s)")
        .y_desc("|error| (µs)")
        .y_label_formatter(&|v| format_us(*v))
        .draw()
        .map_err(&err)?;
    for (c, &i) in followers.iter().enumerate() {
        let color = Palette99::pick(c).to_rgba();
        let points = reduce(&metrics.times_s, &metrics.error_us[i], MAX_POINTS)
            .into_iter()
            .map(|(t, e)| (t, e.abs().max(LOG_FLOOR_US)));
        chart
            .draw_series(LineSeries::new(points, color.stroke_width(1)))
            .map_err(&err)?
            .label(metrics.names[i].as_str())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], color));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(&err)?;

    // Zoom, signed error.
    let k0 = metrics.index_at(zoom_from_s);
    let t0 = metrics.times_s.get(k0).copied().unwrap_or(0.0);
    let (lo, hi) = followers
        .iter()
        .flat_map(|&i| metrics.error_us[i][k0..].iter().copied())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), e| {
            (lo.min(e), hi.max(e))
        });
    // A biased error would leave half a symmetric range empty: fit the
    // data, with a margin and at least ±1 µs.
    let (lo, hi) = if lo <= hi { (lo, hi) } else { (0.0, 0.0) };
    let pad = ((hi - lo) * 0.08).max(1.0);
    let mut zoom = ChartBuilder::on(&lower)
        .caption(
            format!("{title}: error from {t0:.1} s on"),
            ("sans-serif", 18),
        )
        .margin(12)
        .x_label_area_size(36)
        .y_label_area_size(70)
        .build_cartesian_2d(t0..t_end.max(t0 + 1e-3), (lo - pad)..(hi + pad))
        .map_err(&err)?;
    zoom.configure_mesh()
        .x_desc("time (s)")
        .y_desc("error (µs)")
        .y_label_formatter(&|v| format_us(*v))
        .draw()
        .map_err(&err)?;
    for (c, &i) in followers.iter().enumerate() {
        let color = Palette99::pick(c).to_rgba();
        let points = reduce(
            &metrics.times_s[k0..],
            &metrics.error_us[i][k0..],
            MAX_POINTS,
        );
        zoom.draw_series(LineSeries::new(points, color.stroke_width(1)))
            .map_err(&err)?;
    }
    area.present().map_err(&err)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::reduce;

    #[test]
    fn reduction_keeps_spikes() {
        let t: Vec<f64> = (0..10_000).map(f64::from).collect();
        let mut e = vec![1.0; 10_000];
        e[4321] = -500.0;
        let r = reduce(&t, &e, 100);
        assert!(r.len() <= 100);
        assert!(r.contains(&(4321.0, -500.0)));
    }
}
