//! Nonlinear least squares: a [`Model`] with a few parameters fitted to
//! measured points by Levenberg–Marquardt (the `levenberg-marquardt`
//! crate), with each parameter's standard error from the covariance at the
//! optimum.

use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use nalgebra::{DMatrix, DVector, Dyn, Owned};

use crate::FitError;

/// A process model `y = f(params, x)`: the law the fit finds the
/// parameters of.
pub trait Model {
    /// The parameters' names, in the order `params` holds them.
    fn names(&self) -> &'static [&'static str];

    /// The model's prediction at `x` (one measurement's conditions).
    fn predict(&self, params: &[f64], x: &[f64]) -> f64;

    /// `∂predict/∂params` at `x`, into `out` (`names().len()` long). The
    /// default differentiates numerically (central differences).
    fn gradient(&self, params: &[f64], x: &[f64], out: &mut [f64]) {
        let mut p = params.to_vec();
        for (i, g) in out.iter_mut().enumerate() {
            let h = 1e-6 * params[i].abs().max(1e-6);
            p[i] = params[i] + h;
            let up = self.predict(&p, x);
            p[i] = params[i] - h;
            let down = self.predict(&p, x);
            p[i] = params[i];
            *g = (up - down) / (2.0 * h);
        }
    }
}

/// One measurement: the conditions `x` and the measured `y`.
#[derive(Debug, Clone, PartialEq)]
pub struct Point {
    /// The conditions (the model's inputs).
    pub x: Vec<f64>,
    /// What was measured.
    pub y: f64,
}

/// A fitted model.
#[derive(Debug, Clone, PartialEq)]
pub struct Fit {
    /// The parameters, in the model's order.
    pub params: Vec<f64>,
    /// Each parameter's standard error (one σ), from the covariance
    /// `s²·(JᵀJ)⁻¹` with `s²` the residual variance.
    pub std_errors: Vec<f64>,
    /// The covariance of the parameters.
    pub covariance: DMatrix<f64>,
    /// The root-mean-square residual, in `y`'s unit.
    pub rms_residual: f64,
    /// Points fitted.
    pub points: usize,
    /// Model evaluations the solver made.
    pub evaluations: usize,
}

impl Fit {
    /// The standard error of a function `g` of the parameters, given its
    /// gradient `∂g/∂params` at the fit (first-order propagation).
    pub fn std_error_of(&self, gradient: &[f64]) -> f64 {
        let g = DVector::from_column_slice(gradient);
        (g.transpose() * &self.covariance * &g)[(0, 0)]
            .max(0.0)
            .sqrt()
    }
}

struct Problem<'a, M: Model> {
    model: &'a M,
    points: &'a [Point],
    params: DVector<f64>,
}

impl<M: Model> LeastSquaresProblem<f64, Dyn, Dyn> for Problem<'_, M> {
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, Dyn>;
    type ParameterStorage = Owned<f64, Dyn>;

    fn set_params(&mut self, x: &DVector<f64>) {
        self.params.copy_from(x);
    }

    fn params(&self) -> DVector<f64> {
        self.params.clone()
    }

    fn residuals(&self) -> Option<DVector<f64>> {
        let p = self.params.as_slice();
        let r = DVector::from_iterator(
            self.points.len(),
            self.points
                .iter()
                .map(|pt| self.model.predict(p, &pt.x) - pt.y),
        );
        r.iter().all(|v| v.is_finite()).then_some(r)
    }

    fn jacobian(&self) -> Option<DMatrix<f64>> {
        let n = self.params.len();
        let p = self.params.as_slice();
        let mut j = DMatrix::zeros(self.points.len(), n);
        let mut row = vec![0.0; n];
        for (i, pt) in self.points.iter().enumerate() {
            self.model.gradient(p, &pt.x, &mut row);
            for (k, v) in row.iter().enumerate() {
                j[(i, k)] = *v;
            }
        }
        j.iter().all(|v| v.is_finite()).then_some(j)
    }
}

