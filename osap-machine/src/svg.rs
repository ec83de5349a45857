//! SVG drawings: every visible path and shape, with its transforms and
//! units resolved by [`usvg`], flattened to polylines in millimetres within
//! a bounded chord error.
//!
//! The page's size in mm comes from its `width`/`height` (and `viewBox`);
//! the page's bottom-left corner is machine (0, 0) with y up, then
//! [`SvgOptions::scale`] and [`SvgOptions::offset`] apply. Text is not
//! drawn (it would need fonts): each text element gives a warning.

use thiserror::Error;

/// Millimetres per CSS pixel (96 per inch), the unit usvg resolves to.
const MM_PER_PX: f64 = 25.4 / 96.0;

/// How a drawing is read.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SvgOptions {
    /// The largest distance, mm, between a curve and the chords that
    /// replace it (before scaling).
    pub tolerance_mm: f64,
    /// Scale applied to the page, about its bottom-left corner.
    pub scale: f64,
    /// Where the page's bottom-left corner goes, machine mm.
    pub offset: [f64; 2],
}

impl Default for SvgOptions {
    fn default() -> Self {
        SvgOptions {
            tolerance_mm: 0.01,
            scale: 1.0,
            offset: [0.0, 0.0],
        }
    }
}

/// A drawing as polylines.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Drawing {
    /// Each subpath as points in machine mm (a closed one repeats its first
    /// point at the end), in document order.
    pub polylines: Vec<Vec<[f64; 2]>>,
    /// The page's size, mm (before scaling).
    pub page_mm: [f64; 2],
    /// How far a point may lie from where the document puts it, mm (after
    /// scaling): usvg computes in f32, so every coordinate carries a few
    /// f32 roundings of the drawing's largest magnitude (well under a
    /// micrometre on a sheet of paper). A page-edge frame may thus land
    /// this far outside the page.
    pub precision_mm: f64,
    /// What was left out, and why.
    pub warnings: Vec<String>,
}

/// Why a drawing cannot be read.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum SvgError {
    /// The text is not an SVG usvg can read.
    #[error("not a readable SVG: {0}")]
    Parse(String),
    /// An option is out of range.
    #[error("{0}")]
    Options(String),
}

/// Reads an SVG document into polylines.
pub fn read(text: &str, options: &SvgOptions) -> Result<Drawing, SvgError> {
    if !(options.tolerance_mm.is_finite() && options.tolerance_mm > 0.0) {
        return Err(SvgError::Options(format!(
            "the chord tolerance must be positive, not {} mm",
            options.tolerance_mm
        )));
    }
    let placed = options.scale.is_finite()
        && options.scale > 0.0
        && options.offset.iter().all(|o| o.is_finite());
    if !placed {
        return Err(SvgError::Options(
            "scale must be positive and the offset finite".into(),
        ));
    }
    let tree = usvg::Tree::from_str(text, &usvg::Options::default())
        .map_err(|e| SvgError::Parse(e.to_string()))?;
    let size = tree.size();
    let page_mm = [
        f64::from(size.width()) * MM_PER_PX,
        f64::from(size.height()) * MM_PER_PX,
    ];
    let mut drawing = Drawing {
        page_mm,
        ..Drawing::default()
    };
    let place = |x: f32, y: f32| -> [f64; 2] {
        let x_mm = f64::from(x) * MM_PER_PX;
        let y_mm = page_mm[1] - f64::from(y) * MM_PER_PX;
        [
            options.offset[0] + options.scale * x_mm,
            options.offset[1] + options.scale * y_mm,
        ]
    };
    // Chord error is measured in page mm; scaling scales it.
    let tolerance_px = (options.tolerance_mm / MM_PER_PX) as f32;
    walk(
        tree.root(),
        &mut drawing,
        &place,
        tolerance_px.max(f32::MIN_POSITIVE),
    );
    // The largest magnitude a coordinate had in page mm (the page's size
    // included: the y flip subtracts from it).
    let largest = drawing
        .polylines
        .iter()
        .flatten()
        .flat_map(|p| [0, 1].map(|i| ((p[i] - options.offset[i]) / options.scale).abs()))
        .fold(page_mm[0].max(page_mm[1]), f64::max);
    drawing.precision_mm = F32_ROUNDINGS * f64::from(f32::EPSILON) * largest * options.scale;
    Ok(drawing)
}

