//! A simulated spindle on a module's I/O pins (see
//! [`SpindleSpec`](crate::topology::SpindleSpec)): a rotor behind a drive
//! that a PWM output commands, and a tachometer that pulses a digital pin
//! as it turns.
//!
//! The drive is an ideal speed loop with a torque limit: it asks
//!
//! ```text
//! T = J·(ω_c − ω)/τ + drag + load,   held to ±max_torque
//! ```
//!
//! (integral action cancels the drag and load it can), and the rotor
//! follows `J·dω/dt = T − drag − load`, never turning backwards under a
//! load: below the limit the speed approaches `ω_c = duty × max_rpm` as a
//! first-order response of time constant `τ`; at the limit it ramps at
//! `(max_torque − drag − load)/J`, which a load past the limit makes a
//! stall. The state steps in closed form over steps of at most
//! [`STEP_S`] (exact within a regime), and every whole `1/pulses_per_rev`
//! of a turn is a rising edge on the tachometer's pin, timed within its
//! step by the angle. Time is seconds since the module booted.

use crate::topology::SpindleSpec;

/// The longest step of the closed-form update, s.
pub const STEP_S: f64 = 100e-6;

/// rad/s per rpm.
const RAD_PER_S_PER_RPM: f64 = std::f64::consts::TAU / 60.0;

/// The running model of one spindle.
#[derive(Debug, Clone)]
pub struct Spindle {
    spec: SpindleSpec,
    /// Seconds since boot the state is at.
    at: f64,
    /// Speed, rad/s (never negative).
    omega: f64,
    /// Turns since boot.
    turns: f64,
    /// The commanded duty since `at`, a fraction.
    duty: f64,
    /// The load torque since `at`, N·m.
    load_nm: f64,
    /// Tachometer edges since boot.
    edges: u64,
    /// When the newest edge was, s since boot.
    last_edge: f64,
}

impl Spindle {
    /// A spindle standing at boot, its drive commanded to 0.
    pub fn new(spec: SpindleSpec) -> Self {
        Spindle {
            spec,
            at: 0.0,
            omega: 0.0,
            turns: 0.0,
            duty: 0.0,
            load_nm: 0.0,
            edges: 0,
            last_edge: 0.0,
        }
    }

    /// What it is.
    pub fn spec(&self) -> &SpindleSpec {
        &self.spec
    }

    /// The speed at `secs` after boot (not before the latest event), rpm.
    pub fn rpm(&mut self, secs: f64) -> f64 {
        self.advance(secs);
        self.omega / RAD_PER_S_PER_RPM
    }

    /// The commanded duty, a fraction.
    pub fn duty(&self) -> f64 {
        self.duty
    }

    /// The load torque now, N·m.
    pub fn load_nm(&self) -> f64 {
        self.load_nm
    }

    /// The drive is commanded `duty` (of 65 535) from `secs` on.
    pub fn set_duty(&mut self, secs: f64, duty: u16) {
        self.advance(secs);
        self.duty = f64::from(duty) / 65_535.0;
    }

    /// A load of `nm` (a cut, or a tool caught in the work) from `secs` on.
    pub fn set_load(&mut self, secs: f64, nm: f64) {
        self.advance(secs);
        self.load_nm = if nm.is_finite() { nm.max(0.0) } else { 0.0 };
    }

    /// The tachometer's edges since boot (wrapping as a counter does) and
    /// when the newest was, s since boot (0 before any), at `secs`.
    pub fn edges(&mut self, secs: f64) -> (u32, f64) {
        self.advance(secs);
        (self.edges as u32, self.last_edge)
    }

    /// Moves the state to `secs` after boot.
    fn advance(&mut self, secs: f64) {
        while self.at < secs {
            let h = (secs - self.at).min(STEP_S);
            self.step(h);
        }
    }

