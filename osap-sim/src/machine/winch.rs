//! A cable robot's physical world: a point mass in a vertical plane, held
//! by cables wound on spools, each spool on a simulated module's motor
//! ([`WinchSpec`]).
//!
//! Integrated with a fixed step of [`DT_S`] on the host's clock (virtual
//! under a paused tokio), up to whenever a motor's board reads its encoder
//! or changes its coils, so it runs as far as anything has looked:
//!
//! - **Motors** (maxl's [`StepperModel`]): the coils carry a current
//!   vector, a fraction `f` of the rated current at electrical angle `φ`,
//!   and the rotor at electrical angle `θe` (a full step is 90°) feels
//!   `T_hold·f·sin(φ − θe)`. The supply limits `f` at speed to
//!   `current_at(ω)/I_rated`. In torque mode the module sets the vector
//!   ([`StepperHw::drive_coils`](osap_module::board::StepperHw::drive_coils));
//!   in position mode the driver puts it at the microstep position its
//!   steps reached, at the rated current (a magnetic spring, damped at a
//!   ratio of 0.3 as a driver's decay damps it). A disabled driver's motor
//!   is held by its power-off brake.
//! - **Spools** of radius `r`: a positive turn pays cable out. Each spool's
//!   inertia is its drum's plus the rotor's; bearings and the cable's
//!   guide add Coulomb friction (smoothed over 0.01 rad/s) and viscous
//!   friction.
//! - **Cables** from each anchor to the mass: a cable's free length is its
//!   length at boot plus `r·θ`; stretched past it, it pulls with
//!   `k·stretch + c·rate`, never pushes (tension ≥ 0), and slack it does
//!   nothing.
//! - **The mass** under gravity and the cables' pulls.
//!
//! The encoder quantizes the shaft to `encoder_counts` a turn. Steps in
//! position mode reach the driver when the module's step words are
//! clocked out, up to the step generator's lead (2.3 ms) before their tick:
//! a winch runs its motion in torque mode, where no steps are made.

use crate::topology::WinchSpec;
use maxl::motor::StepperModel;
use std::f64::consts::{FRAC_PI_2, PI};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Instant;

/// The integration step, s (20 µs: the stiffest mode, a motor holding its
/// spool in position mode, rings at about 280 Hz).
pub const DT_S: f64 = 20e-6;
/// The speed below which Coulomb friction fades out, rad/s.
const STICTION_RAD_S: f64 = 0.01;
/// The damping ratio of a position-mode motor's magnetic spring.
const HOLD_DAMPING: f64 = 0.3;

/// What drives a motor's coils.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Coils {
    /// The driver's step input, at its microstep position (full steps).
    Steps(f64),
    /// The module, in torque mode: a current vector in fractions of the
    /// rated current.
    Driven { a: f64, b: f64 },
}

/// One spool and its motor.
#[derive(Debug, Clone)]
struct Spool {
    anchor: [f64; 2],
    radius: f64,
    inertia: f64,
    friction: f64,
    viscous: f64,
    /// The cable's free length with the shaft at 0, m.
    length0: f64,
    /// Shaft angle, rad, and speed, rad/s.
    theta: f64,
    omega: f64,
    coils: Coils,
    enabled: bool,
    /// The latest cable tension, N.
    tension: f64,
}

/// The winch's state (see the module docs).
#[derive(Debug, Clone)]
pub struct Plant {
    model: StepperModel,
    mass: f64,
    gravity: f64,
    stiffness: f64,
    damping: f64,
    counts: u32,
    hold_damping: f64,
    spools: Vec<Spool>,
    pos: [f64; 2],
    vel: [f64; 2],
    /// Host time of the state; `None` before anything looked.
    at: Option<Instant>,
    /// Seconds integrated since the first look.
    elapsed: f64,
}

