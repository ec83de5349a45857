//! `[limits] model = "motors"`: each move's acceleration bounded by the
//! torque each motor has at the speed it turns (maxl's [`StepperModel`]),
//! over the masses it moves and its own rotor, times
//! `[limits] torque_margin`.
//!
//! For kinematics linear in the motors (cartesian, CoreXY), motor `m`
//! turns `q_m = Σ_i J_mi·x_i` (motor units per machine unit) and pushes
//! its belt or screw with `f = J⁻ᵀ·(m ⊙ ẍ)` (each axis's moving mass times
//! its acceleration). Moving along `u` at path speed `v` and accelerating
//! along `w` at `a`, the motor turns at `ω_m = κ_m·|J_m·u|·v` (`κ_m`
//! radians per motor unit) and needs
//!
//! ```text
//! τ_m = a · | I_rotor·κ_m·(J_m·w) + (J⁻ᵀ(m ⊙ w))_m / (10⁶·κ_m) |
//! ```
//!
//! (N·m; lengths in mm), so the largest acceleration is the smallest of
//! `margin·T_m(ω_m) / (τ_m / a)` over the modelled motors.

use maxl::blocks::planner::AccelModel;
use maxl::motor::StepperModel;
use nalgebra::DMatrix;

use super::drive::{start_position, Drive, MAX_AXES};
use super::MachineError;
use crate::config::MachineFile;

/// One modelled motor's share of the machine.
#[derive(Debug, Clone)]
struct Term {
    model: StepperModel,
    /// Radians per motor unit.
    kappa: f64,
    /// Motor units per machine unit of each axis slot.
    row: [f64; MAX_AXES],
    /// Its row of `J⁻ᵀ` times each axis's moving mass, kg.
    force: [f64; MAX_AXES],
}

/// The motors' acceleration model of a machine (see the module docs).
#[derive(Debug, Clone)]
pub struct MotorAccel {
    terms: Vec<Term>,
    margin: f64,
}

fn dot(a: &[f64; MAX_AXES], b: &[f64; MAX_AXES]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The drive of `cfg`, its motors' travel per axis unit `J` (motors ×
/// axes, at the start position: exact for linear kinematics), `J⁺`, and
/// each axis's moving mass.
type LinearMap = (Drive, DMatrix<f64>, DMatrix<f64>, Vec<f64>);

fn linear_map(cfg: &MachineFile) -> Result<LinearMap, MachineError> {
    let start = start_position(cfg);
    let drive = Drive::new(cfg, &start).map_err(|e| MachineError::Unsupported(e.to_string()))?;
    let n = drive.axes().len();
    let motors = drive.motors().len();
    let at = |p: &[f64]| -> Result<Vec<f64>, MachineError> {
        drive
            .motor_positions(p)
            .map_err(|e| MachineError::Unsupported(format!("motor model: {e}")))
    };
    let base = at(&start)?;
    let mut j = DMatrix::<f64>::zeros(motors, n);
    for k in 0..n {
        let mut p = start.clone();
        p[k] += 1.0;
        let moved = at(&p)?;
        for m in 0..motors {
            j[(m, k)] = moved[m] - base[m];
        }
    }
    let inverse = j
        .clone()
        .pseudo_inverse(1e-12)
        .map_err(|e| MachineError::Unsupported(format!("motor model: {e}")))?;
    let masses: Vec<f64> = cfg
        .axis_names()
        .iter()
        .map(|a| cfg.axes[*a].moving_mass_kg.unwrap_or(0.0))
        .collect();
    Ok((drive, j, inverse, masses))
}

/// Each modelled motor's load inertia on its shaft, kg·m²: the diagonal of
/// `J⁻ᵀ·diag(m)·J⁻¹` (kg per motor unit²) over `(10³·κ)²`. The coupling
/// between two belt motors (CoreXY with unequal masses) is left out: it is
/// what each simulated motor feels on its own.
pub fn reflected_inertia(cfg: &MachineFile) -> Result<Vec<(String, f64)>, MachineError> {
    let (drive, _, inverse, masses) = linear_map(cfg)?;
    let mut out = Vec::new();
    for (m, dm) in drive.motors().iter().enumerate() {
        let Some(keys) = cfg.motors.get(&dm.name).and_then(|c| c.model) else {
            continue;
        };
        let kappa = std::f64::consts::TAU * dm.full_steps_per_unit / keys.steps_per_rev;
        let kg: f64 = masses
            .iter()
            .enumerate()
            .map(|(k, mass)| inverse[(k, m)] * inverse[(k, m)] * mass)
            .sum();
        out.push((dm.name.clone(), kg / (1e3 * kappa).powi(2)));
    }
    Ok(out)
}

impl MotorAccel {
    /// The model of `cfg`'s modelled motors; `None` when none has a model.
    /// Kinematics must be linear in the motors (the file's validation
    /// checks that for `model = "motors"`).
    pub fn new(cfg: &MachineFile) -> Result<Option<MotorAccel>, MachineError> {
        let (drive, j, inverse, masses) = linear_map(cfg)?;
        let n = drive.axes().len();
        let mut terms = Vec::new();
        for (m, dm) in drive.motors().iter().enumerate() {
            let Some(keys) = cfg.motors.get(&dm.name).and_then(|c| c.model) else {
                continue;
            };
            let model = keys.model();
            let mut row = [0.0; MAX_AXES];
            let mut force = [0.0; MAX_AXES];
            for k in 0..n {
                row[k] = j[(m, k)];
                // J⁻ᵀ = (J⁺)ᵀ: entry (m, k) is J⁺(k, m).
                force[k] = inverse[(k, m)] * masses[k];
            }
            terms.push(Term {
                model,
                kappa: std::f64::consts::TAU * dm.full_steps_per_unit / model.steps_per_rev,
                row,
                force,
            });
        }
        Ok((!terms.is_empty()).then_some(MotorAccel {
            terms,
            margin: cfg.limits.torque_margin,
        }))
    }

    /// The share of the torque planned with.
    pub fn margin(&self) -> f64 {
        self.margin
    }

    /// The same model planning with `margin` of the torque.
    pub fn with_margin(mut self, margin: f64) -> MotorAccel {
        self.margin = margin;
        self
    }
}

impl AccelModel<MAX_AXES> for MotorAccel {
    fn max_accel(&self, motion: &[f64; MAX_AXES], accel: &[f64; MAX_AXES], speed: f64) -> f64 {
        let mut best = f64::INFINITY;
        for t in &self.terms {
            let need = (t.model.rotor_inertia_kgm2 * t.kappa * dot(&t.row, accel)
                + dot(&t.force, accel) / (1e6 * t.kappa))
                .abs();
            if need <= 0.0 {
                continue;
            }
            let omega = t.kappa * dot(&t.row, motion).abs() * speed;
            best = best.min(self.margin * t.model.torque_at(omega) / need);
        }
        best
    }
}