/// How many f32 roundings of its largest magnitude a coordinate may carry
/// through usvg: parsing, the view box and transforms, and the curve
/// evaluation here, each a few.
const F32_ROUNDINGS: f64 = 8.0;

fn walk(
    group: &usvg::Group,
    drawing: &mut Drawing,
    place: &dyn Fn(f32, f32) -> [f64; 2],
    tolerance_px: f32,
) {
    for node in group.children() {
        match node {
            usvg::Node::Group(g) => walk(g, drawing, place, tolerance_px),
            usvg::Node::Path(p) => {
                if !p.is_visible() {
                    continue;
                }
                let Some(path) = p.data().clone().transform(p.abs_transform()) else {
                    drawing.warnings.push(format!(
                        "path {:?}: its transform collapses it; skipped",
                        p.id()
                    ));
                    continue;
                };
                flatten(&path, drawing, place, tolerance_px);
            }
            usvg::Node::Text(t) => drawing.warnings.push(format!(
                "text {:?} is not drawn (convert text to paths)",
                t.id()
            )),
            usvg::Node::Image(i) => drawing
                .warnings
                .push(format!("image {:?} is not drawn", i.id())),
        }
    }
}

type Pt = (f32, f32);

/// Segments for a curve whose second derivative is at most `d2` (px per
/// unit parameter squared), so the chords stay within `tolerance`: the
/// deviation of a chord over a parameter step `h` is at most `d2·h²/8`.
fn pieces(d2: f32, tolerance: f32) -> usize {
    let n = (d2 / (8.0 * tolerance)).sqrt().ceil();
    if n.is_finite() {
        (n as usize).clamp(1, 10_000)
    } else {
        1
    }
}

fn len(x: f32, y: f32) -> f32 {
    x.hypot(y)
}

fn flatten(
    path: &usvg::tiny_skia_path::Path,
    drawing: &mut Drawing,
    place: &dyn Fn(f32, f32) -> [f64; 2],
    tolerance: f32,
) {
    use usvg::tiny_skia_path::PathSegment;
    let mut line: Vec<[f64; 2]> = Vec::new();
    let mut start: Pt = (0.0, 0.0);
    let mut at: Pt = (0.0, 0.0);
    let finish = |line: &mut Vec<[f64; 2]>, drawing: &mut Drawing| {
        if line.len() > 1 {
            drawing.polylines.push(std::mem::take(line));
        } else {
            line.clear();
        }
    };
    for segment in path.segments() {
        match segment {
            PathSegment::MoveTo(p) => {
                finish(&mut line, drawing);
                start = (p.x, p.y);
                at = start;
                line.push(place(p.x, p.y));
            }
            PathSegment::LineTo(p) => {
                at = (p.x, p.y);
                line.push(place(p.x, p.y));
            }
            PathSegment::QuadTo(c, p) => {
                let (p0, p1, p2) = (at, (c.x, c.y), (p.x, p.y));
                let d2 = 2.0 * len(p0.0 - 2.0 * p1.0 + p2.0, p0.1 - 2.0 * p1.1 + p2.1);
                let n = pieces(d2, tolerance);
                for k in 1..=n {
                    let t = k as f32 / n as f32;
                    let u = 1.0 - t;
                    let x = u * u * p0.0 + 2.0 * u * t * p1.0 + t * t * p2.0;
                    let y = u * u * p0.1 + 2.0 * u * t * p1.1 + t * t * p2.1;
                    line.push(place(x, y));
                }
                at = p2;
            }
            PathSegment::CubicTo(c1, c2, p) => {
                let (p0, p1, p2, p3) = (at, (c1.x, c1.y), (c2.x, c2.y), (p.x, p.y));
                let a = len(p0.0 - 2.0 * p1.0 + p2.0, p0.1 - 2.0 * p1.1 + p2.1);
                let b = len(p1.0 - 2.0 * p2.0 + p3.0, p1.1 - 2.0 * p2.1 + p3.1);
                let n = pieces(6.0 * a.max(b), tolerance);
                for k in 1..=n {
                    let t = k as f32 / n as f32;
                    let u = 1.0 - t;
                    let (w0, w1, w2, w3) = (u * u * u, 3.0 * u * u * t, 3.0 * u * t * t, t * t * t);
                    let x = w0 * p0.0 + w1 * p1.0 + w2 * p2.0 + w3 * p3.0;
                    let y = w0 * p0.1 + w1 * p1.1 + w2 * p2.1 + w3 * p3.1;
                    line.push(place(x, y));
                }
                at = p3;
            }
            PathSegment::Close => {
                if at != start {
                    line.push(place(start.0, start.1));
                }
                at = start;
                finish(&mut line, drawing);
                line.push(place(start.0, start.1));
            }
        }
    }
    finish(&mut line, drawing);
}