/// Fits `model` to `points` from the starting parameters `start`.
///
/// Refused: fewer points than parameters plus one (no residual variance
/// to judge the fit by), a start that does not evaluate, and a solver that
/// does not converge.
pub fn fit<M: Model>(model: &M, points: &[Point], start: &[f64]) -> Result<Fit, FitError> {
    let n = model.names().len();
    if start.len() != n {
        return Err(FitError::Shape(format!(
            "{} starting values for {n} parameters",
            start.len()
        )));
    }
    if points.len() <= n {
        return Err(FitError::TooFewPoints {
            points: points.len(),
            params: n,
        });
    }
    let problem = Problem {
        model,
        points,
        params: DVector::from_column_slice(start),
    };
    if problem.residuals().is_none() {
        return Err(FitError::NotFinite("the starting parameters".into()));
    }
    let (problem, report) = LevenbergMarquardt::new()
        .with_patience(200)
        .minimize(problem);
    if !report.termination.was_successful() {
        return Err(FitError::NoConvergence(format!("{:?}", report.termination)));
    }
    let residuals = problem
        .residuals()
        .ok_or_else(|| FitError::NotFinite("the fitted model".into()))?;
    let jacobian = problem
        .jacobian()
        .ok_or_else(|| FitError::NotFinite("the fitted model's gradient".into()))?;
    let ssr = residuals.norm_squared();
    let dof = (points.len() - n) as f64;
    let covariance = (jacobian.transpose() * &jacobian)
        .try_inverse()
        .ok_or_else(|| {
            FitError::Unidentifiable(format!(
                "the measurements do not separate the parameters {:?}: vary the conditions more",
                model.names()
            ))
        })?
        * (ssr / dof);
    let std_errors = (0..n).map(|i| covariance[(i, i)].max(0.0).sqrt()).collect();
    Ok(Fit {
        params: problem.params.as_slice().to_vec(),
        std_errors,
        covariance,
        rms_residual: (ssr / points.len() as f64).sqrt(),
        points: points.len(),
        evaluations: report.number_of_evaluations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `y = a·e^(b·x)`, with its gradient left to the default.
    struct Exponential;

    impl Model for Exponential {
        fn names(&self) -> &'static [&'static str] {
            &["a", "b"]
        }
        fn predict(&self, p: &[f64], x: &[f64]) -> f64 {
            p[0] * (p[1] * x[0]).exp()
        }
    }

    #[test]
    fn an_exact_model_is_recovered_and_its_errors_vanish() {
        let points: Vec<Point> = (0..20)
            .map(|i| {
                let x = f64::from(i) * 0.1;
                Point {
                    x: vec![x],
                    y: 3.0 * (-1.5 * x).exp(),
                }
            })
            .collect();
        let f = fit(&Exponential, &points, &[1.0, -0.5]).unwrap();
        assert!((f.params[0] - 3.0).abs() < 1e-8, "{:?}", f.params);
        assert!((f.params[1] + 1.5).abs() < 1e-8, "{:?}", f.params);
        assert!(f.rms_residual < 1e-9 && f.std_errors.iter().all(|e| *e < 1e-7));
    }

    #[test]
    fn standard_errors_match_the_scatter_of_repeated_fits() {
        // 200 fits of noisy data: the spread of the fitted b is what each
        // fit says its error is, within 20 %.
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut gauss = || {
            // Box–Muller on a xorshift.
            let mut u = || {
                seed ^= seed << 13;
                seed ^= seed >> 7;
                seed ^= seed << 17;
                (seed >> 11) as f64 / (1u64 << 53) as f64
            };
            let (a, b) = (u().max(1e-300), u());
            (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
        };
        let (mut bs, mut said) = (Vec::new(), Vec::new());
        for _ in 0..200 {
            let points: Vec<Point> = (0..30)
                .map(|i| {
                    let x = f64::from(i) * 0.1;
                    Point {
                        x: vec![x],
                        y: 3.0 * (-1.5 * x).exp() + 0.02 * gauss(),
                    }
                })
                .collect();
            let f = fit(&Exponential, &points, &[1.0, -0.5]).unwrap();
            bs.push(f.params[1]);
            said.push(f.std_errors[1]);
        }
        let mean = bs.iter().sum::<f64>() / bs.len() as f64;
        let spread =
            (bs.iter().map(|b| (b - mean).powi(2)).sum::<f64>() / (bs.len() - 1) as f64).sqrt();
        let typical = said.iter().sum::<f64>() / said.len() as f64;
        assert!(
            (mean + 1.5).abs() < 3.0 * spread / (bs.len() as f64).sqrt() + 1e-4,
            "{mean}"
        );
        assert!(
            (typical / spread - 1.0).abs() < 0.2,
            "said {typical}, scatter {spread}"
        );
    }

    #[test]
    fn too_few_points_and_unseparable_parameters_are_refused() {
        let two = vec![
            Point {
                x: vec![0.0],
                y: 1.0,
            },
            Point {
                x: vec![1.0],
                y: 2.0,
            },
        ];
        assert!(matches!(
            fit(&Exponential, &two, &[1.0, 0.1]),
            Err(FitError::TooFewPoints {
                points: 2,
                params: 2
            })
        ));
        // Every point at x = 0: b cannot be told.
        let flat: Vec<Point> = (0..5)
            .map(|_| Point {
                x: vec![0.0],
                y: 2.0,
            })
            .collect();
        assert!(matches!(
            fit(&Exponential, &flat, &[1.0, 0.1]),
            Err(FitError::Unidentifiable(_))
        ));
        assert!(matches!(
            fit(&Exponential, &flat, &[1.0]),
            Err(FitError::Shape(_))
        ));
    }
}
