//! A heater sensor's thermistor curve: named from a catalogue, given as a
//! Beta model, or fitted to a table of (°C, Ω) points. Every form becomes
//! the Steinhart–Hart coefficients the module reads its sensor with
//! (`heater_sensor`'s `a`, `b`, `c`):
//!
//! ```text
//! 1/T = a + b·ln R + c·(ln R)³        T in K, R in Ω
//! ```
//!
//! Three points give the curve through them exactly; more are fitted by
//! least squares in `1/T`, and a table the curve cannot follow within
//! [`MAX_FIT_ERROR_C`] is refused, naming its worst point.

use nalgebra::{Matrix3, Vector3};

/// 0 °C in kelvin.
const ZERO_C_IN_K: f64 = 273.15;

/// The largest distance, °C, a fitted curve may pass from a table's point.
pub const MAX_FIT_ERROR_C: f64 = 1.0;

/// Steinhart–Hart coefficients, 1/K.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SteinhartHart {
    /// `a`.
    pub a: f64,
    /// `b` (`1/β` for a Beta thermistor).
    pub b: f64,
    /// `c` (0 for a Beta thermistor).
    pub c: f64,
}

/// A catalogued thermistor's data: a Beta model or three datasheet points.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Datasheet {
    /// β, K, and the resistance at 25 °C, Ω.
    Beta(f64, f64),
    /// Three (°C, Ω) points.
    Points([(f64, f64); 3]),
}

/// Thermistors printers use, by the names Klipper's `sensor_type` gives
/// them, with their manufacturers' data.
pub const THERMISTORS: &[(&str, Datasheet)] = &[
    ("Generic 3950", Datasheet::Beta(3950.0, 100_000.0)),
    (
        "EPCOS 100K B57560G104F",
        Datasheet::Points([(25.0, 100_000.0), (150.0, 1_641.9), (250.0, 226.15)]),
    ),
    (
        "ATC Semitec 104GT-2",
        Datasheet::Points([(20.0, 126_800.0), (150.0, 1_360.0), (300.0, 80.65)]),
    ),
    (
        "SliceEngineering 450",
        Datasheet::Points([(25.0, 500_000.0), (200.0, 3_734.0), (400.0, 240.0)]),
    ),
    (
        "TDK NTCG104LH104JT1",
        Datasheet::Points([(25.0, 100_000.0), (50.0, 31_230.0), (125.0, 2_066.0)]),
    ),
];

impl Datasheet {
    /// The catalogued thermistor named `name`.
    pub fn named(name: &str) -> Option<Datasheet> {
        THERMISTORS
            .iter()
            .find(|(n, _)| *n == name)
            .map(|(_, d)| *d)
    }

    /// Its curve.
    pub fn curve(&self) -> Result<SteinhartHart, String> {
        match *self {
            Datasheet::Beta(beta, r25) => Ok(SteinhartHart::from_beta(beta, r25)),
            Datasheet::Points(p) => SteinhartHart::fit(&p),
        }
    }
}

impl SteinhartHart {
    /// A Beta thermistor: `beta`, K, and `r25_ohms` at 25 °C.
    pub fn from_beta(beta: f64, r25_ohms: f64) -> SteinhartHart {
        SteinhartHart {
            a: 1.0 / (25.0 + ZERO_C_IN_K) - r25_ohms.ln() / beta,
            b: 1.0 / beta,
            c: 0.0,
        }
    }

    /// The curve through three or more (°C, Ω) points (exact through
    /// three, least squares in `1/T` through more). Refused: fewer than
    /// three points, values not finite or not positive resistances, two
    /// points at one temperature, a resistance that does not fall as the
    /// temperature rises, and a fit that misses a point by more than
    /// [`MAX_FIT_ERROR_C`].
    pub fn fit(points: &[(f64, f64)]) -> Result<SteinhartHart, String> {
        if points.len() < 3 {
            return Err(format!(
                "{} point(s): a curve needs at least 3 (°C, Ω) points",
                points.len()
            ));
        }
        let mut sorted = points.to_vec();
        for &(t, r) in &sorted {
            if !(t.is_finite() && t > -ZERO_C_IN_K && t < 1000.0 && r.is_finite() && r > 0.0) {
                return Err(format!(
                    "[{t}, {r}] is not a thermistor's point: give [°C, Ω], the temperature \
                     above absolute zero and below 1000 °C, the resistance positive"
                ));
            }
        }
        sorted.sort_by(|p, q| p.0.total_cmp(&q.0));
        for w in sorted.windows(2) {
            if w[1].0 == w[0].0 {
                return Err(format!("two points at {} °C", w[0].0));
            }
            if w[1].1 >= w[0].1 {
                return Err(format!(
                    "the resistance rises from {} Ω at {} °C to {} Ω at {} °C: an NTC \
                     thermistor's falls as it warms (are the columns [°C, Ω]?)",
                    w[0].1, w[0].0, w[1].1, w[1].0
                ));
            }
        }
        // Rows (1, L, L³) against 1/T; scaled by the middle point's L so
        // the normal equations stay well conditioned.
        let scale = sorted[sorted.len() / 2].1.ln().abs().max(1.0);
        let mut ata = Matrix3::zeros();
        let mut aty = Vector3::zeros();
        for &(t, r) in &sorted {
            let l = r.ln() / scale;
            let row = Vector3::new(1.0, l, l * l * l);
            ata += row * row.transpose();
            aty += row * (1.0 / (t + ZERO_C_IN_K));
        }
        let x = ata
            .lu()
            .solve(&aty)
            .ok_or("the points do not determine a curve")?;
        let curve = SteinhartHart {
            a: x[0],
            b: x[1] / scale,
            c: x[2] / (scale * scale * scale),
        };
        let (worst, at) = sorted
            .iter()
            .map(|&(t, r)| ((curve.celsius(r) - t).abs(), (t, r)))
            .fold((0.0, (0.0, 0.0)), |m, e| if e.0 > m.0 { e } else { m });
        if worst.is_nan() || worst > MAX_FIT_ERROR_C {
            return Err(format!(
                "no thermistor curve passes within {MAX_FIT_ERROR_C} °C of every point: it \
                 misses [{}, {}] by {worst:.2} °C (is that point a typo, or is the sensor \
                 not an NTC thermistor?)",
                at.0, at.1
            ));
        }
        if !curve.falls_with_temperature() {
            return Err("the fitted curve's resistance does not fall as it warms".into());
        }
        Ok(curve)
    }