impl Plant {
    /// The world `spec` describes, the mass at rest at its start, every
    /// cable just taut, every motor's brake on.
    pub fn new(spec: &WinchSpec) -> Plant {
        let model = spec.model;
        let inertia0 = model.rotor_inertia_kgm2;
        let spools: Vec<Spool> = spec
            .spools
            .iter()
            .map(|s| Spool {
                anchor: s.anchor,
                radius: s.radius_mm * 1e-3,
                inertia: s.inertia_kgm2 + inertia0,
                friction: s.friction_nm,
                viscous: s.viscous_nms,
                length0: dist(s.anchor, spec.start),
                theta: 0.0,
                omega: 0.0,
                coils: Coils::Steps(0.0),
                enabled: false,
                tension: 0.0,
            })
            .collect();
        let hold = spools.first().map_or(0.0, |s| {
            2.0 * HOLD_DAMPING * (model.stiffness() * s.inertia).sqrt()
        });
        Plant {
            model,
            mass: spec.mass_kg,
            gravity: spec.gravity,
            stiffness: spec.cable_stiffness_n_per_m,
            damping: spec.cable_damping_ns_per_m,
            counts: spec.encoder_counts,
            hold_damping: hold,
            spools,
            pos: spec.start,
            vel: [0.0; 2],
            at: None,
            elapsed: 0.0,
        }
    }

    /// Integrates in whole steps up to host time `to`.
    pub fn advance(&mut self, to: Instant) {
        let Some(from) = self.at else {
            self.at = Some(to);
            return;
        };
        let span = to.saturating_duration_since(from).as_secs_f64();
        let steps = (span / DT_S).floor() as u64;
        for _ in 0..steps {
            self.step(DT_S);
        }
        self.elapsed += steps as f64 * DT_S;
        self.at = Some(from + std::time::Duration::from_secs_f64(steps as f64 * DT_S));
    }

    /// Integrates up to the host's clock now.
    pub fn advance_to_now(&mut self) {
        self.advance(osap_host::clock::now());
    }

    fn step(&mut self, dt: f64) {
        let mut force = [0.0, -self.mass * self.gravity];
        let step_angle = self.model.step_angle();
        for s in &mut self.spools {
            let d = dist(s.anchor, self.pos);
            let u = [
                (s.anchor[0] - self.pos[0]) / d,
                (s.anchor[1] - self.pos[1]) / d,
            ];
            let free = s.length0 + s.radius * s.theta;
            let stretch = d - free;
            // d' = −u·v; the free length grows at r·ω.
            let rate = -(u[0] * self.vel[0] + u[1] * self.vel[1]) - s.radius * s.omega;
            s.tension = if stretch > 0.0 {
                (self.stiffness * stretch + self.damping * rate).max(0.0)
            } else {
                0.0
            };
            force[0] += s.tension * u[0];
            force[1] += s.tension * u[1];
            if !s.enabled {
                // The power-off brake holds the shaft.
                s.omega = 0.0;
                continue;
            }
            let theta_e = FRAC_PI_2 * s.theta / step_angle;
            let (fa, fb, hold) = match s.coils {
                Coils::Steps(c) => {
                    let phi = FRAC_PI_2 * c;
                    (phi.cos(), phi.sin(), true)
                }
                Coils::Driven { a, b } => (a, b, false),
            };
            let amp = fa.hypot(fb);
            let limit = self.model.current_at(s.omega) / self.model.rated_current_a;
            let scale = if amp > limit { limit / amp } else { 1.0 };
            let mut torque =
                self.model.holding_torque_nm * scale * (fb * theta_e.cos() - fa * theta_e.sin());
            if hold {
                torque -= self.hold_damping * s.omega;
            }
            let friction = s.friction * (s.omega / STICTION_RAD_S).tanh() + s.viscous * s.omega;
            let acc = (torque + s.radius * s.tension - friction) / s.inertia;
            s.omega += acc * dt;
            s.theta += s.omega * dt;
        }
        for ((v, p), f) in self.vel.iter_mut().zip(&mut self.pos).zip(force) {
            *v += f / self.mass * dt;
            *p += *v * dt;
        }
    }

    /// Motor `i`'s encoder: its shaft in Q16.16 full steps, quantized to
    /// the encoder's counts.
    pub fn read_shaft(&self, i: usize) -> Option<i64> {
        let s = self.spools.get(i)?;
        let counts = f64::from(self.counts);
        let count = (s.theta / (2.0 * PI) * counts).floor();
        let full = count * self.model.steps_per_rev / counts;
        Some((full * 65_536.0).round() as i64)
    }

