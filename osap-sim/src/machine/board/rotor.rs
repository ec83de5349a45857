//! A stepper's rotor behind its driver: it follows the commanded step
//! position through a magnetic spring, and stalls when asked for more
//! torque than the motor has at its speed.
//!
//! The driver puts the rotor's equilibrium at the commanded position `c`
//! (full steps). The rotor, at `θ`, feels `T(|ω|)·sin(π/2·(c − θ))`, the
//! torque maxl's [`StepperModel`] gives at its speed, largest one full step
//! behind; its inertia is the rotor's plus the load reflected onto it, and
//! a viscous term damps its motion relative to the command's
//! (`damping_ratio` of the small-signal mode; the command's speed is the
//! step rate, averaged over [`RATE_TAU_S`]). It is integrated in steps of
//! at most [`MAX_DT_S`] between the step edges.
//!
//! More than two full steps behind (past the unstable equilibrium), the
//! rotor has slipped a pole: the motor **stalls**. From then on it takes no
//! step, whatever it is sent, until it has been sent nothing for
//! [`RESYNC_S`]; then the driver holds it where it stands. Every step sent
//! while stalled is lost: the carriage stays put and the module, open
//! loop, does not know.

use crate::topology::RotorSpec;
use osap_core::Instant;

/// The longest integration step, s.
pub const MAX_DT_S: f64 = 10e-6;
/// How long a stalled motor must be sent nothing before it holds again, s.
pub const RESYNC_S: f64 = 0.05;
/// How far behind the command (full steps) the rotor slips a pole.
pub const SLIP_STEPS: f64 = 2.0;
/// The time constant the command's speed is averaged over, s.
pub const RATE_TAU_S: f64 = 0.5e-3;

/// One stall: when it began and the full steps lost in it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stall {
    /// When the rotor slipped, local µs.
    pub local: Instant,
    /// Full steps sent while it was stalled.
    pub lost_full_steps: f64,
    /// When it held again, local µs (`None` while still stalled).
    pub end: Option<Instant>,
}

/// The rotor's state (see the module docs).
#[derive(Debug, Clone)]
pub struct Rotor {
    spec: RotorSpec,
    inertia: f64,
    damping: f64,
    /// Rotor and command, full steps; rotor speed, full steps/s.
    theta: f64,
    omega: f64,
    command: f64,
    at: Option<Instant>,
    stalled: bool,
    last_sent: Option<Instant>,
    /// The command's speed, full steps/s (averaged step rate).
    command_rate: f64,
    stalls: Vec<Stall>,
    /// The largest lag behind the command seen while following, full steps.
    worst_lag: f64,
}

impl Rotor {
    /// A rotor at rest on its command.
    pub fn new(spec: RotorSpec) -> Rotor {
        let inertia = spec.model.rotor_inertia_kgm2 + spec.load_inertia_kgm2;
        let damping = 2.0 * spec.damping_ratio * (spec.model.stiffness() * inertia).sqrt();
        Rotor {
            spec,
            inertia,
            damping,
            theta: 0.0,
            omega: 0.0,
            command: 0.0,
            at: None,
            stalled: false,
            last_sent: None,
            command_rate: 0.0,
            stalls: Vec::new(),
            worst_lag: 0.0,
        }
    }

    /// Integrates to local `to` with the command held.
    fn advance(&mut self, to: Instant) {
        let Some(from) = self.at else {
            self.at = Some(to);
            return;
        };
        if to <= from {
            return;
        }
        self.at = Some(to);
        if self.stalled {
            return;
        }
        let mut left = (to - from).as_secs_f64();
        // No step for a while: the command stands.
        if self
            .last_sent
            .is_none_or(|t| (to - t.min(to)).as_secs_f64() > 4.0 * RATE_TAU_S)
        {
            self.command_rate = 0.0;
        }
        let angle = self.spec.model.step_angle();
        while left > 0.0 {
            let lag = self.command - self.theta;
            // At rest on the command: nothing moves until the next step.
            if lag.abs() < 1e-12 && self.omega.abs() < 1e-9 && self.command_rate == 0.0 {
                self.theta = self.command;
                self.omega = 0.0;
                return;
            }
            let dt = left.min(MAX_DT_S);
            let w = self.omega * angle;
            let available = self.spec.model.torque_at(w);
            let spring =
                available * (0.5 * std::f64::consts::PI * lag.clamp(-SLIP_STEPS, SLIP_STEPS)).sin();
            let slip = (self.command_rate - self.omega) * angle;
            // The damping is the motor's own torque too: never beyond what
            // it has at this speed.
            let torque = (spring + self.damping * slip).clamp(-available, available);
            let acc = torque / self.inertia / angle;
            self.omega += acc * dt;
            self.theta += self.omega * dt;
            left -= dt;
        }
    }

