//! The melt-flow law of an extruder: the force a filament needs to push
//! molten plastic through the nozzle, a shear-thinning power law in the
//! volumetric flow with an exponential temperature shift,
//!
//! ```text
//! F = flow_k · Q^flow_n · exp(−temp_coeff · (T − t_ref))
//! ```
//!
//! F in newtons at the filament, Q in mm³/s, T in °C, `t_ref` a chosen
//! reference temperature (not fitted: it only rescales `flow_k`). Given a
//! force the drive can hold, the law says the largest flow at each
//! temperature ([`MeltModel::flow_at`]).

use crate::least_squares::{fit, Fit, Model, Point};
use crate::FitError;

/// The melt law with its parameters.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MeltModel {
    /// Force at 1 mm³/s and `t_ref`, N.
    pub flow_k: f64,
    /// The flow exponent (1: Newtonian; below 1: shear-thinning).
    pub flow_n: f64,
    /// How fast the melt thins as it warms, 1/°C.
    pub temp_coeff: f64,
    /// The reference temperature, °C.
    pub t_ref: f64,
}

/// A [`MeltModel`] fitted to measurements, with its uncertainty.
#[derive(Debug, Clone, PartialEq)]
pub struct MeltFit {
    /// The fitted law.
    pub model: MeltModel,
    /// The least-squares fit behind it (`params`: flow_k, flow_n,
    /// temp_coeff).
    pub fit: Fit,
}

/// The law as a [`Model`]: `x = [Q, T]`, params `[flow_k, flow_n,
/// temp_coeff]`.
struct Law {
    t_ref: f64,
}

impl Model for Law {
    fn names(&self) -> &'static [&'static str] {
        &["flow_k", "flow_n", "temp_coeff"]
    }

    fn predict(&self, p: &[f64], x: &[f64]) -> f64 {
        p[0] * x[0].powf(p[1]) * (-p[2] * (x[1] - self.t_ref)).exp()
    }

    fn gradient(&self, p: &[f64], x: &[f64], out: &mut [f64]) {
        let f = self.predict(p, x);
        out[0] = f / p[0];
        out[1] = f * x[0].ln();
        out[2] = -f * (x[1] - self.t_ref);
    }
}

impl MeltModel {
    /// The steady force at flow `q` (mm³/s) and temperature `t` (°C), N.
    pub fn force(&self, q: f64, t: f64) -> f64 {
        Law { t_ref: self.t_ref }.predict(&[self.flow_k, self.flow_n, self.temp_coeff], &[q, t])
    }

    /// The flow that needs `force_n` at `t` °C, mm³/s: the law inverted,
    /// so the largest flow a drive that may push `force_n` allows.
    pub fn flow_at(&self, force_n: f64, t: f64) -> f64 {
        (force_n / (self.flow_k * (-self.temp_coeff * (t - self.t_ref)).exp()))
            .powf(1.0 / self.flow_n)
    }

    /// The lowest temperature within `range` (°C) at which `flow` (mm³/s)
    /// needs at most `force_n`; `None` when even the top of the range
    /// does not suffice.
    pub fn lowest_temperature_for(
        &self,
        flow: f64,
        force_n: f64,
        range: (f64, f64),
    ) -> Option<f64> {
        // F falls with T: solve F(flow, T) = force_n for T.
        let t = self.t_ref
            - ((force_n / (self.flow_k * flow.powf(self.flow_n))).ln()) / self.temp_coeff;
        if t > range.1 {
            None
        } else {
            Some(t.max(range.0))
        }
    }
}

impl MeltFit {
    /// Fits the law to steady measurements `(Q mm³/s, T °C, F N)`, with
    /// `t_ref` the reference temperature (the middle of those measured
    /// suits). Every Q and F must be positive.
    pub fn fit(measurements: &[(f64, f64, f64)], t_ref: f64) -> Result<MeltFit, FitError> {
        if let Some(m) = measurements.iter().find(|(q, t, f)| {
            !(*q > 0.0 && *f > 0.0 && t.is_finite() && q.is_finite() && f.is_finite())
        }) {
            return Err(FitError::NotFinite(format!(
                "the measurement {m:?}: flows and forces must be positive"
            )));
        }
        let start = log_linear_start(measurements, t_ref)?;
        let points: Vec<Point> = measurements
            .iter()
            .map(|&(q, t, f)| Point {
                x: vec![q, t],
                y: f,
            })
            .collect();
        let fit = fit(&Law { t_ref }, &points, &start)?;
        let model = MeltModel {
            flow_k: fit.params[0],
            flow_n: fit.params[1],
            temp_coeff: fit.params[2],
            t_ref,
        };
        if !(model.flow_k > 0.0 && model.flow_n > 0.0) {
            return Err(FitError::Unidentifiable(format!(
                "the fitted law has flow_k {} and flow_n {}: the force does not rise with \
                 flow in these measurements",
                model.flow_k, model.flow_n
            )));
        }
        Ok(MeltFit { model, fit })
    }