    /// Motor `i`'s coils: the module's current vector (Q15 of the rated
    /// current), or `None`: back to the step input, which holds the shaft
    /// where it stands.
    pub fn drive_coils(&mut self, i: usize, coils: Option<maxl::phase::Coils>) {
        let steps_per_rad = self.model.steps_per_rev / (2.0 * PI);
        if let Some(s) = self.spools.get_mut(i) {
            s.coils = match coils {
                Some(c) => Coils::Driven {
                    a: f64::from(c.a) / 32_768.0,
                    b: f64::from(c.b) / 32_768.0,
                },
                None => Coils::Steps(s.theta * steps_per_rad),
            };
        }
    }

    /// Motor `i`'s driver takes a step of `full_steps`.
    pub fn step_motor(&mut self, i: usize, full_steps: f64) {
        if let Some(s) = self.spools.get_mut(i) {
            if let Coils::Steps(c) = &mut s.coils {
                *c += full_steps;
            }
        }
    }

    /// Motor `i`'s driver is powered (`true`) or off (its brake holds).
    pub fn set_enabled(&mut self, i: usize, on: bool) {
        let steps_per_rad = self.model.steps_per_rev / (2.0 * PI);
        if let Some(s) = self.spools.get_mut(i) {
            if on && !s.enabled {
                // The driver comes up holding where the shaft is.
                s.coils = Coils::Steps(s.theta * steps_per_rad);
            }
            s.enabled = on;
        }
    }

    /// Where the mass is, m.
    pub fn position(&self) -> [f64; 2] {
        self.pos
    }

    /// The mass's velocity, m/s.
    pub fn velocity(&self) -> [f64; 2] {
        self.vel
    }

    /// Each cable's tension, N, as of the latest step.
    pub fn tensions(&self) -> Vec<f64> {
        self.spools.iter().map(|s| s.tension).collect()
    }

    /// Each cable's free length, m.
    pub fn lengths(&self) -> Vec<f64> {
        self.spools
            .iter()
            .map(|s| s.length0 + s.radius * s.theta)
            .collect()
    }

    /// Seconds integrated.
    pub fn elapsed(&self) -> f64 {
        self.elapsed
    }
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// The winch, shared by the boards whose motors turn its spools and by
/// whoever watches it ([`SimMachine::winch`](super::SimMachine::winch)).
#[derive(Debug, Clone)]
pub struct SharedPlant(Arc<Mutex<Plant>>);

impl SharedPlant {
    /// A shared plant.
    pub fn new(plant: Plant) -> Self {
        SharedPlant(Arc::new(Mutex::new(plant)))
    }

    /// The plant, integrated up to the host's clock now. The guard locks
    /// it (every board on the winch waits): take what is needed and let it
    /// go; a second `now()` while one is held never returns.
    pub fn now(&self) -> MutexGuard<'_, Plant> {
        let mut p = self.0.lock().unwrap_or_else(|e| e.into_inner());
        p.advance_to_now();
        p
    }
}

/// One motor's place in the winch: what its simulated driver reaches.
#[derive(Debug, Clone)]
pub struct WinchMotor {
    /// The winch.
    pub plant: SharedPlant,
    /// Which spool.
    pub index: usize,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::topology::{SpoolSpec, WinchSpec};
    use std::time::Duration;

    fn nema17() -> StepperModel {
        StepperModel {
            holding_torque_nm: 0.45,
            rated_current_a: 2.0,
            resistance_ohm: 1.4,
            inductance_h: 3.0e-3,
            supply_v: 24.0,
            rotor_inertia_kgm2: 54e-7,
            steps_per_rev: 200.0,
        }
    }

    fn spec() -> WinchSpec {
        let spool = |anchor: [f64; 2]| SpoolSpec {
            module: String::new(),
            anchor,
            radius_mm: 12.0,
            inertia_kgm2: 1.7e-6,
            friction_nm: 0.002,
            viscous_nms: 1e-5,
        };
        WinchSpec {
            mass_kg: 1.0,
            start: [0.5, 0.5],
            gravity: 9.81,
            cable_stiffness_n_per_m: 20_000.0,
            cable_damping_ns_per_m: 20.0,
            encoder_counts: 16_384,
            model: nema17(),
            spools: vec![
                spool([0.0, 1.0]),
                spool([1.0, 1.0]),
                spool([1.0, 0.0]),
                spool([0.0, 0.0]),
            ],
        }
    }

    fn run(p: &mut Plant, t0: Instant, secs: f64) {
        p.advance(t0 + Duration::from_secs_f64(p.elapsed() + secs));
    }