    /// The motor is sent `delta` full steps at local `local`. Returns
    /// whether the carriage follows (false while stalled).
    pub fn step(&mut self, local: Instant, delta: f64) -> bool {
        self.advance(local);
        let since = self.last_sent.map(|t| (local - t.min(local)).as_secs_f64());
        let quiet = since.is_none_or(|s| s >= RESYNC_S);
        if let Some(dt) = since.filter(|&dt| dt > 0.0 && dt < 4.0 * RATE_TAU_S) {
            let k = (dt / RATE_TAU_S).min(1.0);
            self.command_rate += (delta / dt - self.command_rate) * k;
        }
        self.last_sent = Some(local);
        if self.stalled {
            if !quiet {
                if let Some(s) = self.stalls.last_mut() {
                    s.lost_full_steps += delta.abs();
                }
                return false;
            }
            // Held again where it stands.
            self.stalled = false;
            if let Some(s) = self.stalls.last_mut() {
                s.end = Some(local);
            }
            self.command = self.theta;
            self.omega = 0.0;
        }
        self.command += delta;
        let lag = (self.command - self.theta).abs();
        self.worst_lag = self.worst_lag.max(lag);
        if lag > SLIP_STEPS {
            self.stalled = true;
            self.omega = 0.0;
            self.command -= delta;
            self.stalls.push(Stall {
                local,
                lost_full_steps: delta.abs(),
                end: None,
            });
            return false;
        }
        true
    }

    /// The stalls so far.
    pub fn stalls(&self) -> &[Stall] {
        &self.stalls
    }

    /// Whether it is stalled now.
    pub fn stalled(&self) -> bool {
        self.stalled
    }

    /// The largest lag behind the command while following, full steps.
    pub fn worst_lag(&self) -> f64 {
        self.worst_lag
    }

    /// What it is.
    pub fn spec(&self) -> &RotorSpec {
        &self.spec
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use maxl::motor::StepperModel;

    fn spec(load: f64) -> RotorSpec {
        RotorSpec {
            model: StepperModel {
                holding_torque_nm: 0.45,
                rated_current_a: 2.0,
                resistance_ohm: 1.4,
                inductance_h: 3.0e-3,
                supply_v: 24.0,
                rotor_inertia_kgm2: 54e-7,
                steps_per_rev: 200.0,
            },
            load_inertia_kgm2: load,
            damping_ratio: 0.3,
        }
    }

    /// Runs a constant-acceleration ramp of `alpha` rad/s² up to `top`
    /// rad/s in sixteenth steps; returns whether it stalled.
    fn ramp(r: &mut Rotor, alpha: f64, top: f64) -> bool {
        let angle = r.spec.model.step_angle();
        let micro = 1.0 / 16.0;
        let mut t = 0.0f64;
        let mut sent = 0.0;
        while t < 2.0 {
            let t_top = top / alpha;
            let pos = if t < t_top {
                0.5 * alpha * t * t
            } else {
                0.5 * alpha * t_top * t_top + top * (t - t_top)
            } / angle;
            while sent + micro <= pos {
                sent += micro;
                let at = Instant::from_micros((t * 1e6) as u64);
                r.step(at, micro);
            }
            t += 1e-6;
        }
        !r.stalls().is_empty()
    }

    #[test]
    fn follows_within_its_torque_and_stalls_beyond_it() {
        // 0.45 N·m on 54 g·cm² and 2000 g·cm² of load: 2190 rad/s² at
        // rest. Ramps to 40 rad/s (6 rev/s, where the motor still has its
        // holding torque) at 60 % and 140 % of that.
        let s = spec(2000e-7);
        let limit = 0.45 / (54e-7 + 2000e-7);
        let mut ok = Rotor::new(s);
        assert!(!ramp(&mut ok, 0.6 * limit, 40.0), "stalled at 60 %");
        assert!(ok.worst_lag() < 1.0, "{}", ok.worst_lag());
        let mut over = Rotor::new(s);
        assert!(ramp(&mut over, 1.4 * limit, 40.0), "followed at 140 %");
        assert!(over.stalls()[0].lost_full_steps > 100.0);
    }

    #[test]
    fn a_stalled_motor_holds_again_after_a_pause() {
        let mut r = Rotor::new(spec(0.0));
        // A jump of 3 full steps at once slips it.
        assert!(!r.step(Instant::from_micros(1000), 3.0));
        assert!(r.stalled());
        assert!(!r.step(Instant::from_micros(2000), 0.1));
        // After 50 ms of nothing, it follows small steps again.
        assert!(r.step(Instant::from_micros(60_000), 0.0625));
        assert!(!r.stalled());
        assert_eq!(r.stalls().len(), 1);
        assert!((r.stalls()[0].lost_full_steps - 3.1).abs() < 1e-12);
    }
}