#[cfg(test)]
mod tests {
    use super::*;

    fn page(body: &str) -> String {
        format!(
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="100mm" height="50mm" viewBox="0 0 100 50">{body}</svg>"#
        )
    }

    #[test]
    fn units_view_box_and_y_up() {
        let d = read(
            &page(r#"<path d="M 0 0 L 100 50" stroke="black"/>"#),
            &SvgOptions::default(),
        )
        .unwrap();
        assert!((d.page_mm[0] - 100.0).abs() < 1e-3 && (d.page_mm[1] - 50.0).abs() < 1e-3);
        let l = &d.polylines[0];
        assert!(
            (l[0][0]).abs() < 1e-3 && (l[0][1] - 50.0).abs() < 1e-3,
            "{l:?}"
        );
        assert!(
            (l[1][0] - 100.0).abs() < 1e-3 && l[1][1].abs() < 1e-3,
            "{l:?}"
        );
    }

    #[test]
    fn transforms_scale_and_offset_apply() {
        let opts = SvgOptions {
            scale: 2.0,
            offset: [5.0, 7.0],
            ..SvgOptions::default()
        };
        let d = read(
            &page(
                r#"<g transform="translate(10 0)"><path d="M 0 50 L 10 50" stroke="black"/></g>"#,
            ),
            &opts,
        )
        .unwrap();
        let l = &d.polylines[0];
        assert!(
            (l[0][0] - 25.0).abs() < 1e-3 && (l[0][1] - 7.0).abs() < 1e-3,
            "{l:?}"
        );
        assert!((l[1][0] - 45.0).abs() < 1e-3, "{l:?}");
    }

    #[test]
    fn a_circle_stays_within_the_chord_tolerance() {
        for tolerance_mm in [0.1, 0.01, 0.001] {
            let d = read(
                &page(r#"<circle cx="50" cy="25" r="20" fill="none" stroke="black"/>"#),
                &SvgOptions {
                    tolerance_mm,
                    ..SvgOptions::default()
                },
            )
            .unwrap();
            let l = &d.polylines[0];
            assert!(l.len() > 8);
            let closed = (l[0][0] - l[l.len() - 1][0]).hypot(l[0][1] - l[l.len() - 1][1]);
            assert!(closed < 1e-3, "a closed shape ends where it starts");
            // Chords of a circle lie inside it: the worst sagitta, from the
            // chord midpoints. usvg's circle is four cubics (within 0.03 %
            // of the radius), so allow that too.
            let mut worst = 0.0f64;
            for w in l.windows(2) {
                let m = [(w[0][0] + w[1][0]) / 2.0, (w[0][1] + w[1][1]) / 2.0];
                let r = (m[0] - 50.0).hypot(m[1] - 25.0);
                worst = worst.max((20.0 - r).abs());
            }
            assert!(
                worst <= tolerance_mm + 20.0 * 3e-4,
                "{tolerance_mm}: {worst}"
            );
        }
    }

    #[test]
    fn bad_documents_and_options_are_errors() {
        assert!(matches!(
            read("not svg", &SvgOptions::default()),
            Err(SvgError::Parse(_))
        ));
        let bad = SvgOptions {
            tolerance_mm: 0.0,
            ..SvgOptions::default()
        };
        assert!(matches!(read(&page(""), &bad), Err(SvgError::Options(_))));
    }
}