    #[test]
    fn braked_spools_hold_the_mass_on_its_top_cables() {
        let mut p = Plant::new(&spec());
        let t0 = Instant::now();
        p.advance(t0);
        run(&mut p, t0, 1.0);
        // Statics: the two top cables at 45° share m·g: m·g/√2 each, the
        // bottom ones go slack; the mass sags by the cables' stretch.
        let t = p.tensions();
        let want = 9.81 / 2f64.sqrt();
        assert!((t[0] - want).abs() < 0.01 * want, "{t:?}");
        assert!((t[1] - want).abs() < 0.01 * want, "{t:?}");
        assert_eq!((t[2], t[3]), (0.0, 0.0));
        let sag = 0.5 - p.position()[1];
        let stretch = want / 20_000.0;
        assert!((sag - stretch * 2f64.sqrt()).abs() < 2e-5, "{sag}");
    }

    #[test]
    fn torque_from_the_coils_reels_the_mass_up_and_the_encoder_follows() {
        let mut p = Plant::new(&spec());
        let t0 = Instant::now();
        p.advance(t0);
        for i in 0..4 {
            p.set_enabled(i, true);
        }
        // Commutate every 200 µs from the encoder, as a module does: the
        // top cables pull with 0.15 N·m (12.5 N at 12 mm, more than the
        // 6.9 N each holds the mass with), the bottom ones keep 1 N.
        let fractions = [-0.15 / 0.45, -0.15 / 0.45, -0.012 / 0.45, -0.012 / 0.45];
        for _ in 0..(0.1 / 200e-6) as usize {
            for (i, f) in fractions.iter().enumerate() {
                let shaft = p.read_shaft(i).unwrap();
                let c = osap_module::torque::coils_for(shaft, *f as f32);
                p.drive_coils(i, Some(c));
            }
            run(&mut p, t0, 200e-6);
        }
        // Net upward pull: 2·(12.5 − 1)·sin 45° − 9.81 = 6.5 N (less the
        // spools' inertia and friction): the mass rises, and the encoders
        // read the top cables shortening as the mass does.
        let pos = p.position();
        assert!(pos[1] > 0.5 + 0.01, "{pos:?}");
        assert!((pos[0] - 0.5).abs() < 1e-3, "{pos:?}");
        let lengths = p.lengths();
        let shaft = p.read_shaft(0).unwrap() as f64 / 65_536.0;
        let from_encoder = dist([0.0, 1.0], [0.5, 0.5]) + shaft / 200.0 * 2.0 * PI * 0.012;
        assert!((from_encoder - lengths[0]).abs() < 2.0 * PI * 0.012 / 16_384.0 + 1e-9);
        assert!(lengths[0] < dist([0.0, 1.0], [0.5, 0.5]) - 0.007);
        // Every cable still pulls: none went slack.
        assert!(p.tensions().iter().all(|t| *t > 0.0), "{:?}", p.tensions());
    }

    #[test]
    fn a_held_motor_keeps_its_spool_where_the_steps_put_it() {
        let mut p = Plant::new(&spec());
        let t0 = Instant::now();
        p.advance(t0);
        for i in 0..4 {
            p.set_enabled(i, true);
        }
        run(&mut p, t0, 0.5);
        // 6.9 N at 12 mm is 0.083 N·m: 18 % of holding, a lag of
        // 2/π·asin(0.18) = 0.12 full steps.
        let lag = p.read_shaft(0).unwrap() as f64 / 65_536.0;
        assert!(lag > 0.05 && lag < 0.2, "{lag}");
        // Ten full steps in on the top spools, out on the bottom ones: the
        // spools follow, the mass rises.
        let y0 = p.position()[1];
        for _ in 0..160 {
            for (i, dir) in [-1.0, -1.0, 1.0, 1.0].into_iter().enumerate() {
                p.step_motor(i, dir / 16.0);
            }
            run(&mut p, t0, 1e-3);
        }
        run(&mut p, t0, 0.5);
        let rise = p.position()[1] - y0;
        // 10 full steps of 12 mm: 3.77 mm of cable each, √2 as much rise.
        let want = 10.0 / 200.0 * 2.0 * PI * 0.012 * 2f64.sqrt();
        assert!((rise - want).abs() < 0.05 * want, "{rise} vs {want}");
    }
}