    /// The temperature, °C, at `ohms`.
    pub fn celsius(&self, ohms: f64) -> f64 {
        let l = ohms.ln();
        1.0 / (self.a + self.b * l + self.c * l * l * l) - ZERO_C_IN_K
    }

    /// Whether the resistance falls as it warms from 1 Ω to 100 MΩ (the
    /// module refuses a curve that does not).
    pub fn falls_with_temperature(&self) -> bool {
        let slope = |l: f64| self.b + 3.0 * self.c * l * l;
        [self.a, self.b, self.c].iter().all(|v| v.is_finite())
            && slope(0.0) > 0.0
            && slope(1e8f64.ln()) > 0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn three_points_give_the_curve_through_them() {
        for (name, sheet) in THERMISTORS {
            let curve = sheet.curve().unwrap();
            assert!(curve.falls_with_temperature(), "{name}");
            if let Datasheet::Points(points) = sheet {
                for (t, r) in points {
                    let got = curve.celsius(*r);
                    assert!((got - t).abs() < 1e-6, "{name}: {r} Ω is {got} °C, not {t}");
                }
            }
        }
    }

    #[test]
    fn a_beta_model_is_the_curve_without_its_cubic_term() {
        let c = SteinhartHart::from_beta(3950.0, 100_000.0);
        assert!((c.celsius(100_000.0) - 25.0).abs() < 1e-9);
        // β from the 25 °C and 100 °C resistances: R100 = R25·e^(β(1/T − 1/T25)).
        let r100 = 100_000.0 * (3950.0 * (1.0 / 373.15 - 1.0 / 298.15f64)).exp();
        assert!((c.celsius(r100) - 100.0).abs() < 1e-9);
        assert_eq!(c.c, 0.0);
    }

    #[test]
    fn a_table_is_fitted_and_a_bad_point_is_named() {
        // A table of the EPCOS thermistor every 25 °C from 0 to 300 °C,
        // its resistances rounded to 3 significant digits.
        let epcos = Datasheet::named("EPCOS 100K B57560G104F")
            .unwrap()
            .curve()
            .unwrap();
        let ohms = |t: f64| {
            // Invert by bisection on ln R: the curve is monotone.
            let (mut lo, mut hi) = (0.0f64, 25.0f64);
            for _ in 0..200 {
                let mid = 0.5 * (lo + hi);
                if epcos.celsius(mid.exp()) > t {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            let r = (0.5 * (lo + hi)).exp();
            let digits = 10f64.powi(r.log10().floor() as i32 - 2);
            (r / digits).round() * digits
        };
        let table: Vec<(f64, f64)> = (0..=12)
            .map(|i| f64::from(i) * 25.0)
            .map(|t| (t, ohms(t)))
            .collect();
        let fitted = SteinhartHart::fit(&table).unwrap();
        for t in [0.0, 60.0, 210.0, 260.0, 300.0] {
            let err = fitted.celsius(ohms(t)) - t;
            assert!(err.abs() < 0.3, "{t} °C read {err:+.3} off");
        }
        // One resistance mistyped: 5 370 Ω at 100 °C, for 6 370 or so.
        let mut bad = table.clone();
        assert!((bad[4].1 - 6_370.0).abs() < 100.0, "{:?}", bad[4]);
        bad[4].1 -= 1_000.0;
        let e = SteinhartHart::fit(&bad).unwrap_err();
        assert!(e.contains(&format!("misses [100, {}]", bad[4].1)), "{e}");
    }

    #[test]
    fn tables_that_are_no_thermistor_are_refused_with_the_reason() {
        let fit = SteinhartHart::fit;
        assert!(fit(&[(25.0, 1e5), (150.0, 1641.9)])
            .unwrap_err()
            .contains("at least 3"));
        assert!(fit(&[(25.0, 1e5), (25.0, 1e4), (250.0, 226.0)])
            .unwrap_err()
            .contains("two points at 25"));
        assert!(fit(&[(1e5, 25.0), (1641.9, 150.0), (226.0, 250.0)])
            .unwrap_err()
            .contains("[°C, Ω]"));
        assert!(fit(&[(25.0, 1e5), (150.0, 2e5), (250.0, 226.0)])
            .unwrap_err()
            .contains("rises"));
        assert!(fit(&[(25.0, -1.0), (150.0, 1641.9), (250.0, 226.0)])
            .unwrap_err()
            .contains("not a thermistor's point"));
        assert!(fit(&[(f64::NAN, 1e5), (150.0, 1641.9), (250.0, 226.0)])
            .unwrap_err()
            .contains("not a thermistor's point"));
    }
}