    /// One step of `h` s in closed form, in the regime its start is in.
    fn step(&mut self, h: f64) {
        let s = &self.spec;
        let (j, tau) = (s.inertia_kgm2, s.time_constant_s);
        let target = self.duty * s.max_rpm * RAD_PER_S_PER_RPM;
        let resist = s.drag_nm + self.load_nm;
        let asked = j * (target - self.omega) / tau + resist;
        let w0 = self.omega;
        let (w1, angle) = if asked.abs() <= s.max_torque_nm {
            // Following: ω → target with time constant τ.
            let decay = (-h / tau).exp();
            let w1 = target + (w0 - target) * decay;
            (w1, target * h + (w0 - target) * tau * (1.0 - decay))
        } else {
            // At the torque limit: a constant acceleration, stopping at 0.
            let a = (asked.signum() * s.max_torque_nm - resist) / j;
            let run = if a < 0.0 { (w0 / -a).min(h) } else { h };
            (
                (w0 + a * run).max(0.0),
                (w0 * run + 0.5 * a * run * run).max(0.0),
            )
        };
        let before = self.turns;
        self.omega = w1.max(0.0);
        self.turns += angle / std::f64::consts::TAU;
        let ppr = f64::from(s.pulses_per_rev);
        let (n0, n1) = ((before * ppr).floor(), (self.turns * ppr).floor());
        if n1 > n0 {
            self.edges += (n1 - n0) as u64;
            // The newest edge: where the angle crossed it, within the step.
            let f = (n1 / ppr - before) / (self.turns - before);
            self.last_edge = self.at + h * f.clamp(0.0, 1.0);
        }
        self.at += h;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An 80 mm, 1.5 kW water-cooled spindle on a VFD: 2.5·10⁻⁴ kg·m²,
    /// 1.2 N·m at the torque limit, τ = 0.4 s, 0.02 N·m of drag, two
    /// pulses a turn.
    fn spec() -> SpindleSpec {
        SpindleSpec {
            pwm: 0,
            max_rpm: 24_000.0,
            tach_pin: 0,
            pulses_per_rev: 2,
            inertia_kgm2: 2.5e-4,
            max_torque_nm: 1.2,
            time_constant_s: 0.4,
            drag_nm: 0.02,
        }
    }

    #[test]
    fn spins_up_as_its_drive_allows_and_counts_its_pulses() {
        let mut s = Spindle::new(spec());
        s.set_duty(0.0, (0.75 * 65_535.0) as u16);
        // Torque-limited at first: the ramp is (1.2 − 0.02)/2.5e-4 = 4720
        // rad/s², until the error is 4720 · 0.4 = 1888 rad/s; 18 000 rpm
        // is 1885 rad/s, so the drive never saturates past the start.
        let w = 18_000.0 * RAD_PER_S_PER_RPM;
        for t in [0.1, 0.4, 1.0, 2.0] {
            let expect = w * (1.0 - (-t / 0.4_f64).exp());
            let got = s.rpm(t) * RAD_PER_S_PER_RPM;
            assert!((got - expect).abs() < 2.0, "{t}: {got} vs {expect}");
        }
        // Pulses: two a turn, the newest at the angle's crossing.
        let (edges, last) = s.edges(2.0);
        let turns = (w * 2.0 - w * 0.4 * (1.0 - (-5.0_f64).exp())) / std::f64::consts::TAU;
        assert!(
            (f64::from(edges) - 2.0 * turns).abs() <= 1.0,
            "{edges} {turns}"
        );
        assert!(last <= 2.0 && last > 2.0 - 1.0 / (2.0 * 300.0), "{last}");
        // A load past the torque limit stalls it, at (1.2 − 0.02 − 2)/J.
        s.set_load(2.0, 2.0);
        let at = s.rpm(2.0) * RAD_PER_S_PER_RPM;
        let a = (1.2 - 0.02 - 2.0) / 2.5e-4;
        let got = s.rpm(2.1) * RAD_PER_S_PER_RPM;
        assert!((got - (at + a * 0.1)).abs() < 1.0, "{got}");
        assert_eq!(s.rpm(3.0), 0.0);
        let (stopped, _) = s.edges(3.0);
        assert_eq!(s.edges(4.0).0, stopped);
    }
}