    /// The flow at which the steady force reaches `force_n` at `t` °C
    /// ([`MeltModel::flow_at`]) and its standard error, mm³/s.
    pub fn max_flow(&self, t: f64, force_n: f64) -> (f64, f64) {
        let m = &self.model;
        let q = m.flow_at(force_n, t);
        // ln Q = (ln F − ln k + a(T − t_ref)) / n
        let n = m.flow_n;
        let gradient = [-1.0 / (n * m.flow_k), -q.ln() / n, (t - m.t_ref) / n];
        (q, q * self.fit.std_error_of(&gradient))
    }
}

/// Starting values from the law's logarithm, `ln F = ln k + n·ln Q −
/// a·(T − t_ref)`, which is linear in `(ln k, n, a)`.
fn log_linear_start(measurements: &[(f64, f64, f64)], t_ref: f64) -> Result<[f64; 3], FitError> {
    use nalgebra::{Matrix3, Vector3};
    let mut ata = Matrix3::zeros();
    let mut aty = Vector3::zeros();
    for &(q, t, f) in measurements {
        let row = Vector3::new(1.0, q.ln(), -(t - t_ref));
        ata += row * row.transpose();
        aty += row * f.ln();
    }
    let x = ata.lu().solve(&aty).ok_or_else(|| {
        FitError::Unidentifiable(
            "the measurements need at least two flows and two temperatures".into(),
        )
    })?;
    Ok([x[0].exp(), x[1], x[2]])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pla() -> MeltModel {
        MeltModel {
            flow_k: 2.2,
            flow_n: 0.45,
            temp_coeff: 0.018,
            t_ref: 210.0,
        }
    }

    #[test]
    fn max_flow_and_temperature_invert_the_law() {
        let m = pla();
        for t in [190.0, 210.0, 235.0] {
            let q = m.flow_at(20.0, t);
            assert!((m.force(q, t) - 20.0).abs() < 1e-9, "{t}: {q}");
            let back = m.lowest_temperature_for(q, 20.0, (150.0, 300.0)).unwrap();
            assert!((back - t).abs() < 1e-9);
        }
        assert_eq!(m.lowest_temperature_for(1e6, 20.0, (190.0, 240.0)), None);
        assert_eq!(
            m.lowest_temperature_for(0.1, 20.0, (190.0, 240.0)),
            Some(190.0)
        );
    }

    #[test]
    fn a_noiseless_grid_gives_back_the_law() {
        let m = pla();
        let mut data = Vec::new();
        for t in [195.0, 210.0, 225.0] {
            for q in [1.0, 2.0, 4.0, 8.0, 12.0] {
                data.push((q, t, m.force(q, t)));
            }
        }
        let f = MeltFit::fit(&data, 210.0).unwrap();
        assert!((f.model.flow_k - 2.2).abs() < 1e-7);
        assert!((f.model.flow_n - 0.45).abs() < 1e-7);
        assert!((f.model.temp_coeff - 0.018).abs() < 1e-9);
        let (q, err) = f.max_flow(210.0, 20.0);
        assert!((q - m.flow_at(20.0, 210.0)).abs() < 1e-6 && err < 1e-6);
    }

    #[test]
    fn one_temperature_cannot_give_the_temperature_shift() {
        let m = pla();
        let data: Vec<_> = [1.0, 2.0, 4.0, 8.0]
            .iter()
            .map(|&q| (q, 210.0, m.force(q, 210.0)))
            .collect();
        assert!(matches!(
            MeltFit::fit(&data, 210.0),
            Err(FitError::Unidentifiable(_))
        ));
        assert!(matches!(
            MeltFit::fit(
                &[
                    (1.0, 210.0, 0.0),
                    (2.0, 200.0, 1.0),
                    (3.0, 220.0, 1.0),
                    (4.0, 210.0, 2.0)
                ],
                210.0
            ),
            Err(FitError::NotFinite(_))
        ));
    }
}
